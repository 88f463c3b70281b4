/* The C ABI of libbassclient, called from C exactly as users will: every exported port
 * function, with good and bad arguments. Each call must return its documented code and
 * nothing may crash. Run by tests/c/run.sh with BASS_RUNTIME_DIR set to a fresh directory,
 * built with -Wall -Wextra -Wpedantic -Werror, once plain and once under ASan/UBSan. */
#define _POSIX_C_SOURCE 200809L
#include "bass.h"
#include "check.h"

#include <fcntl.h>
#include <inttypes.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

enum { NFPC = 4, NCOP = 3, NFOP = NFPC * NCOP, CH = 2 };

static char dir[4096];

static void path_of(char *out, size_t len, const char *file) {
    snprintf(out, len, "%s/%s", dir, file);
}

/* Copies the port file `src` to `dst`, optionally truncated to `len` bytes, and with
 * `patch_len` bytes at `patch_off` replaced. */
static void copy_port(const char *src, const char *dst, long len, long patch_off, const void *patch,
                      size_t patch_len) {
    FILE *in = fopen(src, "rb");
    FILE *out = fopen(dst, "wb");
    if (!in || !out) {
        perror("copy_port");
        exit(2);
    }
    static char buf[1 << 16];
    long total = 0;
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, in)) > 0) {
        if (len >= 0 && total + (long)n > len) n = (size_t)(len - total);
        if (total <= patch_off && patch_off < total + (long)n)
            memcpy(buf + (patch_off - total), patch, patch_len);
        fwrite(buf, 1, n, out);
        total += (long)n;
        if (len >= 0 && total >= len) break;
    }
    fclose(in);
    fclose(out);
}

static void test_errors_and_strings(void) {
    CHECK(strstr(bass_version(), "bass") != NULL);
    CHECK(strcmp(bass_result_str(BASS_OK), "ok") == 0);
    CHECK(strcmp(bass_result_str(9999), "unknown result code") == 0);
    CHECK(strcmp(bass_result_str(-1), "unknown result code") == 0);
    for (int c = 0; c <= BASS_ERR_BUFFER_TOO_SMALL; c++) CHECK(bass_result_str(c)[0] != '\0');
    CHECK(bass_last_error() != NULL);
}

