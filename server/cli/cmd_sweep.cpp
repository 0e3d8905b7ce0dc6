// fringe sweep: a scenario over rows or a grid of parameter values, in parallel, as a table.
// With a store (--store / --data) each row is a stored run with a deterministic id, so rows
// can be sharded over a batch scheduler (--shard I/N) and merged from the store (--collect).
#include "server/cli/commands.hpp"
#include "signal_gen/base/config.hpp"
#include "server/store/forward.hpp"
#include "server/store/instance_lock.hpp"
#include "server/engine/provenance.hpp"
#include "server/report/report_formats.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/store/store.hpp"
#include "server/engine/sweep.hpp"
#include "signal_gen/base/text.hpp"

#include <cstdio>
#include <filesystem>
#include <mutex>
#include <optional>
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

// With a PostgreSQL --store: forwards what the spool holds for it (within --forward-wait),
// then asks the shared store itself whether each of `ids` is there. True when every one is;
// otherwise says which are not, and why, and returns false (the command exits 2).
bool deliver(const SweepOptions& o, ForwardingStore& fwd, const std::vector<std::string>& ids) {
    const auto p = fwd.forward_until(o.forward_wait_s);
    for (const auto& id : p.conflict_ids)
        spdlog::warn("run {}: the shared store holds a different report under this id (flagged in run_conflicts; neither overwritten)", id);
    const auto have = fwd.shared_has(ids);
    std::vector<std::string> absent;
    for (const auto& id : ids)
        if (!have || !have->count(id)) absent.push_back(id);
    if (absent.empty()) return true;
    std::string names;
    for (std::size_t i = 0; i < absent.size() && i < 10; ++i) names += "\n  " + absent[i];
    if (absent.size() > 10) names += "\n  ...";
    if (!have)
        spdlog::error("forwarding pending: the shared store {} could not be asked whether this shard's {} run(s) are there ({}); they are kept in {}: "
                      "rerun this shard (stored rows are not run again, kept ones are forwarded) or any fringe command with the same --data and --store",
                      redact_store_uri(fwd.shared_uri()), ids.size(), p.error.empty() ? "unreachable" : p.error, fwd.local().path());
    else
        spdlog::error("forwarding pending: {} of this shard's {} run(s) are not in the shared store {} ({}); the ones this folder holds are kept in {}: "
                      "rerun this shard (stored rows are not run again, kept ones are forwarded) or any fringe command with the same --data and --store:{}",
                      absent.size(), ids.size(), redact_store_uri(fwd.shared_uri()),
                      !p.error.empty() ? p.error : p.quarantined ? "quarantined in the spool: see the messages above" : "still running elsewhere, or failed",
                      fwd.local().path(), names);
    return false;
}

// Runs the given rows through the store (each with its deterministic id and provenance);
// returns the results in `rows` order. Forwarding is deliver()'s.
std::vector<SweepResult> run_rows_stored(const SweepOptions& o, const Sweep& s, RunStore& store, const std::vector<std::size_t>& rows) {
    ProvenanceDefaults pd = provenance_defaults();
    if (!o.bench.empty()) pd.bench = o.bench;
    if (!o.operator_name.empty()) pd.operator_name = o.operator_name;
    auto* fwd = dynamic_cast<ForwardingStore*>(&store);
    if (fwd) fwd->start();  // forwards as rows finish (and what an earlier process left pending)
    std::mutex store_mu;
    Progress progress("sweep", "runs", o.quiet);
    const auto res = run_sweep(s, o.jobs > 0 ? o.jobs : s.jobs, [&](std::size_t done, std::size_t total) { progress.update(done, total); }, &rows,
                               [&](std::size_t k, RunPlan plan) {
                                   const Scenario& sc = plan.scenario;
                                   RunOptions ro;
                                   ro.run_id = sweep_run_id(s, k);
                                   ro.provenance = make_provenance(pd, sc);
                                   ro.cancel = &cancel_flag();
                                   {
                                       std::lock_guard<std::mutex> l(store_mu);
                                       store.begin(ro.run_id, iso_now(), sc.name, sc.dut, "running", ro.provenance);
                                   }
                                   json rep = execute_run(std::move(plan), ro);
                                   std::lock_guard<std::mutex> l(store_mu);
                                   // Ctrl-C: the row is not done; left without a report, a rerun takes it over.
                                   if (rep.value("status", "") == "aborted" && cancel_flag().load()) store.mark_interrupted(ro.run_id);
                                   else store.finish(rep);  // a failure here makes the row an error: never a silent gap
                                   return rep;
                               });
    progress.clear();
    if (fwd) fwd->stop();
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
            run_rows_stored(o, s, *store, missing);
            bool forward_ok = true;
            if (auto* fwd = dynamic_cast<ForwardingStore*>(store.get())) {
                std::vector<std::string> ids;
                for (const std::size_t k : missing) ids.push_back(sweep_run_id(s, k));
                forward_ok = deliver(o, *fwd, ids);
            }
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
    auto* fwd = dynamic_cast<ForwardingStore*>(store.get());
    // Stored means stored in the target: with a PostgreSQL --store, that store says which rows
    // it holds (a new or restored server holds none of them, whatever the spool says). A row
    // this folder has run but the target lacks is not run again: its kept report is forwarded.
    std::vector<std::string> ids;
    for (std::size_t k = shard.index; k < s.rows.size(); k += shard.count) ids.push_back(sweep_run_id(s, k));
    const auto in_target = fwd ? fwd->shared_has(ids) : std::nullopt;
    std::vector<std::size_t> rows;
    std::size_t already = 0, kept = 0;
    for (std::size_t k = shard.index, j = 0; k < s.rows.size(); k += shard.count, ++j) {
        if (in_target && in_target->count(ids[j])) ++already;
        else if (stored(fwd ? static_cast<const RunStore&>(fwd->local()) : *store, ids[j])) ++(fwd ? kept : already);
        else rows.push_back(k);
    }
    if (!o.quiet) {
        std::string note;
        if (fwd && !in_target) note = " (the shared store is unreachable: counted from this folder's spool)";
        else if (kept) note = ", " + std::to_string(kept) + " kept in this folder's spool to forward";
        std::fprintf(stderr, "sweep %s shard %zu/%zu: %zu row(s), %zu already stored%s, running %zu\n", sweep_digest(s).substr(0, 16).c_str(), shard.index,
                     shard.count, ids.size(), already + (fwd && !in_target ? kept : 0), note.c_str(), rows.size());
    }
    const auto res = rows.empty() ? std::vector<SweepResult>{} : run_rows_stored(o, s, *store, rows);
    if (!rows.empty()) write_tables(o, s, res, "runs", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    if (cancel_flag().load()) return kExitError;
    // Every row of the shard must be in the target before this shard reports success: a retry
    // whose rows all wait in the spool forwards them here (and fails if it cannot).
    if (fwd && !deliver(o, *fwd, ids)) return kExitError;
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
