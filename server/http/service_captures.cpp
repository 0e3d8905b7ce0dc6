// The service's capture store (service.hpp): uploads streamed to DATA/captures within a quota,
// listed, and evaluated on the worker pool.
#include "server/http/service_internal.hpp"

#include "drivers/capture_file.hpp"
#include "estimator/estimator.hpp"
#include "server/engine/capture_run.hpp"
#include "server/report/report_formats.hpp"
#include "server/engine/run.hpp"

#include <spdlog/spdlog.h>

#include <unistd.h>

#include <chrono>
#include <cstdio>

namespace fringe {

using namespace service_detail;

std::uint64_t Service::upload_room() const {
    // Bytes on disk, and for each kept capture what it expands to beyond them (a .sr's sample
    // data as declared, recorded at upload): a 1 MB ZIP that holds 1 GiB of samples counts 1 GiB.
    std::uint64_t used = 0;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(fs::path(cfg_.data_dir) / "captures", ec)) {
        std::error_code sec;
        if (!e.is_regular_file(sec)) continue;
        used += e.file_size(sec);
        const std::string name = e.path().filename().string();
        if (name.size() > 12 && name.compare(name.size() - 12, 12, ".upload.json") == 0) {
            const json info = json::parse(read_file(e.path()), nullptr, false);
            if (info.is_object() && info.contains("expanded_bytes") && info["expanded_bytes"].is_number_unsigned() &&
                info.contains("bytes") && info["bytes"].is_number_unsigned()) {
                const auto expanded = info["expanded_bytes"].get<std::uint64_t>(), bytes = info["bytes"].get<std::uint64_t>();
                if (expanded > bytes) used += expanded - bytes;
            }
        }
    }
    return used >= cfg_.upload_quota_bytes ? 0 : cfg_.upload_quota_bytes - used;
}

std::string Service::new_upload_path() {
    std::lock_guard<std::mutex> l(upload_mu_);
    return (fs::path(cfg_.data_dir) / "captures" / (".upload-" + std::to_string(getpid()) + "-" + std::to_string(++upload_counter_))).string();
}

std::string Service::capture_path(const std::string& id) const {
    for (const char* ext : {".fcap", ".csv", ".sr"}) {
        const fs::path p = fs::path(cfg_.data_dir) / "captures" / (id + ext);
        if (fs::is_regular_file(p)) return fs::absolute(p).string();
    }
    return "";
}

HttpResponse Service::upload_capture(const HttpRequest& req, const std::map<std::string, std::string>& query) {
    struct Cleanup {
        std::string path;
        ~Cleanup() {
            std::error_code ec;
            if (!path.empty()) fs::remove(path, ec);
        }
    } tmp;
    std::string src = req.body_file;
    if (src.empty()) {  // handle() called with the body in memory (tests): write it out
        src = new_upload_path();
        std::ofstream(src, std::ios::binary) << req.body;
    }
    tmp.path = src;
    for (const auto& [k, v] : query)
        if (k != "format") throw ConfigError(k, "unknown query parameter (known: format)");
    std::string format;
    if (auto it = query.find("format"); it != query.end()) {
        format = it->second;
        if (format != "csv" && format != "fcap" && format != "sr") throw ConfigError("format", "expected csv, fcap or sr");
    } else {
        std::ifstream f(src, std::ios::binary);
        char magic[8] = {};
        f.read(magic, 8);
        // A ZIP's local file header: a sigrok session (.sr).
        format = std::string(magic, 8) == "FRNGCAP1" ? "fcap" : std::string(magic, 4) == std::string("PK\x03\x04", 4) ? "sr" : "csv";
    }
    if (fs::file_size(src) == 0) throw ConfigError("body", "the upload is empty");
    const std::string id = new_run_id();
    const fs::path dst = fs::path(cfg_.data_dir) / "captures" / (id + "." + format);
    fs::rename(src, dst);
    tmp.path = dst.string();
    const std::uint64_t disk_bytes = fs::file_size(dst);
    // Name what the client sent, not our file name.
    auto client_text = [&](std::string msg) {
        if (auto pos = msg.find(dst.string()); pos != std::string::npos) msg.replace(pos, dst.string().size(), "upload");
        return msg;
    };
    auto quota_error = [&](std::uint64_t expanded) {
        return json_error(507, "quota_exceeded", "the upload expands to " + std::to_string(expanded) + " bytes of sample data; uploaded captures may take " +
                                                     std::to_string(cfg_.upload_quota_bytes) + " bytes together, counted as they expand, and " +
                                                     std::to_string(upload_room() + disk_bytes) + " are left (--upload-quota-mb)");
    };
    // Validated block by block: memory stays at one block whatever the capture holds, and a
    // compressed one is refused by its declared sizes before anything is inflated.
    CaptureOptions opts;
    opts.max_expanded_bytes = cfg_.max_upload_expanded_bytes;
    std::uint64_t samples = 0, expanded = 0;
    double fs_hz = 0;
    bool has_truth = false;
    try {
        CaptureReader reader(dst.string(), opts);
        expanded = std::max(reader.expanded_bytes(), disk_bytes);
        if (expanded - disk_bytes > upload_room()) return quota_error(expanded);
        CaptureData block;
        while (reader.read(1 << 16, block)) samples += block.size();
        if (samples == 0) throw CaptureError(dst.string() + ": no samples");
        fs_hz = reader.sample_rate_hz();
        has_truth = reader.columns().theta_true;
    } catch (const CaptureTooLarge& e) {
        return json_error(413, "capture_too_large", client_text(e.what()) + " (--max-upload-expanded-mb)");
    } catch (const CaptureError& e) {
        return json_error(400, "bad_capture", client_text(e.what()));
    }
    const json info{{"id", id}, {"format", format}, {"samples", samples}, {"sample_rate_hz", fs_hz}, {"has_truth", has_truth},
                    {"bytes", disk_bytes}, {"expanded_bytes", expanded}, {"uploaded_at", iso_now()}};
    {
        // Two uploads validated at once each saw the other's file by its disk size only:
        // decide the expanded quota and record the info as one step.
        std::lock_guard<std::mutex> l(upload_quota_mu_);
        if (expanded - disk_bytes > upload_room()) return quota_error(expanded);
        write_file_atomic((fs::path(cfg_.data_dir) / "captures" / (id + ".upload.json")).string(), info.dump());
    }
    tmp.path.clear();  // keep it
    auto r = json_ok(info, 201);
    r.headers.emplace_back("Location", "/api/v1/captures/" + id);
    return r;
}

