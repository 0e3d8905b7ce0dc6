// A client for `fringe serve`: `fringe run SCENARIO --server URL` sends a local scenario to a
// bench's service, follows the run, and fetches its report, so a CI job gets the verdict and
// the report files as if the run had been local. Plain HTTP/1.1 over TCP (Boost.Beast); for a
// bench beyond this host, tunnel it (ssh -L) rather than expose the service.
#pragma once

#include <nlohmann/json.hpp>

#include <atomic>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>

namespace fringe {

// "http://host[:port][/prefix]" (host may be [v6]); anything else throws ConfigError("server").
struct ServiceUrl {
    std::string host, port = "80", prefix;  // prefix: "" or "/path" without a trailing slash
    std::string text() const;               // "http://host:port/prefix/"
};
ServiceUrl parse_service_url(const std::string& url);

// A transport problem (refused, timed out, connection lost; http_status 0) or an error reply
// (http_status 4xx/5xx); the message names the server and the request.
class RemoteError : public std::runtime_error {
public:
    explicit RemoteError(const std::string& what, int status = 0) : std::runtime_error(what), http_status(status) {}
    int http_status;
};

struct HttpReply {
    int status = 0;
    std::string content_type, body;
};

class ServiceClient {
public:
    ServiceClient(ServiceUrl url, std::string token, int timeout_ms = 10000);
    // One request on its own connection; path is below /api/v1/ ("runs/ID"). Throws RemoteError.
    HttpReply request(const std::string& method, const std::string& path, const std::string& body = "");
    // A JSON request that must succeed (2xx); a service error becomes a RemoteError quoting
    // the service's {"error": {code, message, field}} and the HTTP status.
    nlohmann::json call(const std::string& method, const std::string& path, const nlohmann::json* body = nullptr);
    const ServiceUrl& url() const { return url_; }

private:
    ServiceUrl url_;
    std::string token_;
    int timeout_ms_;
};

struct RemoteRunOptions {
    std::string junit, html;  // also fetch these formats (report.xml, report.html) into these files
    std::atomic<bool>* cancel = nullptr;  // set: cancel the run on the service, then wait for its end
    std::function<void(std::uint64_t done, std::uint64_t total)> progress;
    int poll_ms = 200;
};

// Submits {"scenario": scenario}, waits for the run to end, returns its report (report.json).
// Writes the JUnit and HTML files when asked. Throws RemoteError (transport, HTTP errors).
nlohmann::json run_remote(ServiceClient& client, const nlohmann::json& scenario, const RemoteRunOptions& o);

}  // namespace fringe
