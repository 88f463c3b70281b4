/* The callback stream from C (bass_stream_*): its blocks tile the stream of a real port
 * written by bass_writer_* — every frame delivered once, in order, or counted lost — across
 * a lapped callback, a device gap and the end of the acquisition, checked sample by sample
 * against the pattern; on the caller's thread (bass_stream_run, stopped from inside the
 * callback) and on bass's own thread (bass_stream_start, a concurrent writer). Run by
 * tests/c/run.sh with BASS_RUNTIME_DIR set to a fresh directory. */
#define _POSIX_C_SOURCE 200809L
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bass.h"
#include "check.h"

enum { NFPC = 16, NCOP = 8, CH = 2 };

static void publish(bass_writer *w, uint64_t *lfi, uint32_t flags) {
    int32_t chunk[NFPC * CH];
    for (unsigned i = 0; i < NFPC; i++)
        for (unsigned c = 0; c < CH; c++) chunk[i * CH + c] = pattern(*lfi + 1 + i, c);
    bass_chunk_meta meta = {0, 0, flags};
    EXPECT(bass_writer_publish_interleaved(w, chunk, NFPC * CH, &meta, lfi), BASS_OK);
}

/* What the blocks add up to. */
struct tiling {
    bass_writer *w;
    bass_stream *stream; /* for a stop from inside the callback */
    uint64_t lfi, next, delivered, lost, gap_first, gap_last, calls, stop_after;
    uint32_t flags_seen;
    atomic_int ended;
    uint64_t last; /* from the stopped event */
    int wrong;
};

static void check_block(struct tiling *t, const bass_block *b) {
    if (b->first_frame != t->next + b->lost) t->wrong++;
    for (size_t i = 0; i < b->frames; i++) {
        uint64_t f = b->first_frame + i;
        int gap = f >= t->gap_first && f <= t->gap_last;
        for (uint32_t k = 0; k < b->n_channels; k++) {
            int32_t s = b->interleaved ? b->interleaved[i * b->n_channels + k] : b->channels[k][i];
            if (s != (gap ? 0 : pattern(f, b->port_channels[k]))) t->wrong++;
        }
        if (gap && !(b->flags & BASS_CHUNK_GAP)) t->wrong++;
    }
    t->next = b->first_frame + b->frames;
    t->delivered += b->frames;
    t->lost += b->lost;
    t->flags_seen |= b->flags;
    t->calls++;
}

/* The callback drives the writer (one thread, every loss deterministic). */
static int scripted_block(const bass_block *b, void *user) {
    struct tiling *t = user;
    check_block(t, b);
    if (t->calls == 10) { /* a slow callback: lapped by more than the window */
        for (int i = 0; i < NCOP * 2 + 3; i++) publish(t->w, &t->lfi, 0);
    } else if (t->calls == 20) { /* a device gap: zero frames flagged GAP */
        t->gap_first = t->lfi + 1;
        bass_chunk_meta meta = {0, 0, 0};
        EXPECT(bass_writer_publish_gap(t->w, &meta, &t->lfi), BASS_OK);
        t->gap_last = t->lfi;
        publish(t->w, &t->lfi, BASS_CHUNK_DISCONTINUITY);
    } else if (t->calls == 40) {
        publish(t->w, &t->lfi, 0);
        EXPECT(bass_writer_set_state(t->w, BASS_STATE_STOPPED, BASS_DEVERR_NONE, NULL), BASS_OK);
    } else if (t->calls < 40) { /* keep a block ahead */
        while (t->lfi < b->first_frame + 2 * b->frames) publish(t->w, &t->lfi, 0);
    }
    if (t->stop_after && t->calls == t->stop_after) EXPECT(bass_stream_stop(t->stream), BASS_OK);
    return 0;
}

static int on_event(const bass_stream_event *e, void *user) {
    struct tiling *t = user;
    if (e->kind == BASS_EVENT_STOPPED) t->last = e->frame;
    CHECK(e->kind == BASS_EVENT_STOPPED && e->message != NULL && e->message[0] == 0);
    atomic_store(&t->ended, 1);
    return 1; /* end the stream */
}

static void caller_thread(void) {
    struct tiling t = {0};
    t.gap_first = UINT64_MAX;
    EXPECT(bass_writer_create("cstream", "c", 48000, NFPC, NCOP, CH, &t.w), BASS_OK);
    for (int i = 0; i < 3; i++) publish(t.w, &t.lfi, 0);
    bass_port *port;
    EXPECT(bass_port_open("cstream", &port), BASS_OK);
    bass_stream_config cfg = {0};
    cfg.start = BASS_START_OLDEST;
    EXPECT(bass_stream_create(port, &cfg, scripted_block, on_event, &t, &t.stream), BASS_OK);
    EXPECT(bass_port_close(port), BASS_OK); /* the stream keeps its own reference */
    t.next = 1;
    EXPECT(bass_stream_run(t.stream), BASS_OK);
    CHECK(t.wrong == 0);
    CHECK(t.last > 0 && t.next == t.last + 1);
    CHECK(1 + t.delivered + t.lost == t.next);
    CHECK(t.lost > NFPC * NCOP);
    CHECK((t.flags_seen & BASS_CHUNK_GAP) && (t.flags_seen & BASS_CHUNK_DISCONTINUITY));
    EXPECT(bass_stream_close(t.stream), BASS_OK);
    EXPECT(bass_stream_close(t.stream), BASS_ERR_INVALID_HANDLE);
    EXPECT(bass_stream_close(NULL), BASS_OK);
    EXPECT(bass_writer_close(t.w), BASS_OK);
    printf("caller's thread: %llu blocks, %llu frames, %llu lost\n", (unsigned long long)t.calls,
           (unsigned long long)t.delivered, (unsigned long long)t.lost);
}