json Service::captures() const {
    json list = json::array();
    const fs::path dir = fs::path(cfg_.data_dir) / "captures";
    std::vector<fs::path> infos;
    for (const auto& e : fs::directory_iterator(dir)) {
        const auto name = e.path().filename().string();
        if (name.size() > 12 && name.compare(name.size() - 12, 12, ".upload.json") == 0) infos.push_back(e.path());
    }
    std::sort(infos.rbegin(), infos.rend());
    for (const auto& p : infos) {
        try {
            list.push_back(parse_json_bounded(read_file(p), p.string(), kMaxStoredJsonDepth));
        } catch (const ConfigError&) {  // not one the service wrote: not listed
        }
    }
    return list;
}

HttpResponse Service::evaluate(const HttpRequest& req, const std::string& id) {
    const std::string cap = capture_path(id);
    if (cap.empty()) return json_error(404, "not_found", "no uploaded capture " + id, "id");
    const json body = parse_body(req.body);
    only_keys(body, {"estimator", "params", "encoder", "settle_s", "interface"}, "");
    CaptureRunOptions o;
    o.capture_path = cap;
    o.capture.max_expanded_bytes = cfg_.max_upload_expanded_bytes;  // it was checked against this at upload
    if (!body.contains("estimator") || !body["estimator"].is_string()) throw ConfigError("estimator", "expected an estimator name (GET /api/v1/estimators)");
    o.estimator = body["estimator"].get<std::string>();
    if (est::find(o.estimator).traits.child_process && !cfg_.allow_external)  // find throws ConfigError naming the known ones
        throw ConfigError("estimator", "the " + o.estimator + " estimator runs a command on this host; start the service with --allow-external");
    if (body.contains("params")) {
        if (!body["params"].is_object()) throw ConfigError("params", "expected an object");
        o.params = body["params"];
    }
    if (body.contains("settle_s")) {
        if (!body["settle_s"].is_number() || body["settle_s"].get<double>() < 0) throw ConfigError("settle_s", "expected a number >= 0");
        o.settle_s = body["settle_s"].get<double>();
    }
    if (body.contains("encoder")) {
        json enc = body["encoder"];
        if (enc.is_string()) {
            const std::string name = enc.get<std::string>();
            const fs::path p = fs::path(cfg_.fixtures_dir) / "encoders" / (name + ".json");
            if (!valid_id(name) || !fs::is_regular_file(p)) throw ConfigError("encoder", "no encoder fixture named '" + name + "'");
            o.encoder = load_encoder(p.string());
        } else {
            o.encoder = encoder_from_json(enc, "encoder");
        }
    }
    if (body.contains("interface")) {  // a profile of fixtures/interfaces (GET /api/v1/fixtures lists them), or one inline
        const json& itf = body["interface"];
        if (itf.is_string()) {
            const std::string name = itf.get<std::string>();
            const fs::path p = fs::path(cfg_.fixtures_dir) / "interfaces" / (name + ".json");
            if (!valid_id(name) || !fs::is_regular_file(p)) throw ConfigError("interface", "no interface profile named '" + name + "' (GET /api/v1/fixtures lists them)");
            o.interface = load_interface(p.string());
        } else if (itf.is_object()) {
            o.interface = interface_from_json(itf, "interface");
        } else {
            throw ConfigError("interface", "expected an interface profile's name or an object");
        }
    }
    // The run's report; a run that failed part way (the estimator's process died) is a report
    // with status "error", as for any run.
    json rep = run_capture(o);
    rep["capture"]["id"] = id;
    // Without the plot data, as GET runs/{id}/report.json: the figures, not 0.5 MB of traces.
    rep.erase("traces");
    for (auto& e : rep["estimators"]) e.erase("spectrum");
    // The service's folders by their short names (DATA/captures/ID.csv), as every report it serves.
    return json_ok(json::parse(public_text(rep.dump(-1, ' ', false, json::error_handler_t::replace))));
}

}  // namespace fringe
