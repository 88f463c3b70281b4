/* basc: the BASC client of the BASS documentation, in C over libbassclient.
 *
 * GetBlocks(nBlocks, nFramesPerBlock, startOffs) with the seed's defaults (1, 12000,
 * -12000). Two modes:
 *
 *   periodic (default, the seed's): one bass_get_audio_data() call every --period-ms
 *     (250 ms), either requesting a new block or completing the current one. A block
 *     shorter than one period loses frames: that is the seed's example 2.
 *   --wait: blocks on the port's futex (bass_port_wait) until the frames of the block are
 *     published, reading at least every half window; it never loses frames, whatever the
 *     block size, as long as the process is scheduled within half a window.
 *   --callback: the same blocks from a callback stream (bass_stream_start): the library's
 *     thread calls on_block with each whole block, its first frame and the frames lost
 *     before it; the lines printed are the blocking modes' (one "Requested" line per block).
 *
 * Printed on stdout, exactly as in the seed:
 *   "Requested %6zu frames, got %6zu."     (one line per getAudioData call)
 *   "!!Lost %llu frames!!"                  (when the call reports a loss)
 *   "A new block is ready to be processed."
 *
 * startOffs: the first frame to read is nfr = lastFrameIndex + 1 + startOffs, i.e. counted
 * from the first frame not yet on the port: 0 reads only fresh frames, -12000 the last 12000
 * frames on the port (the seed's default description). This is the convention that
 * reproduces the seed's printed examples (see docs/clients.md). nfr is an unsigned 64-bit
 * index here, so an offset reaching before frame 0 is clamped to 0 (the seed's formal
 * algorithm would count the negative part as lost frames).
 *
 * nBlocks = 0 runs until Ctrl-C (SIGINT) or SIGTERM.
 *
 * Exit status: 0 done; 1 a failed call, or the acquisition ended (stopped, device error,
 * replaced); 2 usage; 3 pattern mismatch; 4 the broker writing the port died (both modes
 * notice it within about 100 ms of the next call that finds no new frames).
 *
 * Test options: --check-pattern verifies every delivered sample against the pattern test
 * signal (exit status 3 on a mismatch); --trace prints one "trace ..." line per call on
 * stderr with the last frame index seen just before and after the call; --no-align starts
 * the period clock right away instead of half a chunk after a publish.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <inttypes.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bass.h"

static volatile sig_atomic_t stop_requested;

static void on_signal(int sig) {
    (void)sig;
    stop_requested = 1;
}

struct options {
    const char *port;
    unsigned long n_blocks;
    unsigned long frames_per_block;
    long long start_offs;
    unsigned long period_ms;
    int wait_mode;
    int callback_mode;
    int check_pattern;
    int trace;
    int align;
};

static void usage(FILE *f) {
    fprintf(f,
            "usage: basc [--port NAME] [--period-ms MS | --wait] [--check-pattern] [--trace]\n"
            "            [--no-align] [nBlocks [nFramesPerBlock [startOffs]]]\n"
            "  GetBlocks(nBlocks = 1, nFramesPerBlock = 12000, startOffs = -12000); nBlocks 0 = until Ctrl-C.\n"
            "  --port NAME     port (= broker) name, default \"default\" (in $BASS_RUNTIME_DIR or /dev/shm)\n"
            "  --period-ms MS  period of the getAudioData calls (default 250)\n"
            "  --wait          block on the port until frames arrive instead (never loses frames)\n"
            "  --callback      receive the blocks from a callback stream (bass_stream_start)\n");
}

static int parse_ull(const char *s, unsigned long *out) {
    char *end = NULL;
    errno = 0;
    unsigned long v = strtoul(s, &end, 10);
    if (errno || end == s || *end || s[0] == '-') return -1;
    *out = v;
    return 0;
}

static int parse_ll(const char *s, long long *out) {
    char *end = NULL;
    errno = 0;
    long long v = strtoll(s, &end, 10);
    if (errno || end == s || *end) return -1;
    *out = v;
    return 0;
}

static int parse_args(int argc, char **argv, struct options *o) {
    int positional = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            exit(0);
        } else if (!strcmp(a, "--port") && i + 1 < argc) {
            o->port = argv[++i];
        } else if (!strcmp(a, "--period-ms") && i + 1 < argc) {
            if (parse_ull(argv[++i], &o->period_ms) || o->period_ms == 0) return -1;
        } else if (!strcmp(a, "--wait")) {
            o->wait_mode = 1;
        } else if (!strcmp(a, "--callback")) {
            o->callback_mode = 1;
        } else if (!strcmp(a, "--check-pattern")) {
            o->check_pattern = 1;
        } else if (!strcmp(a, "--trace")) {
            o->trace = 1;
        } else if (!strcmp(a, "--no-align")) {
            o->align = 0;
        } else if (positional == 0 && !parse_ull(a, &o->n_blocks)) {
            positional++;
        } else if (positional == 1 && !parse_ull(a, &o->frames_per_block) && o->frames_per_block > 0) {
            positional++;
        } else if (positional == 2 && !parse_ll(a, &o->start_offs)) {
            positional++;
        } else {
            fprintf(stderr, "basc: bad argument: %s\n", a);
            return -1;
        }
    }
    return 0;
}

static int32_t pattern_expected(uint64_t frame, uint32_t channel) {
    if (frame == 0) return 0;
    return (int32_t)(((uint32_t)(frame & 0x3FFFFFFu) << 6) | (channel & 63u));
}

/* The last frame index now (for --trace only; UINT64_MAX if the header cannot be read). */
static uint64_t lfi_now(const bass_port *port) {
    bass_port_info info;
    if (bass_port_get_info(port, &info) != BASS_OK) return UINT64_MAX;
    return info.last_frame_index;
}

