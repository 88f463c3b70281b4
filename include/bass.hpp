// bass.hpp: header-only C++17 RAII wrapper over the bass C ABI (include/bass.h).
//
//   bass::port p("default");                       // bass_port_open; closed by the destructor
//   std::uint64_t nfr = p.last_frame_index() + 1;  // the next frame to be published
//   bass::audio_data d = p.get_audio_data(12000, nfr);   // formal getAudioData, never blocks
//   for (auto& b : bass::blocks(p, 4410, nfr)) ...        // consecutive blocks (blocking)
//
// Every failing call throws bass::error, which carries the bass_result code, the name of the
// call and the library's detailed message (bass_last_error()). Handles are move-only.
// Link with -lbassclient (pkg-config --cflags --libs bassclient).
#ifndef BASS_HPP
#define BASS_HPP

#include <algorithm>
#include <atomic>
#include <chrono>
#include <exception>
#include <functional>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "bass.h"

namespace bass {

// A failed bass call: code() is the bass_result; what() is the library's detailed message
// (which names the call) followed by the code's description in brackets.
class error : public std::runtime_error {
  public:
    error(const char *call, bass_result code)
        : std::runtime_error(compose(call, code, bass_last_error())), code_(code), call_(call),
          detail_(bass_last_error()) {}
    bass_result code() const noexcept { return code_; }
    const std::string &call() const noexcept { return call_; }
    const std::string &detail() const noexcept { return detail_; }

  private:
    static std::string compose(const char *call, bass_result code, const char *detail) {
        std::string head = (detail && *detail) ? std::string(detail) : std::string(call);
        return head + " [" + bass_result_str(code) + "]";
    }
    bass_result code_;
    std::string call_;
    std::string detail_;
};

inline void check(const char *call, bass_result r) {
    if (r != BASS_OK) throw error(call, r);
}

// The result of one getAudioData: n frames of each channel, the new nfr, the frames lost.
struct audio_data {
    std::vector<std::int32_t> left, right;
    std::uint64_t nfr = 0;
    std::size_t n = 0;
    std::uint64_t loss = 0;
};

// A port opened read-only.
class port {
  public:
    explicit port(const std::string &name = "default") { check("bass_port_open", bass_port_open(name.c_str(), &h_)); }
    ~port() { bass_port_close(h_); }
    port(port &&o) noexcept : h_(std::exchange(o.h_, nullptr)) {}
    port &operator=(port &&o) noexcept {
        if (this != &o) {
            bass_port_close(h_);
            h_ = std::exchange(o.h_, nullptr);
        }
        return *this;
    }
    port(const port &) = delete;
    port &operator=(const port &) = delete;

    const bass_port *handle() const noexcept { return h_; }

    bass_port_info info() const {
        bass_port_info i;
        check("bass_port_get_info", bass_port_get_info(h_, &i));
        return i;
    }
    std::uint64_t last_frame_index() const { return info().last_frame_index; }

    // getAudioData into caller buffers of at least n_frames samples; returns n, sets loss.
    std::size_t get_audio_data(std::size_t n_frames, std::uint64_t &nfr, std::int32_t *left, std::int32_t *right,
                               std::uint64_t &loss) const {
        std::size_t n = 0;
        check("bass_get_audio_data", bass_get_audio_data(h_, n_frames, &nfr, left, right, &n, &loss));
        return n;
    }

    // getAudioData returning vectors of n frames and the new nfr.
    audio_data get_audio_data(std::size_t n_frames, std::uint64_t nfr) const {
        audio_data d;
        std::size_t cap = std::max<std::size_t>(1, std::min<std::uint64_t>(n_frames, info().frames_on_port));
        d.left.resize(cap);
        d.right.resize(cap);
        d.nfr = nfr;
        d.n = get_audio_data(std::min(n_frames, cap), d.nfr, d.left.data(), d.right.data(), d.loss);
        d.left.resize(d.n);
        d.right.resize(d.n);
        return d;
    }

