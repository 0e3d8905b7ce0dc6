// The HTTP service's logic without a socket (after Beast's clean-shutdown example):
// handle(request) -> response. server/http/http_server.cpp carries requests here from Beast;
// tests call handle() directly and also go through a real socket.
//
// API under /api/v1 (docs/http-api.md): health, estimators, drivers, devices, fixtures,
// runs (create, list, get, cancel, report.json|.xml|.html, traces, events), captures
// (upload, list, evaluate). Errors are {"error":{"code","message","field"}}.
#pragma once

#include "server/store/forward.hpp"
#include "server/store/instance_lock.hpp"
#include "server/engine/provenance.hpp"
#include "server/http/run_manager.hpp"
#include "server/store/store.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace fringe {

struct ServiceConfig {
    std::string data_dir;      // runs.db, captures/
    std::string store_uri;     // "" (DATA/runs.db), sqlite:PATH or postgresql://... (forward.hpp: parse_store_uri)
    ProvenanceDefaults provenance = provenance_defaults();  // bench, host, DUT, operator of this service's runs
    std::string fixtures_dir;  // scenarios/, encoders/ (what {"fixture": NAME} and file references may name)
    std::string web_dir;       // static UI; web/vendor/ holds uPlot
    std::string token;         // bearer token for state changes (and for everything when not loopback-only)
    bool token_for_reads = false;  // bound beyond loopback
    std::size_t max_body_bytes = 1 << 20;             // JSON bodies
    std::uint64_t max_upload_bytes = 256ull << 20;    // capture uploads, streamed to disk
    // The most sample data one upload may expand to (a .sr's declared member sizes; .fcap and
    // CSV are their size on disk): 413 capture_too_large beyond it, before anything is inflated.
    std::uint64_t max_upload_expanded_bytes = 512ull << 20;
    unsigned workers = 2;
    bool allow_external = false;  // the `external` estimator runs a shell command: off over HTTP unless asked for
    // Devices a client's scenario may name besides loopback: and uploaded captures: glob
    // patterns over the device without its query (modbus+tcp://127.0.0.1:1502,
    // modbus+rtu:/dev/ttyUSB*, usb:1209:*). Fixtures are the operator's files and not limited.
    std::vector<std::string> allow_devices;
    // Host header names answered besides loopback names and the bound address (DNS rebinding).
    std::vector<std::string> allow_hosts;
    std::string bind_host;  // the bound address (HttpServer sets it); 0.0.0.0 / :: accept any IP literal
    // Per-run bounds (413 too_many_samples / too_many_estimators / too_many_limits) and the
    // largest report stored (a larger one ends the run as an error saying so).
    double max_samples = 1e9;
    std::size_t max_estimators = 16;
    std::size_t max_limits = 64;
    std::size_t max_report_bytes = 64u << 20;
    // Runs waiting to start, all together (429 queue_full with Retry-After beyond it; 0: no bound).
    std::size_t max_queued_runs = 64;
    // Uploaded captures, all together, each counted as the larger of its size on disk and what
    // it expands to (507 quota_exceeded beyond it).
    std::uint64_t upload_quota_bytes = 4ull << 30;
};

struct HttpRequest {
    std::string method, target;
    std::map<std::string, std::string> headers;  // keys lower case
    std::string body;
    std::string body_file;  // a streamed upload already on disk (captures)
};

struct HttpResponse {
    int status = 200;
    std::string content_type = "application/json";
    std::string body;
    std::vector<std::pair<std::string, std::string>> headers;
    std::string events_run;  // non-empty: stream this run's progress as server-sent events
};

HttpResponse json_error(int status, const std::string& code, const std::string& message, const std::string& field = "");

class Service {
public:
    explicit Service(ServiceConfig cfg);
    ~Service();
    Service(const Service&) = delete;
    Service& operator=(const Service&) = delete;

    HttpResponse handle(const HttpRequest& req);

    // Decided from the request line and headers, before any body is read: an answer that
    // ends the request early (token missing, body too large, unknown route), or nullopt.
    std::optional<HttpResponse> precheck(const HttpRequest& head, std::uint64_t content_length, bool has_length) const;
    // POST /api/v1/captures streams its body to a file instead of memory.
    bool is_upload(const std::string& method, const std::string& target) const;
    // Requests that may take long (read a capture or a large report, run an evaluation): the
    // HTTP front runs them on a worker pool, never on its I/O threads.
    bool is_heavy(const std::string& method, const std::string& target);
    // Bytes an upload may still take under upload_quota_bytes (uploaded captures on disk).
    std::uint64_t upload_room() const;
    std::string new_upload_path();  // in data_dir/captures, removed on failure

