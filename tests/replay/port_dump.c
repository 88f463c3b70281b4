/* tests/replay/port_dump.c: reads a port live through the C ABI, from frame 1 until its
 * acquisition ends, in blocks of BLOCK frames (a BASC-style client keeping up), and prints
 * what every call gave:
 *
 *   read NFR N LOSS                  each bass_get_audio_data_multi call that returned frames
 *                                    or a loss (NFR: the frame asked for)
 *   chunk FIRST FLAGS MONO REALTIME BOUND MISSING UNALIGNED
 *                                    once per chunk, from bass_port_chunk_info and
 *                                    bass_port_chunk_ext, when its first frame read arrives
 *                                    (BOUND 18446744073709551615: not known)
 *   frame F S0 S1 ...                every frame read, its samples
 *   end LAST STATE                   the port's last frame and state at the end
 *
 * Usage: port_dump BROKER BLOCK LIMIT_S. Exits 0 once the acquisition has stopped and every
 * frame was read, 1 on an error or after LIMIT_S seconds. tests/replay/compare.py checks the
 * output against the recording (WAV + sidecar). */
#define _POSIX_C_SOURCE 200809L
#include <bass.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double now_s(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + (double)t.tv_nsec / 1e9;
}

static int fail(const char *what, bass_result r) {
  fprintf(stderr, "port_dump: %s: %s (%s)\n", what, bass_result_str((int)r), bass_last_error());
  return 1;
}

/* Reads what is there from *nfr; returns the frames read, or -1 on an error. */
static long drain(const bass_port *port, uint64_t *nfr, size_t block, size_t nch, int32_t **ch,
                  uint32_t nfpc, uint64_t *last_chunk) {
  size_t n = 0;
  uint64_t loss = 0, asked = *nfr;
  bass_result r = bass_get_audio_data_multi(port, block, nfr, (int32_t *const *)ch, nch, &n, &loss);
  if (r != BASS_OK) {
    fail("bass_get_audio_data_multi", r);
    return -1;
  }
  if (n == 0 && loss == 0) return 0;
  printf("read %" PRIu64 " %zu %" PRIu64 "\n", asked, n, loss);
  uint64_t first = *nfr - n;
  for (size_t i = 0; i < n; i++) {
    uint64_t f = first + i;
    uint64_t c = (f - 1) / nfpc;
    if (c != *last_chunk) {
      bass_chunk_info ci;
      bass_chunk_ext ext;
      bass_result rc = bass_port_chunk_info(port, f, &ci);
      if (rc == BASS_OK) rc = bass_port_chunk_ext(port, f, &ext);
      if (rc == BASS_OK && ext.first_frame != ci.first_frame) rc = BASS_ERR_CORRUPT;
      if (rc == BASS_OK) {
        printf("chunk %" PRIu64 " %" PRIu32 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 "\n",
               ci.first_frame, ci.flags, ci.mono_ns, ci.realtime_ns, ext.bound_ns, ext.missing_channels,
               ext.unaligned_channels);
      } else {
        printf("chunk-missing %" PRIu64 " %d\n", c * nfpc + 1, (int)rc);
      }
      *last_chunk = c;
    }
    printf("frame %" PRIu64, f);
    for (size_t k = 0; k < nch; k++) printf(" %" PRId32, ch[k][i]);
    printf("\n");
  }
  return (long)n + (long)(loss > 0);
}

int main(int argc, char **argv) {
  if (argc != 4) {
    fprintf(stderr, "usage: port_dump BROKER BLOCK LIMIT_S\n");
    return 2;
  }
  size_t block = (size_t)strtoul(argv[2], NULL, 10);
  double limit = strtod(argv[3], NULL);
  if (block == 0 || block > 1u << 20 || !(limit > 0)) {
    fprintf(stderr, "port_dump: bad BLOCK %s or LIMIT_S %s\n", argv[2], argv[3]);
    return 2;
  }
  bass_port *port = NULL;
  bass_result r = bass_port_open(argv[1], &port);
  if (r != BASS_OK) return fail("bass_port_open", r);
  bass_port_info info;
  r = bass_port_get_info(port, &info);
  if (r != BASS_OK) return fail("bass_port_get_info", r);
  size_t nch = info.channels;
  int32_t *bufs[64];
  if (nch == 0 || nch > 64) {
    fprintf(stderr, "port_dump: the port has %zu channels\n", nch);
    return 1;
  }
  for (size_t k = 0; k < nch; k++) {
    bufs[k] = calloc(block, sizeof(int32_t));
    if (!bufs[k]) return 1;
  }
  uint64_t nfr = 1, last_chunk = UINT64_MAX;
  double deadline = now_s() + limit;
  int status = 1;
  while (now_s() < deadline) {
    uint64_t lfi = 0;
    r = bass_port_wait(port, nfr, 200, &lfi);
    if (r == BASS_OK) {
      if (drain(port, &nfr, block, nch, bufs, info.frames_per_chunk, &last_chunk) < 0) break;
      continue;
    }
    if (r == BASS_ERR_TIMEOUT || r == BASS_ERR_INTERRUPTED) continue;
    if (r == BASS_ERR_STOPPED) {
      long got;
      while ((got = drain(port, &nfr, block, nch, bufs, info.frames_per_chunk, &last_chunk)) > 0) {
      }
      if (got < 0) break;
      r = bass_port_get_info(port, &info);
      if (r != BASS_OK) return fail("bass_port_get_info", r);
      printf("end %" PRIu64 " %s\n", info.last_frame_index, bass_state_str(info.state));
      status = 0;
      break;
    }
    fail("bass_port_wait", r);
    break;
  }
  if (status != 0 && now_s() >= deadline) fprintf(stderr, "port_dump: no end within %g s\n", limit);
  for (size_t k = 0; k < nch; k++) free(bufs[k]);
  bass_port_close(port);
  return status;
}