static void test_null_arguments(bass_port *port, bass_writer *w) {
    bass_port *p = NULL;
    uint64_t nfr = 0, lfi = 0;
    size_t n = 0;
    uint64_t loss = 0;
    int32_t l[4], r[4];
    int32_t *chans[2] = {l, r};
    bass_port_info info;
    bass_chunk_info ci;
    bass_view view;
    const int32_t *s0, *s1;
    EXPECT(bass_port_open(NULL, &p), BASS_ERR_NULL_ARGUMENT);
    CHECK(strstr(bass_last_error(), "name") != NULL);
    EXPECT(bass_port_open("abi", NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_open_path(NULL, &p), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(NULL, 4, &nfr, l, r, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(port, 4, NULL, l, r, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(port, 4, &nfr, NULL, r, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(port, 4, &nfr, l, NULL, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(port, 4, &nfr, l, r, NULL, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(port, 4, &nfr, l, r, &n, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(port, 4, &nfr, NULL, 2, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    chans[1] = NULL;
    EXPECT(bass_get_audio_data_multi(port, 4, &nfr, chans, 2, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    chans[1] = r;
    EXPECT(bass_port_get_info(port, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_get_info(NULL, &info), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_wait(NULL, 1, 0, &lfi), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_chunk_info(port, 1, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_chunk_info(NULL, 1, &ci), BASS_ERR_NULL_ARGUMENT);
    bass_chunk_ext ce;
    EXPECT(bass_port_chunk_ext(port, 1, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_chunk_ext(NULL, 1, &ce), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view(port, 4, NULL, &view), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view(port, 4, &nfr, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_channel(port, NULL, 0, &s0, &s1), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_check(port, NULL, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_create(NULL, NULL, 48000, 4, 3, 2, &w), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_create("x", NULL, 48000, 4, 3, 2, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_interleaved(w, NULL, 8, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_interleaved(NULL, l, 8, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_planar(w, NULL, 2, 4, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_gap(NULL, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_set_state(NULL, BASS_STATE_STOPPED, 0, NULL), BASS_ERR_NULL_ARGUMENT);
    /* Closing NULL is a no-op, like free(NULL). */
    EXPECT(bass_port_close(NULL), BASS_OK);
    EXPECT(bass_writer_close(NULL), BASS_OK);
    CHECK(nfr == 0); /* outputs untouched on failure */
}

static void test_reads(bass_port *port, bass_writer *w) {
    int32_t l[64], r[64];
    uint64_t nfr = 0, loss = 99, lfi = 0;
    size_t n = 99;
    /* Before any data: frame 0 reads as one zero frame. */
    l[0] = r[0] = 7;
    EXPECT(bass_get_audio_data(port, 64, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 1 && loss == 0 && nfr == 1 && l[0] == 0 && r[0] == 0);
    /* Future nfr: n = 0, nfr unchanged. */
    EXPECT(bass_get_audio_data(port, 64, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 0 && loss == 0 && nfr == 1);
    /* N = 0: nothing copied, nothing lost. */
    EXPECT(bass_get_audio_data(port, 0, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 0 && nfr == 1);
    /* Wait with timeout 0 on an unpublished frame. */
    EXPECT(bass_port_wait(port, 1, 0, &lfi), BASS_ERR_TIMEOUT);

    /* Publish 5 chunks (20 frames) of the pattern: interleaved, planar and a gap. */
    int32_t chunk[NFPC * CH];
    uint64_t frame = 1;
    for (int k = 0; k < 3; k++) {
        for (int i = 0; i < NFPC; i++)
            for (int c = 0; c < CH; c++) chunk[i * CH + c] = pattern(frame + (uint64_t)i, (unsigned)c);
        EXPECT(bass_writer_publish_interleaved(w, chunk, NFPC * CH, NULL, &lfi), BASS_OK);
        frame += NFPC;
        CHECK(lfi == frame - 1);
    }
    int32_t pl[NFPC], pr[NFPC];
    for (int i = 0; i < NFPC; i++) {
        pl[i] = pattern(frame + (uint64_t)i, 0);
        pr[i] = pattern(frame + (uint64_t)i, 1);
    }
    const int32_t *planes[CH] = {pl, pr};
    bass_chunk_meta meta = {123456789, 987654321, 0};
    /* The next chunk's timestamp bound and channel masks (that one chunk only); a mask bit
       past the channels is refused by name and sets nothing; NULL clears. */
    bass_chunk_ext set = {0, 2500, 0x2, 0x1}, bad = {0, 1, 0x4, 0};
    EXPECT(bass_writer_set_chunk_ext(w, &bad), BASS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(bass_last_error(), "missing_channels = 0x4") != NULL);
    EXPECT(bass_writer_set_chunk_ext(NULL, &set), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_set_chunk_ext(w, &set), BASS_OK);
    EXPECT(bass_writer_set_chunk_ext(w, NULL), BASS_OK);
    EXPECT(bass_writer_set_chunk_ext(w, &set), BASS_OK);
    EXPECT(bass_writer_publish_planar(w, planes, CH, NFPC, &meta, &lfi), BASS_OK);
    frame += NFPC;
    EXPECT(bass_writer_publish_gap(w, NULL, &lfi), BASS_OK);
    frame += NFPC;
    CHECK(lfi == 20);
    /* Wrong sizes are refused and publish nothing. */
    EXPECT(bass_writer_publish_interleaved(w, chunk, NFPC * CH - 1, NULL, &lfi), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_publish_planar(w, planes, 1, NFPC, NULL, &lfi), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_publish_planar(w, planes, CH, NFPC + 1, NULL, &lfi), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_port_wait(port, 20, 1000, &lfi), BASS_OK);
    CHECK(lfi == 20);

    /* nfr = 1 is gone (window holds 9..20): loss 8, then 12 frames, the last 4 zero (gap). */
    EXPECT(bass_get_audio_data(port, 64, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 12 && loss == 8 && nfr == 21);
    for (size_t i = 0; i < 8; i++) CHECK(l[i] == pattern(9 + i, 0) && r[i] == pattern(9 + i, 1));
    for (size_t i = 8; i < 12; i++) CHECK(l[i] == 0 && r[i] == 0);

    /* Overlapping output buffers are refused before anything is written. */
    nfr = 10;
    EXPECT(bass_get_audio_data(port, 4, &nfr, l, l + 2, &n, &loss), BASS_ERR_INVALID_ARGUMENT);
    CHECK(nfr == 10);

    /* A huge N only ever writes what is available. */
    nfr = 15;
    EXPECT(bass_get_audio_data(port, (size_t)-1, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 6 && loss == 0 && nfr == 21);
    nfr = UINT64_MAX;
    EXPECT(bass_get_audio_data(port, 64, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 0 && loss == 0 && nfr == UINT64_MAX);

    /* Multichannel variant: channels[c] receives channel c; here only channel 0. */
    int32_t *one[1] = {r};
    nfr = 10;
    EXPECT(bass_get_audio_data_multi(port, 3, &nfr, one, 1, &n, &loss), BASS_OK);
    CHECK(n == 3 && nfr == 13 && r[0] == pattern(10, 0) && r[2] == pattern(12, 0));
    EXPECT(bass_get_audio_data_multi(port, 3, &nfr, one, 0, &n, &loss), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(port, 3, &nfr, one, 3, &n, &loss), BASS_ERR_INVALID_ARGUMENT);
    /* A NULL element of channels is refused, and the message names its index. */
    int32_t *hole[2] = {l, NULL};
    EXPECT(bass_get_audio_data_multi(port, 3, &nfr, hole, 2, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    CHECK(strstr(bass_last_error(), "argument channels[1] is NULL") != NULL);

    /* Info. */
    bass_port_info info;
    EXPECT(bass_port_get_info(port, &info), BASS_OK);
    CHECK(info.channels == CH && info.frames_per_chunk == NFPC && info.chunks_on_port == NCOP);
    CHECK(info.frames_on_port == NFOP && info.last_frame_index == 20 && info.sample_rate == 48000);
    CHECK(info.state == BASS_STATE_CAPTURING && info.writer_alive == 1 && info.writer_pid == (uint32_t)getpid());
    CHECK(info.chunks_published == 5 && info.gap_frames == NFPC && info.epoch >= 1);
    CHECK(strcmp(info.device, "c-abi-test") == 0);

    /* Chunk metadata. */
    bass_chunk_info ci;
    EXPECT(bass_port_chunk_info(port, 14, &ci), BASS_OK);
    CHECK(ci.first_frame == 13 && ci.frames == NFPC && ci.mono_ns == 123456789 && ci.realtime_ns == 987654321);
    EXPECT(bass_port_chunk_info(port, 17, &ci), BASS_OK);
    CHECK(ci.first_frame == 17 && (ci.flags & BASS_CHUNK_GAP));
    EXPECT(bass_port_chunk_info(port, 8, &ci), BASS_ERR_FRAME_LOST);
    EXPECT(bass_port_chunk_info(port, 0, &ci), BASS_ERR_FRAME_LOST);
    EXPECT(bass_port_chunk_info(port, 21, &ci), BASS_ERR_FRAME_NOT_YET);
    /* Format 2.4's extension row: the chunk given bass_writer_set_chunk_ext carries it; the
       writer's other chunks carry no bound and no channel masks. */
    bass_chunk_ext ce;
    EXPECT(bass_port_chunk_ext(port, 14, &ce), BASS_OK);
    CHECK(ce.first_frame == 13 && ce.bound_ns == 2500 && ce.missing_channels == 0x2 && ce.unaligned_channels == 0x1);
    EXPECT(bass_port_chunk_ext(port, 12, &ce), BASS_OK);
    CHECK(ce.first_frame == 9 && ce.bound_ns == BASS_BOUND_UNKNOWN && ce.missing_channels == 0 &&
          ce.unaligned_channels == 0);
    EXPECT(bass_port_chunk_ext(port, 20, &ce), BASS_OK);
    CHECK(ce.first_frame == 17 && ce.bound_ns == BASS_BOUND_UNKNOWN && ce.missing_channels == 0);
    EXPECT(bass_port_chunk_ext(port, 8, &ce), BASS_ERR_FRAME_LOST);
    EXPECT(bass_port_chunk_ext(port, 21, &ce), BASS_ERR_FRAME_NOT_YET);

    /* Zero-copy view: frames 11..20 wrap around the end of the ring. */
    bass_view v;
    nfr = 11;
    EXPECT(bass_port_view(port, 10, &nfr, &v), BASS_OK);
    CHECK(v.first_frame == 11 && v.frames == 10 && v.loss == 0 && nfr == 21);
    CHECK(v.seg_frames[0] + v.seg_frames[1] == 10);
    size_t k = 0;
    for (int s = 0; s < 2; s++)
        for (size_t i = 0; i < v.seg_frames[s]; i++, k++) {
            uint64_t f = 11 + k;
            int32_t want_l = f > 16 ? 0 : pattern(f, 0);
            CHECK(v.left[s][i] == want_l);
            CHECK(v.right[s][i] == (f > 16 ? 0 : pattern(f, 1)));
        }
    const int32_t *s0, *s1;
    EXPECT(bass_port_view_channel(port, &v, 1, &s0, &s1), BASS_OK);
    CHECK(s0 == v.right[0] && s1 == v.right[1]);
    EXPECT(bass_port_view_channel(port, &v, 2, &s0, &s1), BASS_ERR_INVALID_ARGUMENT);
    uint64_t over = 99;
    EXPECT(bass_port_view_check(port, &v, &over), BASS_OK);
    CHECK(over == 0);
    /* Two more chunks overwrite frames 9..16: the view's first 6 frames (11..16) are gone. */
    EXPECT(bass_writer_publish_gap(w, NULL, NULL), BASS_OK);
    EXPECT(bass_writer_publish_gap(w, NULL, NULL), BASS_OK);
    EXPECT(bass_port_view_check(port, &v, &over), BASS_OK);
    CHECK(over == 6);

    /* State changes wake and end waits with the right codes. */
    EXPECT(bass_writer_set_state(w, 99, 0, NULL), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_set_state(w, BASS_STATE_ERROR, BASS_DEVERR_STALLED, "device stalled: test"), BASS_OK);
    EXPECT(bass_port_wait(port, 1000, 1000, &lfi), BASS_ERR_DEVICE);
    CHECK(strstr(bass_last_error(), "device stalled: test") != NULL);
    EXPECT(bass_port_get_info(port, &info), BASS_OK);
    CHECK(info.state == BASS_STATE_ERROR && info.error_code == BASS_DEVERR_STALLED);
    CHECK(strcmp(info.message, "device stalled: test") == 0);
    EXPECT(bass_writer_set_state(w, BASS_STATE_STOPPED, 0, NULL), BASS_OK);
    EXPECT(bass_port_wait(port, 1000, BASS_WAIT_FOREVER, &lfi), BASS_ERR_STOPPED);
    /* A frame already published is still OK after a stop. */
    EXPECT(bass_port_wait(port, 5, 0, NULL), BASS_OK);
}

struct shared {
    bass_port *port;
    int errors;
};

static void *reader_thread(void *arg) {
    struct shared *s = arg;
    int32_t l[NFOP], r[NFOP];
    for (int i = 0; i < 2000; i++) {
        uint64_t nfr = 1, loss = 0;
        size_t n = 0;
        if (bass_get_audio_data(s->port, NFOP, &nfr, l, r, &n, &loss) != BASS_OK) s->errors++;
        bass_port_info info;
        if (bass_port_get_info(s->port, &info) != BASS_OK) s->errors++;
    }
    return NULL;
}

static void test_threads_share_a_handle(bass_port *port) {
    struct shared s = {port, 0};
    pthread_t t[2];
    for (int i = 0; i < 2; i++) pthread_create(&t[i], NULL, reader_thread, &s);
    for (int i = 0; i < 2; i++) pthread_join(t[i], NULL);
    CHECK(s.errors == 0);
}

static void test_bad_files(void) {
    bass_port *p = NULL;
    char good[4200], bad[4200];
    EXPECT(bass_port_open("no-such-port", &p), BASS_ERR_NOT_FOUND);
    CHECK(p == NULL);
    EXPECT(bass_port_open("../etc/passwd", &p), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_port_open("", &p), BASS_ERR_INVALID_ARGUMENT);
    path_of(good, sizeof good, "bass-abi.port");

    /* Bad magic. */
    path_of(bad, sizeof bad, "bass-badmagic.port");
    copy_port(good, bad, -1, 0, "NOTABASS", 8);
    EXPECT(bass_port_open("badmagic", &p), BASS_ERR_BAD_MAGIC);
    /* Truncated: at 100 bytes (inside the header) and at header + 1 page. */
    path_of(bad, sizeof bad, "bass-trunc1.port");
    copy_port(good, bad, 100, -1, NULL, 0);
    EXPECT(bass_port_open("trunc1", &p), BASS_ERR_CORRUPT);
    path_of(bad, sizeof bad, "bass-trunc2.port");
    copy_port(good, bad, 8192, -1, NULL, 0);
    EXPECT(bass_port_open("trunc2", &p), BASS_ERR_CORRUPT);
    /* Empty file. */
    path_of(bad, sizeof bad, "bass-empty.port");
    copy_port(good, bad, 0, -1, NULL, 0);
    EXPECT(bass_port_open("empty", &p), BASS_ERR_CORRUPT);
    /* Wrong major version (offset 8). */
    uint32_t major = BASS_PORT_FORMAT_MAJOR + 1;
    path_of(bad, sizeof bad, "bass-major.port");
    copy_port(good, bad, -1, 8, &major, 4);
    EXPECT(bass_port_open("major", &p), BASS_ERR_INCOMPATIBLE);
    /* Version 0: not initialised yet. */
    major = 0;
    path_of(bad, sizeof bad, "bass-v0.port");
    copy_port(good, bad, -1, 8, &major, 4);
    EXPECT(bass_port_open("v0", &p), BASS_ERR_NOT_READY);
    /* Channels = 0 (offset 20) and an overflowing nFPC (offset 32). */
    uint32_t zero = 0, huge = 0xFFFFFFFFu;
    path_of(bad, sizeof bad, "bass-ch0.port");
    copy_port(good, bad, -1, 20, &zero, 4);
    EXPECT(bass_port_open("ch0", &p), BASS_ERR_CORRUPT);
    path_of(bad, sizeof bad, "bass-nfpc.port");
    copy_port(good, bad, -1, 32, &huge, 4);
    EXPECT(bass_port_open("nfpc", &p), BASS_ERR_CORRUPT);
    CHECK(p == NULL);
}

/* bass_writer_create takes the geometry in bass_acquire's order: sample rate, nFramesPerChunk,
 * nChunksOnPort, channels. All four are uint32_t, so a call in another order compiles; four
 * distinct values read back through bass_port_get_info (and the shape of the data) catch it. */
static void test_writer_create_geometry_order(void) {
    enum { RATE = 22050, G_NFPC = 5, G_NCOP = 7, G_CH = 3 };
    bass_writer *w = NULL;
    bass_port *p = NULL;
    EXPECT(bass_writer_create("geometry", "geometry-order", RATE, G_NFPC, G_NCOP, G_CH, &w), BASS_OK);
    EXPECT(bass_port_open("geometry", &p), BASS_OK);
    if (!w || !p) {
        bass_writer_close(w);
        return;
    }
    bass_port_info info;
    EXPECT(bass_port_get_info(p, &info), BASS_OK);
    CHECK(info.sample_rate == RATE);
    CHECK(info.frames_per_chunk == G_NFPC);
    CHECK(info.chunks_on_port == G_NCOP);
    CHECK(info.channels == G_CH);
    CHECK(info.frames_on_port == (uint64_t)G_NFPC * G_NCOP);

    /* One chunk of G_NFPC frames × G_CH channels is accepted, and reads back channel by channel. */
    int32_t chunk[G_NFPC * G_CH];
    for (unsigned f = 0; f < G_NFPC; f++)
        for (unsigned c = 0; c < G_CH; c++) chunk[f * G_CH + c] = pattern(f + 1, c);
    uint64_t lfi = 0;
    EXPECT(bass_writer_publish_interleaved(w, chunk, G_NFPC * G_CH, NULL, &lfi), BASS_OK);
    CHECK(lfi == G_NFPC);
    int32_t out[G_CH][G_NFPC];
    int32_t *chans[G_CH] = {out[0], out[1], out[2]};
    uint64_t nfr = 1, loss = 9;
    size_t n = 0;
    EXPECT(bass_get_audio_data_multi(p, G_NFPC, &nfr, chans, G_CH, &n, &loss), BASS_OK);
    CHECK(n == G_NFPC && loss == 0 && nfr == G_NFPC + 1);
    for (unsigned c = 0; c < G_CH; c++)
        for (unsigned f = 0; f < G_NFPC; f++) CHECK(out[c][f] == pattern(f + 1, c));

    EXPECT(bass_port_close(p), BASS_OK);
    EXPECT(bass_writer_close(w), BASS_OK);
}

static void test_handles(bass_port *port) {
    uint64_t nfr = 0, loss = 0;
    size_t n = 0;
    int32_t l[4], r[4];
    bass_port *p2 = NULL;
    EXPECT(bass_port_open("abi", &p2), BASS_OK);
    EXPECT(bass_port_close(p2), BASS_OK);
    /* Use after close and double close are reported, not dereferenced. */
    EXPECT(bass_get_audio_data(p2, 4, &nfr, l, r, &n, &loss), BASS_ERR_INVALID_HANDLE);
    EXPECT(bass_port_close(p2), BASS_ERR_INVALID_HANDLE);
    /* A forged handle. */
    EXPECT(bass_port_close((bass_port *)(uintptr_t)0x1234), BASS_ERR_INVALID_HANDLE);
    /* A writer handle is not a port handle. */
    EXPECT(bass_get_audio_data((const bass_port *)(uintptr_t)0x10, 4, &nfr, l, r, &n, &loss),
           BASS_ERR_INVALID_HANDLE);
    (void)port;
}

int main(void) {
    const char *d = getenv("BASS_RUNTIME_DIR");
    if (!d) {
        fprintf(stderr, "set BASS_RUNTIME_DIR to an empty directory\n");
        return 2;
    }
    snprintf(dir, sizeof dir, "%s", d);
    test_errors_and_strings();

    bass_writer *w = NULL;
    EXPECT(bass_writer_create("abi", "c-abi-test", 48000, 0, NCOP, CH, &w), BASS_ERR_INVALID_ARGUMENT);
    CHECK(strstr(bass_last_error(), "nFramesPerChunk = 0") != NULL);
    EXPECT(bass_writer_create("abi", "c-abi-test", 48000, NFPC, NCOP, 0, &w), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_create("abi", "c-abi-test", 48000, 0xFFFFFFFFu, 0xFFFFFFFFu, CH, &w),
           BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_create("abi", "c-abi-test", 48000, NFPC, NCOP, CH, &w), BASS_OK);
    bass_port *port = NULL;
    EXPECT(bass_port_open("abi", &port), BASS_OK);
    if (!port || !w) {
        fprintf(stderr, "cannot continue without a port\n");
        return 1;
    }
    /* The port file is mode 0640. */
    char path[4200];
    struct stat st;
    path_of(path, sizeof path, "bass-abi.port");
    CHECK(stat(path, &st) == 0 && (st.st_mode & 0777) == 0640);

    test_null_arguments(port, w);
    test_reads(port, w);
    test_threads_share_a_handle(port);
    test_bad_files();
    test_handles(port);
    test_writer_create_geometry_order();

    EXPECT(bass_port_close(port), BASS_OK);
    EXPECT(bass_writer_close(w), BASS_OK);
    EXPECT(bass_writer_close(w), BASS_ERR_INVALID_HANDLE);
    printf("abi_test: %d checks, %d failures\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
