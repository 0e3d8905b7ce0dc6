#include "server/engine/calibrated_run.hpp"

#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "estimator/estimator.hpp"
#include "server/engine/calibrate.hpp"
#include "server/engine/provenance.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/base/config.hpp"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

namespace fringe {

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

bool takes_correction(const std::string& name) {
    try {
        for (const auto& p : est::find(name).params)
            if (p.name == "correction") return true;
    } catch (const std::exception&) {
    }
    return false;
}

json number_or_null(const json& j) { return j.is_number() ? j : json(); }

// An after pass whose rms is more than this times the predicted residual is flagged.
constexpr double kOffPrediction = 1.5;

// What a pass ran on: enough to tell two captures apart and to make either again.
json pass_identity(const Scenario& sc, const char* pass) {
    json j{{"pass", pass}, {"seed", sc.seed}, {"motion", sc.motion}, {"device", sc.device_label()}};
    if (!sc.instruments && sc.device.rfind("capture:", 0) == 0) {
        // A replayed capture: the seed and motion are the ones it was recorded with (its
        // metadata's scenario), not this scenario's; unknown when it does not say.
        const dev::UriParts u = dev::check_uri(sc.device);
        j["capture"] = u.path;
        j["motion_from_capture"] = true;
        j["seed"] = nullptr;
        j["motion"] = nullptr;
        try {
            const CaptureReader reader(u.path, capture_options_from_uri(u.settings));
            const json& meta = reader.meta();
            if (meta.is_object() && meta.contains("scenario") && meta["scenario"].is_object()) {
                const json& rs = meta["scenario"];
                if (rs.contains("seed") && rs["seed"].is_number_integer()) j["seed"] = rs["seed"];
                if (rs.contains("motion")) j["motion"] = rs["motion"];
            }
        } catch (const std::exception&) {
            // unreadable here: the pass itself says why
        }
    }
    return j;
}

// The before pass's own record beside the after pass's: all of it but its plot data (the
// traces, and each lane's error spectrum).
json before_json(const RunReport& b) {
    json w = json::array();
    for (const auto& f : b.warnings) w.push_back(f);
    json lanes = estimators_json(b.estimators);
    for (auto& l : lanes) l.erase("spectrum");
    return {{"status", to_string(b.status)},
            {"verdict", b.verdict ? json(to_string(*b.verdict)) : json()},
            {"error", b.error.empty() ? json() : json(b.error)},
            {"started_at", b.started_at},
            {"finished_at", b.finished_at},
            {"wall_s", b.wall_s},
            {"seed", b.scenario.seed},
            {"samples", {{"planned", b.samples_planned}, {"processed", b.samples_processed}}},
            {"signal", b.signal},
            {"warnings", std::move(w)},
            {"estimators", std::move(lanes)},
            {"measurements", b.measurements}};
}

}  // namespace

json apply_to_software_lane(EstimatorSpec& lane, const std::string& correction_path) {
    if (!lane.params.is_object()) lane.params = json::object();
    lane.params["correction"] = correction_path;
    return {{"kind", "estimator_param"}, {"applied", true}, {"how", "params.correction = the correction file"}};
}

json apply_to_external_lane(EstimatorSpec& lane, const std::string& correction_path) {
    // An external estimator that declares correction=FILE hands the file to its child (its
    // environment); one that does not cannot be given it.
    if (takes_correction(lane.name)) {
        if (!lane.params.is_object()) lane.params = json::object();
        lane.params["correction"] = correction_path;
        return {{"kind", "external_env"}, {"applied", true},
                {"how", "params.correction = the correction file, handed to the child process (FRINGE_CORRECTION): whether the child applies it "
                        "shows only in its figures after"}};
    }
    return {{"kind", "external_env"}, {"applied", false},
            {"why_not", "not yet: an external estimator is not handed the correction file's path; it ran as before"}};
}

