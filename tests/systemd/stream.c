/* A callback-stream reader that rides through broker restarts (tests/systemd/run.sh): a
 * bass_stream_start stream on broker NAME's port, one chunk per block from the live edge,
 * whose on_event returns 0 ("wait for the acquisition to go on") on every end. It checks that
 *   - the blocks tile: each block's first_frame is the previous block's end plus its `lost`,
 *     every block has the port's epoch and is a whole chunk;
 *   - every sample is the sim:pattern signal, or a zero of a block flagged GAP or
 *     DISCONTINUITY; the zeros read equal the growth of the port's gap_frames;
 *   - the events come as the docs say: an end (WRITER_GONE, DEVICE) is followed by exactly one
 *     RESUMED, at the frame after the last block, with the port's epoch, before any block; no
 *     other event (RESTARTED, STOPPED) in this test.
 * It prints one line per event and per run of zeros (its frames and the time from the last
 * block before it to the first after it), then
 *   stream: blocks B frames F loss L zero Z gaps G epoch E gap_frames P events SEQ errors X
 * (P: gap_frames grew by P while it read; SEQ: the events in order, W = writer gone,
 * D = device, R = resumed, "-" none).
 *   bass-stream NAME SECONDS         stops at the first block after SECONDS
 *   bass-stream NAME SECONDS K       starts while frames flow, stops at the first DEVICE
 *                                    event after the K-th RESUMED (a device that stalls
 *                                    again after every restart: sim:stall); SECONDS bounds it
 * Exit status 0 when the stream ended as asked without an error; a stream that goes silent
 * (no block and no event past its end) is stopped and reported. */
#include <bass.h>

#include <inttypes.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now_ms(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec * 1e3 + (double)t.tv_nsec / 1e6;
}

static void sleep_ms(long ms) {
  struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
  nanosleep(&t, NULL);
}

typedef struct {
  uint64_t epoch, nfc, rate, resumes_wanted;
  uint64_t next, blocks, frames, loss, zero, gaps, run, errors, shift, resumes, short_blocks;
  int have_next, have_shift, in_gap, paused, short_last;
  double t0_ms, last_block_ms, gap_from_ms, end_ms, paused_ms;
  char seq[64];
  size_t nseq;
  atomic_int done;
} ride;

#define ERR(s, ...)                                \
  do {                                             \
    if ((s)->errors++ < 8) {                       \
      printf("stream: ERROR: " __VA_ARGS__);       \
      printf("\n");                                \
      fflush(stdout);                              \
    }                                              \
  } while (0)

static const char *kind_name(uint32_t k) {
  switch (k) {
  case BASS_EVENT_STOPPED: return "STOPPED";
  case BASS_EVENT_RESTARTED: return "RESTARTED";
  case BASS_EVENT_DEVICE: return "DEVICE";
  case BASS_EVENT_WRITER_GONE: return "WRITER_GONE";
  case BASS_EVENT_REALTIME_REFUSED: return "REALTIME_REFUSED";
  case BASS_EVENT_RESUMED: return "RESUMED";
  default: return "unknown";
  }
}

