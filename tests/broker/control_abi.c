/* The control-plane C ABI (bass_acquire, bass_acquire_devices[_channels], bass_stop, bass_status,
 * bass_broker_device_info, bass_replica_status, bass_list_devices) against real bassd processes started by tests/broker/run.sh: broker
 * "default" and broker "second" in $BASS_RUNTIME_DIR, both idle. Every check prints its name;
 * any failure exits 1. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bass.h"

static int failures = 0, passes = 0;

#define CHECK(cond, ...)                                                        \
  do {                                                                          \
    if (cond) {                                                                 \
      passes++;                                                                 \
    } else {                                                                    \
      failures++;                                                               \
      fprintf(stderr, "FAIL %s:%d: %s -- ", __FILE__, __LINE__, #cond);         \
      fprintf(stderr, __VA_ARGS__);                                             \
      fprintf(stderr, " (last error: %s)\n", bass_last_error());                \
    }                                                                           \
  } while (0)

static int32_t pattern(uint64_t frame, uint32_t channel) {
  return (int32_t)((((uint32_t)(frame & 0x03FFFFFFu)) << 6) | (channel & 63u));
}

static void test_list_devices(void) {
  size_t need = 0;
  bass_result r = bass_list_devices(NULL, NULL, 0, &need);
  CHECK(r == BASS_ERR_BUFFER_TOO_SMALL, "NULL buffer: %d", r);
  CHECK(need > 1, "bytes needed: %zu", need);
  char *buf = malloc(need);
  memset(buf, 'x', need);
  size_t need2 = 0;
  r = bass_list_devices(NULL, buf, need - 1, &need2);
  CHECK(r == BASS_ERR_BUFFER_TOO_SMALL && need2 == need, "one byte short: %d, %zu", r, need2);
  CHECK(buf[0] == 'x', "a too small buffer is not written");
  size_t len = 0;
  r = bass_list_devices(NULL, buf, need, &len);
  CHECK(r == BASS_OK, "list: %d", r);
  CHECK(len == need && strlen(buf) + 1 == len, "length %zu, strlen %zu", len, strlen(buf));
  CHECK(strstr(buf, "sim:pattern\tSimulated") != NULL, "sim:pattern listed with its description");
  CHECK(strstr(buf, "sim:sine\t") != NULL, "sim:sine listed");
  CHECK(buf[len - 2] == '\n', "lines end with a newline");
  free(buf);
}

static void test_acquire_read_stop(void) {
  bass_broker_status st;
  bass_result r = bass_status(NULL, &st);
  CHECK(r == BASS_OK && st.state == BASS_STATE_IDLE && st.epoch == 0, "idle before Acquire: %d %u", r, st.state);

  uint64_t epoch = 0;
  r = bass_acquire(NULL, "sim:pattern", 8000, 80, 10, 0, &epoch);
  CHECK(r == BASS_OK && epoch == 1, "acquire: %d, epoch %llu", r, (unsigned long long)epoch);

  bass_port *port = NULL;
  r = bass_port_open("default", &port);
  CHECK(r == BASS_OK, "open the port: %d", r);
  if (r != BASS_OK) return;
  uint64_t lfi = 0;
  r = bass_port_wait(port, 800, 20000, &lfi);
  CHECK(r == BASS_OK && lfi >= 800, "wait for frame 800: %d, %llu", r, (unsigned long long)lfi);
  int32_t left[800], right[800];
  uint64_t nfr = 1, loss = 0;
  size_t n = 0;
  r = bass_get_audio_data(port, 800, &nfr, left, right, &n, &loss);
  CHECK(r == BASS_OK && n == 800 && loss == 0 && nfr == 801, "read 800 frames: %d n=%zu loss=%llu", r, n,
        (unsigned long long)loss);
  int exact = 1;
  for (size_t i = 0; i < n; i++)
    exact &= left[i] == pattern(i + 1, 0) && right[i] == pattern(i + 1, 1);
  CHECK(exact, "samples are the sim:pattern");

  r = bass_status(NULL, &st);
  CHECK(r == BASS_OK && st.state == BASS_STATE_CAPTURING, "capturing: %d %u", r, st.state);
  CHECK(st.sample_rate == 8000 && st.frames_per_chunk == 80 && st.chunks_on_port == 10 && st.channels == 2,
        "geometry %u %u %u %u", st.sample_rate, st.frames_per_chunk, st.chunks_on_port, st.channels);
  CHECK(st.epoch == 1 && st.last_frame_index >= 800 && st.xruns == 0 && st.gap_frames == 0, "counters");
  CHECK(strcmp(st.device, "sim:pattern") == 0, "device %s", st.device);

  /* Refused requests: BASS_ERR_BROKER with the broker's message; nothing changes. */
  uint64_t untouched = 42;
  r = bass_acquire(NULL, "sim:pattern", 8000, 0, 10, 2, &untouched);
  CHECK(r == BASS_ERR_BROKER && untouched == 42, "zero nFramesPerChunk: %d", r);
  CHECK(strstr(bass_last_error(), "nFramesPerChunk = 0") != NULL, "message names the parameter");
  r = bass_acquire(NULL, "sim:nope", 8000, 80, 10, 2, NULL);
  CHECK(r == BASS_ERR_BROKER && strstr(bass_last_error(), "unknown simulated device") != NULL, "unknown sim: %d", r);
  r = bass_acquire(NULL, "sim:pattern", 8000, 80, 10, 65, NULL);
  CHECK(r == BASS_ERR_BROKER && strstr(bass_last_error(), "channels = 65") != NULL, "65 channels: %d", r);
  r = bass_status(NULL, &st);
  CHECK(r == BASS_OK && st.state == BASS_STATE_CAPTURING && st.epoch == 1, "still capturing epoch 1");

  r = bass_stop(NULL);
  CHECK(r == BASS_OK, "stop: %d", r);
  r = bass_status(NULL, &st);
  CHECK(r == BASS_OK && st.state == BASS_STATE_STOPPED, "stopped: %u", st.state);
  r = bass_port_wait(port, UINT64_C(1) << 40, 20000, &lfi);
  CHECK(r == BASS_ERR_STOPPED, "a waiting reader sees the stop: %d", r);
  r = bass_stop(NULL);
  CHECK(r == BASS_OK, "stop twice: %d", r);

  /* Acquire restarts with a new epoch; the old port handle reports the restart. */
  r = bass_acquire("default", "sim:sine", 48000, 480, 4, 1, &epoch);
  CHECK(r == BASS_OK && epoch == 2, "re-acquire: %d %llu", r, (unsigned long long)epoch);
  r = bass_port_wait(port, UINT64_C(1) << 40, 20000, &lfi);
  CHECK(r == BASS_ERR_RESTARTED, "old port: %d", r);
  bass_port_close(port);
  r = bass_status(NULL, &st);
  CHECK(r == BASS_OK && st.channels == 1 && st.sample_rate == 48000, "new parameters");

  /* The device fails to open: BASS_ERR_BROKER saying why, and nothing changed (the running
   * acquisition keeps its epoch and goes on; no error state). */
  r = bass_acquire(NULL, "bass_no_such_pcm", 48000, 480, 4, 2, NULL);
  CHECK(r == BASS_ERR_BROKER && strstr(bass_last_error(), "bass_no_such_pcm") != NULL, "bad ALSA device: %d", r);
  CHECK(strstr(bass_last_error(), "the port is unchanged (epoch 2") != NULL, "says what was kept: %s",
        bass_last_error());
  r = bass_status(NULL, &st);
  CHECK(r == BASS_OK && st.state != BASS_STATE_ERROR && st.error_code == BASS_DEVERR_NONE && st.epoch == 2,
        "unchanged: %u %u", st.state, st.error_code);
  bass_stop(NULL);
}

