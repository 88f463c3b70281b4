// Conformance driver in C++: replays vectors.txt through include/bass.hpp (bass::writer,
// bass::port) and prints the file back with the `read` results observed.
// Usage: driver_cpp VECTORS > OUT   (ports in $BASS_RUNTIME_DIR)
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bass.hpp"

int main(int argc, char **argv) {
    if (argc != 2) {
        std::cerr << "usage: driver_cpp VECTORS\n";
        return 2;
    }
    std::ifstream in(argv[1]);
    if (!in) {
        std::cerr << "driver_cpp: cannot read " << argv[1] << "\n";
        return 1;
    }
    const std::string name = "conf-cpp-" + std::to_string(getpid());
    std::unique_ptr<bass::writer> w;
    std::unique_ptr<bass::port> p;
    std::string line;
    try {
        while (std::getline(in, line)) {
            std::istringstream ss(line);
            std::string op;
            if (!(ss >> op)) continue;
            std::ostringstream out;
            if (op == "case") {
                std::string cname;
                std::uint32_t ch, rate, fpc, cop;
                ss >> cname >> ch >> rate >> fpc >> cop;
                p.reset();
                w = std::make_unique<bass::writer>(name, rate, fpc, cop, ch, "conformance");
                p = std::make_unique<bass::port>(name);
                out << "case " << cname << ' ' << ch << ' ' << rate << ' ' << fpc << ' ' << cop;
            } else if (op == "publish") {
                std::vector<std::int32_t> s;
                for (long long v; ss >> v;) s.push_back(static_cast<std::int32_t>(v));
                w->publish(s);
                out << "publish";
                for (auto v : s) out << ' ' << v;
            } else if (op == "read") {
                std::size_t n_frames;
                std::uint64_t nfr;
                ss >> n_frames >> nfr;
                bass::audio_data d = p->get_audio_data(n_frames, nfr);
                out << "read " << n_frames << ' ' << nfr << ' ' << d.n << ' ' << d.nfr << ' ' << d.loss;
                for (std::size_t i = 0; i < d.n; i++) out << ' ' << d.left[i] << ' ' << d.right[i];
            } else if (op == "readm") {
                std::size_t n_frames;
                std::uint64_t nfr;
                ss >> n_frames >> nfr;
                auto d = p->get_audio_data_multi(n_frames, nfr);
                out << "readm " << n_frames << ' ' << nfr << ' ' << d.n << ' ' << d.nfr << ' ' << d.loss;
                for (std::size_t i = 0; i < d.n; i++)
                    for (const auto &c : d.channels) out << ' ' << c[i];
            } else if (op == "end") {
                p.reset();
                w.reset();
                out << "end";
            } else {
                out << op;
                for (std::string t; ss >> t;) out << ' ' << t;
            }
            std::cout << out.str() << '\n';
        }
    } catch (const bass::error &e) {
        std::cerr << "driver_cpp: " << e.what() << " [code " << e.code() << "]\n";
        return 1;
    }
    return 0;
}
