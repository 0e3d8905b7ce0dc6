#include "server/http/http_server.hpp"

#include "signal_gen/base/text.hpp"

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/thread_pool.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <spdlog/spdlog.h>

#include <cctype>
#include <atomic>
#include <chrono>
#include <limits>
#include <map>
#include <filesystem>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>

namespace fringe {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;

namespace {

// RFC 3986 6.2.2.2: a percent-escaped unreserved character (letters, digits, '-', '.', '_',
// '~') in the path is that character. Decoded once here, before the service reads the path
// (its routing, upload and traversal checks all see the same string), so /api/v1/%68ealth is
// /api/v1/health and %2E%2E is refused as '..'. Other escapes stay escaped: %2F is not a
// segment separator, and the ids' check then refuses the '%'. The query is decoded later,
// parameter by parameter.
std::string normalise_path_escapes(const std::string& target) {
    const auto q = target.find('?');
    const std::size_t end = q == std::string::npos ? target.size() : q;
    auto hex = [](char c) -> int {
        if (c >= '0' && c <= '9') return c - '0';
        if (c >= 'a' && c <= 'f') return c - 'a' + 10;
        if (c >= 'A' && c <= 'F') return c - 'A' + 10;
        return -1;
    };
    std::string out;
    out.reserve(target.size());
    for (std::size_t i = 0; i < end; ++i) {
        if (target[i] == '%' && i + 2 < end && hex(target[i + 1]) >= 0 && hex(target[i + 2]) >= 0) {
            const char c = static_cast<char>(hex(target[i + 1]) * 16 + hex(target[i + 2]));
            if (std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '.' || c == '_' || c == '~') {
                out += c;
                i += 2;
                continue;
            }
        }
        out += target[i];
    }
    out.append(target, end, std::string::npos);
    return out;
}

tcp::endpoint parse_bind(const std::string& bind) {
    const auto colon = bind.rfind(':');
    if (colon == std::string::npos) throw std::runtime_error("--bind " + bind + ": expected host:port (e.g. 127.0.0.1:8080 or [::1]:8080)");
    std::string host = bind.substr(0, colon);
    const std::string port = bind.substr(colon + 1);
    if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
    if (host.empty() || host == "localhost") host = "127.0.0.1";
    boost::system::error_code ec;
    const auto addr = net::ip::make_address(host, ec);
    if (ec) throw std::runtime_error("--bind " + bind + ": '" + host + "' is not an IP address");
    int p = -1;
    try {
        std::size_t used = 0;
        p = std::stoi(port, &used);
        if (used != port.size()) p = -1;
    } catch (const std::exception&) {
    }
    if (p < 0 || p > 65535) throw std::runtime_error("--bind " + bind + ": '" + port + "' is not a port number");
    return {addr, static_cast<unsigned short>(p)};
}

struct Shared {
    Service& svc;
    HttpServerOptions opt;
    net::thread_pool* work = nullptr;  // heavy requests
    std::atomic<std::size_t> pending_work{0};
    std::atomic<unsigned> sessions{0};  // connections being served (not the ones turned away)
    std::mutex clients_mu{};
    std::map<net::ip::address, unsigned> clients{};  // connections being served, per source address

    // Counts a connection from a; false (nothing counted) if a already has its share.
    bool admit(const net::ip::address& a) {
        std::lock_guard<std::mutex> l(clients_mu);
        auto& n = clients[a];
        if (n >= opt.max_connections_per_client) {
            if (n == 0) clients.erase(a);
            return false;
        }
        ++n;
        return true;
    }
    void release(const net::ip::address& a) {
        std::lock_guard<std::mutex> l(clients_mu);
        auto it = clients.find(a);
        if (it != clients.end() && --it->second == 0) clients.erase(it);
    }
};

// Headers a request may carry once: with two, one reader takes the first and another the last
// (a wrong token then the right one; a body length the proxy and fringe read differently).
constexpr http::field kSingleHeaders[] = {http::field::authorization, http::field::host, http::field::content_length,
                                          http::field::transfer_encoding, http::field::cookie};

bool disk_full(const beast::error_code& ec) {
    return ec == beast::errc::no_space_on_device || ec == beast::errc::file_too_large ||
           (ec.category() == boost::system::system_category() && ec.value() == EDQUOT);
}

class Session : public std::enable_shared_from_this<Session> {
public:
    Session(tcp::socket&& s, Shared& sh) : stream_(std::move(s)), sh_(sh), timer_(stream_.get_executor()) {}
    ~Session() {
        if (counted_) --sh_.sessions;
        if (client_counted_) sh_.release(client_);
    }

