// fringe calibrate: a correction for atan2 from one capture (docs/calibration.md), written as
// fringe's JSON, and optionally as a CSV table and an int16 C header.
#include "server/cli/commands.hpp"
#include "server/analysis/calibration.hpp"
#include "server/engine/calibrate.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/fastmath.hpp"

#include <cstdio>
#include <fstream>
#include <stdexcept>

namespace fringe::cli {

namespace {

struct CalibrateCliOptions {
    std::string capture, output, csv, c_header, encoder, estimator = "atan2", name = "fringe_correction";
    std::size_t table_size = 64;
    int harmonics = 16;
    double lsb_rad = kTwoPi / 65536.0, settle_s = 0.1, min_cycles = 1;
    bool no_lissajous = false, quiet = false;
};

void write_file(const std::string& path, const std::string& text) {
    std::ofstream f(path, std::ios::binary);
    if (!f) throw std::runtime_error("cannot write " + path);
    f << text;
    if (!f.flush()) throw std::runtime_error("cannot write " + path);
}

int run_calibrate(const CalibrateCliOptions& o) {
    refuse_overwrite({{"correction", o.output}, {"CSV table", o.csv}, {"C header", o.c_header}},
                     {{"capture", o.capture}, {"encoder profile", o.encoder}});
    CalibrateOptions co;
    co.capture_path = o.capture;
    co.estimator = o.estimator;
    co.table_size = o.table_size;
    co.harmonics = o.harmonics;
    co.lissajous = !o.no_lissajous;
    co.settle_s = o.settle_s;
    co.min_cycles = o.min_cycles;
    if (!o.encoder.empty()) co.encoder = load_encoder(o.encoder);
    const CalibrateResult r = calibrate_capture(co);
    // Every export is formed before anything is written (an entry that does not fit int16 writes nothing).
    const std::string header = o.c_header.empty() ? std::string() : correction_c_header(r.correction, o.lsb_rad, o.name);
    nlohmann::json j = r.correction.to_json();
    j["calibrated_from"] = r.facts;
    write_file(o.output, j.dump(2) + "\n");
    if (!o.csv.empty()) write_file(o.csv, correction_csv(r.correction));
    if (!o.c_header.empty()) write_file(o.c_header, header);
    if (!o.quiet) {
        const auto& c = r.correction;
        std::printf("correction for %s from %s (%s error)\n", o.estimator.c_str(), o.capture.c_str(),
                    r.source == "truth" ? "truth-scored" : "self-referenced");
        if (c.has_lissajous)
            std::printf("  Lissajous: offsets %.6g / %.6g V, amplitudes %.6g / %.6g V (sin/cos ratio %.6f), quadrature %.6g rad\n",
                        c.offset_sin_v, c.offset_cos_v, c.amplitude_sin_v, c.amplitude_cos_v, c.amplitude_sin_v / c.amplitude_cos_v,
                        c.quadrature_error_rad);
        std::printf("  error after the Lissajous stage: %.4g rad rms (periodic %.4g, the rest %.4g)\n", r.before_rms_rad,
                    r.periodic_rms_rad, r.noise_rms_rad);
        std::printf("  offset: %.4g rad (%s)\n", c.offset_rad, r.source == "truth"    ? "the error's mean against the truth"
                    : c.has_lissajous ? "no truth: keeps the zero atan2 had with the calibration it is told"
                                      : "none: no truth to measure it against");
        std::printf("  table: %zu entries, linear interpolation, from %d harmonics; leaves %.4g rad rms of the periodic error\n",
                    c.table.size(), o.harmonics, r.table_residual_rms_rad);
        std::printf("  predicted residual: %.4g rad rms", r.predicted_rms_rad);
        if (r.per_sample_crb_rad > 0) std::printf(" (%.3g x the per-sample CRB %.4g rad)", r.predicted_rms_rad / r.per_sample_crb_rad, r.per_sample_crb_rad);
        std::printf("\n  verify it on another capture: fringe estimate OTHER --estimator atan2 --param correction=%s\n", o.output.c_str());
    }
    return kExitOk;
}

}  // namespace

Command add_calibrate(CLI::App& app) {
    auto o = std::make_shared<CalibrateCliOptions>();
    auto* c = app.add_subcommand("calibrate", "Compute a correction for atan2 from a capture (Lissajous stage and an angle table; docs/calibration.md)");
    c->add_option("capture", o->capture, "Capture file (.csv with sidecar, .fcap): with theta_true the truth-scored error, else the self-referenced one")
        ->required()
        ->check(CLI::ExistingFile);
    c->add_option("-o,--output", o->output, "Correction JSON to write (atan2's correction=FILE)")->required();
    c->add_option("--table-size", o->table_size, "Entries of the angle table over one electrical period")->check(CLI::Range(2, 1 << 20));
    c->add_option("--harmonics", o->harmonics, "Harmonic orders of the correction the table is built from")->check(CLI::Range(1, 256));
    c->add_option("--estimator", o->estimator, "Estimator to calibrate (atan2)");
    c->add_option("--encoder", o->encoder, "Encoder profile JSON the estimator is told (default: the capture's metadata)")->check(CLI::ExistingFile);
    c->add_option("--settle-s", o->settle_s, "Seconds from the start excluded from the error record")->check(kFiniteNonNegative);
    c->add_option("--min-cycles", o->min_cycles, "Electrical cycles the error record needs (fewer: no correction)")->check(CLI::Range(1.0, 1e12))->capture_default_str();
    c->add_flag("--no-lissajous", o->no_lissajous, "No ellipse fit: keep the nominal calibration, correct the angle only");
    c->add_option("--csv", o->csv, "Also write the table as CSV: angle_rad,correction_rad");
    c->add_option("--c-header", o->c_header, "Also write the table as a C header of int16 entries");
    c->add_option("--lsb-rad", o->lsb_rad, "The C header's LSB in rad (default 2*pi/65536)")->check(kFinitePositive);
    c->add_option("--name", o->name, "The C header's array name");
    c->add_flag("-q,--quiet", o->quiet, "No summary");
    return {c, [o] { return run_calibrate(*o); }};
}

}  // namespace fringe::cli
