// fringe serve: the JSON/HTTP API and the browser UI, running scenarios from a queue.
#include "server/cli/commands.hpp"
#include "drivers/device.hpp"
#include "server/http/http_server.hpp"
#include "server/http/service.hpp"
#include "signal_gen/base/text.hpp"

#include <algorithm>
#include <cstdio>
#include <spdlog/pattern_formatter.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <thread>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct ServeOptions {
    std::string bind = "127.0.0.1:8080", data, store, bench, dut, dut_part, operator_name, token_file, fixtures = FRINGE_SOURCE_DIR "/fixtures", web = FRINGE_SOURCE_DIR "/web";
    unsigned workers = 0, threads = 2;
    double max_upload_mb = 256, max_upload_expanded_mb = 512, upload_quota_mb = 4096, max_report_mb = 64;
    double max_samples = 1e9;
    std::size_t max_estimators = 16, max_limits = 64;
    unsigned max_connections = 256, max_connections_per_client = 32;
    std::size_t max_queued_runs = 64;
    int body_timeout_s = 10, header_timeout_s = 10;
    double upload_min_kib_s = 64;
    bool allow_external = false;
    std::vector<std::string> allow_device, allow_host;
};

// The service logs what requests carry (targets, scenario names, messages): one line per
// event, control characters escaped, so a request cannot forge or split log lines.
class EscapedPayload : public spdlog::custom_flag_formatter {
public:
    void format(const spdlog::details::log_msg& msg, const std::tm&, spdlog::memory_buf_t& dest) override {
        const std::string e = log_escape(std::string_view(msg.payload.data(), msg.payload.size()));
        dest.append(e.data(), e.data() + e.size());
    }
    std::unique_ptr<custom_flag_formatter> clone() const override { return std::make_unique<EscapedPayload>(); }
};

int run_serve(const ServeOptions& o) {
    auto formatter = std::make_unique<spdlog::pattern_formatter>();
    formatter->add_flag<EscapedPayload>('*').set_pattern("%^%l%$: %*");
    spdlog::default_logger()->set_formatter(std::move(formatter));
    // Everything the service creates (run store, uploads, locks) is for its user only, like the token.
    ::umask(077);
    ServiceConfig cfg;
    cfg.data_dir = o.data.empty() ? default_data_dir() : o.data;
    cfg.store_uri = o.store;
    if (!o.bench.empty()) cfg.provenance.bench = o.bench;
    if (!o.dut.empty()) cfg.provenance.dut = o.dut;
    if (!o.dut_part.empty()) cfg.provenance.dut_part = o.dut_part;
    if (!o.operator_name.empty()) cfg.provenance.operator_name = o.operator_name;
    cfg.fixtures_dir = o.fixtures;
    cfg.web_dir = o.web;
    cfg.workers = o.workers ? o.workers : std::max(1u, std::thread::hardware_concurrency());
    cfg.max_upload_bytes = static_cast<std::uint64_t>(o.max_upload_mb * 1024 * 1024);
    cfg.max_upload_expanded_bytes = static_cast<std::uint64_t>(std::min(o.max_upload_expanded_mb * 1048576.0, 1.8e19));
    cfg.allow_external = o.allow_external;
    cfg.allow_devices = o.allow_device;
    cfg.allow_hosts = o.allow_host;
    cfg.max_samples = o.max_samples;
    cfg.max_estimators = o.max_estimators;
    cfg.max_limits = o.max_limits;
    cfg.max_report_bytes = static_cast<std::size_t>(o.max_report_mb * 1024 * 1024);
    cfg.max_queued_runs = o.max_queued_runs;
    cfg.upload_quota_bytes = static_cast<std::uint64_t>(o.upload_quota_mb * 1024 * 1024);
    cfg.token_for_reads = !is_loopback_bind(o.bind);
    const std::string token_file = o.token_file.empty() ? cfg.data_dir + "/token" : o.token_file;
    bool created = false;
    cfg.token = load_or_create_token(token_file, &created);
    Service svc(cfg);
    HttpServerOptions ho;
    ho.bind = o.bind;
    ho.threads = o.threads;
    ho.max_connections = o.max_connections;
    ho.max_connections_per_client = o.max_connections_per_client;
    ho.header_timeout_s = o.header_timeout_s;
    ho.body_timeout_s = o.body_timeout_s;
    ho.upload_min_bytes_per_s = o.upload_min_kib_s * 1024;
    HttpServer server(svc, ho);
    std::printf("fringe %s serving %s (data %s, %u run workers)\n", FRINGE_VERSION, server.url().c_str(), cfg.data_dir.c_str(), cfg.workers);
    if (!cfg.store_uri.empty())
        std::printf("run store %s; bench %s\n", parse_store_uri(cfg.store_uri, cfg.data_dir).kind == StoreUri::Kind::Postgres
                                                   ? (redact_store_uri(cfg.store_uri) + " (through DATA/runs.db, forwarded)").c_str() : cfg.store_uri.c_str(),
                    cfg.provenance.bench.c_str());
    if (created)
        std::printf("API token (printed this once; stored in %s, mode 0600): %s\nopen %s#token=%s\n", token_file.c_str(), cfg.token.c_str(),
                    server.url().c_str(), cfg.token.c_str());
    else
        std::printf("API token: in %s (send Authorization: Bearer <token>; paste it into the UI once)\n", token_file.c_str());
    if (cfg.token_for_reads) std::printf("bound beyond loopback: every API request needs the token\n");
    std::string devices = "loopback:, uploaded captures";
    for (const auto& d : cfg.allow_devices) devices += ", " + d;
    std::printf("devices clients may use: %s (--allow-device adds more)\n", devices.c_str());
    std::fflush(stdout);
    server.run();
    std::printf("fringe serve: stopped\n");
    return kExitOk;
}

}  // namespace

