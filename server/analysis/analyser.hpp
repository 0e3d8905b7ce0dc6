// Analysers: everything fringe computes from one lane (an estimator under test, or a DUT's own
// position) besides the estimates themselves. Each takes the lane's blocks in order and finishes
// into typed results; they are registered by name, like estimators and devices, and every lane
// of every run (and of every capture evaluation) runs all of them. A new analyser is one
// class and one register_analyser() call (docs/architecture.md "A new analyser").
//
// Contract: add() sees whole blocks (no per-sample virtual call) and must not keep the pointers;
// finish() is called once, after the last block, in registration order, so an analyser may read
// the results of those registered before it (the spectrum reads the truth scorer's rate).
// The run engine calls the analysers of one lane on one block as separate tasks, possibly side
// by side on different threads: an analyser's add() touches only its own state.
#pragma once

#include "server/analysis/scoring.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace fringe {

// One block of one lane: the frames as delivered, the truth and the lane's output. Pointers are
// valid for the call only.
struct LaneBlock {
    std::size_t n = 0;
    const double* t_s = nullptr;
    const double* sin_v = nullptr;
    const double* cos_v = nullptr;
    const double* theta_true_rad = nullptr;    // unwrapped electrical phase; meaningful where truth_known
    const double* omega_true_rad_s = nullptr;  // NaN where the rate is unknown
    const std::uint8_t* truth_known = nullptr;
    const double* theta_hat_rad = nullptr;     // the lane's estimate (unwrapped, rad)
    const double* omega_hat_rad_s = nullptr;   // null when the lane has no rate (a DUT's position)
    const std::uint8_t* valid = nullptr;       // the lane vouches for the sample and truth is known
    const std::uint8_t* estimator_valid = nullptr;  // the lane vouches for the sample, truth or not (null: as valid)
};

// What every analyser of a lane is told when it is made.
struct LaneContext {
    double sample_rate_hz = 0;
    double settle_s = 0;         // samples before t0 + settle_s are not scored
    int max_harmonic = 16;       // error harmonics fitted, 1x..max
    std::size_t spectrum_segment = 4096;  // Welch segment (samples), ErrorSpectrum::choose_segment
    bool self_reference = false;  // measure the error without truth too (self_reference.hpp; scoring.self_reference)
};

// Typed results of one lane. Built-in analysers fill their member; others put their JSON under
// `extra[name]` (the report's estimators[].analysers.<name>).
struct LaneResults {
    std::optional<ErrorMetrics> error;                    // "truth": against theta_true
    std::vector<ConventionCheck::Finding> conventions;    // "conventions": output conventions broken
    nlohmann::json spectrum;                              // "spectrum": ErrorSpectrum::to_json
    nlohmann::json extra = nlohmann::json::object();
};

class Analyser {
public:
    virtual ~Analyser() = default;
    virtual void add(const LaneBlock& b) = 0;
    virtual void finish(LaneResults& r) = 0;
};

struct AnalyserInfo {
    std::string name;      // key in results and docs
    std::string summary;   // one line, for `GET /schema` and the docs
    std::function<std::unique_ptr<Analyser>(const LaneContext&)> make;
};

// Every registered analyser, built-in ones first ("truth", "conventions", "spectrum").
std::vector<AnalyserInfo> analyser_registry();
// Registers one more (a name already registered is refused with std::invalid_argument).
void register_analyser(AnalyserInfo info);
void unregister_analyser(const std::string& name);

// Registration for the lifetime of an object: a test's or a plug-in's analyser.
class ScopedAnalyser {
public:
    explicit ScopedAnalyser(AnalyserInfo info) : name_(info.name) { register_analyser(std::move(info)); }
    ~ScopedAnalyser() { unregister_analyser(name_); }
    ScopedAnalyser(const ScopedAnalyser&) = delete;
    ScopedAnalyser& operator=(const ScopedAnalyser&) = delete;

private:
    std::string name_;
};

// The analysers of one lane, made from the registry, fed in order.
class AnalyserSet {
public:
    explicit AnalyserSet(const LaneContext& ctx);
    void add(const LaneBlock& b) {
        for (auto& a : analysers_) a->add(b);
    }
    // The analysers one at a time (the run engine makes each a task of its own).
    std::size_t size() const { return analysers_.size(); }
    void add(std::size_t i, const LaneBlock& b) { analysers_[i]->add(b); }
    LaneResults finish();

private:
    std::vector<std::pair<std::string, std::unique_ptr<Analyser>>> named_;
    std::vector<Analyser*> analysers_;
};

}  // namespace fringe
