#include "server/store/forward.hpp"

#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

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

namespace {
// Why a spooled report cannot be sent as it is ("" if it can): what PgStore::put reads.
std::string spool_problem(const json& rep, const std::string& row_id) {
    if (rep.is_discarded() || !rep.is_object()) return "the stored report is not a JSON object";
    if (!rep.contains("id") || !rep["id"].is_string()) return "the report has no string \"id\"";
    if (rep["id"].get<std::string>() != row_id) return "the report's id is '" + rep["id"].get<std::string>() + "', not its row's";
    if (!rep.contains("scenario") || !rep["scenario"].is_object()) return "the report has no \"scenario\" object";
    for (const char* k : {"status", "verdict", "started_at", "fringe_version"})
        if (rep.contains(k) && !rep[k].is_string() && !rep[k].is_null()) return std::string("\"") + k + "\" is not a string";
    if (!rep.contains("status") || !rep["status"].is_string()) return "the report has no string \"status\"";
    return "";
}
}  // namespace

ForwardingStore::Pass ForwardingStore::pass_locked() {
    Pass p;
    if (!fwd_local_) fwd_local_ = std::make_unique<SqliteStore>(local_.path());
    auto quarantine = [&](const std::string& id, const std::string& problem) {
        ++p.quarantined;
        const std::string msg = "run " + id + ": its spooled report cannot be forwarded (" + problem + "); it stays in " + local_.path() +
                                ", marked quarantined, and is not sent";
        fwd_local_->set_forwarded(id, "quarantined", msg);
        spdlog::error("{}", msg);
    };
    try {
        if (!fwd_shared_ || !fwd_shared_->connected()) {
            fwd_shared_.reset();
            // Nothing to send, and every forwarded row names the store we last reached (or
            // nothing was ever spooled): no need to connect.
            const bool unknown_store = fwd_ident_.empty() ? fwd_local_->spooled_count() > 0 : !fwd_local_->forwarded_elsewhere(fwd_ident_, 1).empty();
            if (fwd_local_->pending_count() == 0 && !unknown_store) return p;
            fwd_shared_ = std::make_unique<PgStore>(shared_uri_);
            fwd_ident_ = fwd_shared_->identity();
        }
        // Rows forwarded to another store (or before the spool named stores): this store says
        // whether it holds them; the ones it lacks, or holds with another checksum, go again.
        for (;;) {
            const auto batch = fwd_local_->forwarded_elsewhere(fwd_ident_, 256);
            if (batch.empty()) break;
            std::vector<std::string> ids;
            for (const auto& f : batch) ids.push_back(f.id);
            const auto have = fwd_shared_->stored_checksums(ids);
            for (const auto& f : batch) {
                const auto it = have.find(f.id);
                if (it != have.end() && it->second == f.report_sha256) fwd_local_->set_forwarded(f.id, "done", "", fwd_ident_);
                else fwd_local_->set_forwarded(f.id, "pending");  // put() below decides: inserted, same or conflict
            }
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
                if (const std::string problem = spool_problem(rep, item.id); !problem.empty()) {
                    quarantine(item.id, problem);
                    continue;
                }
                PgStore::Put put = PgStore::Put::Same;
                try {
                    put = fwd_shared_->put(rep);
                } catch (const StoreError&) {
                    throw;  // the store (unreachable, refused): retried later
                } catch (const std::exception& e) {  // the report (a value put() cannot read)
                    quarantine(item.id, e.what());
                    continue;
                }
                switch (put) {
                    case PgStore::Put::Inserted: ++p.forwarded; fwd_local_->set_forwarded(item.id, "done", "", fwd_ident_); break;
                    case PgStore::Put::Same: ++p.same; fwd_local_->set_forwarded(item.id, "done", "", fwd_ident_); break;
                    case PgStore::Put::Conflict:
                        ++p.conflicts;
                        p.conflict_ids.push_back(item.id);
                        fwd_local_->set_forwarded(item.id, "conflict", "the shared store holds a different report under this id (see its run_conflicts table)",
                                                  fwd_ident_);
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

std::optional<std::set<std::string>> ForwardingStore::shared_has(const std::vector<std::string>& ids) const {
    reader_retry_ = {};  // asked rarely (a sweep's start and end): always try
    PgStore* pg = reader();
    if (!pg) return std::nullopt;
    try {
        std::set<std::string> out;
        for (const auto& [id, sum] : pg->stored_checksums(ids)) out.insert(id);
        return out;
    } catch (const StoreError& e) {
        spdlog::warn("shared store: {}", e.what());
        reader_.reset();
        return std::nullopt;
    }
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
        total.quarantined += p.quarantined;
        total.conflict_ids.insert(total.conflict_ids.end(), p.conflict_ids.begin(), p.conflict_ids.end());
        total.pending = p.pending;
        total.error = p.error;
        if ((p.pending == 0 && p.error.empty()) || std::chrono::steady_clock::now() + std::chrono::duration<double>(wait_s) > deadline) return total;
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
            } catch (const std::exception& e) {  // the spool itself (disk, SQLite): logged, retried, never fatal
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

namespace {
// Every command that opens a data folder's store first settles what dead processes left.
void reap(SqliteStore& s) {
    try {
        if (const int n = s.reap_dead(); n > 0)
            spdlog::warn("{} run(s) of a process that stopped without finishing are marked interrupted in {}", n, s.path());
    } catch (const std::exception& e) {  // a read-only folder: the rows still read as interrupted
        spdlog::debug("could not mark dead runs in {}: {}", s.path(), e.what());
    }
}
}  // namespace

std::unique_ptr<RunStore> open_store(const StoreUri& u, const std::string& instance) {
    if (u.kind == StoreUri::Kind::Postgres) {
        auto f = std::make_unique<ForwardingStore>(u.sqlite_path, instance, u.pg_uri);
        reap(f->local());
        return f;
    }
    auto s = std::make_unique<SqliteStore>(u.sqlite_path, instance);
    reap(*s);
    return s;
}

std::unique_ptr<RunStore> open_store_reader(const StoreUri& u) {
    if (u.kind == StoreUri::Kind::Postgres) return std::make_unique<PgStore>(u.pg_uri);
    auto s = std::make_unique<SqliteStore>(u.sqlite_path);
    reap(*s);
    return s;
}

}  // namespace fringe