static void test_second_broker(void) {
  uint64_t epoch = 0;
  bass_result r = bass_acquire("second", "sim:silence", 16000, 160, 5, 2, &epoch);
  CHECK(r == BASS_OK && epoch == 1, "second broker acquire: %d", r);
  bass_broker_status a, b;
  CHECK(bass_status("second", &b) == BASS_OK && b.sample_rate == 16000, "second broker status");
  CHECK(bass_status("default", &a) == BASS_OK && a.epoch == 2, "default broker unaffected");
  CHECK(bass_stop("second") == BASS_OK, "second broker stop");
}

static void test_errors(void) {
  bass_broker_status st;
  memset(&st, 0x5a, sizeof st);
  bass_result r = bass_status("nobroker", &st);
  CHECK(r == BASS_ERR_NO_BROKER, "no broker: %d", r);
  CHECK(st.state == 0x5a5a5a5au, "outputs untouched on failure");
  r = bass_acquire("nobroker", "sim:sine", 48000, 480, 4, 2, NULL);
  CHECK(r == BASS_ERR_NO_BROKER, "acquire on no broker: %d", r);
  CHECK(bass_stop("nobroker") == BASS_ERR_NO_BROKER, "stop on no broker");
  size_t len;
  CHECK(bass_list_devices("nobroker", NULL, 0, &len) == BASS_ERR_NO_BROKER, "list on no broker");
  CHECK(bass_status("../etc", &st) == BASS_ERR_INVALID_ARGUMENT, "bad broker name");
  CHECK(bass_status(NULL, NULL) == BASS_ERR_NULL_ARGUMENT, "NULL out_status");
  CHECK(bass_acquire(NULL, NULL, 48000, 480, 4, 2, NULL) == BASS_ERR_NULL_ARGUMENT, "NULL device");
  CHECK(bass_list_devices(NULL, NULL, 0, NULL) == BASS_ERR_NULL_ARGUMENT, "NULL out_len");
}

