/* A reader that rides through broker restarts (tests/systemd/run.sh): reads broker NAME's
 * port chunk by chunk from the live edge with bass_port_wait and bass_get_audio_data, in the
 * loop of docs/c-api.md ("Reading"): BASS_ERR_WRITER_GONE and BASS_ERR_DEVICE are a pause (the
 * last frames before the end are read, then it waits for the acquisition to go on), a timeout
 * waits again, anything else is an error. It checks every sample (the sim:pattern signal, or
 * zeros for frames the broker missed) and prints one line per pause and per run of zeros (a
 * restart's gap: its frames and the time from the last chunk before it to the first after
 * it), then a summary line:
 *   ride: frames F loss L zero Z gaps G epoch E gap_frames P errors X pauses N timeouts T
 * (P: how much the port's gap_frames grew while it read.)
 *   bass-ride NAME SECONDS       reads for SECONDS
 *   bass-ride NAME SECONDS K     starts while frames flow, stops at the first BASS_ERR_DEVICE
 *                                after K pauses that ended (sim:stall, which stalls again
 *                                after every restart); SECONDS bounds it
 * Exit status 0 when it read to the end without an error. */
#include <bass.h>

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define CHUNK_MAX 4096

static double now_ms(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec * 1e3 + (double)t.tv_nsec / 1e6;
}

static void sleep_ms(long ms) {
  struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
  nanosleep(&t, NULL);
}

static int32_t left[CHUNK_MAX], right[CHUNK_MAX];
static uint64_t zero, gaps, errors, shift, run, rate;
static int have_shift, in_gap;
static double last_chunk_ms, gap_from_ms;

/* Checks frames first .. first + n - 1 read into left/right at time t. */
static void check(uint64_t first, size_t n, double t) {
  for (size_t i = 0; i < n; i++) {
    uint64_t f = first + i;
    if (left[i] == 0 && right[i] == 0) {
      if (!in_gap) {
        in_gap = 1;
        run = 0;
        gap_from_ms = last_chunk_ms;
      }
      run++;
      zero++;
      continue;
    }
    uint64_t device = (uint64_t)((uint32_t)left[i] >> 6);
    uint64_t s = (f - device) & 0x03FFFFFFu;
    if (in_gap) {
      in_gap = 0;
      gaps++;
      printf("ride: gap of %" PRIu64 " frames (%.1f ms of audio) before frame %" PRIu64
             "; %.1f ms from the last chunk before it to the first after\n",
             run, (double)run * 1e3 / (double)rate, f, t - gap_from_ms);
      fflush(stdout);
      have_shift = 0;
    }
    if (!have_shift) {
      shift = s;
      have_shift = 1;
    }
    uint64_t d = f - shift;
    int32_t want_l = (int32_t)((uint32_t)((d & 0x03FFFFFFu) << 6));
    if (s != shift || left[i] != want_l || right[i] != (int32_t)((uint32_t)want_l | 1u)) {
      if (errors++ < 5) {
        printf("ride: frame %" PRIu64 ": (%" PRId32 ", %" PRId32 ") is not the pattern\n", f, left[i], right[i]);
      }
    }
  }
  if (n > 0) last_chunk_ms = t;
}

