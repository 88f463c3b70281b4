/* A reader that rides through broker restarts (tests/systemd/run.sh): reads the default
 * broker's port chunk by chunk from the live edge for SECONDS seconds with bass_port_wait and
 * bass_get_audio_data, checks every sample (the sim:pattern signal, or zeros for frames the
 * broker missed), and prints one line per run of zeros (a restart's gap: its frames and the
 * time from the last chunk before it to the first after it), then a summary line:
 *   ride: frames F loss L zero Z gaps G epoch E gap_frames P errors X
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

int main(int argc, char **argv) {
  double seconds = argc > 1 ? atof(argv[1]) : 10.0;
  static int32_t left[CHUNK_MAX], right[CHUNK_MAX];
  bass_port *port = NULL;
  bass_port_info info;
  bass_result r = bass_port_open("default", &port);
  if (r != BASS_OK) {
    fprintf(stderr, "ride: open: %s\n", bass_last_error());
    return 2;
  }
  if (bass_port_get_info(port, &info) != BASS_OK || info.frames_per_chunk > CHUNK_MAX || info.channels != 2) {
    fprintf(stderr, "ride: unusable port\n");
    return 2;
  }
  uint64_t epoch = info.epoch, nfc = info.frames_per_chunk, nfr = info.last_frame_index + 1;
  uint64_t frames = 0, loss = 0, zero = 0, gaps = 0, errors = 0, shift = 0, run = 0;
  int have_shift = 0, in_gap = 0;
  double last_chunk_ms = now_ms(), gap_from_ms = 0, end = now_ms() + seconds * 1e3;
  printf("ride: from frame %" PRIu64 ", epoch %" PRIu64 ", broker pid %u\n", nfr, epoch, info.writer_pid);
  fflush(stdout);
  while (now_ms() < end) {
    r = bass_port_wait(port, nfr + nfc - 1, 20000, NULL);
    if (r != BASS_OK) {
      printf("ride: error at frame %" PRIu64 ": %s: %s\n", nfr, bass_result_str(r), bass_last_error());
      errors++;
      break;
    }
    size_t n = 0;
    uint64_t l = 0, first = nfr;
    r = bass_get_audio_data(port, (size_t)nfc, &nfr, left, right, &n, &l);
    if (r != BASS_OK) {
      printf("ride: getAudioData: %s\n", bass_last_error());
      errors++;
      break;
    }
    double t = now_ms();
    loss += l;
    first += l;
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
               run, (double)run * 1e3 / info.sample_rate, f, t - gap_from_ms);
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
    frames += n;
    last_chunk_ms = t;
  }
  if (bass_port_get_info(port, &info) != BASS_OK) {
    errors++;
  }
  if (info.epoch != epoch) {
    printf("ride: epoch changed %" PRIu64 " -> %" PRIu64 "\n", epoch, info.epoch);
    errors++;
  }
  printf("ride: frames %" PRIu64 " loss %" PRIu64 " zero %" PRIu64 " gaps %" PRIu64 " epoch %" PRIu64
         " gap_frames %" PRIu64 " errors %" PRIu64 "\n",
         frames, loss, zero, gaps, info.epoch, info.gap_frames, errors);
  bass_port_close(port);
  return errors ? 1 : 0;
}
