// The HTTP service (service.hpp): construction, the request path (precheck, handle, routing),
// runs and the fixture/device catalogue. Its guards are in service_auth.cpp, the capture store in
// service_captures.cpp, rendered reports in service_report_cache.cpp; shared helpers in
// service_internal.hpp.
#include "server/http/service_internal.hpp"

#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "drivers/usb_protocol.hpp"
#include "estimator/estimator.hpp"
#include "server/report/report_formats.hpp"
#include "server/engine/preflight.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "server/engine/schema_info.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/text.hpp"

#include <spdlog/spdlog.h>

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

namespace fringe {

using namespace service_detail;

namespace {
// A run this bench does not have while the shared store cannot be asked: it may be another
// bench's, so the answer is "store unreachable" (503), never "no such run".
void unknown_while_shared_down(const RunStore& st, const std::string& id) {
    if (const auto* fwd = dynamic_cast<const ForwardingStore*>(&st))
        if (const auto h = fwd->health(); h.reachable == 0)
            throw StoreUnreachable("run " + id + " is not in this bench's spool and the shared store is unreachable, so it cannot be looked up there; "
                                   "retry when it is back (" + h.error + ")");
}
}  // namespace

HttpResponse json_error(int status, const std::string& code, const std::string& message, const std::string& field) {
    json e{{"code", code}, {"message", message}};
    e["field"] = field.empty() ? json(nullptr) : json(field);
    HttpResponse r;
    r.status = status;
    r.body = dump_safe(json{{"error", e}});
    return r;
}


Service::Service(ServiceConfig cfg) : cfg_(std::move(cfg)) {
    // One service per data folder (throws InstanceLockBusy naming the holder); holding it,
    // every queued or running row of an instance whose lock is free is over for good.
    lock_.acquire_service(cfg_.data_dir, new_instance_id());
    fs::create_directories(fs::path(cfg_.data_dir) / "captures");
    // Clients see our folders by short names: every spelling a message may use (as given,
    // absolute, with symlinks resolved).
    auto name_folder = [&](const std::string& dir, const std::string& name) {
        if (dir.empty()) return;
        std::error_code ec;
        const fs::path abs = fs::absolute(dir, ec).lexically_normal();
        for (fs::path p : {fs::path(dir), abs, fs::weakly_canonical(abs, ec)}) {
            std::string t = p.string();
            while (t.size() > 1 && t.back() == '/') t.pop_back();
            if (t.size() > 1 && t[0] == '/') public_names_.emplace_back(t, name);
        }
    };
    name_folder(cfg_.data_dir, "DATA");
    name_folder(cfg_.fixtures_dir, "fixtures");
    name_folder(dev::boards_dir(), "boards");
    name_folder(cfg_.web_dir, "web");
    std::stable_sort(public_names_.begin(), public_names_.end(), [](const auto& a, const auto& b) { return a.first.size() > b.first.size(); });
    ::chmod((fs::path(cfg_.data_dir) / "captures").c_str(), 0700);
    // --store: DATA/runs.db, sqlite:PATH, or a shared PostgreSQL store fed through DATA/runs.db (forward.hpp).
    store_ = open_store(parse_store_uri(cfg_.store_uri, cfg_.data_dir), lock_.id());
    if (const int n = store_->mark_dead_interrupted(); n > 0) spdlog::warn("{} run(s) of a process that stopped without finishing are marked interrupted", n);
    remove_stale_instance_locks(cfg_.data_dir);
    runs_ = std::make_unique<RunManager>(*store_, store_mu_, cfg_.workers);
    runs_->max_report_bytes = cfg_.max_report_bytes;
    runs_->max_queued = cfg_.max_queued_runs;
    runs_->provenance = cfg_.provenance;
    runs_->calibration_dir = (fs::path(cfg_.data_dir) / "corrections").string();  // created by the first calibrated run
    if (auto* fwd = dynamic_cast<ForwardingStore*>(store_.get())) fwd->start();  // forwards what earlier runs left pending, too
    if (!cfg_.web_dir.empty() && fs::is_directory(cfg_.web_dir)) {
        // The UI is read once: requests look files up by exact name, never build paths.
        for (const auto& e : fs::recursive_directory_iterator(cfg_.web_dir)) {
            if (!e.is_regular_file()) continue;
            const auto rel = fs::relative(e.path(), cfg_.web_dir).generic_string();
            if (rel.rfind("node_modules", 0) == 0 || rel.find("/.") != std::string::npos || rel[0] == '.') continue;
            static_["/" + rel] = {content_type_for(e.path().extension().string()), read_file(e.path())};
        }
        if (!static_.count("/vendor/uPlot.esm.js")) spdlog::warn("web/vendor/uPlot.esm.js is missing (scripts/setup vendors it from npm): plots will not draw");
    }
}

Service::~Service() { shutdown(); }

void Service::set_bound_address(const std::string& host) {
    std::string h = lower(host);
    if (h.find(':') != std::string::npos && h.front() != '[') h = "[" + h + "]";
    cfg_.bind_host = h;
}



void Service::shutdown() {
    if (runs_) runs_->shutdown();
}

bool Service::is_upload(const std::string& method, const std::string& target) const {
    return method == "POST" && target.substr(0, target.find('?')) == "/api/v1/captures";
}

bool Service::is_heavy(const std::string& method, const std::string& target) {
    const std::string path = target.substr(0, target.find('?'));
    if (is_upload(method, target)) return true;  // reads the whole capture to check it
    const auto seg = segments(path);
    // With a shared store, run reads may wait for PostgreSQL (up to the statement deadline when
    // it is frozen), and the rest waits for the store lock: never on the I/O threads, so
    // /health and the other endpoints answer meanwhile.
    if (seg.size() >= 3 && seg[0] == "api" && seg[1] == "v1" && seg[2] == "runs" && dynamic_cast<const ForwardingStore*>(store_.get())) return true;
    if (seg.size() == 5 && seg[0] == "api" && seg[1] == "v1") {
        if (seg[2] == "captures" && seg[4] == "evaluate") return method == "POST";
        // The first read of a report parses and renders it (it can be hundreds of MB); later
        // reads come from the cache and stay on the I/O thread.
        if (seg[2] == "runs" && (seg[4] == "report.json" || seg[4] == "report.xml" || seg[4] == "report.html" || seg[4] == "traces" || seg[4] == "metrics")) {
            if (method != "GET") return false;
            std::lock_guard<std::mutex> l(cache_mu_);
            return cache_.count(seg[3]) == 0;
        }
    }
    return false;
}



std::optional<HttpResponse> Service::precheck(const HttpRequest& head, std::uint64_t content_length, bool has_length) const {
    try {
        // Before anything else: a page under a foreign name learns nothing here.
        if (auto wrong = check_host(head)) return wrong;
        const std::string path = head.target.substr(0, head.target.find('?'));
        if (path.rfind("/api/", 0) != 0) {
            if (head.method != "GET") {
                auto r = json_error(405, "method_not_allowed", "static files are GET only");
                r.headers.emplace_back("Allow", "GET");
                return r;
            }
            return std::nullopt;
        }
        if (head.method != "GET" && head.method != "POST") {
            auto r = json_error(405, "method_not_allowed", "the API uses GET to read and POST to change state");
            r.headers.emplace_back("Allow", "GET, POST");
            return r;
        }
        if (auto denied = check_token(head, head.method == "POST")) return denied;
        const bool upload = is_upload(head.method, head.target);
        const std::uint64_t limit = upload ? cfg_.max_upload_bytes : cfg_.max_body_bytes;
        if (has_length && content_length > limit)
            return json_error(413, "body_too_large", "the body is " + std::to_string(content_length) + " bytes; the limit here is " + std::to_string(limit));
        if (upload && has_length && content_length > 0) {
            if (const auto room = upload_room(); content_length > room)
                return json_error(507, "quota_exceeded", "the upload is " + std::to_string(content_length) + " bytes; uploaded captures may take " +
                                                             std::to_string(cfg_.upload_quota_bytes) + " bytes (each counted as it expands) and " + std::to_string(room) +
                                                             " are left (--upload-quota-mb)");
        }
        return std::nullopt;
    } catch (const std::exception& e) {
        return json_error(500, "internal", public_text(e.what()));
    }
}

HttpResponse Service::handle(const HttpRequest& req) {
    try {
        return handle_request(req);
    } catch (...) {
        // Failed while answering a failure (out of memory): still an answer, never an
        // exception into the server's I/O loop.
        HttpResponse r;
        r.status = 500;
        r.body = R"({"error":{"code":"internal","message":"internal error","field":null}})";
        return r;
    }
}

HttpResponse Service::handle_request(const HttpRequest& req) {
    try {
        std::string path;
        std::map<std::string, std::string> query;
        split_target(req.target, path, query);
        if (auto early = precheck(req, req.body.size(), true)) return *early;
        if (path.find("..") != std::string::npos || path.find('\\') != std::string::npos || path.find('\0') != std::string::npos)
            return json_error(400, "bad_path", "the path may not contain '..' or backslashes");
        require_utf8(path, "path", "the path");
        for (const auto& [k, v] : query) {
            require_utf8(k, "query", "a query parameter's name (percent-decoded)");
            require_utf8(v, k, "the value of query parameter '" + k + "' (percent-decoded)");
        }
        if (!is_upload(req.method, req.target)) require_utf8(req.body, "body", "the request body");  // uploads are binary files
        if (path.rfind("/api/", 0) != 0) return static_file(path);
        return route(req, path, query);
    } catch (const HttpError& e) {
        return json_error(e.status, e.code, public_text(e.what()), e.field);
    } catch (const ConfigError& e) {
        return json_error(400, "invalid", public_text(e.message()), e.field());
    } catch (const CaptureError& e) {
        return json_error(400, "bad_capture", public_text(e.what()));
    } catch (const est::EstimatorError& e) {
        return json_error(400, "estimator_error", public_text(e.what()));
    } catch (const dev::DeviceError& e) {
        return json_error(502, "device_error", public_text(e.what()));
    } catch (const StoreFull& e) {
        spdlog::error("{}", log_escape(e.what()));
        return json_error(507, "storage_full", public_text(std::string("the disk is full: ") + e.what()));
    } catch (const StoreUnreachable& e) {
        // The shared store is frozen or gone: what only it could answer is 503, not 404 or 500.
        const std::string msg = redact_store_text(e.what(), cfg_.store_uri);
        spdlog::warn("{}", log_escape(msg));
        auto r = json_error(503, "store_unreachable", public_text(msg));
        r.headers.emplace_back("Retry-After", "10");
        return r;
    } catch (const StoreError& e) {
        const std::string msg = redact_store_text(e.what(), cfg_.store_uri);
        spdlog::error("{}", log_escape(msg));
        return json_error(500, "store_error", public_text(msg));
    } catch (const fs::filesystem_error& e) {
        spdlog::error("{} {}: {}", log_escape(req.method), log_escape(req.target), log_escape(e.what()));
        if (e.code() == std::errc::no_space_on_device || e.code() == std::errc::file_too_large)
            return json_error(507, "storage_full", std::string("the disk is full: ") + e.code().message());
        return json_error(500, "internal", public_text(e.what()));
    } catch (const std::exception& e) {
        spdlog::error("{} {}: {}", log_escape(req.method), log_escape(req.target), log_escape(e.what()));
        return json_error(500, "internal", public_text(e.what()));
    }
}

HttpResponse Service::static_file(const std::string& path) const {
    const auto it = static_.find(path == "/" ? "/index.html" : path);
    if (it == static_.end()) return json_error(404, "not_found", "no such file: " + path);
    HttpResponse r;
    r.content_type = it->second.first;
    r.body = it->second.second;
    r.headers.emplace_back("Cache-Control", "no-cache");
    r.headers.emplace_back("Content-Security-Policy",
                           "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; frame-ancestors 'none'");
    return r;
}

HttpResponse Service::route(const HttpRequest& req, const std::string& path, const std::map<std::string, std::string>& query) {
    const auto seg = segments(path);  // "api", "v1", ...
    if (seg.size() < 3 || seg[1] != "v1") return json_error(404, "not_found", "no such endpoint: " + path + " (the API is under /api/v1)");
    const std::string& top = seg[2];
    const bool get = req.method == "GET", post = req.method == "POST";
    auto wrong_method = [&](const char* allowed) {
        auto r = json_error(405, "method_not_allowed", req.method + " is not allowed on " + path);
        r.headers.emplace_back("Allow", allowed);
        return r;
    };
    auto check_id = [&](const std::string& id) -> std::optional<HttpResponse> {
        if (!valid_id(id)) return json_error(400, "bad_id", "'" + id + "' is not an id (letters, digits, '-', '_'; at most 64)", "id");
        return std::nullopt;
    };

    if (seg.size() == 3) {
        if (top == "health") {
            if (!get) return wrong_method("GET");
            const auto live = runs_->live();
            const auto running = std::count_if(live.begin(), live.end(), [](const RunSnapshot& s) { return s.status == "running"; });
            json out{{"status", "ok"}, {"version", FRINGE_VERSION}, {"workers", runs_->workers()},
                     {"runs", {{"running", running}, {"queued", static_cast<long>(live.size()) - running}}}};
            // The shared store as last seen, without the store lock (a query to a frozen database
            // may hold it): reachable, and the forwarding backlog in this bench's spool.
            if (const auto* fwd = dynamic_cast<const ForwardingStore*>(store_.get())) {
                const auto h = fwd->health();
                out["store"] = {{"kind", "postgresql"}, {"uri", redact_store_uri(cfg_.store_uri)},
                                {"reachable", h.reachable < 0 ? json(nullptr) : json(h.reachable == 1)}, {"pending", h.pending},
                                {"error", h.error.empty() ? json(nullptr) : json(public_text(redact_store_text(h.error, cfg_.store_uri)))}};
            }
            return json_ok(out);
        }
        if (top == "estimators") return get ? json_ok({{"estimators", est::registry()}}) : wrong_method("GET");
        if (top == "drivers") return get ? json_ok({{"drivers", dev::drivers()}}) : wrong_method("GET");
        if (top == "devices") return get ? devices() : wrong_method("GET");
        if (top == "fixtures") return get ? fixtures() : wrong_method("GET");
        if (top == "schema") return get ? json_ok(scenario_schema()) : wrong_method("GET");
        if (top == "preflight") return post ? preflight_run(req) : wrong_method("POST");
        if (top == "runs") return get ? list_runs(query) : post ? create_run(req) : wrong_method("GET, POST");
        if (top == "captures") return get ? json_ok({{"captures", captures()}}) : post ? upload_capture(req, query) : wrong_method("GET, POST");
    }
    if (seg.size() == 4 && top == "fixtures") {
        if (!get) return wrong_method("GET");
        if (auto bad = check_id(seg[3])) return *bad;
        return fixture(seg[3]);
    }
    if (top == "runs" && (seg.size() == 4 || seg.size() == 5)) {
        const std::string& id = seg[3];
        if (auto bad = check_id(id)) return *bad;
        if (seg.size() == 4) return get ? get_run(id) : wrong_method("GET");
        const std::string& what = seg[4];
        if (what == "cancel") {
            if (!post) return wrong_method("POST");
            switch (runs_->cancel(id)) {
                case RunManager::CancelResult::Cancelled: return json_ok({{"id", id}, {"cancelling", true}}, 202);
                case RunManager::CancelResult::Finished: return json_error(409, "finished", "run " + id + " has already finished");
                case RunManager::CancelResult::Unknown: break;
            }
            std::lock_guard<std::mutex> l(store_mu_);
            if (store_->row(id)) return json_error(409, "finished", "run " + id + " is not running in this service");
            unknown_while_shared_down(*store_, id);
            return json_error(404, "not_found", "no run " + id, "id");
        }
        if (what == "events") {
            if (!get) return wrong_method("GET");
            if (!run_state(id)) return json_error(404, "not_found", "no run " + id, "id");
            HttpResponse r;
            r.events_run = id;
            r.content_type = "text/event-stream";
            return r;
        }
        if (what == "report.json" || what == "report.xml" || what == "report.html" || what == "traces" || what == "metrics") {
            if (!get) return wrong_method("GET");
            return run_artifact(id, what, query);
        }
    }
    if (top == "captures" && seg.size() == 5 && seg[4] == "evaluate") {
        if (!post) return wrong_method("POST");
        if (auto bad = check_id(seg[3])) return *bad;
        return evaluate(req, seg[3]);
    }
    return json_error(404, "not_found", "no such endpoint: " + path);
}

// ---- runs ----------------------------------------------------------------------------


std::optional<HttpResponse> Service::run_scenario(const json& body, Scenario& sc) const {
    only_keys(body, {"fixture", "scenario", "seed"}, "");
    if (body.contains("fixture") == body.contains("scenario"))
        throw ConfigError("", "give exactly one of \"fixture\" (a name from GET /api/v1/fixtures) or \"scenario\" (an object)");
    if (body.contains("fixture")) {
        if (!body["fixture"].is_string()) throw ConfigError("fixture", "expected a string");
        const std::string name = body["fixture"].get<std::string>();
        const fs::path p = fs::path(cfg_.fixtures_dir) / "scenarios" / (name + ".json");
        if (!valid_id(name) || !fs::is_regular_file(p)) throw ConfigError("fixture", "no fixture named '" + name + "' (GET /api/v1/fixtures lists them)");
        try {
            sc = load_scenario(p.string());
        } catch (const ConfigError& e) {
            throw e.prefixed("fixture");
        }
        for (const auto& e : sc.estimators)
            if (est::traits_of(e.name).child_process && !cfg_.allow_external)
                throw ConfigError("fixture", "this fixture uses the " + e.name + " estimator, which runs a command on this host; start the service with --allow-external");
    } else {
        // Counted before anything is built from them (each estimator is constructed to check it).
        const json& raw = body["scenario"];
        if (raw.is_object() && raw.contains("estimators") && raw["estimators"].is_array() && raw["estimators"].size() > cfg_.max_estimators)
            return json_error(413, "too_many_estimators", "the scenario has " + std::to_string(raw["estimators"].size()) + " estimators; this service runs at most " +
                                                              std::to_string(cfg_.max_estimators) + " per run (--max-estimators)", "scenario.estimators");
        if (raw.is_object() && raw.contains("limits") && raw["limits"].is_array() && raw["limits"].size() > cfg_.max_limits)
            return json_error(413, "too_many_limits", "the scenario has " + std::to_string(raw["limits"].size()) + " limits; this service takes at most " +
                                                          std::to_string(cfg_.max_limits) + " per run (--max-limits)", "scenario.limits");
        const json safe = sandbox_scenario(body["scenario"]);
        try {
            sc = scenario_from_json(safe, (fs::path(cfg_.fixtures_dir) / "scenarios").string());
        } catch (const ConfigError& e) {
            throw e.prefixed("scenario");
        }
    }
    if (body.contains("seed")) {
        if (!body["seed"].is_number_unsigned() || body["seed"].get<std::uint64_t>() > kMaxSeed)
            throw ConfigError("seed", "expected an integer from 0 to 2^53 (9007199254740992)");
        sc.seed = body["seed"].get<std::uint64_t>();
    }
    return std::nullopt;
}

std::optional<HttpResponse> Service::plan_scenario(const json& body, Scenario sc, std::optional<RunPlan>& plan) const {
    try {
        plan.emplace(plan_run(std::move(sc), RunBudget{cfg_.max_samples, cfg_.max_estimators, cfg_.max_limits}));
    } catch (const RunTooLarge& e) {
        const char* flag = e.code() == "too_many_samples" ? "--max-samples" : e.code() == "too_many_estimators" ? "--max-estimators" : "--max-limits";
        return json_error(413, e.code(), e.message() + " (" + flag + ")", body.contains("fixture") ? "fixture" : "scenario." + e.field());
    } catch (const ConfigError& e) {
        throw e.prefixed("scenario");
    }
    return std::nullopt;
}

HttpResponse Service::create_run(const HttpRequest& req) {
    const json body = parse_body(req.body);
    Scenario sc;
    if (auto refused = run_scenario(body, sc)) return *refused;
    std::optional<RunPlan> plan;  // the run queue keeps it: the worker runs these estimators
    if (auto refused = plan_scenario(body, std::move(sc), plan)) return *refused;
    std::string id;
    try {
        id = runs_->submit(std::move(*plan));
    } catch (const QueueFull& e) {
        auto r = json_error(429, "queue_full", e.what());
        r.headers.emplace_back("Retry-After", "10");
        return r;
    }
    auto r = json_ok({{"id", id}, {"status", "queued"}, {"links", {{"self", "/api/v1/runs/" + id}, {"events", "/api/v1/runs/" + id + "/events"}}}}, 201);
    r.headers.emplace_back("Location", "/api/v1/runs/" + id);
    return r;
}

HttpResponse Service::preflight_run(const HttpRequest& req) const {
    const json body = parse_body(req.body);
    Scenario sc;
    if (auto refused = run_scenario(body, sc)) return *refused;
    std::optional<RunPlan> plan;
    if (auto refused = plan_scenario(body, sc, plan)) return *refused;
    json w = json::array();
    for (auto f : plan->warnings) {
        f.field = "scenario." + f.field;  // the same path a POST runs error names
        w.push_back(f);
    }
    const double spc = plan->samples_per_cycle;
    return json_ok({{"ok", true}, {"warnings", w}, {"samples", sc.samples()}, {"samples_per_cycle", std::isfinite(spc) ? json(spc) : json(nullptr)}});
}

HttpResponse Service::list_runs(const std::map<std::string, std::string>& query) {
    RunFilter f;
    for (const auto& [k, v] : query) {
        if (k == "outcome" || k == "verdict") {
            static const char* verdicts[] = {"PASS", "MARGINAL", "FAIL", "ERROR", "ABORTED"};
            if (std::find(std::begin(verdicts), std::end(verdicts), v) == std::end(verdicts))  // clang 14: no structured binding in a lambda
                throw ConfigError(k, "expected PASS, MARGINAL, FAIL, ERROR or ABORTED");
            f.verdict = v;
        } else if (k == "scenario") {
            f.scenario = v;
        } else if (k == "since") {
            f.since = parse_since(v);
        } else if (k == "bench") {
            f.bench = v;
        } else if (k == "dut") {
            f.dut = v;
        } else if (k == "limit") {
            try {
                std::size_t used = 0;
                f.limit = std::stoi(v, &used);
                if (used != v.size() || f.limit < 1 || f.limit > 1000) throw std::invalid_argument(v);
            } catch (const std::exception&) {
                throw ConfigError("limit", "expected an integer from 1 to 1000");
            }
        } else {
            throw ConfigError(k, "unknown query parameter (known: outcome, scenario, since, bench, dut, limit)");
        }
    }
    std::vector<RunRow> rows;
    {
        std::lock_guard<std::mutex> l(store_mu_);
        rows = store_->list(f);
    }
    json out = json::array();
    for (const auto& row : rows) {
        json j{{"id", row.id}, {"created_at", row.created_at}, {"scenario", row.scenario}, {"dut", row.dut}, {"status", row.status},
               {"bench", row.bench}, {"host", row.host}, {"dut_part", row.dut_part}};
        j["verdict"] = row.verdict.empty() ? json(nullptr) : json(row.verdict);
        if (auto s = runs_->snapshot(row.id)) {
            j["status"] = s->status;
            j["progress"] = {{"done", s->done}, {"total", s->total}};
            if (!s->verdict.empty()) j["verdict"] = s->verdict;
        }
        out.push_back(std::move(j));
    }
    json body{{"runs", out}};
    // The shared store could not be read: this bench's runs only, and the answer says so.
    if (const auto* fwd = dynamic_cast<const ForwardingStore*>(store_.get()); fwd && fwd->health().reachable == 0) {
        body["partial"] = true;
        body["store"] = {{"reachable", false}, {"error", public_text(redact_store_text(fwd->health().error, cfg_.store_uri))}};
    }
    return json_ok(body);
}

std::optional<RunSnapshot> Service::run_state(const std::string& id) {
    if (auto s = runs_->snapshot(id)) {
        s->error = public_text(s->error);
        s->device = public_text(s->device);
        return s;
    }
    std::optional<RunRow> row;
    {
        // The row's summary columns only: never the report (it can be hundreds of MB).
        std::lock_guard<std::mutex> l(store_mu_);
        row = store_->row(id);
        if (row && row->dead) store_->mark_interrupted(id);  // its process is gone: for good
        if (!row) unknown_while_shared_down(*store_, id);
    }
    if (!row) return std::nullopt;
    RunSnapshot s;
    s.id = row->id;
    s.scenario = row->scenario;
    s.dut = row->dut;
    s.created_at = row->created_at;
    s.status = row->status;
    s.verdict = row->verdict;
    s.error = public_text(row->error);
    s.done = row->done;
    s.total = row->total;
    s.device = public_text(row->device);
    s.seq = 1;
    return s;
}

HttpResponse Service::get_run(const std::string& id) {
    auto s = run_state(id);
    if (!s) return json_error(404, "not_found", "no run " + id, "id");
    json j = *s;
    const std::string base = "/api/v1/runs/" + id;
    j["links"] = {{"events", base + "/events"}, {"cancel", base + "/cancel"}};
    if (s->finished() && s->status != "interrupted")
        j["links"].update({{"report_json", base + "/report.json"}, {"report_xml", base + "/report.xml"},
                           {"report_html", base + "/report.html"}, {"traces", base + "/traces"},
                           {"metrics", base + "/metrics"}});
    return json_ok(j);
}


std::string Service::sse_event(const RunSnapshot& s) {
    std::string data;
    try {
        data = dump_safe(json(s));
    } catch (const std::exception&) {
        data = R"({"error":"the run's state could not be serialised"})";
    }
    return "id: " + std::to_string(s.seq) + "\nevent: " + (s.finished() ? "end" : "progress") + "\ndata: " + data + "\n\n";
}

// ---- catalogue ------------------------------------------------------------------------

HttpResponse Service::fixtures() {
    json list = json::array();
    const fs::path dir = fs::path(cfg_.fixtures_dir) / "scenarios";
    std::vector<fs::path> files;
    if (fs::is_directory(dir))
        for (const auto& e : fs::directory_iterator(dir))
            if (e.path().extension() == ".json") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (const auto& p : files) {
        json f{{"name", p.stem().string()}};
        try {
            const Scenario sc = load_scenario(p.string());
            f["description"] = sc.description;
            f["device"] = json(sc)["device"];
            f["duration_s"] = sc.duration_s;
            f["sample_rate_hz"] = sc.sample_rate_hz;
            f["samples"] = sc.samples();
            json est = json::array();
            for (const auto& e : sc.estimators) est.push_back(e.label);
            f["estimators"] = est;
            f["limits"] = sc.limits.size();
            f["runnable"] = !sc.estimators.empty();
        } catch (const std::exception& e) {
            f["runnable"] = false;
            f["problem"] = public_text(e.what());
        }
        list.push_back(std::move(f));
    }
    json encoders = json::array();
    const fs::path edir = fs::path(cfg_.fixtures_dir) / "encoders";
    if (fs::is_directory(edir))
        for (const auto& e : fs::directory_iterator(edir))
            if (e.path().extension() == ".json") encoders.push_back(e.path().stem().string());
    std::sort(encoders.begin(), encoders.end());
    // Interface profiles, by file name, with the name they give themselves.
    json interfaces = json::array();
    const fs::path idir = fs::path(cfg_.fixtures_dir) / "interfaces";
    std::vector<fs::path> ifiles;
    if (fs::is_directory(idir))
        for (const auto& e : fs::directory_iterator(idir))
            if (e.path().extension() == ".json") ifiles.push_back(e.path());
    std::sort(ifiles.begin(), ifiles.end());
    for (const auto& p : ifiles) {
        json f{{"name", p.stem().string()}};
        try {
            f["title"] = load_interface(p.string()).name;
        } catch (const std::exception& e) {
            f["problem"] = public_text(e.what());
        }
        interfaces.push_back(std::move(f));
    }
    return json_ok({{"fixtures", list}, {"encoders", encoders}, {"interfaces", interfaces}});
}

HttpResponse Service::fixture(const std::string& name) {
    const fs::path p = fs::path(cfg_.fixtures_dir) / "scenarios" / (name + ".json");
    if (!fs::is_regular_file(p)) return json_error(404, "not_found", "no fixture named '" + name + "'", "name");
    const Scenario sc = load_scenario(p.string());
    return json_ok({{"name", name}, {"scenario", sc}});
}

HttpResponse Service::devices() {
    json list = json::array();
    // Simulated and file devices are always there; hardware drivers add what they find.
    list.push_back({{"uri", "loopback:"}, {"driver", "loopback"}, {"description", "simulated DAC -> filters -> noise -> ADC"}, {"available", true}});
    for (const auto& drv : dev::drivers())
        if (drv.find)
            for (auto found : drv.find()) {
                found["driver"] = drv.scheme;
                found["available"] = true;
                list.push_back(found);
            }
    for (const auto& c : captures())
        list.push_back({{"uri", "capture:" + c["id"].get<std::string>()}, {"driver", "capture"}, {"description", "uploaded capture (" + c.value("format", "") + ")"},
                        {"available", true}});
    std::map<std::string, bool> busy;
    for (const auto& s : runs_->live())
        if (s.status == "running") {
            // A run's device label is one URI or "OUTPUT -> INPUT".
            for (std::size_t a = 0, b; a <= s.device.size(); a = b + 4) {
                b = s.device.find(" -> ", a);
                if (b == std::string::npos) b = s.device.size();
                if (const std::string k = device_key(s.device.substr(a, b - a)); !k.empty()) busy[k] = true;
            }
        }
    for (auto& d : list) d["busy"] = busy.count(device_key(d["uri"].get<std::string>())) > 0;
    // Configured board profiles: the URI to use once the board's address is known.
    json boards = json::array();
    for (const auto& name : dev::board_names()) {
        try {
            const auto b = dev::load_board(name);
            boards.push_back({{"name", b.name}, {"kind", b.kind}, {"description", b.description}, {"dut_position", b.has_dut_position()},
                              {"uri_template", "modbus+tcp://HOST:PORT?board=" + b.name}});
        } catch (const std::exception& e) {
            boards.push_back({{"name", name}, {"problem", public_text(e.what())}});
        }
    }
    return json_ok({{"devices", list}, {"boards", boards}});
}

}  // namespace fringe