    // This connection's share of its client's (admit() already counted it).
    void count_client(const net::ip::address& a) {
        client_ = a;
        client_counted_ = true;
    }

    void start() {
        counted_ = true;
        ++sh_.sessions;
        net::dispatch(stream_.get_executor(), beast::bind_front_handler(&Session::read_header, shared_from_this()));
    }

    // Over the connection limit: answer 503 and close, without reading a request.
    void reject(bool per_client) {
        net::dispatch(stream_.get_executor(), [self = shared_from_this(), per_client] {
            auto r = per_client ? json_error(503, "too_many_connections",
                                             "this service serves " + std::to_string(self->sh_.opt.max_connections_per_client) +
                                                 " connections at once from one client address; close some or retry shortly")
                                : json_error(503, "too_many_connections",
                                             "this service serves " + std::to_string(self->sh_.opt.max_connections) + " connections at once; retry shortly");
            r.headers.emplace_back("Retry-After", "1");
            self->drain_ = true;
            self->respond(std::move(r), false);
        });
    }

private:
    void read_header() {
        head_.emplace();
        head_->header_limit(16 * 1024);
        head_->body_limit(std::numeric_limits<std::uint64_t>::max());  // decided in on_header
        // One deadline for the whole header (and the idle wait before it): a client trickling
        // a byte at a time is cut off as surely as one that sends nothing.
        stream_.expires_after(std::chrono::seconds(std::max(1, std::min(sh_.opt.read_timeout_s, sh_.opt.header_timeout_s))));
        http::async_read_header(stream_, buf_, *head_, beast::bind_front_handler(&Session::on_header, shared_from_this()));
    }

    // A request Beast could not parse: answered with a JSON 400 (431 for huge headers), then
    // the connection closes. A client that went away or timed out gets nothing.
    bool refuse_malformed(const beast::error_code& ec) {
        if (ec == http::error::header_limit) {
            respond(json_error(431, "headers_too_large", "the request headers exceed 16 KiB"), false);
            return true;
        }
        if (ec.category() != beast::error_code(http::error::bad_method).category() || ec == http::error::end_of_stream ||
            ec == http::error::partial_message || ec == http::error::body_limit)
            return false;
        respond(json_error(400, "bad_request", "malformed HTTP request: " + ec.message()), false);
        return true;
    }

