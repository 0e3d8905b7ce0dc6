// A user's estimator for the `external` protocol (docs/external-estimator.md): plain atan2,
// unwrapped. Text or binary per FRINGE_PROTOCOL. `--crash-after N` aborts after N samples
// (to test that a crashing child is reported).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

int main(int argc, char** argv) {
    long crash_after = -1;
    if (argc == 3 && std::strcmp(argv[1], "--crash-after") == 0) crash_after = std::atol(argv[2]);
    const char* proto = std::getenv("FRINGE_PROTOCOL");
    const char* rate = std::getenv("FRINGE_SAMPLE_RATE_HZ");
    const bool binary = proto && std::strcmp(proto, "binary") == 0;
    const double fs = rate ? std::atof(rate) : 1.0;
    const double two_pi = 6.283185307179586;
    double prev = 0, acc = 0;
    long k = 0;
    for (;;) {
        double s, c;
        if (binary) {
            double in[2];
            if (std::fread(in, sizeof in, 1, stdin) != 1) break;
            s = in[0]; c = in[1];
        } else if (std::scanf("%lf %lf", &s, &c) != 2) break;
        if (k == crash_after) std::abort();
        const double a = std::atan2(s, c);
        double om = 0;
        if (k == 0) acc = a;
        else {
            double d = a - prev;
            d -= two_pi * std::round(d / two_pi);
            acc += d;
            om = d * fs;
        }
        prev = a;
        ++k;
        if (binary) {
            const double out[3] = {acc, om, 1.0};
            std::fwrite(out, sizeof out, 1, stdout);
        } else {
            std::printf("%.17g %.17g 1\n", acc, om);
        }
        // Text: flush every line. Binary: flush whenever no more input is buffered, so
        // fringe never waits on us (the protocol's one rule, docs/external-estimator.md).
        if (!binary || stdin->_IO_read_ptr >= stdin->_IO_read_end) std::fflush(stdout);
    }
    std::fflush(stdout);
    return 0;
}
