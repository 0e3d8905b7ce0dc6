// fringe metrics: the metric table (every figure a report carries; what a limit may name).
#include "server/cli/commands.hpp"
#include "server/analysis/metrics.hpp"

#include <cstdio>

namespace fringe::cli {

namespace {

struct MetricsOptions {
    bool as_json = false, markdown = false;
};

int run_metrics(const MetricsOptions& o) {
    if (o.as_json) {
        std::printf("%s\n", metric_table_json().dump(2).c_str());
        return kExitOk;
    }
    if (o.markdown) {
        std::printf("%s", metric_table_markdown().c_str());
        return kExitOk;
    }
    for (const auto& m : metric_catalog()) {
        std::printf("%-26s %-12s %s%s\n", m.name.c_str(), m.unit.empty() ? "1" : m.unit.c_str(), m.description.c_str(),
                    m.limitable ? "" : " (no limit)");
        std::printf("%-26s %-12s lanes: %s; 95 %% interval: %s\n", "", "", m.lanes.c_str(), m.uncertainty.c_str());
    }
    std::printf("harmonic_Nx_rad is accepted for any order N from 1 to 64 (fitted up to scoring.max_harmonic).\n");
    return kExitOk;
}

}  // namespace

Command add_metrics(CLI::App& app) {
    auto o = std::make_shared<MetricsOptions>();
    auto* c = app.add_subcommand("metrics", "The metrics a report carries and a limit may name: unit, meaning, lanes, 95 % interval");
    auto* js = c->add_flag("--json", o->as_json, "As JSON (the same as GET /api/v1/schema \"metrics\")");
    c->add_flag("--markdown", o->markdown, "As the markdown table of docs/schema.md")->excludes(js);
    return {c, [o] { return run_metrics(*o); }};
}

}  // namespace fringe::cli
