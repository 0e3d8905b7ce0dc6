#include "forward.hpp"

#include "signal_gen/config.hpp"
#include "signal_gen/json_bounded.hpp"

#include <algorithm>
#include <filesystem>
#include <map>
#include <spdlog/spdlog.h>

namespace fringe {

using nlohmann::json;

ForwardingStore::ForwardingStore(const std::string& local_path, std::string instance, std::string shared_uri)
    : local_(local_path, instance), instance_(std::move(instance)), shared_uri_(std::move(shared_uri)), shown_(redact_store_uri(shared_uri_)) {
    local_.set_spool(true);
}

ForwardingStore::~ForwardingStore() { stop(); }

std::string ForwardingStore::describe() const { return shown_ + " (through " + local_.path() + ")"; }

void ForwardingStore::begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
                            const std::string& status, const json& provenance) {
    local_.begin(id, created_at, scenario, dut, status, provenance);
}
void ForwardingStore::set_status(const std::string& id, const std::string& status) { local_.set_status(id, status); }
int ForwardingStore::mark_dead_interrupted() { return local_.mark_dead_interrupted(); }
void ForwardingStore::mark_interrupted(const std::string& id) { local_.mark_interrupted(id); }

void ForwardingStore::finish(const json& report) {
    local_.finish(report);
    {
        std::lock_guard<std::mutex> l(state_mu_);
        kicked_ = true;
    }
    wake_.notify_all();
}

PgStore* ForwardingStore::reader() const {
    if (reader_ && reader_->connected()) return reader_.get();
    // Down: the local rows only, and no connection attempt (up to 5 s) on every read.
    if (std::chrono::steady_clock::now() < reader_retry_) return nullptr;
    try {
        reader_ = std::make_unique<PgStore>(shared_uri_);
        return reader_.get();
    } catch (const StoreError& e) {
        reader_.reset();
        reader_retry_ = std::chrono::steady_clock::now() + std::chrono::seconds(10);
        note_shared(false, e.what());
        spdlog::warn("shared store unreachable, showing this bench's runs only: {}", e.what());
        return nullptr;
    }
}

void ForwardingStore::note_shared(bool ok, const std::string& error) const {
    std::lock_guard<std::mutex> l(state_mu_);
    reachable_ = ok ? 1 : 0;
    shared_error_ = ok ? std::string() : error;
}

ForwardingStore::Health ForwardingStore::health() const {
    std::lock_guard<std::mutex> l(state_mu_);
    return {reachable_, last_.pending, shared_error_};
}

std::vector<RunRow> ForwardingStore::list(const RunFilter& f) const {
    std::vector<RunRow> rows = local_.list(f);
    if (PgStore* pg = reader()) {
        try {
            std::map<std::string, bool> have;
            for (const auto& r : rows) have[r.id] = true;
            for (auto& r : pg->list(f))
                if (!have.count(r.id)) rows.push_back(std::move(r));
            note_shared(true, "");
        } catch (const StoreError& e) {
            // Frozen or gone: the local rows only, and no new attempt for a while (each would wait).
            reader_.reset();
            reader_retry_ = std::chrono::steady_clock::now() + std::chrono::seconds(10);
            note_shared(false, e.what());
            spdlog::warn("shared store: {}", e.what());
        }
    }
    std::sort(rows.begin(), rows.end(), [](const RunRow& a, const RunRow& b) {
        return a.created_at != b.created_at ? a.created_at > b.created_at : a.id > b.id;
    });
    if (rows.size() > static_cast<std::size_t>(std::max(0, f.limit))) rows.resize(static_cast<std::size_t>(std::max(0, f.limit)));
    return rows;
}

std::optional<std::string> ForwardingStore::report_text(const std::string& id) const {
    if (auto t = local_.report_text(id)) return t;
    if (PgStore* pg = reader()) {
        try {
            auto v = pg->report_text(id);
            note_shared(true, "");
            return v;
        } catch (const StoreError& e) {
            // Frozen or gone: the local rows only, and no new attempt for a while (each would wait).
            reader_.reset();
            reader_retry_ = std::chrono::steady_clock::now() + std::chrono::seconds(10);
            note_shared(false, e.what());
            spdlog::warn("shared store: {}", e.what());
        }
    }
    return std::nullopt;
}

std::optional<RunRow> ForwardingStore::row(const std::string& id) const {
    if (auto r = local_.row(id)) return r;
    if (PgStore* pg = reader()) {
        try {
            auto v = pg->row(id);
            note_shared(true, "");
            return v;
        } catch (const StoreError& e) {
            // Frozen or gone: the local rows only, and no new attempt for a while (each would wait).
            reader_.reset();
            reader_retry_ = std::chrono::steady_clock::now() + std::chrono::seconds(10);
            note_shared(false, e.what());
            spdlog::warn("shared store: {}", e.what());
        }
    }
    return std::nullopt;
}

