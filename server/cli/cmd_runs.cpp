// fringe runs: the run history, filtered, or one run's summary.
#include "server/cli/commands.hpp"
#include "signal_gen/base/config.hpp"
#include "server/store/forward.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/http/service.hpp"
#include "server/store/store.hpp"
#include "signal_gen/base/text.hpp"
#include "server/analysis/verdict.hpp"

#include <array>
#include <cstdio>
#include <ctime>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct RunsOptions {
    std::string data, store, verdict, scenario, since, show, bench, dut;
    int limit = 20;
    bool as_json = false, metrics = false;
};

int run_runs(const RunsOptions& o) {
    // A PostgreSQL --store is read directly: every bench's forwarded runs.
    const auto store_ptr = open_store_reader(parse_store_uri(o.store, o.data.empty() ? default_data_dir() : o.data));
    RunStore& store = *store_ptr;
    if (!o.show.empty()) {
        auto r = store.report(o.show);
        if (!r) {
            if (store.row(o.show)) throw ConfigError("id", "run '" + o.show + "' has no report yet (it is queued or running, or ended without one)");
            throw ConfigError("id", "no run '" + o.show + "' in this history (fringe runs lists them)");
        }
        // ensure_ascii: every non-ASCII character as \uXXXX, so no C1 control or bidi override
        // reaches the terminal raw (JSON already escapes ESC and the other C0 controls).
        if (o.as_json) std::printf("%s\n", r->dump(2, ' ', true, json::error_handler_t::replace).c_str());
        else print_run_summary(*r, (*r)["scenario"].is_object() ? (*r)["scenario"].value("name", std::string("run")) : std::string("run"), o.metrics);
        return kExitOk;
    }
    RunFilter f;
    f.verdict = o.verdict;
    f.scenario = o.scenario;
    f.bench = o.bench;
    f.dut = o.dut;
    f.limit = o.limit;
    if (!o.verdict.empty()) {
        const auto v = verdict_from(o.verdict);
        if (!v) throw ConfigError("verdict", "expected PASS, MARGINAL, FAIL, ERROR or ABORTED (any case); got '" + o.verdict + "'");
        f.verdict = to_string(*v);
    }
    if (!o.since.empty()) f.since = parse_since(o.since);
    const auto rows = store.list(f);
    if (o.as_json) {
        json a = json::array();
        for (const auto& r : rows)
            a.push_back({{"id", r.id}, {"created_at", r.created_at}, {"scenario", r.scenario}, {"dut", r.dut}, {"status", r.status}, {"verdict", r.verdict},
                         {"bench", r.bench}, {"host", r.host}, {"dut_part", r.dut_part}, {"operator", r.operator_name}, {"forward", r.forward}, {"forward_store", r.forward_store}});
        std::printf("%s\n", a.dump(2, ' ', true, json::error_handler_t::replace).c_str());
        return kExitOk;
    }
    // Columns as wide as their widest cell; names, DUTs (an instrument's *IDN?) and benches come
    // from clients and devices: escaped for the terminal (a NUL no longer cuts the row).
    constexpr std::size_t kCols = 7;
    std::vector<std::array<std::string, kCols>> cells{{"id", "started", "bench", "scenario", "dut", "status", "verdict"}};
    for (const auto& r : rows)
        cells.push_back({term_escape(r.id), term_escape(r.created_at), term_escape(r.bench), term_escape(r.scenario), term_escape(r.dut), term_escape(r.status),
                         term_escape(r.verdict)});
    std::array<std::size_t, kCols> w{};
    for (const auto& c : cells)
        for (std::size_t k = 0; k < kCols; ++k) w[k] = std::max(w[k], c[k].size());
    for (const auto& c : cells) {
        std::string line;
        for (std::size_t k = 0; k < kCols; ++k) line += c[k] + (k + 1 < kCols ? std::string(w[k] - c[k].size() + 2, ' ') : "");
        std::printf("%s\n", line.c_str());
    }
    if (rows.empty()) std::fprintf(stderr, "no runs match\n");
    return kExitOk;
}

}  // namespace

Command add_runs(CLI::App& app) {
    auto o = std::make_shared<RunsOptions>();
    auto* rs = app.add_subcommand("runs", "List the run history (newest first), or print one run's report");
    rs->add_option("--data", o->data, "Data directory (default $FRINGE_DATA or ~/.local/share/fringe)");
    rs->add_option("--store", o->store, "Run store: sqlite:PATH or postgresql://... (read directly: every bench's runs); default DATA/runs.db");
    rs->add_option("--bench", o->bench, "Only runs of this bench");
    rs->add_option("--dut", o->dut, "Only runs of this DUT serial");
    rs->add_option("--verdict", o->verdict, "Only runs with this verdict (PASS, MARGINAL, FAIL, ERROR, ABORTED; any case)");
    rs->add_option("--scenario", o->scenario, "Only runs of this scenario name");
    rs->add_option("--since", o->since, "Only runs started at or after this UTC date or time (2026-11-21, 2026-11-21T15:00:00Z), today, yesterday or Nd");
    rs->add_option("--limit", o->limit, "At most this many")->check(CLI::PositiveNumber);
    auto* show = rs->add_option("--show", o->show, "Print the summary of this run (its whole report with --json)");
    rs->add_flag("--json", o->as_json, "As JSON");
    rs->add_flag("--metrics", o->metrics, "With --show: also every metric of every estimator")->needs(show);
    return {rs, [o] { return run_runs(*o); }};
}

}  // namespace fringe::cli
