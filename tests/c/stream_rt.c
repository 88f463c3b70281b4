/* The C callback stream's steady path makes no allocation: this program interposes malloc,
 * calloc, realloc and free (an executable's definitions win over libc's for every library,
 * libbassclient included; glibc's __libc_* do the work) and counts the calls made on the
 * stream's thread from its first block on, over 10^5 callbacks of a concurrent writer
 * (laps included) and the stopped event. Not built with ASan (which interposes malloc
 * itself). Run by tests/c/run.sh with BASS_RUNTIME_DIR set to a fresh directory. */
#define _POSIX_C_SOURCE 200809L
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "bass.h"
#include "check.h"

extern void *__libc_malloc(size_t);
extern void *__libc_calloc(size_t, size_t);
extern void *__libc_realloc(void *, size_t);
extern void __libc_free(void *);

static _Thread_local volatile int counting; /* volatile: the compiler assumes malloc reads no user state */
static atomic_ulong allocations;

static void note(void) {
    if (counting) atomic_fetch_add(&allocations, 1);
}
void *malloc(size_t n) {
    note();
    return __libc_malloc(n);
}
void *calloc(size_t n, size_t m) {
    note();
    return __libc_calloc(n, m);
}
void *realloc(void *p, size_t n) {
    note();
    return __libc_realloc(p, n);
}
void free(void *p) {
    if (p) note();
    __libc_free(p);
}

enum { NFPC = 32, NCOP = 16, CH = 2, CALLBACKS = 100000 };

struct run {
    bass_writer *w;
    atomic_int done;
    uint64_t calls, next, delivered, lost, last;
    int wrong;
};

static void *writer_thread(void *arg) {
    struct run *r = arg;
    int32_t chunk[NFPC * CH];
    uint64_t lfi = 0;
    for (unsigned long i = 0; !atomic_load(&r->done); i++) {
        for (unsigned f = 0; f < NFPC; f++)
            for (unsigned c = 0; c < CH; c++) chunk[f * CH + c] = pattern(lfi + 1 + f, c);
        if (bass_writer_publish_interleaved(r->w, chunk, NFPC * CH, NULL, &lfi) != BASS_OK) abort();
        if (i % 8 == 0) sched_yield();
    }
    bass_writer_set_state(r->w, BASS_STATE_STOPPED, BASS_DEVERR_NONE, NULL);
    return NULL;
}

static int on_block(const bass_block *b, void *user) {
    struct run *r = user;
    counting = 1; /* from the first block on: the steady state */
    if (b->first_frame != r->next + b->lost) r->wrong++;
    for (size_t i = 0; i < b->frames; i++)
        for (unsigned k = 0; k < b->n_channels; k++)
            if (b->channels[k][i] != pattern(b->first_frame + i, b->port_channels[k])) r->wrong++;
    r->next = b->first_frame + b->frames;
    r->delivered += b->frames;
    r->lost += b->lost;
    if (++r->calls == CALLBACKS) atomic_store(&r->done, 1);
    return 0;
}

static int on_event(const bass_stream_event *e, void *user) {
    struct run *r = user;
    if (e->kind == BASS_EVENT_STOPPED) r->last = e->frame;
    counting = 0;
    return 1;
}

int main(void) {
    if (!getenv("BASS_RUNTIME_DIR")) {
        fprintf(stderr, "set BASS_RUNTIME_DIR to an empty directory\n");
        return 2;
    }
    /* The interposition counts (a counter that counts nothing proves nothing). */
    counting = 1;
    void *volatile probe = malloc(16); /* volatile: the pair is not optimised away */
    free(probe);
    counting = 0;
    CHECK(atomic_exchange(&allocations, 0) == 2);

    struct run r = {0};
    r.next = 1;
    EXPECT(bass_writer_create("crt", "c", 48000, NFPC, NCOP, CH, &r.w), BASS_OK);
    bass_port *port;
    EXPECT(bass_port_open("crt", &port), BASS_OK);
    /* ... and sees the library's own allocations (bass_port_get_info builds Rust strings). */
    bass_port_info info;
    counting = 1;
    EXPECT(bass_port_get_info(port, &info), BASS_OK);
    counting = 0;
    CHECK(atomic_exchange(&allocations, 0) > 0);
    bass_stream_config cfg = {0};
    cfg.start = BASS_START_FRAME;
    cfg.start_frame = 1;
    bass_stream *s;
    EXPECT(bass_stream_create(port, &cfg, on_block, on_event, &r, &s), BASS_OK);
    pthread_t t;
    pthread_create(&t, NULL, writer_thread, &r);
    EXPECT(bass_stream_run(s), BASS_OK);
    counting = 0;
    unsigned long counted = atomic_load(&allocations);
    pthread_join(t, NULL);
    CHECK(r.calls >= CALLBACKS);
    CHECK(r.wrong == 0);
    CHECK(r.last > 0 && 1 + r.delivered + r.lost == r.last + 1);
    CHECK(counted == 0);
    printf("stream_rt: %llu callbacks, %llu frames lost, %lu allocations on the stream's thread\n",
           (unsigned long long)r.calls, (unsigned long long)r.lost, counted);
    EXPECT(bass_stream_close(s), BASS_OK);
    EXPECT(bass_port_close(port), BASS_OK);
    EXPECT(bass_writer_close(r.w), BASS_OK);
    printf("stream_rt: %d checks, %d failures\n", checks, failures);
    return failures != 0;
}
