/* Conformance driver in C: replays vectors.txt (see gen_vectors.py) through the writer and
 * reader C ABI and prints the file back with the `read` results observed.
 * Usage: driver_c VECTORS > OUT   (ports in $BASS_RUNTIME_DIR) */
#define _POSIX_C_SOURCE 200809L
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bass.h"

static void die(const char *what, bass_result r) {
    fprintf(stderr, "driver_c: %s: %s (%s)\n", what, bass_result_str(r), bass_last_error());
    exit(1);
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: driver_c VECTORS\n");
        return 2;
    }
    FILE *in = fopen(argv[1], "r");
    if (!in) {
        perror(argv[1]);
        return 1;
    }
    char *line = NULL;
    size_t cap = 0;
    bass_writer *w = NULL;
    bass_port *p = NULL;
    char port_name[64];
    int32_t *buf = NULL, *left = NULL, *right = NULL;
    size_t buf_cap = 0;
    unsigned long channels = 0;
    while (getline(&line, &cap, in) > 0) {
        line[strcspn(line, "\n")] = 0;
        char *save = NULL;
        char *tok = strtok_r(line, " ", &save);
        if (!tok) continue;
        if (!strcmp(tok, "case")) {
            char *name = strtok_r(NULL, " ", &save);
            channels = strtoul(strtok_r(NULL, " ", &save), NULL, 10);
            unsigned long rate = strtoul(strtok_r(NULL, " ", &save), NULL, 10);
            unsigned long fpc = strtoul(strtok_r(NULL, " ", &save), NULL, 10);
            unsigned long cop = strtoul(strtok_r(NULL, " ", &save), NULL, 10);
            snprintf(port_name, sizeof port_name, "conf-c-%ld", (long)getpid());
            bass_result r = bass_writer_create(port_name, "conformance", (uint32_t)rate, (uint32_t)fpc,
                                               (uint32_t)cop, (uint32_t)channels, &w);
            if (r) die("bass_writer_create", r);
            if ((r = bass_port_open(port_name, &p))) die("bass_port_open", r);
            printf("case %s %lu %lu %lu %lu\n", name, channels, rate, fpc, cop);
        } else if (!strcmp(tok, "publish")) {
            size_t n = 0;
            for (char *v; (v = strtok_r(NULL, " ", &save));) {
                if (n == buf_cap) {
                    buf_cap = buf_cap ? 2 * buf_cap : 64;
                    buf = realloc(buf, buf_cap * sizeof *buf);
                    if (!buf) return 1;
                }
                buf[n++] = (int32_t)strtol(v, NULL, 10);
            }
            bass_result r = bass_writer_publish_interleaved(w, buf, n, NULL, NULL);
            if (r) die("bass_writer_publish_interleaved", r);
            printf("publish");
            for (size_t i = 0; i < n; i++) printf(" %" PRId32, buf[i]);
            printf("\n");
        } else if (!strcmp(tok, "read")) {
            size_t want = (size_t)strtoull(strtok_r(NULL, " ", &save), NULL, 10);
            uint64_t nfr_in = strtoull(strtok_r(NULL, " ", &save), NULL, 10);
            uint64_t nfr = nfr_in, loss = 0;
            size_t n = 0;
            left = realloc(left, (want ? want : 1) * sizeof *left);
            right = realloc(right, (want ? want : 1) * sizeof *right);
            if (!left || !right) return 1;
            bass_result r = bass_get_audio_data(p, want, &nfr, left, right, &n, &loss);
            if (r) die("bass_get_audio_data", r);
            printf("read %zu %" PRIu64 " %zu %" PRIu64 " %" PRIu64, want, nfr_in, n, nfr, loss);
            for (size_t i = 0; i < n; i++) printf(" %" PRId32 " %" PRId32, left[i], right[i]);
            printf("\n");
        } else if (!strcmp(tok, "readm")) {
            size_t want = (size_t)strtoull(strtok_r(NULL, " ", &save), NULL, 10);
            uint64_t nfr_in = strtoull(strtok_r(NULL, " ", &save), NULL, 10);
            uint64_t nfr = nfr_in, loss = 0;
            size_t n = 0, frames = want ? want : 1;
            int32_t *chans[BASS_MAX_CHANNELS];
            for (unsigned long c = 0; c < channels; c++)
                if (!(chans[c] = malloc(frames * sizeof(int32_t)))) return 1;
            bass_result r = bass_get_audio_data_multi(p, want, &nfr, chans, channels, &n, &loss);
            if (r) die("bass_get_audio_data_multi", r);
            printf("readm %zu %" PRIu64 " %zu %" PRIu64 " %" PRIu64, want, nfr_in, n, nfr, loss);
            for (size_t i = 0; i < n; i++)
                for (unsigned long c = 0; c < channels; c++) printf(" %" PRId32, chans[c][i]);
            printf("\n");
            for (unsigned long c = 0; c < channels; c++) free(chans[c]);
        } else if (!strcmp(tok, "end")) {
            bass_port_close(p);
            bass_writer_close(w);
            p = NULL;
            w = NULL;
            printf("end\n");
        } else {
            /* header and comments: echoed, restoring the spaces strtok replaced */
            printf("%s", tok);
            for (char *v; (v = strtok_r(NULL, " ", &save));) printf(" %s", v);
            printf("\n");
        }
    }
    free(line);
    free(buf);
    free(left);
    free(right);
    fclose(in);
    return 0;
}
