// What the fringe commands share: exit codes, the progress line, Ctrl-C, the run summary.
// Each command lives in its own file (cmd_*.cpp) and registers itself with add_* (commands.hpp).
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace fringe::cli {

constexpr int kExitOk = 0;     // success, PASS or MARGINAL
constexpr int kExitFail = 1;   // a FAIL verdict
constexpr int kExitError = 2;  // bad input, a device or run error

// The scenario schema's range (docs/schema.md): seeds are stored as JSON numbers.
inline const CLI::Range kSeedRange(std::int64_t{0}, std::int64_t{1} << 53);
// A finite number >= 0 (CLI11's NonNegativeNumber lets "nan" through and answers "inf" with a
// 300-digit range); kFinitePositive: > 0.
CLI::Validator finite_number(bool allow_zero);
inline const CLI::Validator kFiniteNonNegative = finite_number(true);
inline const CLI::Validator kFinitePositive = finite_number(false);

// A command: its CLI11 subcommand and what runs when it was chosen (returns the exit code).
struct Command {
    CLI::App* sub = nullptr;
    std::function<int()> run;
};

// One progress line on stderr when it is a terminal (and not --quiet): "LABEL: 42.0 % (n / N
// UNIT)", or "LABEL: n UNIT" without a total; at most four updates a second; the line is cleared
// by clear() or the destructor, so summaries print on a clean line.
class Progress {
public:
    Progress(std::string label, std::string unit, bool quiet);
    ~Progress() { clear(); }
    Progress(const Progress&) = delete;
    Progress& operator=(const Progress&) = delete;
    bool active() const { return active_; }
    void update(std::uint64_t done, std::uint64_t total = 0);
    void clear();

private:
    std::string label_, unit_;
    bool active_ = false, shown_ = false;
    std::chrono::steady_clock::time_point last_{};
};

// A file named on the command line, with what it is for ("capture", "report", ...).
struct NamedPath {
    std::string role, path;
};
// Throws a ConfigError naming both when an output would overwrite an input or another output:
// the same file (links included) or the same path once made absolute. Empty paths are skipped.
void refuse_overwrite(const std::vector<NamedPath>& outputs, std::vector<NamedPath> inputs);  // a capture's sidecar is an input too

// Ctrl-C and SIGTERM set this flag (install_cancel_handlers); runs end as ABORTED with their report.
std::atomic<bool>& cancel_flag();
void install_cancel_handlers();

// The run's verdict, its warnings, each estimator's errors with their evidence, and each
// measurement with its limit and outcome (fringe run, fringe runs --show).
// The estimator state's loss-of-lock count and message, as one line (empty: nothing to say).
std::string state_notes(const nlohmann::json& state);
// " (95 % lo..hi)" for a [lo, hi] interval, "" for anything else.
std::string interval_text(const nlohmann::json& interval);
// all_metrics: also every metric of the table for every lane (--metrics).
void print_run_summary(const nlohmann::json& report, const std::string& name, bool all_metrics = false);
// The report's signal quality as one summary line (docs/signal-quality.md).
void print_signal_summary(const nlohmann::json& report);
// The signals graded against the scenario's interface profile (its bands in the measurements), with a text gauge each.
void print_signal_bands(const nlohmann::json& report);

}  // namespace fringe::cli
