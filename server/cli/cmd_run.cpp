// fringe run: one scenario, here or on a fringe serve (--server); exit 0 PASS/MARGINAL, 1 FAIL, 2 ERROR.
#include "server/cli/commands.hpp"
#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "signal_gen/base/config.hpp"
#include "server/store/forward.hpp"
#include "server/store/instance_lock.hpp"
#include "server/engine/provenance.hpp"
#include "server/http/remote.hpp"
#include "server/report/report_formats.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/http/service.hpp"
#include "server/store/store.hpp"
#include "signal_gen/base/text.hpp"
#include "server/analysis/verdict.hpp"

#include <cstdio>
#include <filesystem>
#include <spdlog/spdlog.h>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct RunCliOptions {
    std::string scenario, report, junit, html, data, record, device, server, token_file, store, calibration_dir;
    std::string bench, dut, dut_part, operator_name;
    double forward_wait_s = 10;
    std::int64_t seed = -1;
    bool no_db = false, quiet = false, metrics = false;
};

// fringe run --server URL: the scenario is read and checked here (file references inlined),
// run by the service, and its report fetched; same output files, summary and exit code.
int run_run_remote(const RunCliOptions& o, const Scenario& sc) {
    if (!o.record.empty()) throw ConfigError("record", "--record needs the device on this host; not with --server");
    if (!o.data.empty()) throw ConfigError("data", "the service keeps the history; --data does not apply with --server");
    if (!o.store.empty()) throw ConfigError("store", "the service keeps the history; --store does not apply with --server");
    if (sc.motion.kind == MotionKind::Table)
        throw ConfigError("motion.file", "a table motion is read from a file on the service's host; with --server, put the table in the service's fixtures and run a scenario there");
    const ServiceUrl url = parse_service_url(o.server);
    const std::string token_path = o.token_file.empty() ? default_data_dir() + "/token" : o.token_file;
    // No default token file: send none, and the service's 401 says what is missing.
    const std::string token = o.token_file.empty() && !std::filesystem::exists(token_path) ? "" : read_token_file(token_path);
    ServiceClient client(url, token);
    RemoteRunOptions ro;
    ro.junit = o.junit;
    ro.html = o.html;
    ro.cancel = &cancel_flag();  // Ctrl-C cancels the run on the service; its report still comes back
    install_cancel_handlers();
    Progress progress("run", "samples", o.quiet);
    if (progress.active()) ro.progress = [&](std::uint64_t done, std::uint64_t total) { progress.update(done, total); };
    json r;
    std::string failure;
    try {
        r = run_remote(client, json(sc), ro);
    } catch (const RemoteError& e) {
        failure = e.what();
    }
    progress.clear();
    if (!failure.empty()) {
        spdlog::error("{}", failure);
        return kExitError;
    }
    if (!o.report.empty()) write_file_atomic(o.report, r.dump(2, ' ', false, json::error_handler_t::replace) + "\n");
    if (!o.quiet) print_run_summary(r, sc.name, o.metrics);
    if (r["error"].is_string()) spdlog::error("{}", r["error"].get<std::string>());
    return exit_code(r);
}

