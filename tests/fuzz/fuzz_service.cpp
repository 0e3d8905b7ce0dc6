// Fuzz target (d): fringe::Service::handle with arbitrary requests. Input, as text:
//   METHOD TARGET\n  then header lines "name: value\n" up to an empty line, then the body.
// Promises: handle() never throws; an error (4xx/5xx) has a JSON body {"error":{"code",
// "message",...}}; every application/json body is valid JSON (hence valid UTF-8).
// One Service for the whole run: a scratch data folder and the repository's fixtures/.
#include "fuzz_common.hpp"

#include "server/http/service.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <memory>
#include <string_view>

using nlohmann::json;

namespace {
constexpr const char* kToken = "fuzz0123456789abcdef0123456789ab";

fringe::Service& service() {
    static std::unique_ptr<fringe::Service> s = [] {
        fringe::ServiceConfig c;
        c.data_dir = fringe::fuzz::scratch_dir() + "/data";
        std::filesystem::create_directories(c.data_dir);
        c.fixtures_dir = FRINGE_SOURCE_DIR "/fixtures";
        c.web_dir = FRINGE_SOURCE_DIR "/web";
        c.token = kToken;
        c.workers = 1;
        c.max_body_bytes = 64 * 1024;
        c.max_upload_bytes = 1 << 20;
        return std::make_unique<fringe::Service>(c);
    }();
    return *s;
}

std::string_view next_line(std::string_view& in) {
    const auto nl = in.find('\n');
    std::string_view line = in.substr(0, nl);
    in.remove_prefix(nl == std::string_view::npos ? in.size() : nl + 1);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    return line;
}

fringe::HttpRequest request_from(std::string_view in) {
    fringe::HttpRequest r;
    const std::string_view first = next_line(in);
    const auto sp = first.find(' ');
    r.method = std::string(first.substr(0, sp));
    r.target = sp == std::string_view::npos ? "/" : std::string(first.substr(sp + 1));
    for (int k = 0; k < 16 && !in.empty(); ++k) {
        const std::string_view h = next_line(in);
        if (h.empty()) break;
        const auto colon = h.find(':');
        std::string name(h.substr(0, colon));
        std::transform(name.begin(), name.end(), name.begin(), [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
        std::string_view value = colon == std::string_view::npos ? std::string_view() : h.substr(colon + 1);
        while (!value.empty() && value.front() == ' ') value.remove_prefix(1);
        r.headers[name] = std::string(value);
    }
    r.body = std::string(in);
    return r;
}

void check_response(const fringe::HttpRequest& req, const fringe::HttpResponse& res) {
    const std::string where = req.method + " " + req.target + " -> " + std::to_string(res.status) + ": ";
    if (res.status < 100 || res.status > 599) fringe::fuzz::fail(where + "not an HTTP status");
    if (!res.events_run.empty()) return;  // a server-sent event stream, no body here
    const bool is_json = res.content_type.rfind("application/json", 0) == 0;
    if (res.status >= 400 && !is_json) fringe::fuzz::fail(where + "error with content type " + res.content_type);
    if (!is_json) return;
    const json body = json::parse(res.body, nullptr, false);  // also rejects invalid UTF-8
    if (body.is_discarded()) fringe::fuzz::fail(where + "application/json body is not valid JSON (or not UTF-8)");
    if (res.status >= 400) {
        if (!body.is_object() || !body.contains("error") || !body["error"].is_object() ||
            !body["error"].contains("code") || !body["error"]["code"].is_string() ||
            !body["error"].contains("message") || !body["error"]["message"].is_string())
            fringe::fuzz::fail(where + "error body is not {\"error\":{\"code\",\"message\"}}: " + res.body);
    }
    // A run the input managed to create is cancelled and waited for: runs would pile up on the
    // CPU, and one still running at exit would outlive the statics it uses.
    if (res.status == 201 && body.is_object() && body.contains("id") && body["id"].is_string() &&
        req.target.rfind("/api/v1/runs", 0) == 0) {
        const std::string id = body["id"].get<std::string>();
        service().runs().cancel(id);
        std::uint64_t seq = 0;
        for (int k = 0; k < 300; ++k) {
            const auto s = service().runs().wait_change(id, seq, 100);
            if (!s || s->finished()) return;
            seq = s->seq;
        }
        fringe::fuzz::fail(where + "a cancelled run did not finish within 30 s");
    }
}
}  // namespace

// The service's run workers stopped and joined before main() returns (replay_main.cpp): a
// worker finishing a run's bookkeeping after its run reported "finished" used statics that
// exit was already destroying (a crash seen once in CI under load).
extern "C" void FringeFuzzTeardown() { service().shutdown(); }

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const fringe::HttpRequest req = request_from(std::string_view(reinterpret_cast<const char*>(data), size));
    fringe::HttpResponse res;
    try {
        res = service().handle(req);
    } catch (const std::exception& e) {
        fringe::fuzz::fail("handle() threw for " + req.method + " " + req.target + ": " + e.what());
    } catch (...) {
        fringe::fuzz::fail("handle() threw a non-std exception for " + req.method + " " + req.target);
    }
    check_response(req, res);
    return 0;
}
