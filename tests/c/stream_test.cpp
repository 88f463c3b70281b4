// The C++ callback stream (bass::stream in include/bass.hpp): a lambda's blocks tile the
// stream of a real port written with bass_writer_*, sample by
// sample against the pattern, across a lapped callback, on the caller's thread and on bass's
// own; an exception thrown by the lambda stops the stream and reaches run() or join(); a
// stream deleted inside its own callback delivers no block after the delete and is released
// once the callback returns (run under ASan by run.sh: no use after free). Run by
// tests/c/run.sh with BASS_RUNTIME_DIR set to a fresh directory.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <memory>
#include <cstdlib>
#include <cstring>
#include <unistd.h>
#include <stdexcept>
#include <thread>

#include "bass.hpp"

namespace {
int failures = 0;
#define CHECK(cond)                                                                    \
    do {                                                                               \
        if (!(cond)) {                                                                 \
            failures++;                                                                \
            std::fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                              \
    } while (0)

constexpr unsigned NFPC = 16, NCOP = 8, CH = 2;

std::int32_t pattern(std::uint64_t f, unsigned c) {
    return static_cast<std::int32_t>(static_cast<std::uint32_t>((f & 0x3FFFFFFu) << 6) | (c & 63u));
}

struct feed {
    bass_writer *w = nullptr;
    std::uint64_t lfi = 0;
    explicit feed(const char *name) { bass::check("bass_writer_create", bass_writer_create(name, "cpp", 48000, NFPC, NCOP, CH, &w)); }
    ~feed() { bass_writer_close(w); }
    void publish() {
        std::int32_t chunk[NFPC * CH];
        for (unsigned i = 0; i < NFPC; i++)
            for (unsigned c = 0; c < CH; c++) chunk[i * CH + c] = pattern(lfi + 1 + i, c);
        bass::check("publish", bass_writer_publish_interleaved(w, chunk, NFPC * CH, nullptr, &lfi));
    }
    void stop() { bass::check("set_state", bass_writer_set_state(w, BASS_STATE_STOPPED, BASS_DEVERR_NONE, nullptr)); }
};

struct tiling {
    std::uint64_t next = 1, delivered = 0, lost = 0, calls = 0, last = 0;
    int wrong = 0;
    void check(const bass_block &b) {
        if (b.first_frame != next + b.lost) wrong++;
        for (std::size_t i = 0; i < b.frames; i++)
            for (std::uint32_t k = 0; k < b.n_channels; k++)
                if (b.channels[k][i] != pattern(b.first_frame + i, b.port_channels[k])) wrong++;
        next = b.first_frame + b.frames;
        delivered += b.frames;
        lost += b.lost;
        calls++;
    }
};

void caller_thread() {
    feed f("cppstream");
    for (int i = 0; i < 3; i++) f.publish();
    bass::port p("cppstream");
    tiling t;
    bass_stream_config cfg{};
    cfg.start = BASS_START_OLDEST;
    bass::stream s(
        p, cfg,
        [&](const bass_block &b) {
            t.check(b);
            if (t.calls == 10)
                for (unsigned i = 0; i < NCOP * 2 + 3; i++) f.publish();  // lapped
            else if (t.calls == 30) {
                f.publish();
                f.stop();
            } else if (t.calls < 30)
                while (f.lfi < b.first_frame + 2 * b.frames) f.publish();
            return true;
        },
        [&](const bass_stream_event &e) {
            if (e.kind == BASS_EVENT_STOPPED) t.last = e.frame;
            return false;
        },
        bass::stream::mode::caller_thread);
    s.run();
    CHECK(t.wrong == 0);
    CHECK(t.last > 0 && t.next == t.last + 1 && 1 + t.delivered + t.lost == t.next);
    CHECK(t.lost > NFPC * NCOP);
    std::printf("C++ caller's thread: %llu blocks, %llu lost\n", (unsigned long long)t.calls, (unsigned long long)t.lost);
}

void own_thread() {
    feed f("cppthread");
    bass::port p("cppthread");
    tiling t;
    std::atomic<bool> ended{false};
    bass_stream_config cfg{};
    cfg.start = BASS_START_FRAME;
    cfg.start_frame = 1;
    bass::stream s(
        p, cfg, [&](const bass_block &b) { t.check(b); return true; },
        [&](const bass_stream_event &e) {
            if (e.kind == BASS_EVENT_STOPPED) t.last = e.frame;
            ended = true;
            return false;
        });
    for (int i = 0; i < 2000; i++) {
        f.publish();
        if (i % 40 == 0) std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    f.stop();
    while (!ended) std::this_thread::sleep_for(std::chrono::milliseconds(1));  // the stopped event
    s.join();
    CHECK(t.wrong == 0);
    CHECK(t.last == 2000ull * NFPC && t.next == t.last + 1 && 1 + t.delivered + t.lost == t.next);
    std::printf("C++ own thread: %llu blocks, %llu lost\n", (unsigned long long)t.calls, (unsigned long long)t.lost);
}

void exception_reaches_run() {
    feed f("cppthrow");
    for (int i = 0; i < 4; i++) f.publish();
    bass::port p("cppthrow");
    bass_stream_config cfg{};
    bass::stream s(p, cfg, [](const bass_block &) -> bool { throw std::runtime_error("from the callback"); }, {},
                   bass::stream::mode::caller_thread);
    bool caught = false;
    try {
        s.run();
    } catch (const std::runtime_error &e) {
        caught = std::string(e.what()) == "from the callback";
    }
    CHECK(caught);
}
void exception_reaches_join() {
    feed f("cppthrowj");
    for (int i = 0; i < 4; i++) f.publish();
    bass::port p("cppthrowj");
    bass_stream_config cfg{};
    std::atomic<bool> thrown{false};
    bass::stream s(p, cfg, [&](const bass_block &) -> bool {
        thrown = true;
        throw std::runtime_error("from bass's thread");
    });
    while (!thrown) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    bool caught = false;
    try {
        s.join();
    } catch (const std::runtime_error &e) {
        caught = std::string(e.what()) == "from bass's thread";
    }
    CHECK(caught);
}

// A stream destroyed without join() after its callback threw: the exception is not lost
// silently, the destructor names it on stderr (a destructor cannot throw).
void exception_dropped_is_reported() {
    feed f("cppthrowd");
    for (int i = 0; i < 4; i++) f.publish();
    bass::port p("cppthrowd");
    bass_stream_config cfg{};
    std::atomic<bool> thrown{false};
    std::FILE *log = std::tmpfile();
    CHECK(log != nullptr);
    if (log == nullptr) return;
    std::fflush(stderr);
    int saved = dup(2);
    dup2(fileno(log), 2);
    {
        bass::stream s(p, cfg, [&](const bass_block &) -> bool {
            thrown = true;
            throw std::runtime_error("dropped by the destructor");
        });
        while (!thrown) std::this_thread::sleep_for(std::chrono::milliseconds(1));
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    std::fflush(stderr);
    dup2(saved, 2);
    close(saved);
    char text[512] = {0};
    std::rewind(log);
    std::size_t n = std::fread(text, 1, sizeof text - 1, log);
    std::fclose(log);
    CHECK(n > 0 && std::strstr(text, "dropped by the destructor") != nullptr);
}

// `delete s` inside on_block while blocks flow: no block after the delete has returned; the
// stream is released (its callables destroyed) once the callback has returned.
void delete_inside_its_callback(bass::stream::mode m, const char *name) {
    feed f(name);
    for (int i = 0; i < 4; i++) f.publish();
    bass::port p(name);
    std::atomic<bool> deleted{false}, done{false};
    std::atomic<unsigned> before{0}, after{0}, published{0};
    std::atomic<bass::stream *> self{nullptr};
    auto token = std::make_shared<int>(0);  // held by the callable only: gone once released
    std::weak_ptr<int> callable_alive = token;
    std::thread feeder([&] {
        for (int i = 0; i < 2000 && !done; i++) {
            f.publish();
            published++;
            std::this_thread::sleep_for(std::chrono::microseconds(300));
        }
    });
    bass_stream_config cfg{};
    cfg.start = BASS_START_OLDEST;
    auto *s = new bass::stream(
        p, cfg,
        [&, token = std::move(token)](const bass_block &) {
            (void)token;
            if (deleted) {
                after++;
                return true;
            }
            if (++before == 3) {
                while (self.load() == nullptr) std::this_thread::yield();
                delete self.load();
                deleted = true;  // the captures live on until the callback has returned
            }
            return true;
        },
        {}, m);
    self = s;
    if (m == bass::stream::mode::caller_thread) s->run();  // returns once it deleted itself
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (!deleted && std::chrono::steady_clock::now() < deadline)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    // Frames keep coming after the delete (40 chunks more): none of them may reach the callback.
    unsigned at = published;
    while (published < at + 40 && std::chrono::steady_clock::now() < deadline)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    while (!callable_alive.expired() && std::chrono::steady_clock::now() < deadline)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    done = true;
    feeder.join();
    CHECK(deleted && before == 3);
    CHECK(published >= at + 40);
    CHECK(after == 0);
    CHECK(callable_alive.expired());
    std::printf("C++ %s: deleted in its callback at block %u; %u blocks after the delete (of %u chunks); released: %s\n",
                m == bass::stream::mode::own_thread ? "own thread" : "caller's thread", before.load(), after.load(),
                published.load() - at, callable_alive.expired() ? "yes" : "no");
}
}  // namespace

int main() {
    if (!std::getenv("BASS_RUNTIME_DIR")) {
        std::fprintf(stderr, "set BASS_RUNTIME_DIR to an empty directory\n");
        return 2;
    }
    caller_thread();
    own_thread();
    exception_reaches_run();
    exception_reaches_join();
    exception_dropped_is_reported();
    delete_inside_its_callback(bass::stream::mode::own_thread, "cppdelete");
    delete_inside_its_callback(bass::stream::mode::caller_thread, "cppdeletec");
    std::printf("stream_test_cpp: %d failures\n", failures);
    return failures != 0;
}