int run_run(const RunCliOptions& o) {
    // checked before the run: a report written over the scenario (or over another report) is lost work
    // A CSV recording writes its sidecar x.json beside it, over a scenario or report of that name.
    const std::string record_sidecar =
        !o.record.empty() && std::filesystem::path(o.record).extension() != ".fcap" ? sidecar_path(o.record) : std::string();
    refuse_overwrite({{"report", o.report}, {"junit", o.junit}, {"html", o.html}, {"record", o.record}, {"record (its sidecar)", record_sidecar}},
                     {{"scenario", o.scenario}});
    Scenario sc = load_scenario(o.scenario);
    if (o.seed >= 0) sc.seed = static_cast<std::uint64_t>(o.seed);
    if (!o.device.empty()) {
        sc.device = o.device;
        sc.instruments.reset();
    }
    if (!o.dut.empty()) sc.dut = o.dut;
    if (!o.dut_part.empty()) sc.dut_part = o.dut_part;
    // Checked once, here: errors stop the run (exit 2); the preflight's warnings come back in the
    // report. With --server the service makes its own plan from the scenario sent.
    RunPlan plan = plan_run(sc);
    // The files the run reads, once the plan has resolved them: a --record (or report) over the
    // capture a run replays, or over its calibrate block's verify capture, destroyed it (and the
    // after pass then "verified" the correction on the before pass's own samples).
    {
        std::vector<NamedPath> reads{{"scenario", o.scenario}};
        auto capture_of = [&](const std::string& uri, const std::string& role) {
            if (uri.rfind("capture:", 0) != 0) return;
            try {
                reads.push_back({role, dev::check_uri(uri).path});
            } catch (const std::exception&) {  // the plan checked it
            }
        };
        if (!plan.scenario.instruments) capture_of(plan.scenario.device, "capture");
        if (plan.scenario.calibrate) capture_of(plan.scenario.calibrate->verify.device, "capture");
        for (const auto& e : plan.scenario.estimators)
            if (e.params.is_object() && e.params.contains("correction") && e.params["correction"].is_string())
                reads.push_back({"correction of " + e.label, e.params["correction"].get<std::string>()});
        refuse_overwrite({{"report", o.report}, {"junit", o.junit}, {"html", o.html}, {"record", o.record}, {"record (its sidecar)", record_sidecar}}, reads);
    }
    if (!o.server.empty()) return run_run_remote(o, sc);
    // The run's row names this process's instance, whose lock we hold until the report is
    // stored: a service on the same folder sees the run alive, and interrupted once we are gone.
    InstanceLock instance;
    std::unique_ptr<RunStore> store;
    RunOptions ro;
    ro.run_id = new_run_id();
    ro.record_path = o.record;
    // A scenario's "calibrate" writes its correction file beside the report (or where asked).
    ro.calibration_dir = !o.calibration_dir.empty() ? o.calibration_dir
                         : !o.report.empty()         ? std::filesystem::absolute(o.report).parent_path().string()
                                                     : std::string();
    ProvenanceDefaults pd = provenance_defaults();
    if (!o.bench.empty()) pd.bench = o.bench;
    if (!o.operator_name.empty()) pd.operator_name = o.operator_name;
    ro.provenance = make_provenance(pd, sc);
    // Ctrl-C / SIGTERM: finish the block, end the run as ABORTED and keep its report.
    ro.cancel = &cancel_flag();
    install_cancel_handlers();
    ForwardingStore* forwarder = nullptr;
    if (!o.no_db) {
        const StoreUri su = parse_store_uri(o.store, o.data.empty() ? default_data_dir() : o.data);
        const std::string dir = std::filesystem::path(su.sqlite_path).parent_path().string();
        instance.acquire_instance(dir.empty() ? "." : dir, "cli-" + new_instance_id());
        store = open_store(su, instance.id());
        forwarder = dynamic_cast<ForwardingStore*>(store.get());
        if (forwarder) {
            // Reports an earlier run on this folder could not forward go first; a database
            // that is down costs one connect timeout here, and the run goes on.
            const auto p = forwarder->forward_pending();
            if (p.forwarded) spdlog::info("forwarded {} earlier run(s) to {}", p.forwarded, redact_store_uri(su.pg_uri));
        }
        store->begin(ro.run_id, iso_now(), sc.name, sc.dut, "running", ro.provenance);
    }
    Progress progress("run", "samples", o.quiet);
    if (progress.active()) ro.progress = [&](std::uint64_t done, std::uint64_t total) { progress.update(done, total); };
    json r;
    try {
        r = execute_run(std::move(plan), ro);
    } catch (const std::exception& e) {  // out of memory, say: the history must not keep it "running"
        r = unstarted_report(sc, ro.run_id, iso_now(), RunStatus::Error, Verdict::Error, e.what(), ro.provenance);
    }
    progress.clear();
    // The report survives first: files, then the history.
    if (!o.report.empty()) write_file_atomic(o.report, r.dump(2, ' ', false, json::error_handler_t::replace) + "\n");
    if (!o.junit.empty()) write_file_atomic(o.junit, junit_xml(r));
    if (!o.html.empty()) write_file_atomic(o.html, report_html(r));
    std::string store_error;
    if (store) {
        try {
            store->finish(r);
        } catch (const std::exception& e) {
            store_error = e.what();
        }
    }
    // Stored here; now to the shared store, for a bounded time. What is still pending stays
    // marked in DATA/runs.db and goes with the next fringe run / serve / sweep on this folder.
    std::string forward_note;
    if (forwarder && store_error.empty()) {
        const auto p = forwarder->forward_until(o.forward_wait_s);
        // Each conflict under its own id: an earlier run's found here is not this run's.
        for (const auto& id : p.conflict_ids)
            spdlog::warn("run {}{}: the shared store holds a different report under this id (flagged in its run_conflicts; neither overwritten)", id,
                         id == ro.run_id ? "" : " (an earlier run kept in this folder)");
        if (p.pending) forward_note = "forwarding pending: " + std::to_string(p.pending) + " run(s) kept in " + forwarder->describe() +
                                           " are not in the shared store yet (" + p.error + "); the next fringe run, serve or sweep with this --data and --store forwards them";
    }
    if (!o.quiet) print_run_summary(r, sc.name, o.metrics);
    if (r["status"] == "error") spdlog::error("{}", r["error"].get<std::string>());
    if (!forward_note.empty()) spdlog::warn("{}", forward_note);
    if (!store_error.empty()) {
        // A verdict that is not in the history is not a finished run: say so and fail.
        spdlog::error("the run's report could not be stored in the history: {}{}", store_error,
                      o.report.empty() ? "" : " (the report file " + o.report + " was written)");
        return kExitError;
    }
    return exit_code(r);
}

}  // namespace

