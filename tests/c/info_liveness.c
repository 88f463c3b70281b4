/* bass_port_get_info answers whether the writer lives without reading /proc on every call
 * (a pidfd opened once: libbassclient/src/reader/liveness.rs). Run under strace by
 * tests/c/run.sh, which counts the opens of /proc/PID/stat: one per writer, not one per call.
 * Every answer must still say the writer (this process) is alive. */
#include <bass.h>

#include <stdio.h>
#include <stdlib.h>

#include "check.h"

#define CALLS 2000

int main(void) {
  bass_writer *w = NULL;
  bass_port *p = NULL;
  bass_port_info info;
  EXPECT(bass_writer_create("liveness", "sim", 48000, 256, 8, 2, &w), BASS_OK);
  EXPECT(bass_port_open("liveness", &p), BASS_OK);
  unsigned alive = 0;
  for (int i = 0; i < CALLS; i++) {
    EXPECT(bass_port_get_info(p, &info), BASS_OK);
    alive += info.writer_alive;
  }
  CHECK(alive == CALLS);
  EXPECT(bass_port_close(p), BASS_OK);
  EXPECT(bass_writer_close(w), BASS_OK);
  printf("info_liveness: %d calls of bass_port_get_info, writer alive in %u\n", CALLS, alive);
  return failures != 0;
}
