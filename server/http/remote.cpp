#include "server/http/remote.hpp"

#include "server/report/report_formats.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include <chrono>
#include <thread>

namespace fringe {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using nlohmann::json;

std::string ServiceUrl::text() const {
    const bool v6 = host.find(':') != std::string::npos;
    return "http://" + (v6 ? "[" + host + "]" : host) + ":" + port + prefix + "/";
}

ServiceUrl parse_service_url(const std::string& url) {
    const std::string scheme = "http://";
    if (url.rfind("https://", 0) == 0)
        throw ConfigError("server", "'" + url + "': https is not supported; fringe serve speaks plain HTTP (tunnel a remote bench, e.g. ssh -L 8080:127.0.0.1:8080)");
    if (url.rfind(scheme, 0) != 0) throw ConfigError("server", "'" + url + "': expected http://HOST[:PORT][/PREFIX]");
    ServiceUrl u;
    std::string rest = url.substr(scheme.size());
    const auto slash = rest.find('/');
    std::string authority = rest.substr(0, slash);
    u.prefix = slash == std::string::npos ? "" : rest.substr(slash);
    while (!u.prefix.empty() && u.prefix.back() == '/') u.prefix.pop_back();
    std::string port;
    if (!authority.empty() && authority.front() == '[') {  // [v6]:port
        const auto close = authority.find(']');
        if (close == std::string::npos) throw ConfigError("server", "'" + url + "': unclosed [ in the host");
        u.host = authority.substr(1, close - 1);
        const std::string after = authority.substr(close + 1);
        if (!after.empty()) {
            if (after.front() != ':') throw ConfigError("server", "'" + url + "': expected :PORT after ]");
            port = after.substr(1);
        }
    } else {
        const auto colon = authority.rfind(':');
        u.host = authority.substr(0, colon);
        if (colon != std::string::npos) port = authority.substr(colon + 1);
    }
    if (u.host.empty()) throw ConfigError("server", "'" + url + "': no host");
    if (!port.empty()) {
        const bool digits = port.find_first_not_of("0123456789") == std::string::npos && port.size() <= 5;
        const int number = digits ? std::stoi(port) : 0;
        if (number < 1 || number > 65535)
            throw ConfigError("server", "'" + url + "': port '" + port + "' is not 1-65535");
        u.port = port;
    }
    return u;
}

ServiceClient::ServiceClient(ServiceUrl url, std::string token, int timeout_ms)
    : url_(std::move(url)), token_(std::move(token)), timeout_ms_(timeout_ms) {}

HttpReply ServiceClient::request(const std::string& method, const std::string& path, const std::string& body) {
    net::io_context ioc;
    tcp::resolver resolver(ioc);
    beast::tcp_stream stream(ioc);
    const auto timeout = std::chrono::milliseconds(timeout_ms_);
    try {
        const auto endpoints = resolver.resolve(url_.host, url_.port);
        stream.expires_after(timeout);
        stream.connect(endpoints);
        http::request<http::string_body> req{method == "POST" ? http::verb::post : http::verb::get, url_.prefix + "/api/v1/" + path, 11};
        const bool v6 = url_.host.find(':') != std::string::npos;
        req.set(http::field::host, (v6 ? "[" + url_.host + "]" : url_.host) + ":" + url_.port);
        req.set(http::field::user_agent, "fringe-cli");
        if (!token_.empty()) req.set(http::field::authorization, "Bearer " + token_);
        if (method == "POST") {
            req.set(http::field::content_type, "application/json");
            req.body() = body;
            req.prepare_payload();
        }
        stream.expires_after(timeout);
        http::write(stream, req);
        beast::flat_buffer buf;
        http::response_parser<http::string_body> parser;
        parser.body_limit(256ull << 20);
        http::read(stream, buf, parser);
        auto& res = parser.get();
        beast::error_code ignored;
        stream.socket().shutdown(tcp::socket::shutdown_both, ignored);
        return {static_cast<int>(res.result_int()), std::string(res[http::field::content_type]), std::move(res.body())};
    } catch (const boost::system::system_error& e) {
        throw RemoteError("fringe serve at " + url_.text() + ": " + method + " " + path + ": " + e.code().message());
    }
}

json ServiceClient::call(const std::string& method, const std::string& path, const json* body) {
    const HttpReply r = request(method, path, body ? body->dump() : std::string());
    json j = json(json::value_t::discarded);
    try {  // an answer nested without bound would recurse in every copy
        j = parse_json_bounded(r.body, "", kMaxStoredJsonDepth);
    } catch (const ConfigError&) {
    }
    if (r.status >= 200 && r.status < 300 && !j.is_discarded()) return j;
    std::string what = "fringe serve at " + url_.text() + ": " + method + " " + path + ": HTTP " + std::to_string(r.status);
    if (!j.is_discarded() && j.contains("error") && j["error"].is_object()) {
        const json& e = j["error"];
        what += " " + e.value("code", std::string()) + ": " + e.value("message", std::string());
        if (e.contains("field") && e["field"].is_string() && !e["field"].get<std::string>().empty()) what += " (" + e["field"].get<std::string>() + ")";
    } else {
        what += ": " + r.body.substr(0, 200);
    }
    if (r.status == 401) what += "; give the service's token with --token-file (fringe serve prints where it keeps it)";
    throw RemoteError(what, r.status);
}

json run_remote(ServiceClient& client, const json& scenario, const RemoteRunOptions& o) {
    const json body{{"scenario", scenario}};
    const json created = client.call("POST", "runs", &body);
    const std::string id = created.at("id").get<std::string>();
    bool cancelled = false;
    int transport_failures = 0;
    for (;;) {
        if (o.cancel && o.cancel->load() && !cancelled) {
            const json none = json::object();
            client.call("POST", "runs/" + id + "/cancel", &none);
            cancelled = true;
        }
        json s;
        try {
            s = client.call("GET", "runs/" + id);
            transport_failures = 0;
        } catch (const RemoteError& e) {
            // A service restarting or a moment of congestion is not the end of the run; a
            // service gone for ~5 s is, and so is any 4xx (the run is unknown there).
            if ((e.http_status > 0 && e.http_status < 500) || ++transport_failures >= 25) throw RemoteError(std::string(e.what()) + " (waiting for run " + id + ")");
            std::this_thread::sleep_for(std::chrono::milliseconds(o.poll_ms));
            continue;
        }
        const std::string status = s.value("status", std::string());
        if (status != "queued" && status != "running") break;
        if (o.progress && s.contains("progress"))
            o.progress(s["progress"].value("done", std::uint64_t{0}), s["progress"].value("total", std::uint64_t{0}));
        std::this_thread::sleep_for(std::chrono::milliseconds(o.poll_ms));
    }
    json report = client.call("GET", "runs/" + id + "/report.json");
    const auto fetch = [&](const std::string& what, const std::string& file) {
        if (file.empty()) return;
        const HttpReply r = client.request("GET", "runs/" + id + "/" + what);
        if (r.status != 200) throw RemoteError("fringe serve at " + client.url().text() + ": GET runs/" + id + "/" + what + ": HTTP " + std::to_string(r.status), r.status);
        write_file_atomic(file, r.body);
    };
    fetch("report.xml", o.junit);
    fetch("report.html", o.html);
    return report;
}

}  // namespace fringe