Command add_run(CLI::App& app) {
    auto o = std::make_shared<RunCliOptions>();
    auto* rn = app.add_subcommand("run", "Run a scenario: generate, play through the device, estimate, score, apply limits; exit 0 PASS/MARGINAL, 1 FAIL, 2 ERROR");
    rn->add_option("scenario", o->scenario, "Scenario JSON file")->required()->check(CLI::ExistingFile);
    rn->add_option("--report", o->report, "Write the report JSON here");
    rn->add_option("--junit", o->junit, "Write JUnit XML here (one testcase per measurement)");
    rn->add_option("--html", o->html, "Write a self-contained HTML report here");
    rn->add_option("--data", o->data, "Data directory for the run history (default $FRINGE_DATA or ~/.local/share/fringe)");
    rn->add_option("--store", o->store, "Run store: sqlite:PATH, or a shared PostgreSQL (postgresql://USER@HOST/DB, postgresql:///DB?host=/socket/dir) "
                                        "written through DATA/runs.db and forwarded (default DATA/runs.db)");
    rn->add_option("--forward-wait", o->forward_wait_s, "With a PostgreSQL --store: seconds to keep retrying the forward before leaving it pending")
        ->check(kFiniteNonNegative)->capture_default_str();
    rn->add_option("--bench", o->bench, "Bench name in the run's provenance (default $FRINGE_BENCH, else the host name)");
    rn->add_option("--dut", o->dut, "DUT serial (overrides the scenario's \"dut\"; default the device's board id)");
    rn->add_option("--dut-part", o->dut_part, "DUT part number (overrides the scenario's \"dut_part\")");
    rn->add_option("--operator", o->operator_name, "Operator in the run's provenance (default $USER)");
    rn->add_option("--seed", o->seed, "Override the scenario's seed (0 to 2^53)")->check(kSeedRange);
    rn->add_flag("--no-db", o->no_db, "Do not record the run in the history");
    rn->add_option("--device", o->device, "Override the scenario's device URI (e.g. modbus+tcp://127.0.0.1:1502?board=dut-interpolator)");
    rn->add_option("--record", o->record, "Record the device input with aligned truth to this capture (.csv or .fcap)");
    rn->add_option("--calibration-dir", o->calibration_dir, "A scenario with \"calibrate\": write the correction (RUN_ID.correction.json) here "
                                                            "(default: beside --report, else a folder under the system's temporary folder)");
    rn->add_flag("-q,--quiet", o->quiet, "No summary or progress");
    rn->add_flag("--metrics", o->metrics, "Also print every metric of every estimator (fringe metrics describes them)");
    rn->add_option("--server", o->server, "Run it on a fringe serve at this URL (http://HOST:PORT): the scenario is checked here, run there, its report fetched");
    rn->add_option("--token-file", o->token_file, "With --server: the service's bearer token file (default $FRINGE_DATA/token or ~/.local/share/fringe/token)");
    return {rn, [o] { return run_run(*o); }};
}

}  // namespace fringe::cli