/* bass_replica_status on a bassd: not a replica (BASS_ERR_NOT_FOUND, the message says so, the
 * output untouched); NULL output refused; a broker that is not running is NO_BROKER. The
 * replica side is read through the same call by tests/bridge/outage_long.sh (Python). */
static void test_replica_status_of_a_bassd(void) {
  bass_replica_info ri;
  memset(&ri, 0xAB, sizeof ri);
  bass_result r = bass_replica_status(NULL, &ri);
  CHECK(r == BASS_ERR_NOT_FOUND, "a bassd is no replica: %d", r);
  CHECK(strstr(bass_last_error(), "not a replica") != NULL, "the message says why: %s", bass_last_error());
  CHECK(ri.link_up == 0xABABABABu && (unsigned char)ri.source[0] == 0xAB, "nothing written on failure");
  r = bass_replica_status(NULL, NULL);
  CHECK(r == BASS_ERR_NULL_ARGUMENT, "NULL output: %d", r);
  r = bass_replica_status("nobody-runs-this", &ri);
  CHECK(r == BASS_ERR_NO_BROKER, "no such broker: %d", r);
}

/* Several devices on broker "second": the devices listed master first with their channels;
 * an index past them, NULL arguments, a bad count and a NULL name are refused. */
static void test_several_devices(void) {
  bass_device_info d;
  memset(&d, 0x5a, sizeof d);
  bass_result r = bass_broker_device_info("second", 0, &d);
  CHECK(r == BASS_OK && strcmp(d.role, "master") == 0 && strcmp(d.name, "sim:silence") == 0 && d.channels == 2,
        "one device: device 0 is the master: %d %s %s %u", r, d.role, d.name, d.channels);
  CHECK(bass_broker_device_info("second", 1, &d) == BASS_ERR_NOT_FOUND, "one device: no device 1");
  const char *devices[] = {"sim:field", "sim:field?ppm=87", "sim:field?ppm=-143&ch=2"};
  uint64_t epoch = 0;
  r = bass_acquire_devices("second", devices, 3, 48000, 480, 20, 2, &epoch);
  CHECK(r == BASS_OK && epoch == 2, "acquire three devices: %d, epoch %llu", r, (unsigned long long)epoch);
  bass_broker_status st;
  CHECK(bass_status("second", &st) == BASS_OK && st.channels == 6, "6 channels: %u", st.channels);
  for (uint32_t i = 0; i < 3; i++) {
    r = bass_broker_device_info("second", i, &d);
    CHECK(r == BASS_OK && strcmp(d.name, devices[i]) == 0 && d.first_channel == 2 * i && d.channels == 2,
          "device %u: %d %s first %u", i, r, d.name, d.first_channel);
    CHECK(strcmp(d.role, i == 0 ? "master" : "follower") == 0, "device %u role %s", i, d.role);
  }
  memset(&d, 0x5a, sizeof d);
  r = bass_broker_device_info("second", 3, &d);
  CHECK(r == BASS_ERR_NOT_FOUND && strstr(bass_last_error(), "3 device(s)") != NULL, "no device 3: %d", r);
  CHECK(d.channels == 0x5a5a5a5au, "nothing written on failure");
  CHECK(bass_broker_device_info("second", 0, NULL) == BASS_ERR_NULL_ARGUMENT, "NULL out_info");
  CHECK(bass_acquire_devices("second", NULL, 2, 48000, 480, 20, 2, NULL) == BASS_ERR_NULL_ARGUMENT, "NULL devices");
  r = bass_acquire_devices("second", devices, 0, 48000, 480, 20, 2, NULL);
  CHECK(r == BASS_ERR_INVALID_ARGUMENT && strstr(bass_last_error(), "devices_len = 0") != NULL, "no devices: %d", r);
  const char *holes[] = {"sim:field", NULL};
  CHECK(bass_acquire_devices("second", holes, 2, 48000, 480, 20, 2, NULL) == BASS_ERR_NULL_ARGUMENT, "NULL name");
  const char *bad[] = {"sim:field", "sim:field?ppm=fast"};
  r = bass_acquire_devices("second", bad, 2, 48000, 480, 20, 2, NULL);
  CHECK(r == BASS_ERR_BROKER && strstr(bass_last_error(), "ppm=\"fast\"") != NULL, "bad follower: %d", r);
  /* A channel count per device: master 2, follower 4 (6 channels), follower 2 at 2 + 4. */
  const uint32_t counts[] = {2, 4, 1};
  r = bass_acquire_devices_channels("second", devices, counts, 3, 48000, 480, 20, &epoch);
  CHECK(r == BASS_OK && epoch == 3, "acquire with per-device channels: %d, epoch %llu", r, (unsigned long long)epoch);
  CHECK(bass_status("second", &st) == BASS_OK && st.channels == 7, "2 + 4 + 1 channels: %u", st.channels);
  const uint32_t first[] = {0, 2, 6};
  for (uint32_t i = 0; i < 3; i++) {
    r = bass_broker_device_info("second", i, &d);
    CHECK(r == BASS_OK && d.first_channel == first[i] && d.channels == counts[i], "device %u: %d first %u channels %u", i,
          r, d.first_channel, d.channels);
  }
  CHECK(bass_acquire_devices_channels("second", devices, NULL, 3, 48000, 480, 20, NULL) == BASS_ERR_NULL_ARGUMENT,
        "NULL channels");
  r = bass_acquire_devices_channels("second", devices, counts, 9, 48000, 480, 20, NULL);
  CHECK(r == BASS_ERR_INVALID_ARGUMENT && strstr(bass_last_error(), "devices_len = 9") != NULL, "9 devices: %d", r);
  CHECK(bass_stop("second") == BASS_OK, "second broker stop");
}

int main(void) {
  test_list_devices();
  test_replica_status_of_a_bassd();
  test_acquire_read_stop();
  test_second_broker();
  test_several_devices();
  test_errors();
  printf("control_abi: %d passed, %d failed\n", passes, failures);
  return failures ? 1 : 0;
}
