/* Item 6 — the C ABI under abuse, built plain, with -fsanitize=address,undefined and with
 * -fsanitize=thread by tests/faults/run.sh. Complements tests/c/abi_test.c (which covers the
 * normal paths): NULL for every pointer of every export, N = 0 / 2^32-1 / SIZE_MAX with
 * buffers of exactly nFOP frames placed against a PROT_NONE guard page (any write past
 * them faults, instrumented or not), nfr = 2^64-1, huge channel counts against a pointer
 * array at the end of a page, double close and use-after-close for every handle function,
 * forged handles, and the thread-safety contract:
 *   - a bass_port may be used by any number of threads at once (4 readers share one,
 *     every sample checked against the pattern while a writer thread publishes);
 *   - a bass_writer serialises its callers (2 threads publish through one handle: every
 *     chunk counted exactly once);
 *   - closing a handle while another thread uses it: calls already inside the library
 *     finish normally, later calls get BASS_ERR_INVALID_HANDLE; never a crash.
 * Pass: every call returns its documented code, 0 sanitizer reports, 0 faults. */
#define _GNU_SOURCE
#include "bass.h"
#include "../../c/check.h"

#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

enum { NFPC = 16, NCOP = 4, NFOP = NFPC * NCOP, CH = 2 };

/* `bytes` of memory ending exactly at a PROT_NONE page: touching one byte more faults. */
static void *guarded(size_t bytes) {
    long page = sysconf(_SC_PAGESIZE);
    size_t span = ((bytes + (size_t)page - 1) / (size_t)page + 1) * (size_t)page;
    char *base = mmap(NULL, span, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (base == MAP_FAILED) {
        perror("mmap");
        exit(2);
    }
    if (mprotect(base + span - (size_t)page, (size_t)page, PROT_NONE) != 0) {
        perror("mprotect");
        exit(2);
    }
    return base + span - (size_t)page - bytes;
}

static void publish_pattern(bass_writer *w, uint64_t *next) {
    int32_t chunk[NFPC * CH];
    for (int i = 0; i < NFPC; i++)
        for (int c = 0; c < CH; c++) chunk[i * CH + c] = pattern(*next + (uint64_t)i, (unsigned)c);
    uint64_t lfi = 0;
    EXPECT(bass_writer_publish_interleaved(w, chunk, NFPC * CH, NULL, &lfi), BASS_OK);
    *next += NFPC;
    CHECK(lfi == *next - 1);
}

static void test_nulls(bass_port *p, bass_writer *w) {
    uint64_t nfr = 0, loss = 0, u = 0;
    size_t n = 0;
    int32_t l[NFOP], r[NFOP];
    int32_t *chans[CH] = {l, r};
    const int32_t *s0, *s1;
    bass_port *po = NULL;
    bass_writer *wo = NULL;
    bass_port_info info;
    bass_chunk_info ci;
    bass_view v;
    bass_broker_status st;
    char buf[64];
    EXPECT(bass_port_open(NULL, &po), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_open("abuse", NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_open_path(NULL, &po), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_open_path("/nonexistent", NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(NULL, 4, &nfr, l, r, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(p, 4, NULL, l, r, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(p, 4, &nfr, NULL, r, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(p, 4, &nfr, l, NULL, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(p, 4, &nfr, l, r, NULL, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data(p, 4, &nfr, l, r, &n, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(NULL, 4, &nfr, chans, CH, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(p, 4, NULL, chans, CH, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(p, 4, &nfr, NULL, CH, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(p, 4, &nfr, chans, CH, NULL, &loss), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_get_audio_data_multi(p, 4, &nfr, chans, CH, &n, NULL), BASS_ERR_NULL_ARGUMENT);
    chans[0] = NULL;
    EXPECT(bass_get_audio_data_multi(p, 4, &nfr, chans, CH, &n, &loss), BASS_ERR_NULL_ARGUMENT);
    chans[0] = l;
    EXPECT(bass_port_get_info(NULL, &info), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_get_info(p, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_wait(NULL, 1, 0, &u), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_wait(p, 1, 0, NULL), BASS_OK); /* out_last_frame_index is optional */
    EXPECT(bass_port_chunk_info(NULL, 1, &ci), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_chunk_info(p, 1, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view(NULL, 4, &nfr, &v), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view(p, 4, NULL, &v), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view(p, 4, &nfr, NULL), BASS_ERR_NULL_ARGUMENT);
    nfr = 1;
    EXPECT(bass_port_view(p, 4, &nfr, &v), BASS_OK);
    EXPECT(bass_port_view_channel(NULL, &v, 0, &s0, &s1), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_channel(p, NULL, 0, &s0, &s1), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_channel(p, &v, 0, NULL, &s1), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_channel(p, &v, 0, &s0, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_check(NULL, &v, &u), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_check(p, NULL, &u), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_view_check(p, &v, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_create(NULL, "d", 48000, NFPC, NCOP, CH, &wo), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_create("abuse-null", "d", 48000, NFPC, NCOP, CH, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_interleaved(NULL, l, NFPC * CH, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_interleaved(w, NULL, NFPC * CH, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    const int32_t *planes[CH] = {l, NULL};
    EXPECT(bass_writer_publish_planar(NULL, planes, CH, NFPC, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_planar(w, NULL, CH, NFPC, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_planar(w, planes, CH, NFPC, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_publish_gap(NULL, NULL, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_writer_set_state(NULL, BASS_STATE_CAPTURING, 0, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_port_close(NULL), BASS_OK);
    EXPECT(bass_writer_close(NULL), BASS_OK);
    /* Control plane, no broker running in this runtime directory. */
    EXPECT(bass_acquire("abuse", NULL, 48000, NFPC, NCOP, CH, &u), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_status("abuse", NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_list_devices("abuse", buf, sizeof buf, NULL), BASS_ERR_NULL_ARGUMENT);
    EXPECT(bass_stop("no-broker-here"), BASS_ERR_NO_BROKER);
    EXPECT(bass_status("no-broker-here", &st), BASS_ERR_NO_BROKER);
    EXPECT(bass_list_devices("no-broker-here", NULL, 0, &n), BASS_ERR_NO_BROKER);
    EXPECT(bass_acquire("../../etc", "sim:sine", 48000, NFPC, NCOP, CH, &u), BASS_ERR_INVALID_ARGUMENT);
    CHECK(bass_result_str(-7) != NULL && bass_result_str(1 << 30) != NULL);
    CHECK(po == NULL && wo == NULL);
}

static void test_sizes(bass_port *p, bass_writer *w) {
    int32_t *l = guarded(NFOP * sizeof(int32_t)), *r = guarded(NFOP * sizeof(int32_t));
    uint64_t nfr, loss;
    size_t n;
    const size_t huge[] = {(size_t)UINT32_MAX, (size_t)UINT32_MAX + 1, SIZE_MAX, SIZE_MAX / 4};
    for (size_t k = 0; k < sizeof huge / sizeof huge[0]; k++) {
        /* Buffers of nFOP frames suffice whatever N is: at most nFOP frames are written. */
        nfr = 0;
        EXPECT(bass_get_audio_data(p, huge[k], &nfr, l, r, &n, &loss), BASS_OK);
        CHECK(n == NFOP && l[NFOP - 1] != 0 && r[NFOP - 1] == pattern(nfr - 1, 1));
        int32_t *chans[CH] = {l, r};
        nfr = 0;
        EXPECT(bass_get_audio_data_multi(p, huge[k], &nfr, chans, CH, &n, &loss), BASS_OK);
        CHECK(n == NFOP);
        bass_view v;
        nfr = 0;
        EXPECT(bass_port_view(p, huge[k], &nfr, &v), BASS_OK);
        CHECK(v.frames == NFOP);
    }
    nfr = 0;
    EXPECT(bass_get_audio_data(p, 0, &nfr, l, r, &n, &loss), BASS_OK);
    CHECK(n == 0 && loss > 0); /* N = 0 still reports the loss and moves nfr to ofi */
    const uint64_t far[] = {UINT64_MAX, UINT64_MAX - 1, (uint64_t)1 << 62, (uint64_t)1 << 63};
    for (size_t k = 0; k < sizeof far / sizeof far[0]; k++) {
        nfr = far[k];
        EXPECT(bass_get_audio_data(p, SIZE_MAX, &nfr, l, r, &n, &loss), BASS_OK);
        CHECK(n == 0 && loss == 0 && nfr == far[k]);
        bass_chunk_info ci;
        EXPECT(bass_port_chunk_info(p, far[k], &ci), BASS_ERR_FRAME_NOT_YET);
        uint64_t lfi;
        EXPECT(bass_port_wait(p, far[k], 0, &lfi), BASS_ERR_TIMEOUT);
        bass_view v;
        nfr = far[k];
        EXPECT(bass_port_view(p, SIZE_MAX, &nfr, &v), BASS_OK);
        CHECK(v.frames == 0 && nfr == far[k]);
    }
    /* Channel counts beyond the port's: refused before the pointer array is read (the array
     * of two pointers ends at a guard page). */
    int32_t **chans = guarded(CH * sizeof(int32_t *));
    chans[0] = l;
    chans[1] = r;
    const size_t nch[] = {0, 3, 64, (size_t)UINT32_MAX, SIZE_MAX};
    for (size_t k = 0; k < sizeof nch / sizeof nch[0]; k++) {
        nfr = 0;
        EXPECT(bass_get_audio_data_multi(p, NFOP, &nfr, chans, nch[k], &n, &loss), BASS_ERR_INVALID_ARGUMENT);
    }
    const int32_t *const *planes = (const int32_t *const *)chans;
    EXPECT(bass_writer_publish_planar(w, planes, SIZE_MAX, NFPC, NULL, NULL), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_publish_planar(w, planes, CH, SIZE_MAX, NULL, NULL), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_publish_interleaved(w, l, SIZE_MAX, NULL, NULL), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_publish_interleaved(w, l, 0, NULL, NULL), BASS_ERR_INVALID_ARGUMENT);
    const int32_t *s0, *s1;
    bass_view v;
    nfr = 1;
    EXPECT(bass_port_view(p, 4, &nfr, &v), BASS_OK);
    EXPECT(bass_port_view_channel(p, &v, UINT32_MAX, &s0, &s1), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_set_state(w, UINT32_MAX, 0, NULL), BASS_ERR_INVALID_ARGUMENT);
    bass_writer *wo = NULL;
    EXPECT(bass_writer_create("abuse-big", NULL, 48000, NFPC, NCOP, UINT32_MAX, &wo), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_create("abuse-big", NULL, 0, NFPC, NCOP, CH, &wo), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_create("abuse-big", NULL, 48000, UINT32_MAX, UINT32_MAX, CH, &wo), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_create("abuse-big", NULL, 48000, 1u << 20, 1u << 12, 64, &wo), BASS_ERR_INVALID_ARGUMENT);
    EXPECT(bass_writer_create("abuse-big", NULL, 48000, 0, 0, CH, &wo), BASS_ERR_INVALID_ARGUMENT);
    CHECK(wo == NULL);
}

static void test_handles(bass_writer *w_live) {
    bass_port *p = NULL;
    bass_writer *w = NULL;
    EXPECT(bass_port_open("abuse", &p), BASS_OK);
    EXPECT(bass_writer_create("abuse-closed", "x", 48000, NFPC, NCOP, CH, &w), BASS_OK);
    EXPECT(bass_port_close(p), BASS_OK);
    EXPECT(bass_writer_close(w), BASS_OK);
    uint64_t nfr = 0, loss, u;
    size_t n;
    int32_t l[NFOP], r[NFOP];
    int32_t *chans[CH] = {l, r};
    bass_port_info info;
    bass_chunk_info ci;
    bass_view v = {0};
    const int32_t *s0, *s1;
    int stack_var = 0;
    bass_port *forged[] = {p, (bass_port *)(uintptr_t)1, (bass_port *)(uintptr_t)0xdeadbeef0,
                           (bass_port *)(void *)&stack_var, (bass_port *)(uintptr_t)UINTPTR_MAX,
                           (bass_port *)(void *)w_live};
    for (size_t k = 0; k < sizeof forged / sizeof forged[0]; k++) {
        bass_port *h = forged[k];
        EXPECT(bass_get_audio_data(h, 4, &nfr, l, r, &n, &loss), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_get_audio_data_multi(h, 4, &nfr, chans, CH, &n, &loss), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_get_info(h, &info), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_wait(h, 1, 0, &u), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_chunk_info(h, 1, &ci), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_view(h, 4, &nfr, &v), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_view_channel(h, &v, 0, &s0, &s1), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_view_check(h, &v, &u), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_port_close(h), BASS_ERR_INVALID_HANDLE);
    }
    bass_writer *wforged[] = {w, (bass_writer *)(uintptr_t)1, (bass_writer *)(void *)&stack_var,
                              (bass_writer *)(uintptr_t)UINTPTR_MAX};
    const int32_t *planes[CH] = {l, r};
    for (size_t k = 0; k < sizeof wforged / sizeof wforged[0]; k++) {
        bass_writer *h = wforged[k];
        EXPECT(bass_writer_publish_interleaved(h, l, NFPC * CH, NULL, NULL), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_writer_publish_planar(h, planes, CH, NFPC, NULL, NULL), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_writer_publish_gap(h, NULL, NULL), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_writer_set_state(h, BASS_STATE_STOPPED, 0, NULL), BASS_ERR_INVALID_HANDLE);
        EXPECT(bass_writer_close(h), BASS_ERR_INVALID_HANDLE);
    }
    CHECK(stack_var == 0);
}

/* ---- threads ---- */

struct shared {
    bass_port *port;
    atomic_int stop;
    atomic_ulong checked, corrupted, bad_codes, reads;
};

static void *reader_thread(void *arg) {
    struct shared *s = arg;
    int32_t l[NFOP], r[NFOP];
    uint64_t nfr = 1;
    while (!atomic_load(&s->stop)) {
        uint64_t before = nfr, loss = 0;
        size_t n = 0;
        if (bass_get_audio_data(s->port, NFOP, &nfr, l, r, &n, &loss) != BASS_OK) {
            atomic_fetch_add(&s->bad_codes, 1);
            continue;
        }
        uint64_t first = before + loss;
        for (size_t i = 0; i < n; i++) {
            uint64_t f = first + i;
            if (l[i] != (f ? pattern(f, 0) : 0) || r[i] != (f ? pattern(f, 1) : 0)) atomic_fetch_add(&s->corrupted, 1);
        }
        atomic_fetch_add(&s->checked, n);
        atomic_fetch_add(&s->reads, 1);
        bass_port_info info;
        if (bass_port_get_info(s->port, &info) != BASS_OK) atomic_fetch_add(&s->bad_codes, 1);
    }
    return NULL;
}

struct pub {
    bass_writer *w;
    int chunks;
    atomic_ulong bad;
};

static void *gap_publisher(void *arg) {
    struct pub *p = arg;
    for (int i = 0; i < p->chunks; i++)
        if (bass_writer_publish_gap(p->w, NULL, NULL) != BASS_OK) atomic_fetch_add(&p->bad, 1);
    return NULL;
}

struct closer {
    bass_port *port;
    atomic_int phase; /* 0 running ok, 1 saw INVALID_HANDLE */
    atomic_ulong ok_calls, other_codes;
    atomic_int readers_running; /* reader threads that made a successful call */
    atomic_int waiter_tid;      /* thread id of the waiting thread, once it is about to wait */
};

static void *use_until_closed(void *arg) {
    struct closer *c = arg;
    int32_t l[NFOP], r[NFOP];
    int counted = 0;
    for (;;) {
        uint64_t nfr = 0, loss;
        size_t n;
        bass_result res = bass_get_audio_data(c->port, NFOP, &nfr, l, r, &n, &loss);
        if (res == BASS_OK) {
            atomic_fetch_add(&c->ok_calls, 1);
            if (!counted) {
                atomic_fetch_add(&c->readers_running, 1);
                counted = 1;
            }
        } else if (res == BASS_ERR_INVALID_HANDLE) {
            atomic_store(&c->phase, 1);
            return NULL;
        } else {
            atomic_fetch_add(&c->other_codes, 1);
            return NULL;
        }
    }
}

static void *wait_while_closed(void *arg) {
    struct closer *c = arg;
    uint64_t lfi;
    /* Blocks in the library while the main thread closes the handle: must end normally. */
    atomic_store(&c->waiter_tid, (int)syscall(SYS_gettid));
    bass_result res = bass_port_wait(c->port, UINT64_MAX / 2, 2000, &lfi);
    if (res != BASS_ERR_TIMEOUT) atomic_fetch_add(&c->other_codes, 1);
    return NULL;
}

static void sleep_us(long us) {
    struct timespec ts = {us / 1000000, (us % 1000000) * 1000L};
    nanosleep(&ts, NULL);
}

/* Whether thread `tid` of this process sleeps in futex(2) now: the first field of
 * /proc/self/task/TID/syscall is the number of the call it is blocked in. */
static int blocked_in_futex(int tid) {
    char path[64];
    snprintf(path, sizeof path, "/proc/self/task/%d/syscall", tid);
    FILE *f = fopen(path, "r");
    if (!f) return 0;
    long nr = -1;
    int ok = fscanf(f, "%ld", &nr) == 1;
    fclose(f);
    return ok && nr == SYS_futex;
}

static void test_threads(void) {
    bass_writer *w = NULL;
    bass_port *p = NULL;
    EXPECT(bass_writer_create("abuse-mt", "mt", 48000, NFPC, NCOP, CH, &w), BASS_OK);
    EXPECT(bass_port_open("abuse-mt", &p), BASS_OK);
    if (!w || !p) return;
    struct shared s = {.port = p};
    pthread_t t[4];
    for (int i = 0; i < 4; i++) pthread_create(&t[i], NULL, reader_thread, &s);
    uint64_t next = 1;
    int chunks = 20000;
    for (int i = 0; i < chunks; i++) publish_pattern(w, &next);
    atomic_store(&s.stop, 1);
    for (int i = 0; i < 4; i++) pthread_join(t[i], NULL);
    printf("FIGURE item 6: 4 threads sharing one bass_port while a writer published %d chunks: %lu reads, %lu frames x 2 checked, %lu corrupted, %lu unexpected codes\n",
           chunks, atomic_load(&s.reads), atomic_load(&s.checked), atomic_load(&s.corrupted), atomic_load(&s.bad_codes));
    CHECK(atomic_load(&s.corrupted) == 0);
    CHECK(atomic_load(&s.bad_codes) == 0);
    CHECK(atomic_load(&s.checked) > 0);

    /* Two threads publish through one writer handle: serialised, every chunk counted. */
    bass_port_info before, after;
    EXPECT(bass_port_get_info(p, &before), BASS_OK);
    struct pub pub = {.w = w, .chunks = 2000};
    pthread_t pt[2];
    for (int i = 0; i < 2; i++) pthread_create(&pt[i], NULL, gap_publisher, &pub);
    for (int i = 0; i < 2; i++) pthread_join(pt[i], NULL);
    EXPECT(bass_port_get_info(p, &after), BASS_OK);
    CHECK(atomic_load(&pub.bad) == 0);
    CHECK(after.last_frame_index - before.last_frame_index == 2u * 2000u * NFPC);
    CHECK(after.chunks_published - before.chunks_published == 2u * 2000u);
    CHECK(after.gap_frames - before.gap_frames == 2u * 2000u * NFPC);
    printf("FIGURE item 6: 2 threads x 2000 chunks through one bass_writer: lastFrameIndex +%" PRIu64 ", chunks +%" PRIu64 " (expected %d, %d)\n",
           after.last_frame_index - before.last_frame_index, after.chunks_published - before.chunks_published,
           2 * 2000 * NFPC, 2 * 2000);

    /* Close a handle while other threads are using it. */
    struct closer c = {.port = NULL};
    EXPECT(bass_port_open("abuse-mt", &c.port), BASS_OK);
    pthread_t ct[3];
    pthread_create(&ct[0], NULL, use_until_closed, &c);
    pthread_create(&ct[1], NULL, use_until_closed, &c);
    pthread_create(&ct[2], NULL, wait_while_closed, &c);
    /* Close once both readers are reading and the waiter sleeps inside bass_port_wait (its
     * 2 s timeout far beyond this 1 s bound, which only guards against a hang). */
    int in_use = 0;
    for (int i = 0; i < 10000 && !in_use; i++) {
        int tid = atomic_load(&c.waiter_tid);
        in_use = atomic_load(&c.readers_running) == 2 && tid != 0 && blocked_in_futex(tid);
        if (!in_use) sleep_us(100);
    }
    CHECK(in_use);
    EXPECT(bass_port_close(c.port), BASS_OK);
    for (int i = 0; i < 3; i++) pthread_join(ct[i], NULL);
    CHECK(atomic_load(&c.phase) == 1);
    CHECK(atomic_load(&c.other_codes) == 0);
    printf("FIGURE item 6: handle closed while 2 threads read and 1 waits: %lu calls OK before, then BASS_ERR_INVALID_HANDLE; the wait ended with BASS_ERR_TIMEOUT; unexpected codes %lu\n",
           atomic_load(&c.ok_calls), atomic_load(&c.other_codes));
    EXPECT(bass_port_close(p), BASS_OK);
    EXPECT(bass_writer_close(w), BASS_OK);
}

static void test_view_write_faults(bass_port *p) {
    bass_view v;
    uint64_t nfr = 1;
    EXPECT(bass_port_view(p, 4, &nfr, &v), BASS_OK);
    fflush(NULL);
    pid_t pid = fork();
    if (pid == 0) {
        /* The view points into the read-only mapping: this store must fault. The default
         * action is restored first, since ASan installs a SIGSEGV handler of its own. */
        struct sigaction sa;
        memset(&sa, 0, sizeof sa);
        sa.sa_handler = SIG_DFL;
        sigaction(SIGSEGV, &sa, NULL);
        ((volatile int32_t *)v.left[0])[0] = 42;
        _exit(0);
    }
    int status = 0;
    waitpid(pid, &status, 0);
    CHECK(WIFSIGNALED(status) && WTERMSIG(status) == SIGSEGV);
    printf("FIGURE item 6: write through a bass_port_view pointer in a child: %s\n",
           WIFSIGNALED(status) && WTERMSIG(status) == SIGSEGV ? "SIGSEGV" : "did not fault");
}

int main(void) {
    if (!getenv("BASS_RUNTIME_DIR")) {
        fprintf(stderr, "set BASS_RUNTIME_DIR to an empty directory\n");
        return 2;
    }
    bass_writer *w = NULL;
    bass_port *p = NULL;
    EXPECT(bass_writer_create("abuse", "abuse", 48000, NFPC, NCOP, CH, &w), BASS_OK);
    EXPECT(bass_port_open("abuse", &p), BASS_OK);
    if (!w || !p) return 1;
    uint64_t next = 1;
    for (int i = 0; i < 2 * NCOP + 1; i++) publish_pattern(w, &next);
    test_nulls(p, w);
    test_sizes(p, w);
    test_handles(w);
    test_threads();
    test_view_write_faults(p); /* after test_threads: no other thread runs at the fork */
    EXPECT(bass_port_close(p), BASS_OK);
    EXPECT(bass_port_close(p), BASS_ERR_INVALID_HANDLE);
    EXPECT(bass_writer_close(w), BASS_OK);
    EXPECT(bass_writer_close(w), BASS_ERR_INVALID_HANDLE);
    printf("abi_abuse: %d checks, %d failures\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