ForwardingStore::Pass ForwardingStore::pass_locked() {
    Pass p;
    if (!fwd_local_) fwd_local_ = std::make_unique<SqliteStore>(local_.path());
    try {
        if (!fwd_shared_ || !fwd_shared_->connected()) {
            fwd_shared_.reset();
            if (fwd_local_->pending_count() == 0) return p;  // nothing to send: no need to connect
            fwd_shared_ = std::make_unique<PgStore>(shared_uri_);
        }
        for (;;) {
            const auto batch = fwd_local_->pending_forward(64);
            if (batch.empty()) break;
            for (const auto& item : batch) {
                json rep = json(json::value_t::discarded);
                try {
                    rep = parse_json_bounded(item.report, "", kMaxStoredJsonDepth);
                } catch (const ConfigError&) {
                }
                if (rep.is_discarded() || !rep.is_object()) {
                    fwd_local_->set_forwarded(item.id, "failed", "the stored report is not JSON");
                    continue;
                }
                switch (fwd_shared_->put(rep)) {
                    case PgStore::Put::Inserted: ++p.forwarded; fwd_local_->set_forwarded(item.id, "done"); break;
                    case PgStore::Put::Same: ++p.same; fwd_local_->set_forwarded(item.id, "done"); break;
                    case PgStore::Put::Conflict:
                        ++p.conflicts;
                        fwd_local_->set_forwarded(item.id, "conflict", "the shared store holds a different report under this id (see its run_conflicts table)");
                        spdlog::error("run {}: {} holds a different report under this id; ours is kept here and in its run_conflicts, "
                                      "neither is overwritten", item.id, shown_);
                        break;
                }
            }
        }
        if (fwd_shared_) note_shared(true, "");
    } catch (const StoreError& e) {
        p.error = e.what();
        fwd_shared_.reset();  // reconnect on the next pass
        note_shared(false, p.error);
    }
    p.pending = fwd_local_->pending_count();
    {
        std::lock_guard<std::mutex> l(state_mu_);
        last_ = p;
    }
    return p;
}

ForwardingStore::Pass ForwardingStore::forward_pending() {
    std::lock_guard<std::mutex> l(fwd_mu_);
    return pass_locked();
}

ForwardingStore::Pass ForwardingStore::forward_until(double timeout_s) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    double wait_s = 0.25;
    Pass total;
    for (;;) {
        const Pass p = forward_pending();
        total.forwarded += p.forwarded;
        total.same += p.same;
        total.conflicts += p.conflicts;
        total.pending = p.pending;
        total.error = p.error;
        if (p.pending == 0 || std::chrono::steady_clock::now() + std::chrono::duration<double>(wait_s) > deadline) return total;
        std::this_thread::sleep_for(std::chrono::duration<double>(wait_s));
        wait_s = std::min(wait_s * 2, 5.0);
    }
}

void ForwardingStore::start() {
    if (thread_.joinable()) return;
    stop_ = false;
    thread_ = std::thread([this] {
        double backoff_s = 0.5;
        bool was_down = false;
        for (;;) {
            // No exception leaves this thread (it would end the service): what the pass could
            // not do is reported like an unreachable store, and retried with backoff.
            Pass p;
            try {
                p = forward_pending();
            } catch (const std::exception& e) {
                p.error = e.what();
                p.pending = 1;
            }
            if (!p.error.empty() && !was_down) spdlog::warn("forwarding to the shared store paused ({} run(s) pending, retrying): {}", p.pending, p.error);
            if (p.error.empty() && was_down) spdlog::info("shared store {} reachable again: {} run(s) forwarded", shown_, p.forwarded);
            was_down = !p.error.empty();
            // Retry soon while something is pending; otherwise wake on a new report, and look
            // every 30 s for reports other processes on this folder left pending.
            const auto wait = p.pending > 0 ? std::chrono::duration<double>(backoff_s) : std::chrono::duration<double>(30.0);
            backoff_s = p.pending > 0 ? std::min(backoff_s * 2, 30.0) : 0.5;
            std::unique_lock<std::mutex> l(state_mu_);
            wake_.wait_for(l, wait, [&] { return stop_ || kicked_; });
            if (stop_) return;
            if (kicked_ && p.pending == 0) backoff_s = 0.5;
            kicked_ = false;
        }
    });
}

void ForwardingStore::stop() {
    {
        std::lock_guard<std::mutex> l(state_mu_);
        stop_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) thread_.join();
}

ForwardingStore::Pass ForwardingStore::last() const {
    std::lock_guard<std::mutex> l(state_mu_);
    return last_;
}

StoreUri parse_store_uri(const std::string& uri, const std::string& data_dir) {
    StoreUri u;
    const std::string spool = (std::filesystem::path(data_dir) / "runs.db").string();
    if (uri.empty()) {
        u.sqlite_path = spool;
    } else if (uri.rfind("sqlite:", 0) == 0) {
        u.sqlite_path = uri.substr(7);
        if (u.sqlite_path.rfind("//", 0) == 0) u.sqlite_path = u.sqlite_path.substr(2);  // sqlite:///abs/path
        if (u.sqlite_path.empty()) throw ConfigError("store", "sqlite: needs a file (sqlite:/var/lib/fringe/runs.db)");
    } else if (uri.rfind("postgresql://", 0) == 0 || uri.rfind("postgres://", 0) == 0) {
        if (const std::string bad = store_uri_problem(uri); !bad.empty())
            throw ConfigError("store", "the PostgreSQL URI '" + redact_store_uri(uri) + "' holds " + bad);
        u.kind = StoreUri::Kind::Postgres;
        u.pg_uri = uri;
        u.sqlite_path = spool;
    } else {
        throw ConfigError("store", "expected sqlite:PATH or a PostgreSQL URI (postgresql://USER@HOST/DB, postgresql:///DB?host=/run/postgresql); got '" +
                                       redact_store_uri(uri) + "'");
    }
    return u;
}

std::unique_ptr<RunStore> open_store(const StoreUri& u, const std::string& instance) {
    if (u.kind == StoreUri::Kind::Postgres) return std::make_unique<ForwardingStore>(u.sqlite_path, instance, u.pg_uri);
    return std::make_unique<SqliteStore>(u.sqlite_path, instance);
}

std::unique_ptr<RunStore> open_store_reader(const StoreUri& u) {
    if (u.kind == StoreUri::Kind::Postgres) return std::make_unique<PgStore>(u.pg_uri);
    return std::make_unique<SqliteStore>(u.sqlite_path);
}

}  // namespace fringe
