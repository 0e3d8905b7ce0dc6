// A run's status and verdict as types, with their one spelling in reports, the store and the
// API ("done", "PASS", ...).
#pragma once

#include <optional>
#include <string>

namespace fringe {

enum class RunStatus { Queued, Running, Done, Error, Aborted, Interrupted };
enum class Verdict { Pass, Marginal, Fail, Error, Aborted };

inline const char* to_string(RunStatus s) {
    switch (s) {
        case RunStatus::Queued: return "queued";
        case RunStatus::Running: return "running";
        case RunStatus::Done: return "done";
        case RunStatus::Error: return "error";
        case RunStatus::Aborted: return "aborted";
        case RunStatus::Interrupted: return "interrupted";
    }
    return "error";
}

inline const char* to_string(Verdict v) {
    switch (v) {
        case Verdict::Pass: return "PASS";
        case Verdict::Marginal: return "MARGINAL";
        case Verdict::Fail: return "FAIL";
        case Verdict::Error: return "ERROR";
        case Verdict::Aborted: return "ABORTED";
    }
    return "ERROR";
}

inline std::optional<RunStatus> run_status_from(const std::string& s) {
    for (auto v : {RunStatus::Queued, RunStatus::Running, RunStatus::Done, RunStatus::Error, RunStatus::Aborted, RunStatus::Interrupted})
        if (s == to_string(v)) return v;
    return std::nullopt;
}

// Case-insensitive ("fail" and "FAIL" are the same verdict).
inline std::optional<Verdict> verdict_from(std::string s) {
    for (auto& c : s) c = static_cast<char>(c >= 'a' && c <= 'z' ? c - 32 : c);
    for (auto v : {Verdict::Pass, Verdict::Marginal, Verdict::Fail, Verdict::Error, Verdict::Aborted})
        if (s == to_string(v)) return v;
    return std::nullopt;
}

// The worse of two verdicts for an outcome list: FAIL beats MARGINAL beats PASS.
inline Verdict worse(Verdict a, Verdict b) { return static_cast<int>(a) >= static_cast<int>(b) ? a : b; }

}  // namespace fringe