    void on_header(beast::error_code ec, std::size_t) {
        if (ec) {  // end of stream, timeout, garbage
            if (ec != http::error::end_of_stream && ec != beast::error::timeout) spdlog::warn("header: {}", ec.message());
            if (refuse_malformed(ec)) return;
            return close();
        }
        const auto& h = head_->get();
        req_ = HttpRequest{};
        req_.method = std::string(h.method_string());
        req_.target = normalise_path_escapes(std::string(h.target()));
        for (const auto& f : h) {
            std::string k(f.name_string());
            for (auto& c : k) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
            req_.headers[k] = std::string(f.value());
        }
        keep_alive_ = h.keep_alive();
        const auto len = head_->content_length();
        std::optional<HttpResponse> early;
        for (const auto f : kSingleHeaders)
            if (h.count(f) > 1) {
                const std::string name(http::to_string(f));
                std::string field = name;
                for (auto& c : field) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
                early = json_error(400, f == http::field::host ? "bad_host" : "duplicate_header",
                                   "the request has more than one " + name + " header", field);
                keep_alive_ = false;
                break;
            }
        // HTTP/1.1 requires exactly one Host (RFC 9112 3.2); the service checks its value.
        if (early) {
        } else if (h.version() >= 11 && h.count(http::field::host) == 0)
            early = json_error(400, "missing_host", "an HTTP/1.1 request needs a Host header", "host");
        else
            early = sh_.svc.precheck(req_, len ? *len : 0, len.has_value());
        if (early) {
            // The body (if any) is not read: answer and close.
            const bool has_body = (len && *len > 0) || head_->chunked();
            drain_ = has_body;  // let the client finish sending, so it reads the answer
            return respond(std::move(*early), keep_alive_ && !has_body);
        }
        quota_limited_ = false;
        if (sh_.svc.is_upload(req_.method, req_.target)) {
            upload_path_ = sh_.svc.new_upload_path();
            file_.emplace(std::move(*head_));
            const std::uint64_t room = sh_.svc.upload_room();
            quota_limited_ = room < sh_.svc.config().max_upload_bytes;
            file_->body_limit(std::min(room, sh_.svc.config().max_upload_bytes));
            file_->get().body().open(upload_path_.c_str(), beast::file_mode::write, ec);
            if (ec) {
                drain_ = true;
                if (disk_full(ec)) return respond(json_error(507, "storage_full", "cannot store the upload: " + ec.message()), false);
                return respond(json_error(500, "upload", "cannot store the upload: " + ec.message()), false);
            }
        } else {
            str_.emplace(std::move(*head_));
            str_->body_limit(sh_.svc.config().max_body_bytes);
        }
        // The body's pace is watched here (read_some + a watchdog), not by the stream's
        // timeout, which would close the socket before a 408 could be sent.
        stream_.expires_never();
        body_start_ = std::chrono::steady_clock::now();
        body_bytes_ = 0;
        timed_out_ = false;
        reading_body_ = true;
        ++body_gen_;
        watch_body();
        read_body();
    }

    bool body_done() const { return file_ ? file_->is_done() : str_->is_done(); }

    void read_body() {
        if (body_done()) return on_body_some({}, 0);
        if (file_) http::async_read_some(stream_, buf_, *file_, beast::bind_front_handler(&Session::on_body_some, shared_from_this()));
        else http::async_read_some(stream_, buf_, *str_, beast::bind_front_handler(&Session::on_body_some, shared_from_this()));
    }

    void on_body_some(beast::error_code ec, std::size_t n) {
        body_bytes_ += n;
        if (!ec && !timed_out_ && !body_done()) return read_body();
        reading_body_ = false;
        timer_.cancel();
        on_body(ec);
    }

    void watch_body() {
        timer_.expires_after(std::chrono::milliseconds(250));
        timer_.async_wait([self = shared_from_this(), gen = body_gen_](beast::error_code ec) {
            if (ec || gen != self->body_gen_ || !self->reading_body_) return;
            const double elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - self->body_start_).count();
            const double limit_s = self->sh_.opt.body_timeout_s;
            const bool slow = self->file_ ? elapsed_s > limit_s && static_cast<double>(self->body_bytes_) < self->sh_.opt.upload_min_bytes_per_s * elapsed_s
                                          : elapsed_s > limit_s;
            if (slow) {
                self->timed_out_ = true;
                beast::error_code ignored;
                self->stream_.socket().cancel(ignored);  // the pending read ends: on_body answers 408
                return;
            }
            self->watch_body();
        });
    }