static int on_block(const bass_block *b, void *user) {
  ride *s = user;
  double t = now_ms();
  if (b->epoch != s->epoch) ERR(s, "block at frame %" PRIu64 " of epoch %" PRIu64 ", the port's is %" PRIu64, b->first_frame, b->epoch, s->epoch);
  if (s->paused) ERR(s, "a block at frame %" PRIu64 " after an end without RESUMED", b->first_frame);
  if (s->have_next && b->first_frame != s->next + b->lost)
    ERR(s, "block at frame %" PRIu64 " does not tile: the previous ended before %" PRIu64 ", lost %" PRIu64, b->first_frame, s->next, b->lost);
  if (s->short_last) ERR(s, "a short block before frame %" PRIu64 " was not an acquisition's end", b->first_frame);
  s->short_last = b->frames != s->nfc;
  if (s->short_last) s->short_blocks++;
  if (b->n_channels != 2 || b->channels == NULL) {
    ERR(s, "block with %" PRIu32 " channels, planar %d", b->n_channels, b->channels != NULL);
    atomic_store(&s->done, 1);
    return 1;
  }
  s->loss += b->lost;
  const int32_t *left = b->channels[0], *right = b->channels[1];
  for (size_t i = 0; i < b->frames; i++) {
    uint64_t f = b->first_frame + i;
    if (left[i] == 0 && right[i] == 0) {
      if (!(b->flags & (BASS_CHUNK_GAP | BASS_CHUNK_DISCONTINUITY)))
        ERR(s, "frame %" PRIu64 " is zero in a block not flagged GAP (flags %" PRIu32 ")", f, b->flags);
      if (!s->in_gap) {
        s->in_gap = 1;
        s->run = 0;
        s->gap_from_ms = s->last_block_ms;
      }
      s->run++;
      s->zero++;
      continue;
    }
    uint64_t device = (uint64_t)((uint32_t)left[i] >> 6);
    uint64_t sh = (f - device) & 0x03FFFFFFu;
    if (s->in_gap) {
      s->in_gap = 0;
      s->gaps++;
      printf("stream: gap of %" PRIu64 " frames (%.1f ms of audio) before frame %" PRIu64
             "; %.1f ms from the last block before it to the first after\n",
             s->run, (double)s->run * 1e3 / (double)s->rate, f, t - s->gap_from_ms);
      fflush(stdout);
      s->have_shift = 0;
    }
    if (!s->have_shift) {
      s->shift = sh;
      s->have_shift = 1;
    }
    uint64_t d = f - s->shift;
    int32_t want_l = (int32_t)((uint32_t)((d & 0x03FFFFFFu) << 6));
    if (sh != s->shift || left[i] != want_l || right[i] != (int32_t)((uint32_t)want_l | 1u))
      ERR(s, "frame %" PRIu64 ": (%" PRId32 ", %" PRId32 ") is not the pattern", f, left[i], right[i]);
  }
  s->next = b->first_frame + b->frames;
  s->have_next = 1;
  s->blocks++;
  s->frames += b->frames;
  s->last_block_ms = t;
  if (t >= s->end_ms) {
    if (s->resumes_wanted) ERR(s, "%" PRIu64 " of %" PRIu64 " resumes seen in the time allowed", s->resumes, s->resumes_wanted);
    atomic_store(&s->done, 1);
    return 1;
  }
  return 0;
}

static int on_event(const bass_stream_event *e, void *user) {
  ride *s = user;
  double t = now_ms();
  printf("stream: event %s at %.0f ms: epoch %" PRIu64 " frame %" PRIu64 " code %" PRIu32 "%s%s; %.0f ms after the last block\n",
         kind_name(e->kind), t - s->t0_ms, e->epoch, e->frame, e->code, *e->message ? ": " : "", e->message,
         t - s->last_block_ms);
  fflush(stdout);
  if (s->nseq + 1 < sizeof s->seq) {
    s->seq[s->nseq++] = e->kind == BASS_EVENT_WRITER_GONE ? 'W'
                        : e->kind == BASS_EVENT_DEVICE    ? 'D'
                        : e->kind == BASS_EVENT_RESUMED   ? 'R'
                        : e->kind == BASS_EVENT_STOPPED   ? 'S'
                        : e->kind == BASS_EVENT_RESTARTED ? 'N'
                                                          : '?';
    s->seq[s->nseq] = 0;
  }
  if (e->epoch != s->epoch) ERR(s, "event %s with epoch %" PRIu64 ", the port's is %" PRIu64, kind_name(e->kind), e->epoch, s->epoch);
  s->short_last = 0;
  switch (e->kind) {
  case BASS_EVENT_WRITER_GONE:
  case BASS_EVENT_DEVICE:
    if (s->paused) ERR(s, "a second end (%s) without a RESUMED between", kind_name(e->kind));
    s->paused = 1;
    s->paused_ms = t;
    if (e->kind == BASS_EVENT_DEVICE && s->resumes_wanted && s->resumes >= s->resumes_wanted) {
      atomic_store(&s->done, 1);
      return 1;
    }
    return 0;
  case BASS_EVENT_RESUMED:
    if (!s->paused) ERR(s, "RESUMED without an end before it");
    if (s->have_next && e->frame != s->next) ERR(s, "RESUMED at frame %" PRIu64 ", the last block ended before %" PRIu64, e->frame, s->next);
    printf("stream: resumed %.0f ms after the end\n", t - s->paused_ms);
    fflush(stdout);
    s->paused = 0;
    s->resumes++;
    return 0;
  default:
    ERR(s, "unexpected event %s (%" PRIu32 ")", kind_name(e->kind), e->kind);
    atomic_store(&s->done, 1);
    return 1;
  }
}

