// What sigrok's demo driver streams through SigrokLive (docs/sigrok-live.md): for each rate,
// a continuous acquisition read for a few seconds, printing samples received per second against
// the rate asked (expected_samples_by_wall_clock). The demo generates on a wall-clock schedule
// and falls behind it at high rates: that shortfall is what the drop accounting can see, and
// all it can see (sigrok-cli reports no lost samples).
//   sigrok_live_rate [seconds=2] [kind=logic|analog] [rate_hz ...]
#include "drivers/sigrok_live.hpp"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

int main(int argc, char** argv) {
    using namespace fringe::dev;
    const double seconds = argc > 1 ? std::atof(argv[1]) : 2.0;
    const std::string kind = argc > 2 ? argv[2] : "logic";
    std::vector<double> rates;
    for (int i = 3; i < argc; ++i) rates.push_back(std::atof(argv[i]));
    if (rates.empty()) rates = kind == "analog" ? std::vector<double>{1e4, 1e5, 1e6} : std::vector<double>{1e6, 1e7, 1e8, 1e9};
    std::printf("%-7s %14s %14s %8s %8s %10s\n", "kind", "rate_hz", "received/s", "ratio", "ratio_fd", "first_s");
    for (double rate : rates) {
        SigrokLiveConfig c;
        c.driver = "demo";
        c.samplerate_hz = rate;
        if (kind == "analog")
            c.analog_channels = {"A0", "A1"};
        else
            c.logic_channels = {"D0", "D1", "D2", "D3", "D4", "D5", "D6", "D7"};
        SigrokLive s(c);
        s.start();
        std::vector<std::uint64_t> logic;
        std::vector<std::vector<double>> analog;
        const auto t0 = std::chrono::steady_clock::now();
        while (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() < seconds) {
            auto r = s.read(1 << 20, logic, analog, 2000);
            if (r.status != StreamStatus::Ok || r.frames == 0) {
                std::fprintf(stderr, "%s\n", r.message.c_str());
                return 1;
            }
        }
        const auto st = s.stats();
        s.stop();
        const double wall_s = st.value("wall_s", 1.0);
        const double n = st.value("samples", 0.0);
        // ratio: against wall-clock time x rate since the spawn; ratio_fd: since the first byte.
        std::printf("%-7s %14.0f %14.0f %8.3f %8.3f %10.3f\n", kind.c_str(), rate, n / wall_s, n / st.value("expected_samples_by_wall_clock", 1.0),
                    n / st.value("expected_samples_since_first_data", 1.0), st.value("first_data_s", -1.0));
    }
    return 0;
}