static int plain_block(const bass_block *b, void *user) {
    check_block(user, b);
    struct tiling *t = user;
    if (t->stop_after && t->calls == t->stop_after) {
        EXPECT(bass_stream_close(t->stream), BASS_ERR_INVALID_ARGUMENT); /* not from inside */
        EXPECT(bass_stream_stop(t->stream), BASS_OK);
    }
    return 0;
}

static void stop_inside_callback(void) {
    struct tiling t = {0};
    t.gap_first = UINT64_MAX;
    t.stop_after = 5;
    EXPECT(bass_writer_create("cstop", "c", 48000, NFPC, NCOP, CH, &t.w), BASS_OK);
    for (int i = 0; i < 7; i++) publish(t.w, &t.lfi, 0);
    bass_port *port;
    EXPECT(bass_port_open("cstop", &port), BASS_OK);
    bass_stream_config cfg = {0};
    EXPECT(bass_stream_create(port, &cfg, plain_block, on_event, &t, &t.stream), BASS_OK);
    t.next = 1;
    EXPECT(bass_stream_run(t.stream), BASS_OK);
    CHECK(t.calls == 5 && t.wrong == 0 && t.next == 5 * NFPC + 1);
    /* Run again: it goes on where it stopped. */
    t.stop_after = 7;
    EXPECT(bass_stream_run(t.stream), BASS_OK);
    CHECK(t.calls == 7 && t.wrong == 0 && t.lost == 0);
    EXPECT(bass_stream_close(t.stream), BASS_OK);
    cfg.start = 9;
    EXPECT(bass_stream_create(port, &cfg, plain_block, on_event, &t, &t.stream), BASS_ERR_INVALID_ARGUMENT);
    cfg.start = BASS_START_NOW;
    EXPECT(bass_stream_create(port, &cfg, NULL, on_event, &t, &t.stream), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_stream_create(port, NULL, plain_block, on_event, &t, &t.stream), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_close(port), BASS_OK);
    EXPECT(bass_writer_close(t.w), BASS_OK);
}

static void bass_thread(void) {
    struct tiling t = {0};
    t.gap_first = UINT64_MAX;
    EXPECT(bass_writer_create("cthread", "c", 48000, NFPC, NCOP, CH, &t.w), BASS_OK);
    bass_port *port;
    EXPECT(bass_port_open("cthread", &port), BASS_OK);
    uint32_t channels[1] = {1};
    bass_stream_config cfg = {0};
    cfg.frames_per_call = 24;
    cfg.start = BASS_START_FRAME;
    cfg.start_frame = 1;
    cfg.interleaved = 1;
    cfg.channels = channels;
    cfg.n_channels = 1;
    t.next = 1;
    bass_stream *s;
    EXPECT(bass_stream_start(port, &cfg, plain_block, on_event, &t, &s), BASS_OK);
    for (int i = 0; i < 3000; i++) {
        publish(t.w, &t.lfi, 0);
        if (i % 40 == 0) {
            struct timespec ts = {0, 200000};
            nanosleep(&ts, NULL);
        }
    }
    EXPECT(bass_writer_set_state(t.w, BASS_STATE_STOPPED, BASS_DEVERR_NONE, NULL), BASS_OK);
    while (!atomic_load(&t.ended)) { /* wait for the condition: the stopped event */
        struct timespec ts = {0, 1000000};
        nanosleep(&ts, NULL);
    }
    EXPECT(bass_stream_close(s), BASS_OK);
    CHECK(t.wrong == 0);
    CHECK(t.last == 3000ull * NFPC && t.next == t.last + 1);
    CHECK(1 + t.delivered + t.lost == t.next);
    EXPECT(bass_port_close(port), BASS_OK);
    EXPECT(bass_writer_close(t.w), BASS_OK);
    printf("bass's thread: %llu blocks, %llu frames, %llu lost\n", (unsigned long long)t.calls,
           (unsigned long long)t.delivered, (unsigned long long)t.lost);
}

int main(void) {
    if (!getenv("BASS_RUNTIME_DIR")) {
        fprintf(stderr, "set BASS_RUNTIME_DIR to an empty directory\n");
        return 2;
    }
    caller_thread();
    stop_inside_callback();
    bass_thread();
    printf("stream_test: %d checks, %d failures\n", checks, failures);
    return failures != 0;
}
