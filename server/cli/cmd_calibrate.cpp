// fringe calibrate: a correction for atan2 from one capture (docs/calibration.md), written as
// fringe's JSON, and optionally as a CSV table, an int16 C header, a Modbus board's register
// writes (a file, and/or written to the board and read back). fringe write-correction: an
// existing correction file to a board or its register-writes file.
#include "server/cli/commands.hpp"
#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "server/analysis/calibration.hpp"
#include "server/engine/calibrate.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <optional>
#include <stdexcept>

namespace fringe::cli {

namespace {

// Where a correction goes besides its files: a Modbus board (written, read back) and/or the
// register writes as a file, for the board profile named by the URI or by --board.
struct BoardTarget {
    std::string uri, board, writes;
    std::string uri_option = "--write-board";  // the option that gave the URI, for messages (write-correction: --device)
    bool any() const { return !uri.empty() || !writes.empty(); }
};

// The profile the target names (checked before anything is computed or written).
std::optional<dev::BoardProfile> target_profile(const BoardTarget& t) {
    if (!t.uri.empty() && !t.board.empty()) throw ConfigError("--board", "give the board by --write-board's URI or by --board, not both");
    if (!t.writes.empty() && t.uri.empty() && t.board.empty())
        throw ConfigError("--modbus-writes", "needs the board profile: --board NAME (or " + t.uri_option + " URI)");
    std::string name = t.board;
    if (!t.uri.empty()) {
        const dev::UriParts u = dev::check_uri(t.uri);
        if (u.scheme != "modbus+tcp" && u.scheme != "modbus+rtu")
            throw ConfigError(t.uri_option, "a correction is written to a Modbus board (modbus+tcp://HOST:PORT?board=NAME), not '" + u.scheme + "'");
        name = u.settings.value("board", std::string("generic-aio"));
    }
    if (name.empty()) return std::nullopt;
    dev::BoardProfile b = dev::load_board(name);
    if (!b.has_correction())
        throw ConfigError(t.uri.empty() ? "--board" : t.uri_option, "board profile " + b.name + " (" + b.path +
                                               ") declares no correction registers (correction_table_rad, trim_*; docs/modbus.md \"Correction registers\")");
    return b;
}

// The register writes formed (nothing is written when a value does not fit its register).
std::string writes_text(const dev::BoardProfile& b, const std::vector<dev::RegisterValue>& plan, const std::string& path) {
    const bool csv = path.size() >= 4 && path.compare(path.size() - 4, 4, ".csv") == 0;
    return csv ? dev::modbus_writes_csv(b, plan) : dev::modbus_writes_json(b, plan);
}

// Writes the correction to the board and reads it back; prints what it did.
void write_to_board(const BoardTarget& t, const est::Correction& c, bool quiet) {
    if (t.uri.empty()) return;
    const auto plan = dev::write_correction(t.uri, c);
    std::size_t regs = 0;
    for (const auto& v : plan) regs += v.words.size();
    if (!quiet)
        std::printf("wrote the correction to %s: %zu values (%zu registers), read back and verified%s\n", t.uri.c_str(), plan.size(), regs,
                    plan.back().role == "correction_enable" ? "; correction_enable = 1" : "");
}

struct CalibrateCliOptions {
    BoardTarget target;
    bool table_size_given = false;
    std::string capture, output, csv, c_header, encoder, estimator = "atan2", name = "fringe_correction", error_source = "auto";
    std::size_t table_size = 64;
    int harmonics = 16;
    double lsb_rad = kTwoPi / 65536.0, settle_s = 0.1, min_cycles = 1;
    bool settle_given = false;
    bool no_lissajous = false, quiet = false;
};

void write_file(const std::string& path, const std::string& text) {
    std::ofstream f(path, std::ios::binary);
    if (!f) throw std::runtime_error("cannot write " + path);
    f << text;
    if (!f.flush()) throw std::runtime_error("cannot write " + path);
}

std::string fmt_g(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.4g", v);
    return b;
}

int run_calibrate(const CalibrateCliOptions& o) {
    refuse_overwrite({{"correction", o.output}, {"CSV table", o.csv}, {"C header", o.c_header}, {"Modbus writes", o.target.writes}},
                     {{"capture", o.capture}, {"encoder profile", o.encoder}});
    // A board to write to is checked first: its table's entry count is the default, and a
    // Lissajous stage needs its trims.
    const auto board = target_profile(o.target);
    std::size_t table_size = o.table_size;
    if (board) {
        if (const auto* t = board->find("correction_table_rad")) {
            if (o.table_size_given && o.table_size != static_cast<std::size_t>(t->count))
                throw ConfigError("--table-size", std::to_string(o.table_size) + " entries, but board " + board->name + "'s correction_table_rad has " +
                                                      std::to_string(t->count) + " (leave --table-size out to use the board's)");
            table_size = static_cast<std::size_t>(t->count);
        }
        if (!o.no_lissajous && !board->find("trim_offset_sin_v"))
            throw ConfigError("--no-lissajous", "board " + board->name + " has no Lissajous trim registers: calibrate with --no-lissajous (a correction of the angle only)");
    }
    CalibrateOptions co;
    co.capture_path = o.capture;
    co.estimator = o.estimator;
    co.table_size = table_size;
    co.harmonics = o.harmonics;
    co.lissajous = !o.no_lissajous;
    if (o.settle_given) co.settle_s = o.settle_s;
    co.min_cycles = o.min_cycles;
    co.error_source = o.error_source == "self-reference" ? "self_reference" : o.error_source;
    if (!o.encoder.empty()) co.encoder = load_encoder(o.encoder);
    const CalibrateResult r = calibrate_capture(co);
    // Every export is formed before anything is written (an entry that does not fit int16 writes nothing).
    if (!o.c_header.empty()) {
        // An LSB coarser than the whole correction writes a table of zeros: refused, not written.
        double largest_rad = 0;
        for (const double v : r.correction.table) largest_rad = std::max(largest_rad, std::fabs(v + r.correction.offset_rad));
        if (largest_rad > 0 && largest_rad < o.lsb_rad / 2)
            throw ConfigError("--lsb-rad", "an LSB of " + fmt_g(o.lsb_rad) + " rad is coarser than the whole correction (largest entry " +
                                               fmt_g(largest_rad) + " rad): every entry would round to 0");
    }
    const std::string header = o.c_header.empty() ? std::string() : correction_c_header(r.correction, o.lsb_rad, o.name);
    std::vector<dev::RegisterValue> plan;
    if (board) plan = dev::plan_correction_writes(*board, r.correction);  // a value that does not fit its register writes nothing
    // The board first: when it cannot take the correction, no file claims one was made for it.
    write_to_board(o.target, r.correction, o.quiet);
    nlohmann::json j = r.correction.to_json();
    j["calibrated_from"] = r.facts;
    write_file(o.output, j.dump(2) + "\n");
    if (!o.csv.empty()) write_file(o.csv, correction_csv(r.correction));
    if (!o.c_header.empty()) write_file(o.c_header, header);
    if (!o.target.writes.empty()) write_file(o.target.writes, writes_text(*board, plan, o.target.writes));
    if (!o.quiet) {
        const auto& c = r.correction;
        std::printf("correction for %s from %s (%s error)\n", o.estimator.c_str(), o.capture.c_str(),
                    r.source == "truth" ? "truth-scored" : "self-referenced");
        if (c.has_lissajous)
            std::printf("  Lissajous: offsets %.6g / %.6g V, amplitudes %.6g / %.6g V (sin/cos ratio %.6f), quadrature %.6g rad\n",
                        c.offset_sin_v, c.offset_cos_v, c.amplitude_sin_v, c.amplitude_cos_v, c.amplitude_sin_v / c.amplitude_cos_v,
                        c.quadrature_error_rad);
        std::printf("  error after the Lissajous stage: %.4g rad rms (periodic %.4g, the rest %.4g), after %.6g s settle (%s)\n", r.before_rms_rad,
                    r.periodic_rms_rad, r.noise_rms_rad, r.settle_s,
                    r.settle_from == "given" ? "--settle-s" : r.settle_from == "capture" ? "the capture's recording scenario" : "default");
        std::printf("  offset: %.4g rad (%s)\n", c.offset_rad, r.source == "truth"    ? "the error's mean against the truth, less the table's mean over the record"
                    : c.has_lissajous ? "self-referenced, the zero not observable: keeps the one atan2 had with the calibration it is told"
                                      : "none: no truth to measure it against (self-referenced)");
        std::printf("  table: %zu entries, linear interpolation, from %d harmonics; leaves %.4g rad rms of the periodic error\n",
                    c.table.size(), o.harmonics, r.table_residual_rms_rad);
        std::printf("  predicted residual: %.4g rad rms", r.predicted_rms_rad);
        if (r.per_sample_crb_rad > 0) std::printf(" (%.3g x the per-sample CRB %.4g rad)", r.predicted_rms_rad / r.per_sample_crb_rad, r.per_sample_crb_rad);
        std::printf("\n  verify it on another capture: fringe estimate OTHER --estimator atan2 --param correction=%s\n", o.output.c_str());
        if (!o.target.writes.empty()) std::printf("  register writes for board %s: %s (%zu values)\n", board->name.c_str(), o.target.writes.c_str(), plan.size());
    }
    return kExitOk;
}

struct WriteCorrectionOptions {
    BoardTarget target{{}, {}, {}, "--device"};
    std::string correction;
    bool quiet = false;
};

int run_write_correction(const WriteCorrectionOptions& o) {
    if (!o.target.any()) throw ConfigError("--device", "give the board to write to (--device URI) and/or --modbus-writes FILE with --board NAME");
    refuse_overwrite({{"Modbus writes", o.target.writes}}, {{"correction", o.correction}});
    const auto board = target_profile(o.target);
    const est::Correction c = est::Correction::load(o.correction);
    const auto plan = dev::plan_correction_writes(*board, c);  // refused before anything is written
    if (!o.target.writes.empty()) {
        write_file(o.target.writes, writes_text(*board, plan, o.target.writes));
        if (!o.quiet) std::printf("register writes for board %s: %s (%zu values)\n", board->name.c_str(), o.target.writes.c_str(), plan.size());
    }
    write_to_board(o.target, c, o.quiet);
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
    auto* ts = c->add_option("--table-size", o->table_size, "Entries of the angle table over one electrical period (default 64, or the board's correction_table_rad)")
                   ->check(CLI::Range(2, 1 << 20));
    c->add_option("--harmonics", o->harmonics, "Harmonic orders of the correction the table is built from")->check(CLI::Range(1, 256));
    c->add_option("--estimator", o->estimator, "Estimator to calibrate (atan2)");
    c->add_option("--encoder", o->encoder, "Encoder profile JSON the estimator is told (default: the capture's metadata)")->check(CLI::ExistingFile);
    auto* st = c->add_option("--settle-s", o->settle_s,
                             "Seconds from the start excluded from the error record (default: the settle_s the capture was recorded with, else 0.1)")
                   ->check(kFiniteNonNegative);
    c->add_option("--min-cycles", o->min_cycles, "Electrical cycles the error record needs (fewer: no correction)")->check(CLI::Range(1.0, 1e12))->capture_default_str();
    c->add_option("--error-source", o->error_source,
                  "The error the table is computed from: auto (truth where the capture has theta_true, else self-referenced), truth, self-reference")
        ->check(CLI::IsMember({"auto", "truth", "self-reference", "self_reference"}))
        ->capture_default_str();
    c->add_flag("--no-lissajous", o->no_lissajous, "No ellipse fit: keep the nominal calibration, correct the angle only");
    c->add_option("--csv", o->csv, "Also write the table as CSV: angle_rad,correction_rad");
    c->add_option("--c-header", o->c_header, "Also write the table as a C header of int16 entries");
    c->add_option("--lsb-rad", o->lsb_rad, "The C header's LSB in rad (default 2*pi/65536)")->check(kFinitePositive);
    c->add_option("--name", o->name, "The C header's array name (a C identifier)")
        ->check(CLI::Validator(
            [](std::string& v) -> std::string {
                // It is pasted into C source: only an identifier that is not a keyword (a name with
                // a space, a bracket or a comment marker wrote code into the header).
                static const char* const kKeywords[] = {"auto", "break", "case", "char", "const", "continue", "default", "do", "double", "else",
                                                        "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long", "register",
                                                        "restrict", "return", "short", "signed", "sizeof", "static", "struct", "switch",
                                                        "typedef", "union", "unsigned", "void", "volatile", "while", "bool", "true", "false"};
                const bool ident = !v.empty() && v.size() <= 63 && !std::isdigit(static_cast<unsigned char>(v[0])) &&
                                   std::all_of(v.begin(), v.end(), [](char ch) { return std::isalnum(static_cast<unsigned char>(ch)) || ch == '_'; });
                if (!ident) return "must be a C identifier (letters, digits and _, not starting with a digit, at most 63 characters)";
                for (const char* k : kKeywords)
                    if (v == k) return "'" + v + "' is a C keyword";
                return {};
            },
            "C identifier"));
    c->add_option("--write-board", o->target.uri, "Write the correction to this Modbus board and read it back (modbus+tcp://HOST:PORT?board=NAME; docs/modbus.md)");
    c->add_option("--modbus-writes", o->target.writes, "Also write the board's register writes as a file (JSON, or CSV for a .csv name)");
    c->add_option("--board", o->target.board, "The board profile for --modbus-writes without --write-board");
    c->add_flag("-q,--quiet", o->quiet, "No summary");
    return {c, [o, ts, st] {
                o->table_size_given = ts->count() > 0;
                o->settle_given = st->count() > 0;
                return run_calibrate(*o);
            }};
}

Command add_write_correction(CLI::App& app) {
    auto o = std::make_shared<WriteCorrectionOptions>();
    auto* c = app.add_subcommand("write-correction", "Write a correction file to a Modbus board's correction registers and read it back, or export the register writes (docs/modbus.md)");
    c->add_option("correction", o->correction, "Correction JSON (fringe calibrate -o)")->required()->check(CLI::ExistingFile);
    c->add_option("--device", o->target.uri, "The board: modbus+tcp://HOST:PORT?board=NAME or modbus+rtu:/dev/ttyX?board=NAME");
    c->add_option("--modbus-writes", o->target.writes, "Write the register writes as a file (JSON, or CSV for a .csv name)");
    c->add_option("--board", o->target.board, "The board profile for --modbus-writes without --device");
    c->add_flag("-q,--quiet", o->quiet, "No summary");
    return {c, [o] { return run_write_correction(*o); }};
}

}  // namespace fringe::cli
