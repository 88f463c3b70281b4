// blocks: the C++ example. Reads consecutive blocks from a port with bass::block_reader and
// prints one line per block (frames, loss, peak of each channel); --check-pattern verifies the
// samples against the pattern test signal.
//
// Usage: blocks [--port NAME] [--acquire DEVICE] [--check-pattern] [nBlocks [nFramesPerBlock [startOffs]]]
//        (defaults: 10 blocks of 4410 frames from the next frame; startOffs as in basc)
//        --acquire first asks the broker NAME to acquire DEVICE (44100 Hz, 2205 x 20), lists
//        its devices and prints its status.
#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "bass.hpp"

static std::int32_t pattern_expected(std::uint64_t frame, std::uint32_t channel) {
    if (frame == 0) return 0;
    return static_cast<std::int32_t>((static_cast<std::uint32_t>(frame & 0x3FFFFFFu) << 6) | (channel & 63u));
}

int main(int argc, char **argv) {
    std::string name = "default", device;
    bool check_pattern = false;
    long long args[3] = {10, 4410, 0};
    int positional = 0;
    for (int i = 1; i < argc; i++) {
        if (!std::strcmp(argv[i], "--port") && i + 1 < argc) name = argv[++i];
        else if (!std::strcmp(argv[i], "--acquire") && i + 1 < argc) device = argv[++i];
        else if (!std::strcmp(argv[i], "--check-pattern")) check_pattern = true;
        else if (positional < 3) args[positional++] = std::strtoll(argv[i], nullptr, 10);
        else {
            std::fprintf(stderr,
                         "usage: blocks [--port NAME] [--acquire DEVICE] [--check-pattern] [nBlocks [nFramesPerBlock "
                         "[startOffs]]]\n");
            return 2;
        }
    }
    if (args[0] < 0 || args[1] <= 0) {
        std::fprintf(stderr, "blocks: nBlocks must be >= 0 and nFramesPerBlock > 0\n");
        return 2;
    }
    try {
        if (!device.empty()) {
            for (const auto &d : bass::list_devices(name)) std::printf("device %s: %s\n", d.first.c_str(), d.second.c_str());
            std::uint64_t epoch = bass::acquire(device, 44100, 2205, 20, 2, name);
            bass::port waiting(name);
            waiting.wait(1, std::chrono::seconds(5));  // the first chunk
            bass_broker_status st = bass::status(name);
            std::printf("acquired %s: epoch %" PRIu64 ", state %u, %u Hz\n", st.device, epoch, st.state, st.sample_rate);
        }
        bass::port p(name);
        bass_port_info info = p.info();
        std::printf("port %s: %s, %u Hz, %u frames/chunk, %u chunks on port, epoch %" PRIu64 "\n", name.c_str(),
                    info.device, info.sample_rate, info.frames_per_chunk, info.chunks_on_port, info.epoch);
        long long start = static_cast<long long>(info.last_frame_index) + 1 + args[2];
        bass::block_reader reader(p, static_cast<std::size_t>(args[1]), start < 0 ? 0 : static_cast<std::uint64_t>(start),
                                  std::chrono::seconds(5));
        std::uint64_t bad = 0;
        for (long long k = 0; args[0] == 0 || k < args[0]; k++) {
            bass::block b = reader.next();
            std::int32_t peak_l = 0, peak_r = 0;
            for (std::size_t i = 0; i < b.left.size(); i++) {
                peak_l = std::max(peak_l, b.left[i] < 0 ? -(b.left[i] + 1) : b.left[i]);
                peak_r = std::max(peak_r, b.right[i] < 0 ? -(b.right[i] + 1) : b.right[i]);
                if (check_pattern && b.loss == 0 &&
                    (b.left[i] != pattern_expected(b.first_frame + i, 0) ||
                     b.right[i] != pattern_expected(b.first_frame + i, 1)))
                    bad++;
            }
            std::printf("block %lld: frames %" PRIu64 "..%" PRIu64 ", lost %" PRIu64 ", peak %d / %d\n", k + 1,
                        b.first_frame, b.next_frame - 1, b.loss, peak_l, peak_r);
        }
        if (bad) {
            std::fprintf(stderr, "blocks: %" PRIu64 " samples did not hold the pattern signal\n", bad);
            return 3;
        }
    } catch (const bass::error &e) {
        std::fprintf(stderr, "blocks: %s [code %d]\n", e.what(), static_cast<int>(e.code()));
        return 1;
    }
    return 0;
}
