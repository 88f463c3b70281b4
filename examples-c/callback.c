/* callback: the callback stream of libbassclient (docs/c-api.md, "Callback streams").
 * Prints where each of 10 blocks starts, how many frames it holds and how many were lost
 * before it, then stops. Usage: callback [PORT]   (default "default")
 * Build: cc -std=c11 callback.c $(pkg-config --cflags --libs bassclient) */
#include <stdio.h>

#include "bass.h"

static int on_block(const bass_block *b, void *user) {
    int *left = user;
    printf("frame %llu: %zu frames, %llu lost, flags 0x%x, ch0[0] = %d\n", (unsigned long long)b->first_frame,
           b->frames, (unsigned long long)b->lost, b->flags, b->frames ? b->channels[0][0] : 0);
    return --*left == 0; /* non-zero: stop */
}

static int on_event(const bass_stream_event *e, void *user) {
    (void)user;
    fprintf(stderr, "event %u (frame %llu) %s\n", e->kind, (unsigned long long)e->frame, e->message);
    return e->kind != BASS_EVENT_RESTARTED; /* follow a restart; end on anything else */
}

int main(int argc, char **argv) {
    bass_port *port;
    bass_stream *stream;
    bass_stream_config cfg = {0}; /* one chunk per call, planar, every channel */
    cfg.start = BASS_START_NOW;
    int left = 10;
    if (bass_port_open(argc > 1 ? argv[1] : "default", &port) != BASS_OK ||
        bass_stream_create(port, &cfg, on_block, on_event, &left, &stream) != BASS_OK ||
        bass_stream_run(stream) != BASS_OK) { /* on this thread, until a callback says stop */
        fprintf(stderr, "%s\n", bass_last_error());
        return 1;
    }
    bass_stream_close(stream);
    bass_port_close(port);
    return 0;
}
