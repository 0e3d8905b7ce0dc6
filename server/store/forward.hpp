// Store and forward to a shared PostgreSQL store (pg_store.hpp). A bench writes every run to
// its local SQLite first (DATA/runs.db, as without a shared store) and marks the finished
// report "pending" in the row's forward column; a forwarder sends pending reports to the
// shared store, oldest first, and records the outcome there: "done", or "conflict" (the
// shared store holds a different report under that id: flagged, neither is overwritten), each
// with the identity of the store it reached (PgStore::identity: the server's system identifier
// and the database). Pointed at another store (a new or restored server), the forwarder asks
// that store which of the spool's runs it holds and sends the others: whether a run is stored
// is decided by the store, never by the spool. A spooled report that cannot be sent (not JSON,
// no scenario, an id that is not its row's) is "quarantined" with a message naming the run and
// the problem, and the others go on.
// While the database is unreachable the bench keeps running; the forwarder retries with
// backoff (0.5 s doubling to 30 s), and any later fringe command on that data folder with
// the same --store forwards what is still pending when it starts. Nothing is lost.
//
// Reads merge both: the local rows (live, and not yet forwarded) and the shared store's
// (every bench's); when the shared store is down, the local ones alone.
#pragma once

#include "server/store/pg_store.hpp"
#include "server/store/store.hpp"

#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

namespace fringe {

class ForwardingStore : public RunStore {
public:
    // local_path: DATA/runs.db; instance as for SqliteStore. Does not connect yet (a bench
    // starts while the database is down).
    ForwardingStore(const std::string& local_path, std::string instance, std::string shared_uri);
    ~ForwardingStore() override;

    void begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
               const std::string& status = "running", const nlohmann::json& provenance = nullptr) override;
    void set_status(const std::string& id, const std::string& status) override;
    void finish(const nlohmann::json& report) override;  // local, then wakes the forwarder
    std::vector<RunRow> list(const RunFilter& f = {}) const override;
    std::optional<std::string> report_text(const std::string& id) const override;
    std::optional<RunRow> row(const std::string& id) const override;
    int mark_dead_interrupted() override;
    void mark_interrupted(const std::string& id) override;
    std::string describe() const override;

    struct Pass {
        int forwarded = 0, same = 0, conflicts = 0, pending = 0, quarantined = 0;
        std::vector<std::string> conflict_ids;  // the runs found in conflict, each by its own id
        std::string error;  // why the pass stopped early (the shared store unreachable)
    };
    // One pass over the pending reports (its own connections; not with start() running).
    Pass forward_pending();
    // Passes with backoff until nothing is pending or timeout_s has passed: the last pass.
    Pass forward_until(double timeout_s);
    // A background forwarder (fringe serve, fringe sweep): woken by finish(), else retrying.
    void start();
    void stop();
    // The last outcome, for messages and the health check.
    Pass last() const;
    // The shared store as the last read or forwarding pass found it (thread-safe, never waits
    // for the database: the health check calls it without the store lock). reachable: -1 not
    // tried yet, 0 unreachable (error says why, without the password), 1 reachable.
    struct Health {
        int reachable = -1;
        int pending = 0;
        std::string error;
    };
    Health health() const;
    const std::string& shared_uri() const { return shared_uri_; }
    SqliteStore& local() { return local_; }
    // Of these run ids, those the shared store holds with a report; nullopt when it cannot
    // be asked (down).
    std::optional<std::set<std::string>> shared_has(const std::vector<std::string>& ids) const;

private:
    PgStore* reader() const;  // connected reader for merged reads, or null (down; retried after a pause)
    Pass pass_locked();
    void note_shared(bool ok, const std::string& error) const;  // for health()

    SqliteStore local_;
    std::string instance_, shared_uri_, shown_;
    // Merged reads (callers serialise them, like every RunStore use).
    mutable std::unique_ptr<PgStore> reader_;
    mutable std::chrono::steady_clock::time_point reader_retry_{};
    // The forwarder's own connections (its thread, or forward_pending's caller).
    std::mutex fwd_mu_;
    std::unique_ptr<SqliteStore> fwd_local_;
    std::unique_ptr<PgStore> fwd_shared_;
    std::string fwd_ident_;  // fwd_shared_'s identity; kept once learnt, to know when to connect
    mutable std::mutex state_mu_;
    std::condition_variable wake_;
    bool stop_ = false, kicked_ = false;
    Pass last_;
    mutable int reachable_ = -1;  // state_mu_
    mutable std::string shared_error_;
    std::thread thread_;
};

// --store URI (or none) to a store: "" -> SQLite DATA/runs.db; "sqlite:PATH" -> that file;
// "postgresql://..." / "postgres://..." -> store and forward through DATA/runs.db. Throws
// ConfigError("store", ...) for any other form.
struct StoreUri {
    enum class Kind { Sqlite, Postgres } kind = Kind::Sqlite;
    std::string sqlite_path;  // Sqlite: the file; Postgres: the local spool
    std::string pg_uri;
};
StoreUri parse_store_uri(const std::string& uri, const std::string& data_dir);
// A writer (fringe run, serve, sweep): the instance id as for SqliteStore.
std::unique_ptr<RunStore> open_store(const StoreUri& u, const std::string& instance);
// A reader (fringe runs, sweep --collect): PostgreSQL directly, no spool.
std::unique_ptr<RunStore> open_store_reader(const StoreUri& u);

}  // namespace fringe