static void timespec_add_ns(struct timespec *t, long long ns) {
    t->tv_sec += (time_t)(ns / 1000000000LL);
    t->tv_nsec += (long)(ns % 1000000000LL);
    if (t->tv_nsec >= 1000000000L) {
        t->tv_nsec -= 1000000000L;
        t->tv_sec++;
    }
}

/* Sleeps until the absolute CLOCK_MONOTONIC time `t`; returns -1 if a stop was requested. */
static int sleep_until(const struct timespec *t) {
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, t, NULL) == EINTR)
        if (stop_requested) return -1;
    return stop_requested ? -1 : 0;
}

/* Reports a failed call and returns the exit status for it. */
static int fail(const char *what, bass_result r) {
    fprintf(stderr, "basc: %s: %s (%s)\n", what, bass_result_str(r), bass_last_error());
    return 1;
}

/* The state of a --callback run, shared by the stream's thread and main. */
struct cb_run {
    const struct options *o;
    unsigned long blocks;
    size_t remaining; /* frames still missing from the current block */
    uint64_t total_loss, mismatches, next;
    atomic_int done; /* 1: the stream ended (enough blocks, or the acquisition ended) */
    int status;
};

static int on_block(const bass_block *b, void *user) {
    struct cb_run *run = user;
    if (run->o->check_pattern)
        for (size_t i = 0; i < b->frames; i++)
            if (b->channels[0][i] != pattern_expected(b->first_frame + i, 0) ||
                b->channels[1][i] != pattern_expected(b->first_frame + i, 1))
                run->mismatches++;
    /* One callback holds at most half a window; a block is completed by as many callbacks as
     * it takes, each printed as the blocking modes print one read. */
    for (size_t off = 0; off < b->frames;) {
        size_t requested = run->remaining ? run->remaining : run->o->frames_per_block;
        size_t take = b->frames - off < requested ? b->frames - off : requested;
        printf("Requested %6zu frames, got %6zu.\n", requested, take);
        if (off == 0 && b->lost) {
            printf("!!Lost %" PRIu64 " frames!!\n", b->lost);
            run->total_loss += b->lost;
        }
        run->remaining = requested - take;
        off += take;
        if (run->remaining == 0) {
            printf("A new block is ready to be processed.\n");
            run->blocks++;
            if (run->o->n_blocks && run->blocks >= run->o->n_blocks) {
                run->next = b->first_frame + off;
                fflush(stdout);
                atomic_store(&run->done, 1);
                return 1;
            }
        }
    }
    fflush(stdout);
    run->next = b->first_frame + b->frames;
    return 0;
}

static int on_event(const bass_stream_event *e, void *user) {
    struct cb_run *run = user;
    if (e->kind == BASS_EVENT_REALTIME_REFUSED) return 0;
    fprintf(stderr, "basc: the acquisition ended (%s)%s%s\n",
            e->kind == BASS_EVENT_WRITER_GONE ? "writer gone"
            : e->kind == BASS_EVENT_DEVICE    ? "device error"
            : e->kind == BASS_EVENT_RESTARTED ? "restarted"
                                              : "stopped",
            e->message[0] ? ": " : "", e->message);
    run->status = e->kind == BASS_EVENT_WRITER_GONE ? 4 : 1;
    atomic_store(&run->done, 1);
    return 1;
}

