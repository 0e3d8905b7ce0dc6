#include "server/engine/run.hpp"
#include "server/analysis/signal_quality.hpp"

#include "server/analysis/bounds.hpp"
#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "estimator/estimator.hpp"
#include "server/engine/frame_source.hpp"
#include "server/analysis/analyser.hpp"
#include "server/analysis/scoring.hpp"
#include "server/analysis/spectrum.hpp"
#include "server/analysis/task_pool.hpp"
#include "server/analysis/traces.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <limits>
#include <numbers>
#include <random>
#include <thread>

#include "server/engine/calibrated_run.hpp"
#include "server/engine/provenance.hpp"

namespace fringe {

using nlohmann::json;

std::string iso_now() {
    const auto t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

std::string new_run_id() { return new_uuid7(); }

RunReport unstarted_report(const Scenario& sc, const std::string& id, const std::string& started_at, RunStatus status, Verdict verdict,
                           const std::string& error, const json& provenance) {
    RunReport r;
    r.id = id;
    r.started_at = started_at;
    r.finished_at = iso_now();
    r.scenario = sc;
    r.status = status;
    r.verdict = verdict;
    r.error = error;
    r.samples_planned = sc.samples();
    r.provenance = provenance;
    return r;
}

namespace {

// One estimator under test (or the DUT's own position) with its analysers. Its output for a
// block stays in one of two slots while its analysers and the traces take that block beside
// the estimator's next one.
struct Lane {
    const EstimatorSpec* spec;
    std::unique_ptr<est::Estimator> e;  // null: the DUT's own position
    AnalyserSet analysers;
    struct Slot {
        std::vector<double> th, om;
        std::vector<std::uint8_t> valid;      // scored: the estimator vouched and truth is known
        std::vector<std::uint8_t> own_valid;  // as the estimator vouched (self-referenced analysis)
        std::vector<double> err;  // theta_hat - theta_true, NaN where invalid (plot traces)
        LaneBlock b;              // what the analysers see (into this slot and the frames)
        // A readout lane's words: latch instants on the run's clock, the truth there, zeros for the signals.
        std::vector<double> wt, wtruth, womega, wzeros, werr;  // werr: theta_hat - theta_true, NaN where not scored (traces)
        std::vector<std::uint8_t> wknown;
        std::vector<std::uint32_t> wframe;  // the block's frame a word is drawn at in the traces
    } out[2];
    double estimator_s = 0;  // time inside the estimator
    // The estimator writes here, never into a slot: a slot's lines were last read by the other
    // threads' analysers, and an estimator's stores into them, a sample at a time, slowed it
    // (ekf-diffraction 20 % slower on two threads than on one). Whole copies into the slot follow.
    struct Own {
        std::vector<double> th, om;
        std::vector<std::uint8_t> valid;
    } own;
    bool self_reference = false;  // keep the estimator's own flags for the self-referenced analyser
    std::function<void(std::size_t, const double*, const double*, const double*, const std::uint8_t*)> tap;  // RunOptions::estimates
    Lane(const EstimatorSpec* s, const LaneContext& ctx) : spec(s), analysers(ctx), self_reference(ctx.self_reference), settle_s(ctx.settle_s) {}
    double settle_s = 0;

    // A DUT read out by its own device (device.dut): its words, each scored once against the
    // truth at its latch instant, which falls between two frames (cubic Hermite through their
    // truth and rate: exact to O(h^4) on the motion; linear where a rate is unknown).
    dev::ReadoutPort* readout = nullptr;
    struct WordFeed {
        std::vector<dev::PositionWordOut> words;
        bool have_prev = false;
        double prev_t = 0, prev_th = 0, prev_om = 0;
        bool prev_known = false;
        std::uint64_t received = 0, before_run = 0, scored_truth_known = 0;
        std::string failed;  // the readout's fault, raised at the next block
        // The latency fit: e = -omega * tau over the valid words after the settle time (e the
        // word's error wrapped to (-pi, pi]), least squares through zero, and what is left.
        bool have_t0 = false;
        double t0 = 0, n = 0, see = 0, seo = 0, soo = 0;
        double last_word_t = -std::numeric_limits<double>::infinity();  // run clock
    } feed;
    // A readout fault not yet raised (its block was the run's last).
    void fail_pending() const {
        if (readout && !feed.failed.empty()) throw std::runtime_error(feed.failed);
    }

    struct TruthAt {
        double t_s, theta_rad, omega_rad_s;
        bool known;
    };
    void estimate_words(const Frames& f, int slot) {
        Slot& o = out[slot];
        const std::size_t m = f.size();
        o.err.assign(m, std::numeric_limits<double>::quiet_NaN());  // per frame: NaN (the words are drawn at their own instants: werr, wframe)
        auto& w = feed;
        w.words.clear();
        const double off = readout->readout_to_run_s();
        // A readout that fails: the words it read are still scored, and the run ends at the next
        // block (or after this one, if it was the last: fail_pending()).
        if (!w.failed.empty()) throw std::runtime_error(w.failed);
        if (m > 0) {
            const dev::StreamResult r = readout->read_words(f.t_s[m - 1] - off, w.words, static_cast<int>(readout->stall_s() * 1000));
            if (r.status != dev::StreamStatus::Ok)
                w.failed = std::string("device.dut: ") + dev::to_string(r.status) + ": " + r.message + " (the words read before it are scored)";
        }
        const std::size_t n = w.words.size();
        w.received += n;
        o.wt.resize(n); o.wtruth.resize(n); o.womega.resize(n); o.wknown.resize(n); o.wzeros.assign(n, 0.0);
        o.werr.assign(n, std::numeric_limits<double>::quiet_NaN()); o.wframe.assign(n, 0);
        o.th.resize(n); o.om.assign(n, std::numeric_limits<double>::quiet_NaN()); o.valid.resize(n);
        std::size_t j = 0;
        for (std::size_t k = 0; k < n; ++k) {
            const double tw = w.words[k].t_s + off;
            while (j < m && f.t_s[j] < tw) ++j;
            o.wt[k] = tw;
            o.th[k] = w.words[k].theta_rad;
            w.last_word_t = std::max(w.last_word_t, tw);
            if (j >= m) j = m - 1;  // read up to the last frame: only rounding puts a word past it
            o.wframe[k] = static_cast<std::uint32_t>(j);
            if (j == 0 && !(f.t_s[0] <= tw) && !w.have_prev) {  // latched before the run's first frame
                ++w.before_run;
                o.wknown[k] = 0;
                o.wtruth[k] = o.womega[k] = 0;
                o.valid[k] = 0;
                continue;
            }
            // The truth at the frames on either side of the latch (the previous block's last
            // frame before this block's first; one frame when the word is on it).
            const auto frame = [&](std::size_t i) { return TruthAt{f.t_s[i], f.theta_true_rad[i], f.omega_true_rad_s[i], f.truth_known[i] != 0}; };
            const TruthAt b1 = frame(j);
            const TruthAt b0 = f.t_s[j] <= tw || (j == 0 && !w.have_prev) ? b1 : j == 0 ? TruthAt{w.prev_t, w.prev_th, w.prev_om, w.prev_known} : frame(j - 1);
            const auto [t0, th0, om0, k0] = b0;
            const auto [t1, th1, om1, k1] = b1;
            const double h = t1 - t0;
            double th = th1, om = om1;
            if (h > 0) {
                const double s = (tw - t0) / h;
                if (std::isfinite(om0) && std::isfinite(om1)) {
                    const double s2 = s * s, s3 = s2 * s;
                    th = (2 * s3 - 3 * s2 + 1) * th0 + (s3 - 2 * s2 + s) * h * om0 + (-2 * s3 + 3 * s2) * th1 + (s3 - s2) * h * om1;
                    om = (1 - s) * om0 + s * om1;
                } else {
                    th = (1 - s) * th0 + s * th1;
                    om = std::numeric_limits<double>::quiet_NaN();
                }
            }
            o.wtruth[k] = th;
            o.womega[k] = om;
            o.wknown[k] = static_cast<std::uint8_t>(k0 && k1);
            w.scored_truth_known += o.wknown[k];
            o.valid[k] = static_cast<std::uint8_t>(w.words[k].valid && o.wknown[k] && std::isfinite(o.th[k]));
            if (o.valid[k]) o.werr[k] = o.th[k] - th;
            if (!w.have_t0) { w.have_t0 = true; w.t0 = tw; }
            if (o.valid[k] && std::isfinite(om) && tw - w.t0 >= settle_s) {
                const double err = std::remainder(o.th[k] - th, 2 * std::numbers::pi);
                w.n += 1; w.see += err * err; w.seo += err * om; w.soo += om * om;
            }
        }
        if (m > 0) {
            w.have_prev = true;
            w.prev_t = f.t_s[m - 1];
            w.prev_th = f.theta_true_rad[m - 1];
            w.prev_om = f.omega_true_rad_s[m - 1];
            w.prev_known = f.truth_known[m - 1] != 0;
        }
        LaneBlock& b = o.b;
        b.n = n;
        b.t_s = o.wt.data();
        b.sin_v = o.wzeros.data();
        b.cos_v = o.wzeros.data();
        b.theta_true_rad = o.wtruth.data();
        b.omega_true_rad_s = o.womega.data();
        b.truth_known = o.wknown.data();
        b.theta_hat_rad = o.th.data();
        b.omega_hat_rad_s = nullptr;
        b.valid = o.valid.data();
        b.estimator_valid = nullptr;
    }

    // The estimator on one block, into a slot (the analysers take it in the next step).
    void estimate(const Frames& f, int slot) {
        if (readout) return estimate_words(f, slot);
        Slot& o = out[slot];
        auto& th = o.th;
        auto& om = o.om;
        auto& valid = o.valid;
        const std::size_t m = f.size();
        th.resize(m); om.resize(m); valid.resize(m);
        if (!e) {  // the DUT's own position: no rate
            for (std::size_t i = 0; i < m; ++i) {
                th[i] = f.dut_theta_rad[i];
                om[i] = std::numeric_limits<double>::quiet_NaN();
                valid[i] = std::isfinite(th[i]);
            }
        } else {
            const auto t0 = std::chrono::steady_clock::now();
            own.th.resize(m); own.om.resize(m); own.valid.resize(m);
            e->process({std::span(f.sin_v), std::span(f.cos_v)}, {std::span(own.th), std::span(own.om), std::span(own.valid)});
            estimator_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            std::copy(own.th.begin(), own.th.end(), th.begin());
            std::copy(own.om.begin(), own.om.end(), om.begin());
            std::copy(own.valid.begin(), own.valid.end(), valid.begin());
        }
        if (tap) tap(m, f.t_s.data(), th.data(), om.data(), valid.data());
        if (self_reference) o.own_valid.assign(valid.begin(), valid.end());
        // Valid where the truth is known too; then the error (branch-free passes that vectorise).
        std::uint8_t* vd = valid.data();
        const std::uint8_t* tk = f.truth_known.data();
        for (std::size_t i = 0; i < m; ++i) vd[i] = static_cast<std::uint8_t>((vd[i] != 0) & (tk[i] != 0));
        LaneBlock& b = o.b;
        b.n = m;
        b.t_s = f.t_s.data();
        b.sin_v = f.sin_v.data();
        b.cos_v = f.cos_v.data();
        b.theta_true_rad = f.theta_true_rad.data();
        b.omega_true_rad_s = f.omega_true_rad_s.data();
        b.truth_known = f.truth_known.data();
        b.theta_hat_rad = th.data();
        b.omega_hat_rad_s = e ? om.data() : nullptr;
        b.valid = valid.data();
        b.estimator_valid = self_reference ? o.own_valid.data() : nullptr;
        o.err.resize(m);
        const double* tt = f.theta_true_rad.data();
        const double* hat = th.data();
        double* er = o.err.data();
        for (std::size_t i = 0; i < m; ++i) {
            const double d = hat[i] - tt[i];
            er[i] = vd[i] ? d : std::numeric_limits<double>::quiet_NaN();
        }
    }
    // Analyser i on the block in a slot.
    void analyse(std::size_t i, int slot) { analysers.add(i, out[slot].b); }
};

// The pipeline's threads: asked for, else FRINGE_THREADS, else one per hardware thread.
unsigned pipeline_threads(unsigned asked) {
    if (asked) return asked;
    if (const char* env = std::getenv("FRINGE_THREADS")) {
        const long v = std::strtol(env, nullptr, 10);
        if (v >= 1 && v <= 64) return static_cast<unsigned>(v);
    }
    return std::max(1u, std::thread::hardware_concurrency());
}

// The spectrum's segment length wants the electrical frequency: the mean planned rate.
double planned_electrical_hz(const Scenario& sc) {
    constexpr std::size_t n = 1000;
    std::vector<double> t(n), phi(n), om(n), al(n);
    for (std::size_t i = 0; i < n; ++i) t[i] = sc.t0_s + sc.duration_s * static_cast<double>(i) / (n - 1);
    sc.motion.evaluate(t.data(), n, phi.data(), om.data(), al.data());
    double sum = 0;
    for (double w : om) sum += std::fabs(w);
    return sum / n * sc.encoder.lines_per_rev / kTwoPi;
}

class Recorder {
public:
    Recorder(const std::string& path, const Scenario& sc, const dev::DeviceInfo& d, const std::string& id) {
        json meta{{"sample_rate_hz", sc.sample_rate_hz}, {"t0_s", sc.t0_s}, {"encoder", sc.encoder}, {"scenario", sc},
                  {"device", d}, {"board_id", d.board_id}, {"run_id", id},
                  {"note", "device input recorded by fringe run; theta_true aligned for the device latency (0 where unknown)"}};
        w_.emplace(path, CaptureColumns{true, true, false}, meta);
    }
    void add(const Frames& f) {
        rec_.t_s = f.t_s;
        rec_.sin_v = f.sin_v;
        rec_.cos_v = f.cos_v;
        rec_.theta_true_rad = f.theta_true_rad;
        rec_.omega_true_rad_s = f.omega_true_rad_s;
        for (std::size_t i = 0; i < f.size(); ++i)
            if (!f.truth_known[i]) rec_.theta_true_rad[i] = rec_.omega_true_rad_s[i] = 0.0;
        w_->write(rec_);
    }
    void close() { w_->close(); }

private:
    std::optional<CaptureWriter> w_;
    CaptureData rec_;
};

// A replayed capture without a theta_true column has no truth; every other source has.
bool device_has_truth(const dev::DeviceInfo& d) {
    return !(d.replay && d.settings.is_object() && d.settings.value("has_truth", true) == false);
}

// The scored lanes' report entries: metrics with their evidence, bounds from the signal as
// delivered, and convention findings.
std::vector<EstimatorReport> score_lanes(const Scenario& sc, const dev::DeviceInfo& dinfo, std::vector<std::unique_ptr<Lane>>& lanes,
                                         const json& dut_readout, std::vector<Finding>& warnings) {
    json basis;
    const EncoderProfile delivered = delivered_profile(sc.encoder, dinfo.converter, &basis);
    std::vector<EstimatorReport> out;
    for (auto& lane : lanes) {
        const LaneResults res = lane->analysers.finish();
        EstimatorReport e;
        e.label = lane->spec->label;
        e.name = lane->spec->name;
        e.params = lane->spec->params;
        e.state = lane->e ? lane->e->state() : json();
        e.metrics = res.error.value_or(ErrorMetrics{});
        const ErrorMetrics& m = e.metrics;
        e.lines_per_rev = sc.encoder_known ? sc.encoder.lines_per_rev : 0;  // arcsec need lines_per_rev
        // The DUT's ABZ readout: what the decoder counted is part of its metrics (limits name
        // abz_illegal_transitions, abz_index_errors), and an illegal transition is an error.
        if (!lane->e && dut_readout.is_object()) {
            e.abz = dut_readout;
            const auto illegal = dut_readout.value("illegal_transitions", std::uint64_t{0});
            if (illegal > 0)
                warnings.push_back({true, "dut_illegal_transitions", "estimators.dut",
                                    "dut: " + std::to_string(illegal) + " illegal A/B transitions (both lines changed between two samples); "
                                    "the position was invalid from each until the next index (" +
                                        std::to_string(dut_readout.value("invalid_samples", std::uint64_t{0})) + " samples without a position)"});
            const auto index_errors = dut_readout.value("index_errors", std::uint64_t{0});
            if (index_errors > 0)
                warnings.push_back({true, "dut_index_errors", "estimators.dut",
                                    "dut: the count was off at " + std::to_string(index_errors) + " index pulses (by up to " +
                                        std::to_string(dut_readout.value("max_index_error_counts", 0LL)) + " counts) and was reset there"});
            if (const auto missed = dut_readout.value("missed_index", std::uint64_t{0}); missed > 0)
                warnings.push_back({true, "dut_missed_index", "estimators.dut",
                                    "dut: the count crossed the index " + std::to_string(missed) + " times with no Z pulse (a Z line broken, or pulses lost)"});
        }
        if (lane->readout) {
            // The readout's own account: what it read and what was wrong on the wire, and the
            // DUT's latency (the lag fit of its error against the true rate), stated apart.
            json ro = lane->readout->stats();
            ro["clock_offset_s"] = lane->readout->readout_to_run_s();
            ro["words_received"] = lane->feed.received;
            ro["words_before_run"] = lane->feed.before_run;
            ro["words_with_truth"] = lane->feed.scored_truth_known;
            // The latency by least squares over the valid words (null when the motion never
            // moved), and the rms error with it taken out: what the DUT's interpolation is
            // worth apart from its delay.
            const auto& fw = lane->feed;
            const bool fit = fw.n >= 2 && fw.soo > 0;
            ro["latency_s"] = fit ? json(-fw.seo / fw.soo) : json();
            ro["latency_words"] = fw.n;
            ro["rms_without_latency_rad"] = fit ? json(std::sqrt(std::max(0.0, fw.see - fw.seo * fw.seo / fw.soo) / fw.n)) : json();
            e.readout = ro;
            std::vector<std::pair<const char*, const char*>> causes = {
                {"crc_errors", "bad CRC"}, {"short_frames", "short frames"}, {"long_frames", "long frames"}, {"error_flags", "error bit set"},
                {"not_ready", "not ready"}, {"no_start", "no start bit"}, {"out_of_range", "out of range"},
                {"malformed_lines", "malformed lines"}, {"time_reversals", "time reversals"}};
            std::string what;
            for (const auto& [k, label] : causes)
                if (ro.value(k, std::uint64_t{0}) > 0) what += (what.empty() ? "" : ", ") + std::to_string(ro[k].get<std::uint64_t>()) + " " + label;
            if (ro.contains("abz"))
                for (const auto& [k, label] : std::vector<std::pair<const char*, const char*>>{
                         {"illegal_transitions", "illegal A/B transitions"}, {"index_errors", "index pulses at the wrong count"}, {"missed_index", "missed index pulses"}})
                    if (ro["abz"].value(k, std::uint64_t{0}) > 0)
                        what += (what.empty() ? "" : ", ") + std::to_string(ro["abz"][k].get<std::uint64_t>()) + " " + label;
            // Words that do not cover the run: what was scored is said, never assumed.
            const double word_dt_s = 1.0 / std::max(1e-300, lane->readout->word_rate_hz());
            if (fw.received == 0)
                warnings.push_back({true, "dut_no_words", "estimators.dut",
                                    "dut: the readout gave no word within the run's time (check the readout's clock: clock_offset_s)"});
            else if (fw.have_prev && fw.last_word_t < fw.prev_t - 2 * word_dt_s)
                warnings.push_back({true, "dut_words_end_early", "estimators.dut",
                                    "dut: the readout's words end at t = " + std::to_string(fw.last_word_t) + " s, the run's frames at " +
                                        std::to_string(fw.prev_t) + " s: the rest of the run has no DUT words"});
            if (fw.before_run > 0)
                warnings.push_back({true, "dut_words_outside_run", "estimators.dut",
                                    "dut: " + std::to_string(fw.before_run) + " words were latched before the run's first frame and not scored "
                                    "(check the readout's clock: clock_offset_s)"});
            ro["last_word_s"] = fw.received ? json(fw.last_word_t) : json();
            e.readout = ro;
            if (!what.empty())
                warnings.push_back({true, "dut_wire_errors", "estimators.dut",
                                    "dut: errors on the wire (" + what + "): each invalidated its word, which was not scored"});
        }
        e.spectrum = res.spectrum;
        e.analysers = res.extra;
        if (m.scored > 0 && lane->e && sc.encoder_known) {  // bounds need the signal model
            e.bounds = bounds_json(delivered, *lane->e, sc.sample_rate_hz, m.scored, m.rms_rad);
            e.bounds["signal_as_delivered"] = basis;
        }
        // An estimator that vouched for none of its output after the settle time: the cause is
        // its own (told another signal model or amplitude, no lock), whatever else is reported.
        {
            const json sr = e.analysers.is_object() ? e.analysers.value("self_reference", json()) : json();
            const bool truthless_never = sr.is_object() && sr.value("samples_after_settle", std::uint64_t{0}) > 0 && sr.value("valid_fraction", json()) == json(0.0);
            // (without truth the scorer counts every sample invalid: only the self-referenced count says)
            const bool scored_never = device_has_truth(dinfo) && m.after_settle > 0 && m.invalid_after_settle == m.after_settle;
            if (lane->e && (truthless_never || scored_never)) {
                const std::string msg = "marked every sample after the settle time invalid: nothing it output can be judged (its state says why; an "
                                        "estimator told another signal model or amplitude than the signals' often does)";
                e.diagnosis.push_back({"never_valid", msg});
                warnings.push_back({false, "never_valid", "estimators." + e.label, e.label + " " + msg});
            }
        }
        e.convention_violations = res.conventions.size();
        for (const auto& f : res.conventions) {
            e.diagnosis.push_back({f.code, f.message});
            warnings.push_back({false, f.code, "estimators." + e.label, e.label + ": " + f.message});
        }
        if (e.bounds.is_object() && e.bounds.value("efficiency_not_credible", json()).is_string()) {
            const std::string msg = e.bounds["efficiency_not_credible"].get<std::string>();
            e.diagnosis.push_back({"efficiency_not_credible", msg});
            warnings.push_back({false, "efficiency_not_credible", "estimators." + e.label, e.label + ": " + msg});
        }
        out.push_back(std::move(e));
    }
    return out;
}

// One DeviceInfo for a generator and a digitizer: the digitizer's, with the generator's DAC
// and the label of both (report "device"; each in full under "output" and "input").
dev::DeviceInfo combined_info(const Scenario& sc, const dev::DeviceInfo& out, const dev::DeviceInfo& in) {
    if (sc.instruments->output == sc.instruments->input) return in;
    dev::DeviceInfo d = in;
    d.driver = out.driver == in.driver ? in.driver : out.driver + "+" + in.driver;
    d.uri = sc.device_label();
    d.description = out.description + " -> " + in.description;
    d.can_play = out.can_play;
    d.max_play_samples = out.max_play_samples;
    d.own_clock = out.own_clock || in.own_clock;
    auto& c = d.converter;
    c.known = out.converter.known && in.converter.known;
    c.dac_bits = out.converter.dac_bits;
    c.dac_range_v = out.converter.dac_range_v;
    c.dac_step_v = out.converter.dac_step_v;
    c.added_noise_v = c.independent_noise_v();
    c.note = "generator's DAC and digitizer's ADC quantise independently";
    return d;
}

}  // namespace

RunReport execute_run(const Scenario& sc, const RunOptions& o) { return execute_run(plan_run(sc), o); }

RunReport execute_run(RunPlan plan, const RunOptions& o) {
    if (plan.scenario.calibrate) return execute_calibrated_run(std::move(plan), o);
    return execute_pass(std::move(plan), o);
}

RunReport execute_pass(RunPlan plan, const RunOptions& o) {
    RunReport report;
    report.scenario = std::move(plan.scenario);
    const Scenario& sc = report.scenario;
    std::vector<Finding> warnings = std::move(plan.warnings);
    report.id = o.run_id.empty() ? new_run_id() : o.run_id;
    report.started_at = iso_now();
    report.provenance = o.provenance;
    RunStatus status = RunStatus::Done;
    std::string error;
    const auto wall0 = std::chrono::steady_clock::now();

    std::vector<std::unique_ptr<Lane>> lanes;
    dev::DeviceInfo dinfo;
    const std::uint64_t total = sc.samples();
    std::uint64_t processed = 0;
    std::optional<TraceRecorder> traces;
    SignalQuality signal;  // the signals' quality, drawn beside the traces
    json dut_readout;
    static const EstimatorSpec dut_spec{"dut", "dut", nlohmann::json::object(), std::nullopt};
    const std::size_t segment = ErrorSpectrum::choose_segment(
        sc.sample_rate_hz, planned_electrical_hz(sc), static_cast<std::uint64_t>(std::max(0.0, (sc.duration_s - sc.settle_s) * sc.sample_rate_hz)));
    json alignment = nullptr;
    bool has_truth = true;
    std::unique_ptr<dev::Device> dut_device;  // device.dut: a readout of the DUT's own words
    try {
        // Separate instruments: the generator (output) and the digitizer (input); the same URI
        // twice is one device. Faults name the scenario field.
        std::unique_ptr<dev::Device> device, input_device;
        dev::DeviceInfo out_info, in_info;
        auto open_named = [](const std::string& field, const std::string& uri) {
            try {
                return dev::open(uri);
            } catch (const std::exception& e) {
                throw std::runtime_error(field + ": " + e.what());
            }
        };
        if (sc.instruments) {
            device = open_named("device.output", sc.instruments->output);
            if (sc.instruments->input != sc.instruments->output) input_device = open_named("device.input", sc.instruments->input);
            out_info = device->info();
            in_info = input_device ? input_device->info() : out_info;
            dinfo = combined_info(sc, out_info, in_info);
        } else {
            device = dev::open(sc.device);
            dinfo = device->info();
        }
        for (auto* d : {device.get(), input_device.get()})
            if (d) d->set_cancel(o.cancel);  // a device waiting on a failing board sees a cancel
        for (const auto& f : preflight_device(sc, dinfo)) warnings.push_back(f);
        // A capture without truth: nothing can be scored against truth, so each lane's error is
        // measured self-referenced (docs/self-reference.md) and the evidence is that analysis's.
        has_truth = device_has_truth(dinfo);
        const LaneContext lane_ctx{sc.sample_rate_hz, sc.settle_s, sc.scoring.max_harmonic, segment, sc.scoring.self_reference || !has_truth};
        for (std::size_t i = 0; i < sc.estimators.size(); ++i) {
            const auto& spec = sc.estimators[i];
            auto lane = std::make_unique<Lane>(&spec, lane_ctx);
            // built by plan_run; a child process starts here
            lane->e = plan.estimators[i] ? std::move(plan.estimators[i]) : est::make(spec.name, plan.configs[i]);
            if (lanes.empty()) lane->tap = o.estimates;
            lanes.push_back(std::move(lane));
        }
        // A board that reports its own interpolated position is scored like an estimator, "dut".
        if (dinfo.dut_position) lanes.push_back(std::make_unique<Lane>(&dut_spec, lane_ctx));
        // A DUT read out by a device of its own (device.dut): its words at their own rate.
        if (sc.instruments && !sc.instruments->dut.empty()) {
            dut_device = open_named("device.dut", sc.instruments->dut);
            dut_device->set_cancel(o.cancel);
            dev::ReadoutPort* port = dut_device->readout();
            if (!port) throw std::runtime_error("device.dut: " + sc.instruments->dut + " reads out no position words (a readout: URI does)");
            try {
                port->start();
            } catch (const std::exception& e) {
                throw std::runtime_error(std::string("device.dut: ") + e.what());
            }
            LaneContext word_ctx = lane_ctx;
            word_ctx.sample_rate_hz = port->word_rate_hz();
            word_ctx.self_reference = false;  // no signals of its own to refer to
            word_ctx.spectrum_segment = ErrorSpectrum::choose_segment(
                word_ctx.sample_rate_hz, planned_electrical_hz(sc),
                static_cast<std::uint64_t>(std::max(0.0, (sc.duration_s - sc.settle_s) * word_ctx.sample_rate_hz)));
            auto lane = std::make_unique<Lane>(&dut_spec, word_ctx);
            lane->readout = port;
            lanes.push_back(std::move(lane));
        }
        {
            std::vector<std::string> labels;
            for (auto& lane : lanes) labels.push_back(lane->spec->label);
            // Angle folds from the settle time on, so a lock transient does not swamp them.
            traces.emplace(total, o.trace_points, labels, sc.t0_s + sc.settle_s);
        }
        // One device for output and input that streams (a loopback, a USB board) runs as a
        // stream even beside a DUT readout; a generator and a digitizer run in instrument mode.
        const bool instrument_mode = sc.instruments && (input_device || device->player());
        auto source = instrument_mode ? make_instrument_source(sc, *device, input_device ? *input_device : *device)
                                      : make_frame_source(sc, *device, dinfo, o.block);
        if (!instrument_mode) dinfo = device->info();  // started: converter figures at the run's rate
        report.device = dinfo;
        if (input_device) {
            report.device_output = out_info;
            report.device_input = in_info;
        }
        if (report.provenance.is_object() && report.provenance["dut"]["serial"] == "") report.provenance["dut"]["serial"] = dinfo.board_id;
        std::optional<Recorder> recorder;
        if (!o.record_path.empty()) recorder.emplace(o.record_path, sc, dinfo, report.id);
        // The pipeline, one step per block: the source fills block k+1, the estimators take
        // block k (each lane a task of its own), and block k-1 goes to each lane's analysers
        // (each analyser a task), the recorder and the traces, all side by side. Each task
        // touches only its own slot and state, so the report is the same for any thread count;
        // the tasks are handed out longest first (by their time in the step before), so the
        // slowest estimator starts at once and the rest fill the other threads around it.
        // Frames delivered before a fault or a cancel are processed.
        TaskPool pool(pipeline_threads(o.threads));
        Frames slot[3];
        SourceStatus st;
        bool source_done = false;
        std::exception_ptr source_failure;
        std::uint64_t produced = 0, laned = 0;  // frames delivered by the source, and through the estimators
        std::size_t have[3] = {0, 0, 0};  // frames in each slot
        enum class Kind { Source, Ahead, Estimate, Analyse, Traces, Signal };
        struct Job {
            Kind kind;
            std::size_t lane = 0, analyser = 0;
            double* seconds = nullptr;  // the task's time in the last step it ran
        };
        double source_s = 0, ahead_s = 0, traces_s = 0, signal_s = 0;
        std::vector<double> estimate_s(lanes.size(), 0.0);
        std::vector<std::vector<double>> analyse_s(lanes.size());
        for (std::size_t j = 0; j < lanes.size(); ++j) analyse_s[j].assign(lanes[j]->analysers.size(), 0.0);
        std::vector<Job> jobs;
        std::vector<std::function<void()>> tasks;
        std::vector<std::exception_ptr> errors;
        for (std::uint64_t step = 0;; ++step) {
            if (!source_done && o.cancel && o.cancel->load()) { status = RunStatus::Aborted; error = "cancelled"; source_done = true; }
            const bool produce = !source_done && produced < total;
            const bool estimate_step = step >= 1 && have[(step - 1) % 3] > 0;  // block step-1
            const bool analyse_step = step >= 2 && have[(step - 2) % 3] > 0;   // block step-2
            if (!produce && !estimate_step && !analyse_step) break;
            const std::size_t ks = step % 3, ke = (step + 2) % 3, ka = (step + 1) % 3;  // slots of blocks step, step-1, step-2
            const int le = static_cast<int>((step + 1) % 2), la = static_cast<int>(step % 2);  // lane slots of blocks step-1, step-2
            jobs.clear();
            if (produce) {
                jobs.push_back({Kind::Source, 0, 0, &source_s});
                jobs.push_back({Kind::Ahead, 0, 0, &ahead_s});
            }
            if (estimate_step)
                for (std::size_t j = 0; j < lanes.size(); ++j) jobs.push_back({Kind::Estimate, j, 0, &estimate_s[j]});
            if (analyse_step) {
                for (std::size_t j = 0; j < lanes.size(); ++j)
                    for (std::size_t a = 0; a < lanes[j]->analysers.size(); ++a) jobs.push_back({Kind::Analyse, j, a, &analyse_s[j][a]});
                jobs.push_back({Kind::Traces, 0, 0, &traces_s});
                jobs.push_back({Kind::Signal, 0, 0, &signal_s});
            }
            std::stable_sort(jobs.begin(), jobs.end(), [](const Job& x, const Job& y) { return *x.seconds > *y.seconds; });
            tasks.clear();
            for (const Job& jb : jobs)
                tasks.emplace_back([&, jb] {
                    const auto t0 = std::chrono::steady_clock::now();
                    switch (jb.kind) {
                    case Kind::Source:
                        st = source->next(o.block, slot[ks]);
                        alignment = source->alignment();
                        break;
                    case Kind::Ahead: source->generate_ahead(); break;
                    case Kind::Estimate: lanes[jb.lane]->estimate(slot[ke], le); break;
                    case Kind::Analyse: lanes[jb.lane]->analyse(jb.analyser, la); break;
                    case Kind::Traces: {
                        const Frames& f = slot[ka];
                        if (recorder) recorder->add(f);
                        std::vector<const double*> errs;
                        for (auto& lane : lanes) errs.push_back(lane->out[la].err.data());
                        traces->add(f.size(), f.t_s.data(), f.sin_v.data(), f.cos_v.data(), f.theta_true_rad.data(), f.truth_known.data(), errs);
                        for (std::size_t j = 0; j < lanes.size(); ++j)  // a DUT's words, each at its own latch instant
                            if (const auto& w = lanes[j]->out[la]; lanes[j]->readout)
                                traces->add_points(j, w.wt.size(), w.wframe.data(), w.wt.data(), w.wtruth.data(), w.werr.data());
                        break;
                    }
                    case Kind::Signal: {
                        const Frames& f = slot[ka];
                        signal.add(f.t_s.data(), f.sin_v.data(), f.cos_v.data(), f.size());
                        break;
                    }
                    }
                    *jb.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
                });
            pool.run(tasks, errors);
            // Faults in the order the one-lane-task pipeline met them: the source's, then an
            // estimator's (the lanes whose estimator finished that block still analyse it), then
            // an analyser's or the traces'.
            std::exception_ptr source_error, ahead_error, estimator_error, analysis_error;
            std::vector<bool> estimated(lanes.size(), true);
            for (std::size_t t = 0; t < jobs.size(); ++t) {
                if (!errors[t]) continue;
                switch (jobs[t].kind) {
                case Kind::Source: source_error = errors[t]; break;
                case Kind::Ahead: ahead_error = errors[t]; break;
                case Kind::Estimate:
                    estimated[jobs[t].lane] = false;
                    if (!estimator_error) estimator_error = errors[t];
                    break;
                default:
                    if (!analysis_error) analysis_error = errors[t];
                }
            }
            if (!source_error) source_error = ahead_error;  // the source could not generate ahead
            if (analyse_step) have[ka] = 0;
            if (produce) {
                if (source_error) {
                    source_failure = source_error;  // like a fault: what came before is still processed
                    have[ks] = 0;
                    source_done = true;
                } else {
                    have[ks] = slot[ks].size();
                    produced += have[ks];
                    if (!st.ok) { status = RunStatus::Error; error = st.error; source_done = true; }
                    if (st.end) source_done = true;
                }
            }
            if (estimator_error) {
                // An estimator failed: the run ends here, once the others' analysers took this block.
                for (std::size_t j = 0; j < lanes.size() && !analysis_error; ++j)
                    if (estimated[j])
                        for (std::size_t a = 0; a < lanes[j]->analysers.size(); ++a) lanes[j]->analyse(a, le);
                std::rethrow_exception(estimator_error);
            }
            if (estimate_step) {
                laned += have[ke];
                processed = laned;
                if (o.progress) o.progress(processed, total);
            }
            if (analysis_error) std::rethrow_exception(analysis_error);
        }
        if (source_failure) std::rethrow_exception(source_failure);
        for (const auto& lane : lanes) lane->fail_pending();
        source->stop();
        if (dut_device) dut_device->readout()->stop();
        if (dinfo.dut_position)
            if (dev::ReplayPort* replay = device->replay()) dut_readout = replay->dut_readout();  // what an ABZ readout counted
        if (status == RunStatus::Done)
            for (auto& lane : lanes)
                if (lane->e) lane->e->finish();
        if (recorder) recorder->close();
    } catch (const std::exception& e) {  // device, estimator and capture faults, and anything unforeseen
        // A device that gave up because the run was cancelled: the run was aborted, not faulty.
        const bool cancelled = o.cancel && o.cancel->load();
        status = cancelled ? RunStatus::Aborted : RunStatus::Error;
        error = cancelled ? std::string("cancelled (") + e.what() + ")" : std::string(e.what());
    } catch (...) {
        status = RunStatus::Error;
        error = "the run failed with an unknown exception";
    }

    if (o.estimator_s && !lanes.empty()) *o.estimator_s = lanes[0]->estimator_s;
    try {
        report.estimators = score_lanes(sc, dinfo, lanes, dut_readout, warnings);
    } catch (const std::exception& e) {
        report.estimators.clear();
        if (status == RunStatus::Done) status = RunStatus::Error;
        if (error.empty()) error = std::string("scoring failed: ") + e.what();
    }
    Verdict verdict;
    report.alignment = alignment;
    report.signal = signal.to_json();
    for (auto& f : amplitude_findings(sc, report.signal)) warnings.push_back(std::move(f));
    report.measurements = evaluate_limits(sc, estimators_json(report.estimators), status, verdict,
                                          json{{"alignment", report.alignment}, {"signal", report.signal}}, has_truth);
    report.status = status;
    report.verdict = verdict;
    report.error = error;
    report.warnings = std::move(warnings);
    report.samples_planned = total;
    report.samples_processed = processed;
    if (traces) report.traces = traces->to_json();
    report.finished_at = iso_now();
    report.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
    return report;
}

int exit_code(const json& report) {
    if (!report.contains("verdict") || !report["verdict"].is_string()) return 2;  // no verdict (a capture without truth)
    const std::string v = report["verdict"].get<std::string>();
    if (v == "PASS" || v == "MARGINAL") return 0;
    if (v == "FAIL") return 1;
    return 2;
}

}  // namespace fringe