json apply_to_board(const Scenario& after, const std::string& correction_path) {
    auto not_applied = [&](const std::string& why) { return json{{"kind", "board_registers"}, {"applied", false}, {"why_not", why}}; };
    if (after.instruments) return not_applied("not yet with separate output and input instruments; its own position ran as before");
    dev::UriParts u;
    try {
        u = dev::check_uri(after.device);
    } catch (const std::exception& e) {
        return not_applied(e.what());
    }
    if (u.scheme != "modbus+tcp" && u.scheme != "modbus+rtu") return not_applied("the device is not a Modbus board; nothing to write");
    try {
        const dev::BoardProfile b = dev::load_board(u.settings.value("board", std::string("generic-aio")));
        if (!b.has_correction())
            return not_applied("board profile " + b.name + " declares no correction registers (docs/modbus.md \"Correction registers\"); its own position ran as before");
        const est::Correction c = est::Correction::from_json(load_json_file(correction_path));
        // Written, read back and verified, correction_enable set last: the after pass opens the board with it on.
        const auto plan = dev::write_correction(after.device, c);
        std::size_t regs = 0;
        for (const auto& v : plan) regs += v.words.size();
        return {{"kind", "board_registers"}, {"applied", true},
                {"how", "written to " + after.device + ": " + std::to_string(plan.size()) + " values (" + std::to_string(regs) +
                            " registers), read back and verified; correction_enable = 1"}};
    } catch (const std::exception& e) {
        return not_applied(std::string("the correction could not be written to the board: ") + e.what() + "; its own position ran as before");
    }
}

// Before the before pass: a Modbus board that declares correction registers may still apply a
// correction from an earlier run (its registers keep it); the before pass must see it
// uncorrected, so correction_enable is cleared first and the report says what it held.
json clear_board_correction(const Scenario& sc) {
    if (sc.instruments) return nullptr;
    dev::UriParts u;
    try {
        u = dev::check_uri(sc.device);
    } catch (const std::exception&) {
        return nullptr;
    }
    if (u.scheme != "modbus+tcp" && u.scheme != "modbus+rtu") return nullptr;
    try {
        const dev::BoardProfile b = dev::load_board(u.settings.value("board", std::string("generic-aio")));
        if (!b.has_correction()) return nullptr;
        const std::optional<double> was = dev::disable_correction(sc.device);
        if (!was) return {{"cleared", false}, {"why", "board profile " + b.name + " declares no correction_enable"}};
        return {{"cleared", true}, {"correction_enable_was", *was},
                {"how", *was != 0 ? "the board applied a correction (correction_enable " + std::to_string(*was) + "): cleared before the before pass"
                                  : "correction_enable was 0"}};
    } catch (const std::exception& e) {
        return {{"cleared", false}, {"failed", true}, {"why", std::string("correction_enable could not be cleared: ") + e.what()}};
    }
}

json apply_correction(EstimatorSpec& lane, const std::string& correction_path) {
    if (lane.params.is_object() && lane.params.contains("correction") && !lane.params["correction"].is_null())
        return {{"kind", "estimator_param"}, {"applied", false}, {"why_not", "applies a correction of its own (params.correction), kept"}};
    bool child = false;
    try {
        child = est::traits_of(lane.name).child_process;
    } catch (const std::exception&) {
    }
    if (child) return apply_to_external_lane(lane, correction_path);
    if (takes_correction(lane.name)) return apply_to_software_lane(lane, correction_path);
    return {{"kind", "none"}, {"applied", false}, {"why_not", lane.name + " takes no correction of an arctangent; it ran as before"}};
}

