/* sim_writer: a paced simulated device for tests, written with the bass writer C ABI.
 *
 * Publishes the pattern signal (every sample names its frame and channel:
 * ((frame & 0x3FFFFFF) << 6) | channel) into the port NAME, one chunk every
 * nFramesPerChunk / sampleRate seconds on CLOCK_MONOTONIC (absolute deadlines, so the
 * long-run rate is exact), until SIGINT/SIGTERM or --chunks K chunks.
 *
 * Usage: sim_writer [--name NAME] [--rate HZ] [--fpc N] [--cop N] [--channels C]
 *                   [--chunks K] [--fast]
 * Ports live in $BASS_RUNTIME_DIR (default /dev/shm). --fast publishes without pacing.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <signal.h>
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

static int32_t pattern_sample(uint64_t frame, uint32_t channel) {
    return (int32_t)(((uint32_t)(frame & 0x3FFFFFFu) << 6) | (channel & 63u));
}

static unsigned long arg_ul(const char *s, const char *what) {
    char *end = NULL;
    errno = 0;
    unsigned long v = strtoul(s, &end, 10);
    if (errno || end == s || *end) {
        fprintf(stderr, "sim_writer: bad %s: %s\n", what, s);
        exit(2);
    }
    return v;
}

int main(int argc, char **argv) {
    const char *name = "default";
    unsigned long rate = 44100, fpc = 2205, cop = 20, channels = 2, chunks = 0;
    int fast = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--fast")) {
            fast = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "sim_writer: %s needs a value (see the comment at the top of sim_writer.c)\n", a);
            return 2;
        }
        if (!strcmp(a, "--name")) name = v;
        else if (!strcmp(a, "--rate")) rate = arg_ul(v, "rate");
        else if (!strcmp(a, "--fpc")) fpc = arg_ul(v, "fpc");
        else if (!strcmp(a, "--cop")) cop = arg_ul(v, "cop");
        else if (!strcmp(a, "--channels")) channels = arg_ul(v, "channels");
        else if (!strcmp(a, "--chunks")) chunks = arg_ul(v, "chunks");
        else {
            fprintf(stderr, "sim_writer: unknown option %s\n", a);
            return 2;
        }
        i++;
    }
    if (!rate || !fpc || !cop || !channels || channels > BASS_MAX_CHANNELS) {
        fprintf(stderr, "sim_writer: rate, fpc, cop must be > 0 and channels 1..%d\n", BASS_MAX_CHANNELS);
        return 2;
    }

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    bass_writer *w = NULL;
    bass_result r = bass_writer_create(name, "sim_writer:pattern", (uint32_t)rate, (uint32_t)fpc, (uint32_t)cop,
                                       (uint32_t)channels, &w);
    if (r != BASS_OK) {
        fprintf(stderr, "sim_writer: bass_writer_create: %s (%s)\n", bass_result_str(r), bass_last_error());
        return 1;
    }
    int32_t *buf = malloc(sizeof(int32_t) * fpc * channels);
    if (!buf) return 1;

    const long long period_ns = (long long)(1000000000.0 * (double)fpc / (double)rate);
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    uint64_t lfi = 0;
    fprintf(stderr, "sim_writer: port %s, %lu Hz, %lu frames/chunk, %lu chunks on port, %lu channels\n", name,
            rate, fpc, cop, channels);
    for (unsigned long k = 0; !stop_requested && (chunks == 0 || k < chunks); k++) {
        if (!fast) {
            next.tv_nsec += period_ns;
            while (next.tv_nsec >= 1000000000L) {
                next.tv_nsec -= 1000000000L;
                next.tv_sec++;
            }
            int e;
            while ((e = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL)) == EINTR && !stop_requested) {
            }
            if (stop_requested) break;
        }
        for (unsigned long f = 0; f < fpc; f++)
            for (unsigned long c = 0; c < channels; c++)
                buf[f * channels + c] = pattern_sample(lfi + 1 + f, (uint32_t)c);
        r = bass_writer_publish_interleaved(w, buf, fpc * channels, NULL, &lfi);
        if (r != BASS_OK) {
            fprintf(stderr, "sim_writer: publish: %s (%s)\n", bass_result_str(r), bass_last_error());
            break;
        }
    }
    free(buf);
    bass_writer_close(w);
    fprintf(stderr, "sim_writer: stopped at frame %llu\n", (unsigned long long)lfi);
    return r == BASS_OK ? 0 : 1;
}