    void on_body(beast::error_code ec) {
        if (timed_out_) {
            drop_upload();
            spdlog::warn("{} {}: body too slow ({} bytes in {} s)", req_.method, req_.target, body_bytes_,
                         std::chrono::duration_cast<std::chrono::seconds>(std::chrono::steady_clock::now() - body_start_).count());
            const std::string msg = file_ ? "the upload arrived slower than " + std::to_string(static_cast<long>(sh_.opt.upload_min_bytes_per_s / 1024)) +
                                                " KiB/s on average after " + std::to_string(sh_.opt.body_timeout_s) + " s"
                                          : "the body did not arrive within " + std::to_string(sh_.opt.body_timeout_s) + " s";
            return respond(json_error(408, "body_timeout", msg), false);
        }
        if (ec == http::error::body_limit) {
            drop_upload();
            drain_ = true;
            if (file_ && quota_limited_)
                return respond(json_error(507, "quota_exceeded", "uploaded captures may take " + std::to_string(sh_.svc.config().upload_quota_bytes) +
                                                                     " bytes, each counted as it expands; this upload does not fit (--upload-quota-mb)"),
                               false);
            return respond(json_error(413, "body_too_large", "the body exceeds this endpoint's limit"), false);
        }
        if (ec && file_ && disk_full(ec)) {
            drop_upload();
            drain_ = true;
            spdlog::error("{} {}: {}", req_.method, req_.target, ec.message());
            return respond(json_error(507, "storage_full", "cannot store the upload: " + ec.message()), false);
        }
        if (ec) {
            spdlog::warn("{} {}: {}", log_escape(req_.method), log_escape(req_.target), ec.message());
            drop_upload();  // a client that went away mid-upload leaves nothing behind
            if (refuse_malformed(ec)) return;
            return close();
        }
        if (file_) {
            file_->get().body().close();
            req_.body_file = upload_path_;
        } else {
            req_.body = std::move(str_->get().body());
        }
        if (!sh_.svc.is_heavy(req_.method, req_.target)) return complete(sh_.svc.handle(req_));
        // Off the I/O threads: the answer comes back to this connection's strand.
        if (sh_.pending_work.load() >= sh_.opt.max_pending_work) {
            auto r = json_error(503, "busy", "this service already has " + std::to_string(sh_.pending_work.load()) + " long requests waiting; retry shortly");
            r.headers.emplace_back("Retry-After", "1");
            return complete(std::move(r));
        }
        ++sh_.pending_work;
        net::post(*sh_.work, [self = shared_from_this(), req = std::move(req_)]() {
            HttpResponse res;
            try {
                res = self->sh_.svc.handle(req);
            } catch (const std::exception& e) {
                res = json_error(500, "internal", e.what());
            }
            --self->sh_.pending_work;
            net::post(self->stream_.get_executor(), [self, res = std::move(res)]() mutable { self->complete(std::move(res)); });
        });
    }

    void complete(HttpResponse&& res) {
        drop_upload();  // the service moved it into place if it kept it
        file_.reset();
        str_.reset();
        if (!res.events_run.empty()) return start_events(res.events_run);
        respond(std::move(res), keep_alive_);
    }

    void drop_upload() {
        if (upload_path_.empty()) return;
        std::error_code fec;
        std::filesystem::remove(upload_path_, fec);
        upload_path_.clear();
    }

    void respond(HttpResponse&& r, bool keep) {
        auto res = std::make_shared<http::response<http::string_body>>(static_cast<http::status>(r.status), 11);
        res->set(http::field::server, "fringe/" FRINGE_VERSION);
        res->set(http::field::content_type, r.content_type);
        res->set("X-Content-Type-Options", "nosniff");
        for (const auto& [k, v] : r.headers) res->insert(k, v);
        res->keep_alive(keep);
        res->body() = std::move(r.body);
        res->prepare_payload();
        res_ = res;  // alive until the write completes (Beast 1.74 has no message_generator)
        stream_.expires_after(std::chrono::seconds(sh_.opt.read_timeout_s));
        http::async_write(stream_, *res, beast::bind_front_handler(&Session::on_write, shared_from_this(), !keep));
    }

    void on_write(bool close_after, beast::error_code ec, std::size_t) {
        res_.reset();
        if (!ec && close_after && drain_) return linger();
        if (ec || close_after) return close();
        read_header();
    }

    // Answered before the request's body was read: stop sending, then read and drop what the
    // client still sends (up to 16 MiB or 2 s), so it reads the answer instead of a reset.
    void linger() {
        drain_ = false;
        beast::error_code ec;
        stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
        scratch_.resize(16384);
        stream_.expires_after(std::chrono::seconds(2));
        drain_more();
    }

    void drain_more() {
        stream_.async_read_some(net::buffer(scratch_), [self = shared_from_this()](beast::error_code ec, std::size_t n) {
            self->drained_ += n;
            if (ec || self->drained_ > (16u << 20)) return self->close();
            self->drain_more();
        });
    }

    // ---- server-sent events: progress until the run ends, then close ----
    void start_events(const std::string& id) {
        ev_id_ = id;
        out_ = "HTTP/1.1 200 OK\r\nServer: fringe/" FRINGE_VERSION "\r\nContent-Type: text/event-stream\r\nCache-Control: no-cache\r\n"
               "X-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\nretry: 1000\n\n";
        last_write_ = std::chrono::steady_clock::now();
        write_events(false);
    }