Command add_serve(CLI::App& app) {
    auto o = std::make_shared<ServeOptions>();
    auto* sv = app.add_subcommand("serve", "Serve the JSON/HTTP API and the browser UI; run scenarios from a queue");
    sv->add_option("--bind", o->bind, "host:port to listen on; beyond loopback every request needs the token")->capture_default_str();
    sv->add_option("--data", o->data, "Data directory: run history, uploads, token (default $FRINGE_DATA or ~/.local/share/fringe)");
    sv->add_option("--store", o->store, "Run store: sqlite:PATH, or a PostgreSQL shared by benches (postgresql://...): runs are written to DATA/runs.db "
                                        "first and forwarded; the UI and API list every bench's runs");
    sv->add_option("--bench", o->bench, "This bench's name in run provenance (default $FRINGE_BENCH, else the host name)");
    sv->add_option("--dut", o->dut, "DUT serial for runs whose scenario names none (default the device's board id)");
    sv->add_option("--dut-part", o->dut_part, "DUT part number for runs whose scenario names none");
    sv->add_option("--operator", o->operator_name, "Operator in run provenance (default $USER)");
    sv->add_option("--token-file", o->token_file, "Bearer token file (default DATA/token; created with mode 0600 when absent)");
    sv->add_option("--fixtures", o->fixtures, "Fixtures folder ({\"fixture\": NAME} and file references resolve here)")->capture_default_str();
    sv->add_option("--web", o->web, "Browser UI folder")->capture_default_str();
    sv->add_option("--workers", o->workers, "Runs executed in parallel (default: cores); runs on one board always queue");
    sv->add_option("--threads", o->threads, "HTTP I/O threads")->check(CLI::Range(1, 64))->capture_default_str();
    sv->add_option("--max-upload-mb", o->max_upload_mb, "Largest capture upload, MiB")->check(kFinitePositive)->capture_default_str();
    sv->add_option("--max-upload-expanded-mb", o->max_upload_expanded_mb,
                   "Most sample data one upload may expand to, MiB: a sigrok .sr's members as declared (.fcap and CSV: their size); "
                   "413 capture_too_large beyond, before anything is inflated")
        ->check(kFinitePositive)->capture_default_str();
    sv->add_option("--upload-quota-mb", o->upload_quota_mb, "All uploaded captures together, each counted as it expands (at least its size on disk), MiB "
                                                            "(507 quota_exceeded beyond)")
        ->check(kFinitePositive)->capture_default_str();
    sv->add_option("--max-samples", o->max_samples, "Samples per run (duration_s x sample_rate_hz; 413 too_many_samples beyond)")
        ->check(kFinitePositive)->capture_default_str();
    sv->add_option("--max-estimators", o->max_estimators, "Estimators per run (413 too_many_estimators beyond)")->check(CLI::Range(1, 1000))->capture_default_str();
    sv->add_option("--max-limits", o->max_limits, "Limits per run (413 too_many_limits beyond)")->check(CLI::Range(1, 10000))->capture_default_str();
    sv->add_option("--max-report-mb", o->max_report_mb, "Largest report stored, MiB (a larger one ends the run as an error)")
        ->check(kFinitePositive)->capture_default_str();
    sv->add_option("--max-connections", o->max_connections, "Connections served at once; more get 503 and are closed")
        ->check(CLI::Range(1, 100000))->capture_default_str();
    sv->add_option("--max-connections-per-client", o->max_connections_per_client,
                   "Connections served at once from one client address; more get 503 and are closed")
        ->check(CLI::Range(1, 100000))->capture_default_str();
    sv->add_option("--header-timeout", o->header_timeout_s, "Seconds a request's whole header may take to arrive (and a kept-alive connection may idle); then closed")
        ->check(CLI::Range(1, 3600))->capture_default_str();
    sv->add_option("--max-queued-runs", o->max_queued_runs, "Runs waiting to start, all together (429 queue_full with Retry-After beyond)")
        ->check(CLI::Range(1, 1000000))->capture_default_str();
    sv->add_option("--body-timeout", o->body_timeout_s, "Seconds a JSON body may take to arrive; also the grace before the upload rate applies (408 beyond)")
        ->check(CLI::Range(1, 3600))->capture_default_str();
    sv->add_option("--upload-min-kibps", o->upload_min_kib_s, "Slowest average upload rate accepted after --body-timeout seconds, KiB/s (408 below)")
        ->check(kFiniteNonNegative)->capture_default_str();
    sv->add_flag("--allow-external", o->allow_external, "Allow the external estimator (runs a command on this host) in HTTP requests");
    sv->add_option("--allow-device", o->allow_device,
                   "Let clients' scenarios use devices matching this glob (repeatable): modbus+tcp://HOST:PORT, modbus+rtu:/dev/ttyUSB*, usb:1209:*; "
                   "loopback: and uploaded captures always, fixtures' devices are the operator's")
        ->allow_extra_args(false)
        ->check([](const std::string& p) -> std::string {
            const auto colon = p.find(':');
            const std::string scheme = colon == std::string::npos ? "" : p.substr(0, colon);
            for (const auto& d : dev::drivers())
                if (d.scheme == scheme && scheme != "loopback" && scheme != "capture") return "";
            return "'" + p + "' is not a device pattern: expected modbus+tcp://HOST:PORT, modbus+rtu:/dev/PATH or usb:VID:PID (globs * and ? allowed)";
        });
    sv->add_option("--allow-host", o->allow_host,
                   "Answer requests whose Host header names this (repeatable), besides localhost, 127.0.0.1, [::1] and the bound address")
        ->allow_extra_args(false)
        ->check([](const std::string& h) -> std::string {
            const bool ok = !h.empty() && std::all_of(h.begin(), h.end(), [](char c) {
                return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_' || c == ':' || c == '[' || c == ']';
            });
            return ok ? "" : "'" + h + "' is not a host name";
        });
    return {sv, [o] { return run_serve(*o); }};
}

}  // namespace fringe::cli