    // getAudioData for the first `n_channels` channels (all if 0): channels[c] holds n frames.
    struct multi_data {
        std::vector<std::vector<std::int32_t>> channels;
        std::uint64_t nfr = 0;
        std::size_t n = 0;
        std::uint64_t loss = 0;
    };
    multi_data get_audio_data_multi(std::size_t n_frames, std::uint64_t nfr, std::size_t n_channels = 0) const {
        bass_port_info i = info();
        if (n_channels == 0) n_channels = i.channels;
        std::size_t cap = std::max<std::size_t>(1, std::min<std::uint64_t>(n_frames, i.frames_on_port));
        multi_data d;
        d.channels.assign(n_channels, std::vector<std::int32_t>(cap));
        std::vector<std::int32_t *> ptrs;
        for (auto &c : d.channels) ptrs.push_back(c.data());
        d.nfr = nfr;
        check("bass_get_audio_data_multi", bass_get_audio_data_multi(h_, std::min(n_frames, cap), &d.nfr, ptrs.data(),
                                                                     n_channels, &d.n, &d.loss));
        for (auto &c : d.channels) c.resize(d.n);
        return d;
    }

    // Blocks until `frame` is published; returns the last frame index. Throws bass::error with
    // BASS_ERR_TIMEOUT, _STOPPED, _DEVICE, _RESTARTED, _WRITER_GONE or _INTERRUPTED.
    std::uint64_t wait(std::uint64_t frame, std::chrono::milliseconds timeout) const {
        std::uint64_t lfi = 0;
        auto ms = timeout.count() < 0 ? 0 : timeout.count();
        auto t = ms >= static_cast<long long>(BASS_WAIT_FOREVER) ? BASS_WAIT_FOREVER : static_cast<std::uint32_t>(ms);
        check("bass_port_wait", bass_port_wait(h_, frame, t, &lfi));
        return lfi;
    }

    bass_chunk_info chunk_info(std::uint64_t frame) const {
        bass_chunk_info c;
        check("bass_port_chunk_info", bass_port_chunk_info(h_, frame, &c));
        return c;
    }

  private:
    bass_port *h_ = nullptr;
};

// A port writer (simulators and test rigs; the broker is the writer in production).
class writer {
  public:
    // The geometry in the order of bass::acquire and the C ABI: rate, nFPC, nCOP, channels.
    writer(const std::string &name, std::uint32_t sample_rate, std::uint32_t frames_per_chunk,
           std::uint32_t chunks_on_port, std::uint32_t channels, const std::string &device = "c++") {
        check("bass_writer_create", bass_writer_create(name.c_str(), device.c_str(), sample_rate, frames_per_chunk,
                                                       chunks_on_port, channels, &h_));
    }
    ~writer() { bass_writer_close(h_); }
    writer(writer &&o) noexcept : h_(std::exchange(o.h_, nullptr)) {}
    writer &operator=(writer &&o) noexcept {
        if (this != &o) {
            bass_writer_close(h_);
            h_ = std::exchange(o.h_, nullptr);
        }
        return *this;
    }
    writer(const writer &) = delete;
    writer &operator=(const writer &) = delete;

    // Publishes one chunk of interleaved samples; returns the new last frame index.
    std::uint64_t publish(const std::vector<std::int32_t> &interleaved) {
        std::uint64_t lfi = 0;
        check("bass_writer_publish_interleaved",
              bass_writer_publish_interleaved(h_, interleaved.data(), interleaved.size(), nullptr, &lfi));
        return lfi;
    }
    std::uint64_t publish_gap() {
        std::uint64_t lfi = 0;
        check("bass_writer_publish_gap", bass_writer_publish_gap(h_, nullptr, &lfi));
        return lfi;
    }
    void set_state(std::uint32_t state, std::uint32_t error_code = BASS_DEVERR_NONE, const char *message = nullptr) {
        check("bass_writer_set_state", bass_writer_set_state(h_, state, error_code, message));
    }

  private:
    bass_writer *h_ = nullptr;
};

// One complete block from bass::block_reader.
struct block {
    std::vector<std::int32_t> left, right;
    std::uint64_t first_frame = 0;  // index of left[0]
    std::uint64_t next_frame = 0;   // the frame after the block
    std::uint64_t loss = 0;         // frames lost while the block was assembled (0: contiguous)
};

// Reads consecutive blocks of n_frames, blocking on the port (reads at least every half
// window, so nothing is lost while the caller keeps up).
class block_reader {
  public:
    block_reader(const port &p, std::size_t n_frames, std::uint64_t nfr,
                 std::chrono::milliseconds timeout = std::chrono::milliseconds(BASS_WAIT_FOREVER))
        : p_(p), n_(n_frames), nfr_(nfr), timeout_(timeout) {
        if (n_frames == 0) throw std::invalid_argument("bass::block_reader: n_frames must be > 0");
        auto i = p.info();
        fop_ = i.frames_on_port;
    }

