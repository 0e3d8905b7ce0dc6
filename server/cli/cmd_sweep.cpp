// fringe sweep: a scenario over rows or a grid of parameter values, in parallel, as a table.
// With a store (--store / --data) each row is a stored run with a deterministic id, so rows
// can be sharded over a batch scheduler (--shard I/N) and merged from the store (--collect).
#include "server/cli/commands.hpp"
#include "signal_gen/config.hpp"
#include "server/forward.hpp"
#include "server/instance_lock.hpp"
#include "server/provenance.hpp"
#include "server/report_formats.hpp"
#include "server/run.hpp"
#include "server/scenario.hpp"
#include "server/store.hpp"
#include "server/sweep.hpp"
#include "server/text.hpp"

#include <cstdio>
#include <filesystem>
#include <mutex>
#include <spdlog/spdlog.h>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct SweepOptions {
    std::string sweep, csv, md, store, data, shard, bench, operator_name;
    std::size_t shard_count = 0;
    int jobs = 0;
    double forward_wait_s = 60;
    bool quiet = false, collect = false, only_missing = false;
};

void write_tables(const SweepOptions& o, const Sweep& s, const std::vector<SweepResult>& res, const char* what, double secs) {
    if (!o.csv.empty()) write_file_atomic(o.csv, sweep_csv(s, res));
    const std::string md = sweep_markdown(s, res);
    if (!o.md.empty()) write_file_atomic(o.md, md);
    if (!o.quiet) std::printf("%s\n%zu %s in %.1f s\n", md.c_str(), res.size(), what, secs);
}

int table_exit(const std::vector<SweepResult>& res) {
    for (const auto& r : res)
        if (r.status != "done") {
            spdlog::error("{}: {}", r.row.label, r.error);
            return kExitError;
        }
    return kExitOk;
}

// A row counts as stored when its run has an outcome (finished, or running in a live process).
bool stored(const RunStore& st, const std::string& id) {
    const auto row = st.row(id);
    return row && row->status != "interrupted" && !row->dead;
}

// Runs the given rows through the store (each with its deterministic id and provenance) and
// forwards them; returns the results in `rows` order and whether forwarding finished.
std::vector<SweepResult> run_rows_stored(const SweepOptions& o, const Sweep& s, RunStore& store, const std::vector<std::size_t>& rows,
                                         bool& forward_ok) {
    ProvenanceDefaults pd = provenance_defaults();
    if (!o.bench.empty()) pd.bench = o.bench;
    if (!o.operator_name.empty()) pd.operator_name = o.operator_name;
    auto* fwd = dynamic_cast<ForwardingStore*>(&store);
    if (fwd) fwd->start();  // forwards as rows finish (and what an earlier process left pending)
    std::mutex store_mu;
    Progress progress("sweep", "runs", o.quiet);
    const auto res = run_sweep(s, o.jobs > 0 ? o.jobs : s.jobs, [&](std::size_t done, std::size_t total) { progress.update(done, total); }, &rows,
                               [&](std::size_t k, const Scenario& sc) {
                                   RunOptions ro;
                                   ro.run_id = sweep_run_id(s, k);
                                   ro.provenance = make_provenance(pd, sc);
                                   ro.cancel = &cancel_flag();
                                   {
                                       std::lock_guard<std::mutex> l(store_mu);
                                       store.begin(ro.run_id, iso_now(), sc.name, sc.dut, "running", ro.provenance);
                                   }
                                   json rep = execute_run(sc, ro);
                                   std::lock_guard<std::mutex> l(store_mu);
                                   // Ctrl-C: the row is not done; left without a report, a rerun takes it over.
                                   if (rep.value("status", "") == "aborted" && cancel_flag().load()) store.mark_interrupted(ro.run_id);
                                   else store.finish(rep);  // a failure here makes the row an error: never a silent gap
                                   return rep;
                               });
    progress.clear();
    forward_ok = true;
    if (fwd) {
        fwd->stop();
        const auto p = fwd->forward_until(o.forward_wait_s);
        if (p.pending) {
            spdlog::error("forwarding pending: {} run(s) are stored in {} but not yet in the shared store ({}); rerun this shard (stored rows are "
                          "not run again) or any fringe command with the same --data and --store to forward them",
                          p.pending, fwd->describe(), p.error);
            forward_ok = false;
        }
        if (p.conflicts) spdlog::warn("{} run(s) had a different report under the same id in the shared store (flagged in run_conflicts)", p.conflicts);
    }
    return res;
}