int main(int argc, char **argv) {
  if (argc < 3) {
    fprintf(stderr, "usage: bass-stream NAME SECONDS [RESUMES]\n");
    return 2;
  }
  static ride s;
  const char *name = argv[1];
  double seconds = atof(argv[2]);
  s.resumes_wanted = argc > 3 ? strtoull(argv[3], NULL, 10) : 0;
  s.t0_ms = now_ms();
  s.end_ms = s.t0_ms + seconds * 1e3;
  strcpy(s.seq, "-");
  bass_port *port = NULL;
  bass_port_info info;
  if (bass_port_open(name, &port) != BASS_OK) {
    fprintf(stderr, "stream: open %s: %s\n", name, bass_last_error());
    return 2;
  }
  if (bass_port_get_info(port, &info) != BASS_OK || info.channels != 2) {
    fprintf(stderr, "stream: unusable port\n");
    return 2;
  }
  if (s.resumes_wanted) {
    /* Start while frames flow (not during a restart's burst of GAP zeros): the port
     * capturing, its writer alive, a new chunk since the last look, and that chunk the
     * device's (neither GAP nor DISCONTINUITY). */
    uint64_t lfi = info.last_frame_index;
    for (;;) {
      if (now_ms() > s.end_ms) {
        fprintf(stderr, "stream: the port %s never flowed\n", name);
        return 2;
      }
      sleep_ms(5);
      if (bass_port_get_info(port, &info) != BASS_OK) return 2;
      bass_chunk_info ci;
      if (info.state == BASS_STATE_CAPTURING && info.writer_alive && info.last_frame_index > lfi && lfi > 0 &&
          bass_port_chunk_info(port, info.last_frame_index, &ci) == BASS_OK &&
          !(ci.flags & (BASS_CHUNK_GAP | BASS_CHUNK_DISCONTINUITY)))
        break;
      lfi = info.last_frame_index;
    }
  }
  s.epoch = info.epoch;
  s.nfc = info.frames_per_chunk;
  s.rate = info.sample_rate;
  s.last_block_ms = now_ms();
  uint64_t gap0 = info.gap_frames;
  printf("stream: %s from frame %" PRIu64 ", epoch %" PRIu64 ", broker pid %" PRIu32 ", gap_frames %" PRIu64 "\n", name,
         info.last_frame_index + 1, s.epoch, info.writer_pid, gap0);
  fflush(stdout);
  bass_stream_config cfg;
  memset(&cfg, 0, sizeof cfg);
  cfg.start = BASS_START_NOW;
  bass_stream *stream = NULL;
  if (bass_stream_start(port, &cfg, on_block, on_event, &s, &stream) != BASS_OK) {
    fprintf(stderr, "stream: start: %s\n", bass_last_error());
    return 2;
  }
  /* The stream ends itself; past its end plus 10 s it has gone silent. */
  while (!atomic_load(&s.done) && now_ms() < s.end_ms + 10e3) sleep_ms(10);
  int silent = !atomic_load(&s.done);
  bass_result r = bass_stream_close(stream);
  if (silent)
    ERR(&s, "the stream went silent: no block for %.0f ms, %s, events %s", now_ms() - s.last_block_ms,
        s.paused ? "waiting after an end" : "not paused", s.seq);
  if (r != BASS_OK) ERR(&s, "bass_stream_close: %s: %s", bass_result_str(r), bass_last_error());
  if (s.paused && !s.resumes_wanted) ERR(&s, "ended waiting after an end without RESUMED");
  if (bass_port_get_info(port, &info) != BASS_OK) s.errors++;
  if (info.epoch != s.epoch) ERR(&s, "epoch changed %" PRIu64 " -> %" PRIu64, s.epoch, info.epoch);
  printf("stream: blocks %" PRIu64 " frames %" PRIu64 " loss %" PRIu64 " zero %" PRIu64 " gaps %" PRIu64 " epoch %" PRIu64
         " gap_frames %" PRIu64 " events %s errors %" PRIu64 "\n",
         s.blocks, s.frames, s.loss, s.zero, s.gaps, info.epoch, info.gap_frames - gap0, s.seq, s.errors);
  bass_port_close(port);
  return s.errors ? 1 : 0;
}