    block next() {
        block b;
        b.left.resize(n_);
        b.right.resize(n_);
        std::size_t filled = 0;
        bool first = true;
        const std::uint64_t half = std::max<std::uint64_t>(1, fop_ / 2);
        while (filled < n_) {
            std::uint64_t rem = n_ - filled;
            p_.wait(nfr_ + std::min(rem, half) - 1, timeout_);
            std::uint64_t loss = 0;
            std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(rem, fop_));
            std::size_t n = p_.get_audio_data(want, nfr_, b.left.data() + filled, b.right.data() + filled, loss);
            if (first && n) {
                b.first_frame = nfr_ - n;
                first = false;
            }
            b.loss += loss;
            filled += n;
        }
        b.next_frame = nfr_;
        return b;
    }
    std::uint64_t nfr() const noexcept { return nfr_; }

  private:
    const port &p_;
    std::size_t n_;
    std::uint64_t nfr_;
    std::chrono::milliseconds timeout_;
    std::uint64_t fop_ = 0;
};

// A callback stream (bass_stream_*, docs/c-api.md "Callback streams"): on_block(const
// bass_block &) is called with every block and returns true to go on; on_event(const
// bass_stream_event &) with every acquisition event (true: go on, e.g. wait for a restart;
// none given: every event but BASS_EVENT_REALTIME_REFUSED ends the stream). mode::own_thread starts it on bass's thread;
// mode::caller_thread waits for run(). The destructor stops and joins it. Not copyable or
// movable. Realtime: calling the std::function does not allocate; the callables must not
// either (see the rules in docs/c-api.md).
//
// Exceptions: nothing a callable throws reaches the C ABI (where it would abort the process:
// see docs/c-api.md). The wrapper catches it, stops the stream, and run() or join() rethrows
// it; a stream destroyed without join() writes the exception's what() to stderr (a destructor
// cannot throw it, and a failure is not dropped silently).
//
// Destroyed inside its own callback (`delete s;` from on_block or on_event): the stream is
// stopped — no callback is made after the destructor returns — and released once the running
// callback has returned (an own_thread stream by a short-lived thread of the wrapper's, a
// caller_thread stream by the run() below it, which then returns without touching the
// object). The callables are destroyed only then, so the running callback may still use its
// captures after the delete; it must not touch the deleted stream itself.
class stream {
  public:
    using block_fn = std::function<bool(const bass_block &)>;
    using event_fn = std::function<bool(const bass_stream_event &)>;
    enum class mode { own_thread, caller_thread };

    stream(const port &p, const bass_stream_config &cfg, block_fn on_block, event_fn on_event = {},
           mode m = mode::own_thread)
        : st_(std::make_shared<state>(std::move(on_block), std::move(on_event), m == mode::own_thread)) {
        if (m == mode::own_thread)
            check("bass_stream_start",
                  bass_stream_start(p.handle(), &cfg, block_tramp, event_tramp, st_.get(), &st_->h));
        else
            check("bass_stream_create",
                  bass_stream_create(p.handle(), &cfg, block_tramp, event_tramp, st_.get(), &st_->h));
    }
    ~stream() {
        bass_stream *h = st_->h;
        if (h == nullptr) return;
        if (bass_stream_close(h) != BASS_ERR_INVALID_ARGUMENT) {
            report_dropped(st_->failure);
            return;
        }
        // Inside one of its own callbacks, where the library refuses to close it: stop it here,
        // release it once the callback has returned.
        st_->detached.store(true, std::memory_order_release);
        bass_stream_stop(h);
        if (!st_->own_thread) return;  // the run() on this thread's stack closes it
        std::shared_ptr<state> st = std::move(st_);
        try {
            std::thread([st] { bass_stream_close(st->h); }).detach();
        } catch (...) {
            new std::shared_ptr<state>(std::move(st));  // no thread to release it: stopped, kept
        }
    }
    stream(const stream &) = delete;
    stream &operator=(const stream &) = delete;

    // Runs a caller_thread stream here until a callback or stop() ends it.
    void run() {
        std::shared_ptr<state> st = st_;  // a callback may destroy the stream meanwhile
        bass_result r = bass_stream_run(st->h);
        if (st->detached.load(std::memory_order_acquire)) {
            bass_stream_close(st->h);  // destroyed by its callback: released here, `this` untouched
            return;
        }
        check("bass_stream_run", r);
        if (st->failure) std::rethrow_exception(std::exchange(st->failure, nullptr));
    }
    // Asks the stream to stop; from any thread, also inside a callback.
    void stop() noexcept { bass_stream_stop(st_->h); }
    // Stops an own_thread stream and waits for it; rethrows a callback's exception. Not from
    // inside its own callbacks (bass::error BASS_ERR_INVALID_ARGUMENT; the stream goes on).
    void join() {
        bass_result r = bass_stream_close(st_->h);
        if (r != BASS_ERR_INVALID_ARGUMENT) st_->h = nullptr;
        check("bass_stream_close", r);
        rethrow();
    }

