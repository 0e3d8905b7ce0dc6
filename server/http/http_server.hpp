// Boost.Beast front of the Service (the only translation unit that includes Beast): async
// HTTP/1.1 with keep-alive, one strand and a timeout per connection, body limits checked
// from the headers before a body is read, slow bodies cut off (408), capture uploads
// streamed to disk, heavy requests handed to a worker pool (the I/O threads only move
// bytes), a bound on connections (in all and per client address), a header deadline,
// duplicate security-relevant headers refused, server-sent progress events, and a clean shutdown on
// SIGINT/SIGTERM or stop().
#pragma once

#include "server/http/service.hpp"

#include <memory>
#include <string>

namespace fringe {

struct HttpServerOptions {
    std::string bind = "127.0.0.1:8080";  // host:port, [v6]:port; port 0 picks a free one
    unsigned threads = 2;
    int read_timeout_s = 30;     // per request (header + body), and idle keep-alive
    // A request's whole header must arrive within this many seconds of the connection opening
    // or of its last answer (trickling a byte at a time does not extend it): slow-header
    // clients give their connection back quickly.
    int header_timeout_s = 10;
    int event_poll_ms = 25;      // how often an events stream looks for progress
    bool handle_signals = true;  // SIGINT/SIGTERM stop the server
    // Slow bodies (408 body_timeout, then close): a JSON body must arrive within
    // body_timeout_s; an upload must average upload_min_bytes_per_s once body_timeout_s
    // have passed (and may take as long as it needs at that rate).
    int body_timeout_s = 10;
    double upload_min_bytes_per_s = 64 * 1024;
    // Connections served at once; one more gets 503 too_many_connections and is closed.
    unsigned max_connections = 256;
    // Connections served at once from one source address; one more gets 503
    // too_many_connections (client) and is closed, so one client cannot take every slot.
    unsigned max_connections_per_client = 32;
    // Requests the service marks heavy (uploads, evaluations, first report reads) run on
    // this many pool threads, never on the I/O threads (0: the service's run workers);
    // beyond max_pending_work waiting, 503 busy.
    unsigned work_threads = 0;
    std::size_t max_pending_work = 64;
    int accept_backoff_ms = 100;  // accept failed (no file descriptors left): wait, do not spin
};

// True if host (as in bind) is a loopback address.
bool is_loopback_bind(const std::string& bind);

class HttpServer {
public:
    HttpServer(Service& service, HttpServerOptions o);  // binds; throws std::runtime_error naming the address
    ~HttpServer();
    unsigned short port() const;
    std::string url() const;
    void run();   // serves until stop() or a signal; then shuts the service down
    void stop();  // thread-safe

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace fringe
