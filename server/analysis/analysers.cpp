// The built-in analysers (truth scorer, output conventions, error spectrum) and the registry.
#include "server/analysis/analyser.hpp"

#include "server/analysis/self_reference.hpp"
#include "server/analysis/spectrum.hpp"
#include "signal_gen/fastmath.hpp"

#include <algorithm>
#include <mutex>
#include <stdexcept>

namespace fringe {

namespace {

// "truth": the error against theta_true (scoring.hpp).
class TruthScorer final : public Analyser {
public:
    explicit TruthScorer(const LaneContext& c) : scorer_(ScoringOptions{c.settle_s, 0.1, c.max_harmonic}) {}
    void add(const LaneBlock& b) override {
        scorer_.add(b.n, b.t_s, b.theta_true_rad, b.omega_true_rad_s, b.theta_hat_rad, b.omega_hat_rad_s, b.valid);
    }
    void finish(LaneResults& r) override { r.error = scorer_.finish(); }

private:
    Scorer scorer_;
};

// "conventions": an output in degrees or wrapped (ConventionCheck).
class Conventions final : public Analyser {
public:
    void add(const LaneBlock& b) override { check_.add(b.n, b.theta_true_rad, b.theta_hat_rad, b.valid); }
    void finish(LaneResults& r) override { r.conventions = check_.findings(); }

private:
    ConventionCheck check_;
};

// "self_reference": the error without truth (self_reference.hpp), on the samples the lane
// vouched for whether or not truth is known; only when the run asks for it (a capture without
// truth does), as it costs a least-squares fit of every sample.
class SelfReferenced final : public Analyser {
public:
    explicit SelfReferenced(const LaneContext& c) : on_(c.self_reference), sr_([&] {
        SelfReferenceOptions o;  // the defaults, from the lane's settle time
        o.settle_s = c.settle_s;
        return o;
    }()) {}
    void add(const LaneBlock& b) override {
        if (on_) sr_.add(b.n, b.t_s, b.sin_v, b.cos_v, b.theta_hat_rad, b.estimator_valid ? b.estimator_valid : b.valid);
    }
    void finish(LaneResults& r) override {
        if (on_) r.extra["self_reference"] = to_json(sr_.finish());
    }

private:
    bool on_;
    SelfReference sr_;
};

// "spectrum": the error's spectrum at the full rate after the settle time (spectrum.hpp). Each
// Welch segment removes its own mean, so the whole 2*pi multiple the scorer removes does not
// matter here; invalid samples end a segment.
class Spectrum final : public Analyser {
public:
    explicit Spectrum(const LaneContext& c) : settle_s_(c.settle_s), spectrum_(c.sample_rate_hz, c.spectrum_segment) {}
    void add(const LaneBlock& b) override {
        if (!b.n) return;
        if (!have_t0_) { t0_ = b.t_s[0]; have_t0_ = true; }
        // After the settle time, in order (the same samples the truth scorer scores); once
        // settled, the whole block without a copy of the flags.
        e_.resize(b.n);
        const double* t = b.t_s;
        const double t0 = t0_, settle = settle_s_;
        std::size_t before = 0;
        for (std::size_t i = 0; i < b.n; ++i) before += t[i] - t0 < settle;
        if (!before) {
            double* e = e_.data();
            for (std::size_t i = 0; i < b.n; ++i) e[i] = b.theta_hat_rad[i] - b.theta_true_rad[i];
            spectrum_.add(b.n, e, b.valid);
            return;
        }
        ok_.resize(b.n);
        std::size_t m = 0;
        for (std::size_t i = 0; i < b.n; ++i) {
            if (t[i] - t0 < settle) continue;
            e_[m] = b.theta_hat_rad[i] - b.theta_true_rad[i];
            ok_[m] = b.valid[i];
            ++m;
        }
        spectrum_.add(m, e_.data(), ok_.data());
    }
    void finish(LaneResults& r) override {
        const double electrical_hz = r.error ? r.error->mean_abs_omega_true_rad_s / kTwoPi : 0.0;
        r.spectrum = spectrum_.to_json(electrical_hz);
    }

private:
    double settle_s_;
    double t0_ = 0;
    bool have_t0_ = false;
    ErrorSpectrum spectrum_;
    std::vector<double> e_;
    std::vector<std::uint8_t> ok_;
};

std::mutex& registry_mutex() {
    static std::mutex m;
    return m;
}

std::vector<AnalyserInfo>& registry() {
    static std::vector<AnalyserInfo> r{
        {"truth", "the error against theta_true: moments, slips, harmonics 1x..Kx, broadband rest, rate error, lag, lock time, "
                  "evidence and the 95 % intervals",
         [](const LaneContext& c) { return std::make_unique<TruthScorer>(c); }},
        {"conventions", "signs that theta is not unwrapped radians (wrapped, degrees, degrees wrapped)",
         [](const LaneContext&) { return std::make_unique<Conventions>(); }},
        {"spectrum", "the error's amplitude spectrum at the full rate (Welch, Hann, 50 % overlap)",
         [](const LaneContext& c) { return std::make_unique<Spectrum>(c); }},
        {"self_reference", "the error without truth: a smooth motion per window and the error's harmonics of the estimated angle, "
                           "fitted jointly (only when scoring.self_reference is on, as for a capture without truth)",
         [](const LaneContext& c) { return std::make_unique<SelfReferenced>(c); }},
    };
    return r;
}

}  // namespace

std::vector<AnalyserInfo> analyser_registry() {
    std::lock_guard lock(registry_mutex());
    return registry();
}

void register_analyser(AnalyserInfo info) {
    std::lock_guard lock(registry_mutex());
    auto& r = registry();
    if (info.name.empty() || !info.make) throw std::invalid_argument("an analyser needs a name and a factory");
    for (const auto& a : r)
        if (a.name == info.name) throw std::invalid_argument("an analyser named '" + info.name + "' is already registered");
    r.push_back(std::move(info));
}

void unregister_analyser(const std::string& name) {
    std::lock_guard lock(registry_mutex());
    auto& r = registry();
    r.erase(std::remove_if(r.begin(), r.end(), [&](const AnalyserInfo& a) { return a.name == name; }), r.end());
}

AnalyserSet::AnalyserSet(const LaneContext& ctx) {
    for (const auto& info : analyser_registry()) {
        named_.emplace_back(info.name, info.make(ctx));
        analysers_.push_back(named_.back().second.get());
    }
}

LaneResults AnalyserSet::finish() {
    LaneResults r;
    for (auto& [name, a] : named_) a->finish(r);
    return r;
}

}  // namespace fringe
