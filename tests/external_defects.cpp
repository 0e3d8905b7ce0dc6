// Children with known defects for the `external` contract's tests (docs/external-estimator.md):
// plain unwrapped atan2 on text frames, then one defect by name:
//   h8 AMP        adds AMP*cos(8*theta) rad (a polynomial atan2's largest error order)
//   invalid       marks every estimate valid = 0 (a firmware whose amplitude check trips)
//   extra         answers the first frame twice (one output frame too many)
//   missing       never answers the last input frame (exits on EOF one short)
//   wrapped       reports theta wrapped to (-pi, pi]
//   degrees       reports theta and omega in degrees
//   degrees-wrapped  theta in degrees wrapped to [0, 360) (VESC's enc_sincos_read_deg), omega in degrees/s
//   degrees-signed   theta in degrees wrapped to (-180, 180]
//   pll FN        a type-2 phase-locked loop of natural frequency FN Hz on atan2 (damping 0.707)
//   nan-omega     a NaN rate on valid estimates from frame 5000 on
//   env           exits 3 unless FRINGE_ENCODER_JSON names a readable file with "sample_rate_hz"
//   correction    exits 4 unless FRINGE_CORRECTION is an absolute path to a readable file of schema
//                 "fringe.correction" that the configuration file names too; "no-correction":
//                 exits 4 if FRINGE_CORRECTION is set
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>

int main(int argc, char** argv) {
    const std::string mode = argc > 1 ? argv[1] : "";
    const double amp = argc > 2 ? std::atof(argv[2]) : 0.0;
    const char* rate = std::getenv("FRINGE_SAMPLE_RATE_HZ");
    const double fs = rate ? std::atof(rate) : 1.0;
    if (mode == "env") {
        const char* p = std::getenv("FRINGE_ENCODER_JSON");
        if (!p) return 3;
        std::ifstream f(p);
        const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        if (text.find("\"sample_rate_hz\"") == std::string::npos || text.find("\"encoder\"") == std::string::npos) return 3;
    }
    if (mode == "correction") {
        const char* p = std::getenv("FRINGE_CORRECTION");
        const char* conf = std::getenv("FRINGE_ENCODER_JSON");
        if (!p || p[0] != '/' || !conf) return 4;
        std::ifstream f(p), g(conf);
        const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        const std::string ctext((std::istreambuf_iterator<char>(g)), std::istreambuf_iterator<char>());
        if (text.find("\"fringe.correction\"") == std::string::npos || ctext.find(std::string("\"correction\": \"") + p + "\"") == std::string::npos) return 4;
    }
    if (mode == "no-correction" && std::getenv("FRINGE_CORRECTION")) return 4;
    const double two_pi = 6.283185307179586, pi = two_pi / 2;
    double prev = 0, acc = 0;
    double pll_th = 0, pll_om = 0;  // "pll": phase (rad, unwrapped) and rate (rad/s)
    long k = 0;
    std::string pending;  // "missing": each answer is held until the next input arrives
    double s, c;
    while (std::scanf("%lf %lf", &s, &c) == 2) {
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
        double th = acc, valid = 1;
        if (mode == "h8") th += amp * std::cos(8 * acc);
        if (mode == "invalid") valid = 0;
        if (mode == "wrapped") th = std::remainder(acc, two_pi);
        if (mode == "degrees") { th = acc * 180 / pi; om = om * 180 / pi; }
        if (mode == "degrees-wrapped") { th = std::fmod(acc * 180 / pi, 360.0); if (th < 0) th += 360; om = om * 180 / pi; }
        if (mode == "degrees-signed") { th = std::remainder(acc * 180 / pi, 360.0); om = om * 180 / pi; }
        if (mode == "pll") {
            const double T = 1 / fs, wn = two_pi * amp, kp = 2 * 0.7071 * wn * T, ki = wn * wn * T * T;
            if (k == 0) { pll_th = a; pll_om = 0; }
            else {
                const double pred = pll_th + pll_om * T;
                const double e = std::remainder(a - pred, two_pi);
                pll_th = pred + kp * e;
                pll_om += ki / T * e;
            }
            th = pll_th;
            om = pll_om;
        }
        if (mode == "nan-omega" && k >= 5000) om = std::nan("");
        char line[128];
        std::snprintf(line, sizeof line, "%.17g %.17g %g\n", th, om, valid);
        if (mode == "missing") {
            std::fputs(pending.c_str(), stdout);
            pending = line;
        } else {
            std::fputs(line, stdout);
            if (mode == "extra" && k == 0) std::fputs(line, stdout);
        }
        ++k;
        std::fflush(stdout);
    }
    return 0;
}
