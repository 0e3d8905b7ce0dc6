// fringe sweep: a scenario over rows or a grid of parameter values, in parallel, as a table.
#include "server/cli/commands.hpp"
#include "server/report_formats.hpp"
#include "server/run.hpp"
#include "server/sweep.hpp"
#include "server/text.hpp"

#include <cstdio>
#include <spdlog/spdlog.h>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct SweepOptions {
    std::string sweep, csv, md;
    int jobs = 0;
    bool quiet = false;
};

int run_sweep_cli(const SweepOptions& o) {
    const Sweep s = load_sweep(o.sweep);
    Progress progress("sweep", "runs", o.quiet);
    const auto t0 = std::chrono::steady_clock::now();
    const auto res = run_sweep(s, o.jobs > 0 ? o.jobs : s.jobs, [&](std::size_t done, std::size_t total) {
        progress.update(done, total);
    });
    progress.clear();
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!o.csv.empty()) write_file_atomic(o.csv, sweep_csv(s, res));
    const std::string md = sweep_markdown(s, res);
    if (!o.md.empty()) write_file_atomic(o.md, md);
    if (!o.quiet) std::printf("%s\n%zu runs in %.1f s\n", md.c_str(), res.size(), secs);
    for (const auto& r : res)
        if (r.status != "done") {
            spdlog::error("{}: {}", r.row.label, r.error);
            return kExitError;
        }
    return kExitOk;
}

}  // namespace

Command add_sweep(CLI::App& app) {
    auto o = std::make_shared<SweepOptions>();
    auto* sw = app.add_subcommand("sweep", "Run a scenario over rows or a grid of parameter values, in parallel; write a table (CSV, Markdown)");
    sw->add_option("sweep", o->sweep, "Sweep JSON file (e.g. fixtures/sweeps/table1.json)")->required()->check(CLI::ExistingFile);
    sw->add_option("-o,--csv", o->csv, "Write the table as CSV here");
    sw->add_option("--md", o->md, "Write the table as Markdown here");
    sw->add_option("--jobs", o->jobs, "Parallel runs (default: the sweep's, else all cores)")->check(CLI::NonNegativeNumber);
    sw->add_flag("-q,--quiet", o->quiet, "No table on stdout or progress");
    return {sw, [o] { return run_sweep_cli(*o); }};
}

}  // namespace fringe::cli