/* --callback: the blocks from a callback stream on the library's thread; main waits for its
 * end or for Ctrl-C / SIGTERM. */
static int run_callback(bass_port *port, const struct options *o, uint64_t nfr, uint64_t frames_on_port) {
    struct cb_run run = {o, 0, 0, 0, 0, nfr, 0, 0};
    bass_stream_config c;
    memset(&c, 0, sizeof c);
    size_t half = (size_t)(frames_on_port / 2) ? (size_t)(frames_on_port / 2) : 1;
    c.frames_per_call = o->frames_per_block < half ? o->frames_per_block : half;
    c.start = BASS_START_FRAME;
    c.start_frame = nfr ? nfr : 1;
    bass_stream *stream = NULL;
    bass_result r = bass_stream_start(port, &c, on_block, on_event, &run, &stream);
    if (r != BASS_OK) return fail("bass_stream_start", r);
    while (!stop_requested && !atomic_load(&run.done)) {
        struct timespec t = {0, 20000000L};
        nanosleep(&t, NULL);
    }
    r = bass_stream_close(stream);
    if (r != BASS_OK && !run.status) run.status = fail("bass_stream_close", r);
    fprintf(stderr, "basc: %lu block(s) of %lu frames, %" PRIu64 " frames lost, next frame %" PRIu64 "\n", run.blocks,
            o->frames_per_block, run.total_loss, run.next);
    if (run.mismatches) {
        fprintf(stderr, "basc: %" PRIu64 " frames did not hold the pattern signal\n", run.mismatches);
        return 3;
    }
    return run.status;
}