int main(int argc, char **argv) {
  if (argc < 3) {
    fprintf(stderr, "usage: bass-ride NAME SECONDS [PAUSES]\n");
    return 2;
  }
  const char *name = argv[1];
  double seconds = atof(argv[2]);
  uint64_t pauses_wanted = argc > 3 ? strtoull(argv[3], NULL, 10) : 0;
  bass_port *port = NULL;
  bass_port_info info;
  double t0 = now_ms(), end = t0 + seconds * 1e3;
  bass_result r = bass_port_open(name, &port);
  if (r != BASS_OK) {
    fprintf(stderr, "ride: open %s: %s\n", name, bass_last_error());
    return 2;
  }
  if (bass_port_get_info(port, &info) != BASS_OK || info.frames_per_chunk > CHUNK_MAX || info.channels != 2) {
    fprintf(stderr, "ride: unusable port\n");
    return 2;
  }
  if (pauses_wanted) {
    /* Start while frames flow: capturing, the writer alive, a new chunk since the last look,
     * and that chunk the device's (not one of the GAP zeros a resumed broker publishes at once). */
    uint64_t lfi = info.last_frame_index;
    for (;;) {
      if (now_ms() > end) {
        fprintf(stderr, "ride: the port %s never flowed\n", name);
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
  rate = info.sample_rate;
  uint64_t epoch = info.epoch, nfc = info.frames_per_chunk, nfr = info.last_frame_index + 1, gap0 = info.gap_frames;
  uint64_t frames = 0, loss = 0, pauses = 0, resumed = 0, timeouts = 0;
  int paused = 0, done = 0;
  double paused_ms = 0;
  last_chunk_ms = now_ms();
  printf("ride: %s from frame %" PRIu64 ", epoch %" PRIu64 ", broker pid %u\n", name, nfr, epoch, info.writer_pid);
  fflush(stdout);
  while (!done) {
    if (now_ms() >= end) {
      if (pauses_wanted) {
        printf("ride: %" PRIu64 " of %" PRIu64 " pauses ended in the time allowed\n", resumed, pauses_wanted);
        errors++;
      }
      break;
    }
    r = bass_port_wait(port, nfr + nfc - 1, 1000, NULL);
    double t = now_ms();
    if (r == BASS_OK && paused) {
      paused = 0;
      resumed++;
      printf("ride: goes on %.0f ms after the pause\n", t - paused_ms);
      fflush(stdout);
    } else if (r == BASS_ERR_TIMEOUT) {
      timeouts++;
      continue;
    } else if (r == BASS_ERR_DEVICE || r == BASS_ERR_WRITER_GONE) {
      if (!paused) {
        paused = 1;
        paused_ms = t;
        pauses++;
        printf("ride: paused at %.0f ms, %.0f ms after the last chunk: %s: %s\n", t - t0, t - last_chunk_ms,
               bass_result_str(r), bass_last_error());
        fflush(stdout);
        done = r == BASS_ERR_DEVICE && pauses_wanted && resumed >= pauses_wanted;
      }
    } else if (r != BASS_OK) {
      printf("ride: error at frame %" PRIu64 ": %s: %s\n", nfr, bass_result_str(r), bass_last_error());
      errors++;
      break;
    }
    /* A full chunk on BASS_OK; on an end the last frames before it, then nothing. */
    for (;;) {
      size_t n = 0;
      uint64_t l = 0, first = nfr;
      bass_result g = bass_get_audio_data(port, (size_t)nfc, &nfr, left, right, &n, &l);
      if (g != BASS_OK) {
        printf("ride: getAudioData: %s\n", bass_last_error());
        errors++;
        done = 1;
        break;
      }
      loss += l;
      check(first + l, n, t);
      frames += n;
      if (r == BASS_OK || n == 0) break;
    }
    if (paused && !done) sleep_ms(100);
  }
  if (bass_port_get_info(port, &info) != BASS_OK) {
    errors++;
  }
  if (info.epoch != epoch) {
    printf("ride: epoch changed %" PRIu64 " -> %" PRIu64 "\n", epoch, info.epoch);
    errors++;
  }
  if (paused && !pauses_wanted) {
    printf("ride: ended in a pause\n");
    errors++;
  }
  printf("ride: frames %" PRIu64 " loss %" PRIu64 " zero %" PRIu64 " gaps %" PRIu64 " epoch %" PRIu64
         " gap_frames %" PRIu64 " errors %" PRIu64 " pauses %" PRIu64 " timeouts %" PRIu64 "\n",
         frames, loss, zero, gaps, info.epoch, info.gap_frames - gap0, errors, pauses, timeouts);
  bass_port_close(port);
  return errors ? 1 : 0;
}