  private:
    // What the callbacks use: owned by the stream, and by whoever releases it after it was
    // destroyed inside a callback.
    struct state {
        state(block_fn b, event_fn e, bool own) : on_block(std::move(b)), on_event(std::move(e)), own_thread(own) {}
        block_fn on_block;
        event_fn on_event;
        bool own_thread;
        std::exception_ptr failure;
        std::atomic<bool> detached{false};
        bass_stream *h = nullptr;
    };
    static int block_tramp(const bass_block *b, void *user) {
        auto *st = static_cast<state *>(user);
        if (st->detached.load(std::memory_order_acquire)) return 1;
        try {
            return st->on_block(*b) ? 0 : 1;
        } catch (...) {
            st->failure = std::current_exception();
            return 1;
        }
    }
    static int event_tramp(const bass_stream_event *e, void *user) {
        auto *st = static_cast<state *>(user);
        if (st->detached.load(std::memory_order_acquire)) return 1;
        // Without an event callback every end ends the stream; a refused priority is no end.
        if (!st->on_event) return e->kind == BASS_EVENT_REALTIME_REFUSED ? 0 : 1;
        try {
            return st->on_event(*e) ? 0 : 1;
        } catch (...) {
            st->failure = std::current_exception();
            return 1;
        }
    }
    // The exception a stream destroyed without join() would drop, named on stderr.
    static void report_dropped(const std::exception_ptr &failure) noexcept {
        if (!failure) return;
        try {
            std::rethrow_exception(failure);
        } catch (const std::exception &e) {
            std::fprintf(stderr, "bass::stream destroyed without join(): its callback threw: %s\n", e.what());
        } catch (...) {
            std::fprintf(stderr, "bass::stream destroyed without join(): its callback threw a non-std exception\n");
        }
    }
    void rethrow() {
        if (st_->failure) std::rethrow_exception(std::exchange(st_->failure, nullptr));
    }
    std::shared_ptr<state> st_;
};

inline const char *version() noexcept { return bass_version(); }

// The control plane: the broker's Acquire, Stop, Status and ListDevices services.
// `broker` empty = "default".
namespace detail {
inline const char *broker_arg(const std::string &broker) { return broker.empty() ? nullptr : broker.c_str(); }
}  // namespace detail

// Starts (or restarts) an acquisition; returns its epoch. channels 0 = 2.
inline std::uint64_t acquire(const std::string &device, std::uint32_t sample_rate = 44100,
                             std::uint32_t frames_per_chunk = 2205, std::uint32_t chunks_on_port = 20,
                             std::uint32_t channels = 0, const std::string &broker = "") {
    std::uint64_t epoch = 0;
    check("bass_acquire", bass_acquire(detail::broker_arg(broker), device.c_str(), sample_rate, frames_per_chunk,
                                       chunks_on_port, channels, &epoch));
    return epoch;
}

inline void stop(const std::string &broker = "") { check("bass_stop", bass_stop(detail::broker_arg(broker))); }

inline bass_broker_status status(const std::string &broker = "") {
    bass_broker_status s;
    check("bass_status", bass_status(detail::broker_arg(broker), &s));
    return s;
}

// The broker's capture devices as (name, description) pairs.
inline std::vector<std::pair<std::string, std::string>> list_devices(const std::string &broker = "") {
    std::size_t need = 0;
    bass_result r = bass_list_devices(detail::broker_arg(broker), nullptr, 0, &need);
    if (r != BASS_ERR_BUFFER_TOO_SMALL) check("bass_list_devices", r);
    std::string buf(need, '\0');
    check("bass_list_devices", bass_list_devices(detail::broker_arg(broker), &buf[0], buf.size(), &need));
    std::vector<std::pair<std::string, std::string>> out;
    std::size_t pos = 0;
    for (std::size_t nl; (nl = buf.find('\n', pos)) != std::string::npos; pos = nl + 1) {
        std::string line = buf.substr(pos, nl - pos);
        std::size_t tab = line.find('\t');
        out.emplace_back(line.substr(0, tab), tab == std::string::npos ? "" : line.substr(tab + 1));
    }
    return out;
}

}  // namespace bass

#endif  // BASS_HPP