    // Progress of a run for the events stream; nullopt if the id is unknown.
    std::optional<RunSnapshot> run_state(const std::string& id);
    static std::string sse_event(const RunSnapshot& s);

    RunManager& runs() { return *runs_; }
    const ServiceConfig& config() const { return cfg_; }
    // The address the server listens on (before it serves): Host headers may name it.
    void set_bound_address(const std::string& host);
    // This start's instance id (stamped on its runs; instance_lock.hpp).
    const std::string& instance_id() const { return lock_.id(); }
    // Stops the queue: running runs end "interrupted" with their partial reports stored.
    void shutdown();

private:
    HttpResponse handle_request(const HttpRequest& req);
    std::optional<HttpResponse> check_host(const HttpRequest& req) const;
    // Makes a client's device URI safe to open here (capture:ID -> the uploaded file, board
    // profiles by name, other devices from allow_devices); throws naming scenario.device.
    std::string sandbox_device(const std::string& uri, const std::string& field = "scenario.device") const;
    // Text for a client: the service's absolute folders replaced by short names.
    std::string public_text(std::string s) const;
    HttpResponse route(const HttpRequest& req, const std::string& path, const std::map<std::string, std::string>& query);
    HttpResponse create_run(const HttpRequest& req);
    // The scenario a POST runs (or preflight) body describes, sandboxed and read (plan_scenario
    // checks it); a refusal that is not a ConfigError comes back as the response to send.
    std::optional<HttpResponse> run_scenario(const nlohmann::json& body, Scenario& sc) const;
    // POST preflight: the checks and warnings of POST runs, without starting anything.
    HttpResponse preflight_run(const HttpRequest& req) const;
    // The plan of a POST runs (or preflight) scenario: plan_run within this service's per-run
    // bounds. Beyond them: the 413 to send, naming the field where the client set the value
    // ("fixture" for a fixture); any other error throws as a ConfigError under "scenario".
    std::optional<HttpResponse> plan_scenario(const nlohmann::json& body, Scenario sc, std::optional<RunPlan>& plan) const;
    HttpResponse list_runs(const std::map<std::string, std::string>& query);
    HttpResponse get_run(const std::string& id);
    HttpResponse run_artifact(const std::string& id, const std::string& what, const std::map<std::string, std::string>& query);
    HttpResponse upload_capture(const HttpRequest& req, const std::map<std::string, std::string>& query);
    nlohmann::json captures() const;  // uploaded captures' info, newest first
    HttpResponse evaluate(const HttpRequest& req, const std::string& id);
    HttpResponse fixtures();
    HttpResponse fixture(const std::string& name);
    HttpResponse devices();
    HttpResponse static_file(const std::string& path) const;
    std::optional<HttpResponse> check_token(const HttpRequest& req, bool state_change) const;
    // Makes a client's scenario safe to run here: file references must stay inside
    // fixtures_dir, capture: devices must name an uploaded capture, `external` needs
    // allow_external. Throws ConfigError naming the field.
    nlohmann::json sandbox_scenario(nlohmann::json j) const;
    std::string capture_path(const std::string& id) const;  // "" if no such upload

    struct Cached {
        std::string json, json_full, xml, html, traces, metrics;
    };
    std::shared_ptr<const Cached> cached_report(const std::string& id);

    ServiceConfig cfg_;
    std::vector<std::pair<std::string, std::string>> public_names_;  // absolute folder -> name for clients, longest first
    InstanceLock lock_;  // DATA/lock for the service's lifetime: one service per data folder
    std::mutex store_mu_;
    std::unique_ptr<RunStore> store_;
    std::unique_ptr<RunManager> runs_;
    std::map<std::string, std::pair<std::string, std::string>> static_;  // url path -> (content type, bytes)
    std::mutex cache_mu_;
    std::map<std::string, std::pair<std::shared_ptr<const Cached>, std::list<std::string>::iterator>> cache_;
    std::list<std::string> lru_;
    std::mutex upload_mu_;
    std::mutex upload_quota_mu_;  // an upload's expanded-size check and its info file, as one step
    std::uint64_t upload_counter_ = 0;
};

// Bearer token: read from path, or created there (mode 0600, 256 random bits, hex) when
// absent. created is set when this call made it.
std::string load_or_create_token(const std::string& path, bool* created);
// A token file's text without trailing newline, CR or spaces (the service's and the
// clients' reading); throws std::runtime_error naming the file when it cannot be read.
std::string read_token_file(const std::string& path);

}  // namespace fringe