int run_sweep_cli(SweepOptions o) {
    const Sweep s = load_sweep(o.sweep);
    const auto t0 = std::chrono::steady_clock::now();
    // --shard, --collect and --only-missing keep the rows in a store: without --store or --data,
    // the default one (DATA/runs.db, $FRINGE_DATA or ~/.local/share/fringe) as docs/scale.md says.
    // Inside a Slurm array or an Indexed Job the shard comes from the environment: a store too.
    const bool with_store = !o.store.empty() || !o.data.empty() || o.collect || !o.shard.empty() || o.only_missing ||
                            shard_from_env(o.shard_count).has_value();
    if (!with_store) {
        Progress progress("sweep", "runs", o.quiet);
        const auto res = run_sweep(s, o.jobs > 0 ? o.jobs : s.jobs, [&](std::size_t done, std::size_t total) { progress.update(done, total); });
        progress.clear();
        write_tables(o, s, res, "runs", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        return table_exit(res);
    }
    if (o.only_missing && !o.collect) throw ConfigError("only-missing", "--only-missing goes with --collect");
    if (o.collect && !o.shard.empty()) throw ConfigError("shard", "--collect reads every row; it takes no --shard");
    install_cancel_handlers();
    const StoreUri su = parse_store_uri(o.store, o.data.empty() ? default_data_dir() : o.data);
    const std::string dir = std::filesystem::path(su.sqlite_path).parent_path().string();

    if (o.collect) {
        std::vector<std::size_t> missing;
        std::vector<std::optional<json>> reports(s.rows.size());
        {
            const auto reader = open_store_reader(su);
            for (std::size_t k = 0; k < s.rows.size(); ++k)
                if (!(reports[k] = reader->report(sweep_run_id(s, k)))) missing.push_back(k);
        }
        if (!missing.empty() && o.only_missing) {
            InstanceLock instance;
            instance.acquire_instance(dir.empty() ? "." : dir, "sweep-" + new_instance_id());
            const auto store = open_store(su, instance.id());
            if (!o.quiet) std::fprintf(stderr, "running the %zu missing row(s)\n", missing.size());
            bool forward_ok = true;
            run_rows_stored(o, s, *store, missing, forward_ok);
            for (const std::size_t k : missing) reports[k] = store->report(sweep_run_id(s, k));
            missing.clear();
            for (std::size_t k = 0; k < s.rows.size(); ++k)
                if (!reports[k]) missing.push_back(k);
            if (!forward_ok) return kExitError;
        }
        std::vector<SweepResult> res;
        for (std::size_t k = 0; k < s.rows.size(); ++k) {
            if (reports[k]) {
                res.push_back(sweep_result(s, s.rows[k], *reports[k]));
            } else {
                SweepResult r;
                r.row = s.rows[k];
                r.status = "missing";
                r.verdict = "MISSING";
                r.error = "not in the store (run " + sweep_run_id(s, k) + ")";
                r.values.assign(s.columns.size(), std::nullopt);
                res.push_back(std::move(r));
            }
        }
        write_tables(o, s, res, "rows collected", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        if (!missing.empty()) {
            std::string names;
            for (const std::size_t k : missing) names += "\n  row " + std::to_string(k) + " (" + s.rows[k].label + "): " + sweep_run_id(s, k);
            spdlog::error("{} of {} rows are missing from {} (--only-missing runs them):{}", missing.size(), s.rows.size(), redact_store_uri(o.store.empty() ? su.sqlite_path : o.store), names);
            return kExitError;
        }
        return table_exit(res);
    }

    // A shard (or, without one, every row) into the store; rows already stored are skipped.
    Shard shard;
    if (!o.shard.empty()) shard = parse_shard(o.shard);
    else if (auto env = shard_from_env(o.shard_count)) shard = *env;
    InstanceLock instance;
    instance.acquire_instance(dir.empty() ? "." : dir, "sweep-" + new_instance_id());
    const auto store = open_store(su, instance.id());
    std::vector<std::size_t> rows;
    std::size_t mine = 0;
    for (std::size_t k = shard.index; k < s.rows.size(); k += shard.count) {
        ++mine;
        if (!stored(*store, sweep_run_id(s, k))) rows.push_back(k);
    }
    if (!o.quiet)
        std::fprintf(stderr, "sweep %s shard %zu/%zu: %zu row(s), %zu already stored, running %zu\n", sweep_digest(s).substr(0, 16).c_str(), shard.index,
                     shard.count, mine, mine - rows.size(), rows.size());
    bool forward_ok = true;
    const auto res = rows.empty() ? std::vector<SweepResult>{} : run_rows_stored(o, s, *store, rows, forward_ok);
    if (!rows.empty()) write_tables(o, s, res, "runs", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    if (cancel_flag().load()) return kExitError;
    if (!forward_ok) return kExitError;
    return table_exit(res);
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
    sw->add_option("--store", o->store, "Keep each row as a run in this store (sqlite:PATH or postgresql://...; a PostgreSQL store is fed through DATA/runs.db)");
    sw->add_option("--data", o->data, "Data directory (the local store, or the spool for a PostgreSQL --store; default $FRINGE_DATA or ~/.local/share/fringe)");
    sw->add_option("--shard", o->shard, "Run rows k with k mod N == I (I/N); default from SLURM_ARRAY_TASK_ID/COUNT or JOB_COMPLETION_INDEX; needs a store");
    sw->add_option("--shard-count", o->shard_count, "Shards in all when the index comes from JOB_COMPLETION_INDEX (a Kubernetes Indexed Job's completions)")
        ->check(CLI::PositiveNumber);
    sw->add_flag("--collect", o->collect, "Build the table from the store's runs (every row); names rows still missing (exit 2)");
    sw->add_flag("--only-missing", o->only_missing, "With --collect: run the missing rows first");
    sw->add_option("--forward-wait", o->forward_wait_s, "With a PostgreSQL --store: seconds to keep retrying the forward at the end")
        ->check(kFiniteNonNegative)->capture_default_str();
    sw->add_option("--bench", o->bench, "Bench name in each run's provenance (default $FRINGE_BENCH, else the host name)");
    sw->add_option("--operator", o->operator_name, "Operator in each run's provenance (default $USER)");
    return {sw, [o] { return run_sweep_cli(*o); }};
}

}  // namespace fringe::cli