    void write_events(bool last) {
        stream_.expires_after(std::chrono::seconds(10));
        net::async_write(stream_, net::buffer(out_), [self = shared_from_this(), last](beast::error_code ec, std::size_t) {
            self->out_.clear();
            self->stream_.expires_never();
            if (ec || last) return self->close();
            self->last_write_ = std::chrono::steady_clock::now();
            self->poll_events();
        });
    }

    void poll_events() {
        std::optional<RunSnapshot> s;
        try {
            s = sh_.svc.run_state(ev_id_);
        } catch (const std::exception& e) {  // the store failed: end this stream, not the server
            spdlog::error("events of run {}: {}", ev_id_, log_escape(e.what()));
        }
        if (!s) return close();
        if (s->seq != last_seq_ || s->finished()) {
            last_seq_ = s->seq;
            out_ = Service::sse_event(*s);
            return write_events(s->finished());
        }
        if (std::chrono::steady_clock::now() - last_write_ > std::chrono::seconds(15)) {
            out_ = ": keep-alive\n\n";
            return write_events(false);
        }
        timer_.expires_after(std::chrono::milliseconds(sh_.opt.event_poll_ms));
        timer_.async_wait([self = shared_from_this()](beast::error_code ec) {
            if (ec) return self->close();
            self->poll_events();
        });
    }

    void close() {
        drop_upload();
        beast::error_code ec;
        stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
        stream_.socket().close(ec);
    }

    beast::tcp_stream stream_;
    Shared& sh_;
    net::steady_timer timer_;
    beast::flat_buffer buf_;
    std::optional<http::request_parser<http::empty_body>> head_;
    std::optional<http::request_parser<http::string_body>> str_;
    std::optional<http::request_parser<http::file_body>> file_;
    HttpRequest req_;
    bool keep_alive_ = true;
    std::shared_ptr<void> res_;
    std::string upload_path_;
    std::string ev_id_, out_;
    std::uint64_t last_seq_ = 0;
    std::chrono::steady_clock::time_point last_write_;
    bool counted_ = false;
    net::ip::address client_;
    bool client_counted_ = false;
    // body pace
    std::chrono::steady_clock::time_point body_start_;
    std::uint64_t body_bytes_ = 0, body_gen_ = 0;
    bool reading_body_ = false, timed_out_ = false, quota_limited_ = false;
    // lingering close
    bool drain_ = false;
    std::vector<char> scratch_;
    std::size_t drained_ = 0;
};

}  // namespace

bool is_loopback_bind(const std::string& bind) { return parse_bind(bind).address().is_loopback(); }

struct HttpServer::Impl {
    Shared sh;
    net::io_context ioc;
    tcp::acceptor acceptor;
    net::signal_set signals;
    std::once_flag stop_once;
    std::mutex stopper_mu;  // the stopper may end the io loop before its assignment completes
    std::thread stopper;
    tcp::endpoint local;
    net::steady_timer backoff;
    std::chrono::steady_clock::time_point last_accept_warning;
    net::thread_pool work;  // after ioc: joined before the io_context goes

    Impl(Service& s, HttpServerOptions o)
        : sh{s, std::move(o)}, ioc(static_cast<int>(std::max(1u, sh.opt.threads))), acceptor(net::make_strand(ioc)), signals(ioc),
          backoff(acceptor.get_executor()), work(std::max(1u, sh.opt.work_threads ? sh.opt.work_threads : s.config().workers)) {
        sh.work = &work;
        const auto ep = parse_bind(sh.opt.bind);
        beast::error_code ec;
        acceptor.open(ep.protocol(), ec);
        if (!ec) acceptor.set_option(net::socket_base::reuse_address(true), ec);
        if (!ec) acceptor.bind(ep, ec);
        if (!ec) acceptor.listen(net::socket_base::max_listen_connections, ec);
        if (ec) throw std::runtime_error("cannot listen on " + sh.opt.bind + ": " + ec.message());
        local = acceptor.local_endpoint();
        sh.svc.set_bound_address(local.address().to_string());  // Host headers may name it
    }

