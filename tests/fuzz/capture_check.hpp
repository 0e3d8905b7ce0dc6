// What the capture targets promise: a capture file of any bytes either reads (every present
// column one value per frame) and evaluates, or fails with a CaptureError / ConfigError /
// EstimatorError whose message is valid UTF-8. Anything else (a crash, another exception)
// is a finding.
#pragma once

#include "fuzz_common.hpp"

#include "drivers/capture_file.hpp"
#include "estimator/estimator.hpp"
#include "server/engine/capture_run.hpp"
#include "signal_gen/base/config.hpp"

#include <nlohmann/json.hpp>

namespace fringe::fuzz {

inline void check_message(const char* kind, const char* what) {
    try {
        (void)nlohmann::json(what).dump();  // throws on invalid UTF-8
    } catch (const nlohmann::json::type_error&) {
        fail(std::string(kind) + " message is not valid UTF-8: " + what);
    }
}

inline void check_capture(const std::string& path) {
    try {
        CaptureReader r(path);
        CaptureData d;
        while (r.read(37, d)) {  // small odd blocks: every chunk boundary is exercised
            const std::size_t n = d.size();
            if (d.sin_v.size() != n || d.cos_v.size() != n) fail("sin/cos not one value per frame");
            for (auto* v : {&d.theta_true_rad, &d.omega_true_rad_s, &d.index_v, &d.a, &d.b, &d.z})
                if (!v->empty() && v->size() != n) fail("an optional column not one value per frame");
            if (r.columns().theta_true != !d.theta_true_rad.empty()) fail("columns().theta_true disagrees with the data");
        }
        CaptureRunOptions o;
        o.capture_path = path;
        o.estimator = "atan2";
        o.block = 53;
        if (CaptureReader(path).columns().abz()) o.abz = AbzConfig{4, 0, 0.0};  // the DUT's ABZ readout too
        const nlohmann::json rep = run_capture(o);  // a fault part way is a report with status "error"
        if (rep["status"] == "error") check_message("a run's error", rep["error"].get<std::string>().c_str());
    } catch (const CaptureError& e) {
        check_message("CaptureError", e.what());
    } catch (const ConfigError& e) {
        check_message("ConfigError", e.what());
    } catch (const est::EstimatorError& e) {
        check_message("EstimatorError", e.what());
    } catch (const std::exception& e) {
        unexpected(e);
    }
}

}  // namespace fringe::fuzz