json lane_figures(const json& lane) {
    json f{{"error_source", nullptr}, {"rms_rad", nullptr}, {"max_abs_rad", nullptr}, {"mean_rad", nullptr}, {"harmonics", json::array()}};
    const json& m = lane.value("metrics", json::object());
    const json sr = lane.value("analysers", json::object()).value("self_reference", json());
    if (m.value("scored", std::uint64_t{0}) > 0) {
        f["error_source"] = "truth";
        f["rms_rad"] = number_or_null(m["rms"]["rad"]);
        f["max_abs_rad"] = number_or_null(m["max_abs"]["rad"]);
        f["mean_rad"] = number_or_null(m["mean"]["rad"]);
        f["scored_samples"] = m["evidence"]["scored_samples"];
        for (const auto& h : m.value("harmonics", json::array())) f["harmonics"].push_back({{"order", h["order"]}, {"amplitude_rad", h["amplitude"]["rad"]}});
    } else if (sr.is_object() && sr.value("measured", false)) {
        f["error_source"] = "self_reference";
        f["rms_rad"] = number_or_null(sr["rms_rad"]);
        f["samples"] = sr["samples"];
        for (const auto& h : sr.value("harmonics", json::array())) f["harmonics"].push_back({{"order", h["order"]}, {"amplitude_rad", h["amplitude_rad"]}});
    } else if (sr.is_object()) {
        f["why_not"] = sr.value("why_not", std::string("not measured"));
    } else {
        f["why_not"] = "nothing scored";
    }
    const json& b = lane.value("bounds", json());
    f["per_sample_crb_rad"] = b.is_object() ? number_or_null(b.value("per_sample_crb_rad", json())) : json();
    if (f["rms_rad"].is_number() && f["per_sample_crb_rad"].is_number() && f["per_sample_crb_rad"].get<double>() > 0)
        f["rms_over_crb"] = f["rms_rad"].get<double>() / f["per_sample_crb_rad"].get<double>();
    return f;
}