int main(int argc, char **argv) {
    struct options o = {"default", 1, 12000, -12000, 250, 0, 0, 0, 0, 1};
    if (parse_args(argc, argv, &o)) {
        usage(stderr);
        return 2;
    }

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal; /* no SA_RESTART: a signal interrupts waits and sleeps */
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    bass_port *port = NULL;
    bass_result r = bass_port_open(o.port, &port);
    if (r != BASS_OK) return fail("bass_port_open", r);
    bass_port_info info;
    r = bass_port_get_info(port, &info);
    if (r != BASS_OK) return fail("bass_port_get_info", r);
    if (info.channels < 2) {
        fprintf(stderr, "basc: port %s has %u channel(s); BASC reads binaural ports\n", o.port, info.channels);
        return 1;
    }

    const long long chunk_ns = (long long)(1e9 * info.frames_per_chunk / info.sample_rate);
    const long long period_ns = (long long)o.period_ms * 1000000LL;
    /* Periodic mode: start the period clock half a chunk after a publish, so that a
     * scheduling delay of up to half a chunk never changes which chunks a call sees. */
    if (!o.wait_mode && !o.callback_mode && o.align && info.state == BASS_STATE_CAPTURING) {
        uint64_t lfi = 0;
        r = bass_port_wait(port, info.last_frame_index + 1, 10000, &lfi);
        if (r == BASS_OK) {
            struct timespec t;
            clock_gettime(CLOCK_MONOTONIC, &t);
            timespec_add_ns(&t, chunk_ns / 2);
            if (sleep_until(&t)) return 0;
        } else if (r == BASS_ERR_INTERRUPTED) {
            return 0; /* Ctrl-C before the first call */
        } else if (r != BASS_ERR_TIMEOUT) {
            return fail("bass_port_wait", r);
        }
    }

    r = bass_port_get_info(port, &info);
    if (r != BASS_OK) return fail("bass_port_get_info", r);
    uint64_t lfi0 = info.last_frame_index;
    long long first = (long long)lfi0 + 1 + o.start_offs;
    uint64_t nfr = first < 0 ? 0 : (uint64_t)first; /* clamped: nfr is unsigned */
    if (o.trace) fprintf(stderr, "trace start lfi=%" PRIu64 " nfr=%" PRIu64 "\n", lfi0, nfr);
    if (o.callback_mode) {
        int st = run_callback(port, &o, nfr, info.frames_on_port);
        bass_port_close(port);
        return st;
    }

    size_t cap = o.frames_per_block;
    if (cap > info.frames_on_port) cap = (size_t)info.frames_on_port; /* at most nFOP per call */
    int32_t *left = malloc(sizeof(int32_t) * cap);
    int32_t *right = malloc(sizeof(int32_t) * cap);
    if (!left || !right) return 1;

    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    unsigned long blocks = 0;
    size_t remaining = 0; /* frames still missing from the current block; 0 = start a new one */
    uint64_t total_loss = 0, mismatches = 0;
    int status = 0;
    while (!stop_requested && (o.n_blocks == 0 || blocks < o.n_blocks)) {
        if (o.wait_mode) {
            /* Wake when the block is complete, or after half a window, whichever is first. */
            size_t want = remaining ? remaining : o.frames_per_block;
            uint64_t ahead = want;
            if (ahead > info.frames_on_port / 2) ahead = info.frames_on_port / 2;
            if (ahead == 0) ahead = 1;
            r = bass_port_wait(port, nfr + ahead - 1, 200, NULL);
            if (r == BASS_ERR_TIMEOUT) continue; /* sliced wait: re-check stop_requested */
            if (r == BASS_ERR_INTERRUPTED) continue;
            if (r != BASS_OK) {
                status = r == BASS_ERR_WRITER_GONE ? 4 : fail("bass_port_wait", r);
                if (status == 4) fprintf(stderr, "basc: the broker writing port %s is gone (%s); restart bassd\n", o.port, bass_last_error());
                break;
            }
        } else {
            timespec_add_ns(&next, period_ns);
            if (sleep_until(&next)) break;
        }

        size_t requested = remaining ? remaining : o.frames_per_block;
        size_t want = requested < cap ? requested : cap;
        size_t n = 0;
        uint64_t loss = 0, nfr_in = nfr, lfi_before = o.trace ? lfi_now(port) : 0;
        r = bass_get_audio_data(port, want, &nfr, left, right, &n, &loss);
        if (r != BASS_OK) {
            status = fail("bass_get_audio_data", r);
            break;
        }
        if (o.trace)
            fprintf(stderr,
                    "trace lfi_before=%" PRIu64 " lfi_after=%" PRIu64 " nfr_in=%" PRIu64 " requested=%zu n=%zu loss=%" PRIu64
                    " nfr_out=%" PRIu64 "\n",
                    lfi_before, lfi_now(port), nfr_in, requested, n, loss, nfr);
        if (o.check_pattern) {
            uint64_t f0 = nfr - n;
            for (size_t i = 0; i < n; i++)
                if (left[i] != pattern_expected(f0 + i, 0) || right[i] != pattern_expected(f0 + i, 1)) {
                    if (!mismatches)
                        fprintf(stderr, "basc: frame %" PRIu64 " holds (%d, %d), expected (%d, %d)\n", f0 + i, left[i],
                                right[i], pattern_expected(f0 + i, 0), pattern_expected(f0 + i, 1));
                    mismatches++;
                }
        }
        printf("Requested %6zu frames, got %6zu.\n", requested, n);
        if (loss) {
            printf("!!Lost %" PRIu64 " frames!!\n", loss);
            total_loss += loss;
        }
        remaining = requested - n;
        if (remaining == 0) {
            printf("A new block is ready to be processed.\n");
            blocks++;
        }
        fflush(stdout);
        /* The periodic mode never blocks, so it notices the end of the acquisition here: once
         * the port has nothing more to give and no longer captures, stop. */
        if (!o.wait_mode && n < requested) {
            /* A zero-timeout wait reports a writer that died without a word (killed broker:
             * the port still says "capturing"); the library checks the writer's pid. */
            uint64_t unused = 0;
            r = bass_port_wait(port, nfr, 0, &unused);
            if (r == BASS_ERR_WRITER_GONE) {
                fprintf(stderr, "basc: the broker writing port %s is gone (%s); restart bassd\n", o.port,
                        bass_last_error());
                status = 4;
                break;
            }
            bass_port_info now;
            r = bass_port_get_info(port, &now);
            if (r != BASS_OK) {
                status = fail("bass_port_get_info", r);
                break;
            }
            if (now.state != BASS_STATE_CAPTURING && now.state != BASS_STATE_IDLE &&
                now.state != BASS_STATE_STARTING && nfr > now.last_frame_index) {
                fprintf(stderr, "basc: the acquisition ended (state %s)%s%s\n", bass_state_str(now.state),
                        now.message[0] ? ": " : "", now.message);
                status = 1;
                break;
            }
        }
    }
    fprintf(stderr, "basc: %lu block(s) of %lu frames, %" PRIu64 " frames lost, next frame %" PRIu64 "\n", blocks,
            o.frames_per_block, total_loss, nfr);
    if (mismatches) {
        fprintf(stderr, "basc: %" PRIu64 " frames did not hold the pattern signal\n", mismatches);
        status = 3;
    }
    free(left);
    free(right);
    bass_port_close(port);
    return status;
}