    void accept() {
        acceptor.async_accept(net::make_strand(ioc), [this](beast::error_code ec, tcp::socket s) {
            if (ec == net::error::operation_aborted || !acceptor.is_open()) return;
            if (ec) {
                // EMFILE/ENFILE (slow clients hold every descriptor), ENOBUFS...: the pending
                // connection stays in the backlog; retrying at once would spin a core.
                const auto now = std::chrono::steady_clock::now();
                if (now - last_accept_warning > std::chrono::seconds(10)) {
                    spdlog::warn("accept: {}; retrying every {} ms", ec.message(), sh.opt.accept_backoff_ms);
                    last_accept_warning = now;
                }
                backoff.expires_after(std::chrono::milliseconds(sh.opt.accept_backoff_ms));
                backoff.async_wait([this](beast::error_code tec) {
                    if (!tec && acceptor.is_open()) accept();
                });
                return;
            }
            s.set_option(tcp::no_delay(true), ec);
            const auto peer = s.remote_endpoint(ec);
            auto session = std::make_shared<Session>(std::move(s), sh);
            if (sh.sessions.load() >= sh.opt.max_connections) {
                session->reject(false);
            } else if (!ec && !sh.admit(peer.address())) {
                session->reject(true);
            } else {
                if (!ec) session->count_client(peer.address());
                session->start();
            }
            accept();
        });
    }

    void stop() {
        std::call_once(stop_once, [this] {
            {
                // Runs end after their current block and are stored before the sockets go.
                std::lock_guard<std::mutex> l(stopper_mu);
                stopper = std::thread([this] {
                    sh.svc.shutdown();
                    std::this_thread::sleep_for(std::chrono::milliseconds(2 * sh.opt.event_poll_ms + 50));  // last events out
                    ioc.stop();
                });
            }
            net::post(acceptor.get_executor(), [this] {
                beast::error_code ec;
                acceptor.close(ec);
                backoff.cancel();
                signals.cancel(ec);
            });
        });
    }
};

HttpServer::HttpServer(Service& service, HttpServerOptions o) : impl_(std::make_unique<Impl>(service, std::move(o))) {}

HttpServer::~HttpServer() {
    stop();
    std::lock_guard<std::mutex> l(impl_->stopper_mu);
    if (impl_->stopper.joinable()) impl_->stopper.join();
}

unsigned short HttpServer::port() const { return impl_->local.port(); }

std::string HttpServer::url() const {
    const auto a = impl_->local.address();
    std::string host = a.is_v6() ? "[" + a.to_string() + "]" : a.to_string();
    if (a.is_unspecified()) host = a.is_v6() ? "[::1]" : "127.0.0.1";
    return "http://" + host + ":" + std::to_string(port()) + "/";
}

void HttpServer::run() {
    if (impl_->sh.opt.handle_signals) {
        impl_->signals.add(SIGINT);
        impl_->signals.add(SIGTERM);
        impl_->signals.async_wait([this](beast::error_code ec, int sig) {
            if (ec) return;
            spdlog::info("signal {}: stopping (running runs end as interrupted, their reports kept)", sig);
            stop();
        });
    }
    impl_->accept();
    // A handler that throws would end the io loop (and the process): log it and go on.
    auto serve = [this] {
        for (;;) {
            try {
                impl_->ioc.run();
                return;
            } catch (const std::exception& e) {
                spdlog::error("request handler: {}", log_escape(e.what()));
            }
        }
    };
    std::vector<std::thread> extra;
    for (unsigned i = 1; i < std::max(1u, impl_->sh.opt.threads); ++i) extra.emplace_back(serve);
    serve();
    for (auto& t : extra) t.join();
    impl_->work.stop();  // waiting heavy requests are dropped (their connections are gone)
    impl_->work.join();
    {
        std::lock_guard<std::mutex> l(impl_->stopper_mu);
        if (impl_->stopper.joinable()) impl_->stopper.join();
    }
    impl_->sh.svc.shutdown();
}

void HttpServer::stop() { impl_->stop(); }

}  // namespace fringe
