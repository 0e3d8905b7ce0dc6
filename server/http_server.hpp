// Boost.Beast front of the Service (the only translation unit that includes Beast): async
// HTTP/1.1 with keep-alive, one strand and a timeout per connection, body limits checked
// from the headers before a body is read, capture uploads streamed to disk, server-sent
// progress events, and a clean shutdown on SIGINT/SIGTERM or stop().
#pragma once

#include "service.hpp"

#include <memory>
#include <string>

namespace fringe {

struct HttpServerOptions {
    std::string bind = "127.0.0.1:8080";  // host:port, [v6]:port; port 0 picks a free one
    unsigned threads = 2;
    int read_timeout_s = 30;     // per request (header + body), and idle keep-alive
    int event_poll_ms = 25;      // how often an events stream looks for progress
    bool handle_signals = true;  // SIGINT/SIGTERM stop the server
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
