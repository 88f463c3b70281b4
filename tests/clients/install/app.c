/* An out-of-tree client built against an installed bass (pkg-config or CMake): asks the
 * broker for the simulated pattern device, reads the first 4800 frames and checks them.
 * Usage: app BROKER     prints "app: ok ..." and exits 0 on success. */
#include <inttypes.h>
#include <stdio.h>

#include <bass.h>

static int fail(const char *what, bass_result r) {
    fprintf(stderr, "app: %s: %s (%s)\n", what, bass_result_str(r), bass_last_error());
    return 1;
}

int main(int argc, char **argv) {
    const char *broker = argc > 1 ? argv[1] : NULL;
    uint64_t epoch = 0;
    bass_result r = bass_acquire(broker, "sim:pattern", 48000, 480, 20, 2, &epoch);
    if (r) return fail("bass_acquire", r);
    bass_port *port = NULL;
    if ((r = bass_port_open(broker ? broker : "default", &port))) return fail("bass_port_open", r);
    static int32_t left[4800], right[4800];
    uint64_t nfr = 1, lost = 0, bad = 0;
    size_t got = 0;
    while (got < 4800) {
        if ((r = bass_port_wait(port, nfr, 5000, NULL))) return fail("bass_port_wait", r);
        size_t n = 0;
        uint64_t loss = 0;
        if ((r = bass_get_audio_data(port, 4800 - got, &nfr, left + got, right + got, &n, &loss)))
            return fail("bass_get_audio_data", r);
        got += n;
        lost += loss;
    }
    for (size_t i = 0; i < got; i++) {
        uint32_t f = (uint32_t)(i + 1);
        if (left[i] != (int32_t)(f << 6) || right[i] != (int32_t)((f << 6) | 1u)) bad++;
    }
    bass_broker_status st;
    if ((r = bass_status(broker, &st))) return fail("bass_status", r);
    if ((r = bass_stop(broker))) return fail("bass_stop", r);
    bass_port_close(port);
    if (lost || bad || st.sample_rate != 48000 || st.epoch != epoch) {
        fprintf(stderr, "app: lost %" PRIu64 ", %" PRIu64 " bad frames, rate %u, epoch %" PRIu64 "/%" PRIu64 "\n", lost,
                bad, st.sample_rate, st.epoch, epoch);
        return 1;
    }
    printf("app: ok, frames 1..%zu of epoch %" PRIu64 " hold the pattern (%s)\n", got, epoch, bass_version());
    return 0;
}