RunReport execute_calibrated_run(RunPlan plan, const RunOptions& o) {
    const Scenario sc = plan.scenario;  // as planned (a capture's rate, length and motion taken)
    const CalibrateSpec spec = *sc.calibrate;
    const std::string id = o.run_id.empty() ? new_run_id() : o.run_id;
    const std::uint64_t before_total = std::max<std::uint64_t>(1, sc.samples());
    const bool replay = !sc.instruments && sc.device.rfind("capture:", 0) == 0;

    json cal{{"lane", spec.lane},
             {"spec", json(sc)["calibrate"]},
             {"limits", "the verdict and measurements are the after pass's; the before pass's are kept in calibration.before"},
             {"computed_on", pass_identity(sc, "before")}};
    // The folder for the correction file (and the before pass's capture while it is read).
    fs::path dir;
    std::string dir_error;
    fs::path made_from;  // the first folder made here (and those under it): removed again when the run leaves nothing in them
    try {
        dir = o.calibration_dir.empty() ? fs::temp_directory_path() / ("fringe-run-" + id) : fs::path(o.calibration_dir);
        for (fs::path p = fs::absolute(dir); !p.empty() && !fs::exists(p) && p != p.parent_path(); p = p.parent_path()) made_from = p;
        fs::create_directories(dir);
    } catch (const std::exception& e) {
        dir_error = e.what();
    }
    std::string before_capture;
    CaptureOptions capture_options;
    bool remove_capture = false;
    RunOptions bo = o;
    bo.run_id = id;
    if (o.progress) bo.progress = [&](std::uint64_t done, std::uint64_t) { o.progress(done, 2 * before_total); };
    if (replay) {
        const dev::UriParts u = dev::check_uri(sc.device);
        before_capture = u.path;
        capture_options = capture_options_from_uri(u.settings);
    } else if (!o.record_path.empty()) {
        before_capture = o.record_path;
    } else if (dir_error.empty()) {
        before_capture = (dir / (id + ".before.fcap")).string();
        bo.record_path = before_capture;
        remove_capture = true;
    }
    if (!replay) cal["computed_on"]["capture"] = remove_capture ? json() : json(before_capture);

    const json board_before = clear_board_correction(sc);
    if (!board_before.is_null()) cal["board_before"] = board_before;
    RunReport before = execute_pass(std::move(plan), bo);
    std::optional<Finding> not_cleared;
    if (board_before.is_object() && board_before.value("failed", false)) {
        not_cleared = Finding{false, "board_correction_not_cleared", "calibrate",
                              "the board's own correction could not be switched off before the before pass (" + board_before["why"].get<std::string>() +
                                  "): its before figures may include a correction from an earlier run"};
        before.warnings.push_back(*not_cleared);
    }
    // A report with no after pass: the before pass's, saying why.
    auto without_after = [&](const std::string& status, const std::string& why, RunStatus run_status, Verdict verdict) {
        std::error_code ec;
        if (remove_capture) fs::remove(before_capture, ec);
        // An interrupted run leaves no empty folder behind.
        if (!made_from.empty())
            for (fs::path p = fs::absolute(dir, ec); !ec && p.string().size() >= made_from.string().size() && fs::is_empty(p, ec) && !ec; p = p.parent_path())
                if (!fs::remove(p, ec) || p == made_from) break;
        cal["status"] = status;
        cal["why"] = why;
        cal["limits"] = "no after pass: the measurements are the before pass's, for reference; the verdict is not theirs";
        cal["before"] = before_json(before);
        cal["after"] = nullptr;
        cal["lanes"] = json::array();
        for (const auto& e : before.estimators) {
            const json lj = e;
            cal["lanes"].push_back({{"label", e.label}, {"name", e.name}, {"before", lane_figures(lj)}, {"after", nullptr}});
        }
        RunReport r = std::move(before);
        if (r.status == RunStatus::Done) {
            r.status = run_status;
            r.verdict = verdict;
            r.error = why;
        }
        r.calibration = std::move(cal);
        return r;
    };
    if (before.status != RunStatus::Done)
        return without_after("before_incomplete", "the before pass did not complete: " + before.error, before.status, before.verdict.value_or(Verdict::Error));
    if (!dir_error.empty())
        return without_after("no_correction", "no folder for the correction: " + dir_error, RunStatus::Error, Verdict::Error);
    if (o.cancel && o.cancel->load()) return without_after("after_incomplete", "cancelled before the after pass", RunStatus::Aborted, Verdict::Aborted);

    // The correction, through the same path as `fringe calibrate`.
    const EstimatorSpec* lane = nullptr;
    for (const auto& e : sc.estimators)
        if (e.label == spec.lane) lane = &e;
    CalibrateOptions co;
    co.capture_path = before_capture;
    co.capture = capture_options;
    co.table_size = spec.table_size;
    co.harmonics = spec.harmonics;
    co.lissajous = spec.lissajous;
    co.settle_s = sc.settle_s;
    co.min_cycles = spec.min_cycles;
    co.error_source = spec.error_source;
    if (lane && lane->encoder) co.encoder = lane->encoder;
    else if (sc.encoder_known) co.encoder = sc.encoder;
    CalibrateResult cr;
    try {
        cr = calibrate_capture(co);
    } catch (const std::exception& e) {
        return without_after("no_correction", std::string("no correction: ") + e.what(), RunStatus::Error, Verdict::Error);
    }
    if (remove_capture) {
        std::error_code ec;
        fs::remove(before_capture, ec);
    }
    cal["computed_on"]["error_source"] = cr.source;
    json facts = cr.facts;
    facts["capture"] = remove_capture ? json("the before pass of run " + id + " (seed " + std::to_string(sc.seed) + ")") : json(before_capture);
    json file = cr.correction.to_json();
    file["calibrated_from"] = facts;
    const std::string text = file.dump(2) + "\n";
    const std::string correction_path = (dir / (id + ".correction.json")).string();
    {
        std::ofstream f(correction_path, std::ios::binary);
        f << text;
        if (!f.flush())
            return without_after("no_correction", "the correction could not be written to " + correction_path, RunStatus::Error, Verdict::Error);
    }
    cal["correction"] = {{"path", correction_path}, {"sha256", sha256_hex(text)}, {"file", file}};
    cal["predicted_rms_rad"] = cr.predicted_rms_rad;
    cal["calibrated_from"] = facts;

    // The after pass: another capture, the correction applied.
    Scenario after = sc;
    after.calibrate.reset();
    after.seed = spec.verify.seed.value_or(sc.seed + 1);
    if (spec.verify.motion) after.motion = *spec.verify.motion;
    if (!spec.verify.device.empty()) after.device = spec.verify.device;
    if (!after.instruments && after.device.rfind("capture:", 0) == 0) {
        // another capture: its own rate, length and motion
        after.motion_from_capture = false;
        after.length_from_capture = true;
        after.sample_rate_hz = 0;
        after.duration_s = 0;
    }
    json applied = json::object();
    for (auto& e : after.estimators) applied[e.label] = apply_correction(e, correction_path);
    applied["dut"] = apply_to_board(after, correction_path);
    cal["verified_on"] = pass_identity(after, "after");
    if (o.cancel && o.cancel->load()) return without_after("after_incomplete", "cancelled before the after pass", RunStatus::Aborted, Verdict::Aborted);
    RunPlan after_plan;
    try {
        after_plan = plan_run(after);
    } catch (const std::exception& e) {
        return without_after("after_incomplete", std::string("the after pass did not start: ") + e.what(), RunStatus::Error, Verdict::Error);
    }
    cal["verified_on"] = pass_identity(after_plan.scenario, "after");
    RunOptions ao = o;
    ao.run_id = id;
    ao.record_path.clear();
    ao.estimates = nullptr;
    ao.estimator_s = nullptr;
    const std::uint64_t after_total = std::max<std::uint64_t>(1, after_plan.scenario.samples());
    if (o.progress)
        ao.progress = [&](std::uint64_t done, std::uint64_t) {
            o.progress(before_total + static_cast<std::uint64_t>(static_cast<double>(done) * before_total / after_total), 2 * before_total);
        };
    RunReport r = execute_pass(std::move(after_plan), ao);
    if (not_cleared) r.warnings.push_back(*not_cleared);

    cal["before"] = before_json(before);
    cal["after"] = {{"status", to_string(r.status)}, {"error", r.error.empty() ? json() : json(r.error)}, {"seed", r.scenario.seed}};
    cal["lanes"] = json::array();
    for (const auto& e : before.estimators) {
        json row{{"label", e.label}, {"name", e.name}, {"before", lane_figures(json(e))}, {"after", nullptr}};
        for (const auto& a : r.estimators)
            if (a.label == e.label) row["after"] = lane_figures(json(a));
        row["correction"] = applied.contains(e.label) ? applied[e.label] : json();
        // The prediction is atan2's (its reading's noise); a loop's output filters that noise.
        if (e.label == spec.lane && e.name == "atan2") row["predicted_rms_rad"] = cr.predicted_rms_rad;
        // "verified" says both passes ran; whether the correction helped is each lane's change.
        const json& b = row["before"];
        const json& a = row["after"];
        if (row["correction"].is_object() && row["correction"].value("applied", false) && a.is_object() && b["rms_rad"].is_number() &&
            a["rms_rad"].is_number()) {
            const double rb = b["rms_rad"].get<double>(), ra = a["rms_rad"].get<double>();
            row["change"] = ra < rb ? "better" : "worse";
            if (!(ra < rb))
                r.warnings.push_back({false, "calibration_worse", "calibrate",
                                      "lane " + e.label + ": the correction left its error larger than before (" + std::to_string(rb) + " -> " +
                                          std::to_string(ra) + " rad rms): it does not fit this signal (table_size, harmonics or the record it came from)"});
            // Far above its prediction: the record did not describe this signal (another noise,
            // another distortion), whatever "better" says.
            if (row.contains("predicted_rms_rad") && ra < rb && ra > kOffPrediction * cr.predicted_rms_rad) {
                row["off_prediction"] = true;
                char msg[256];
                std::snprintf(msg, sizeof msg, "lane %s: after the correction %.4g rad rms, %.3g x its prediction %.4g: the record it came from does not describe this signal",
                              e.label.c_str(), ra, ra / cr.predicted_rms_rad, cr.predicted_rms_rad);
                r.warnings.push_back({false, "calibration_off_prediction", "calibrate", msg});
            }
        }
        cal["lanes"].push_back(std::move(row));
    }
    if (r.status == RunStatus::Done) {
        cal["status"] = "verified";
    } else {
        cal["status"] = "after_incomplete";
        cal["why"] = "the after pass did not complete: " + r.error;
        r.error = "the after pass did not complete: " + r.error;
    }
    r.id = id;
    r.started_at = before.started_at;
    r.wall_s += before.wall_s;
    r.calibration = std::move(cal);
    return r;
}

}  // namespace fringe
