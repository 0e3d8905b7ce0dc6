// The run history behind one interface (RunStore), with two implementations: SqliteStore
// (below; embedded, the default) and PgStore (pg_store.hpp; PostgreSQL shared by many
// benches, reached through store and forward: forward.hpp). open_store() picks one from a
// --store URI.
//
// Run history in SQLite (embedded, WAL, synchronous=FULL): one row per run with id, time,
// scenario, DUT/board id, status, verdict, a summary (error, samples, device URI: what a
// status query needs without parsing the report) and the complete report. A run is inserted
// as "running" when it starts and its report is written in one transaction when it ends, so
// a killed process loses no completed report. Each row names the instance (instance_lock.hpp)
// that runs it; a "running" row whose instance lock nobody holds is listed as "interrupted".
// The database is created mode 0600 (SQLite gives -wal/-shm the same mode).
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

struct sqlite3;

namespace fringe {

class StoreError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};
// The disk (or the file size limit) is full: the service answers 507.
class StoreFull : public StoreError {
public:
    using StoreError::StoreError;
};

struct RunRow {
    std::string id, created_at, scenario, dut, status, verdict;
    std::string bench, host, dut_part, operator_name;  // provenance (provenance.hpp)
    std::string forward;                   // local spool of a shared store: "", pending, done, conflict, quarantined
    std::string forward_store;             // the shared store that state refers to (PgStore::identity), once reached
    std::string error, device;             // from the report, once finished
    std::uint64_t done = 0, total = 0;     // samples processed / planned, once finished
    bool dead = false;                     // stored as queued/running, but its instance is gone
};

struct RunFilter {
    std::string verdict;  // empty: any
    std::string scenario;
    std::string since;    // ISO time, inclusive
    int limit = 100;
    std::string bench;    // provenance bench name
    std::string dut;      // DUT serial
};

// Not thread-safe: one user at a time (the service guards it with a mutex).
class RunStore {
public:
    virtual ~RunStore() = default;
    // status "running" (the CLI) or "queued" (the service); the row records this process.
    // provenance (provenance.hpp, may be null) fills the row's bench, host, part and operator
    // so filters find a run while it runs. A row of this id that never got a report (an
    // interrupted run of a deterministic sweep id) is taken over; one with a report is an error.
    virtual void begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
                       const std::string& status = "running", const nlohmann::json& provenance = nullptr) = 0;
    virtual void set_status(const std::string& id, const std::string& status) = 0;
    virtual void finish(const nlohmann::json& report) = 0;  // by report["id"]; inserts if begin() was not called
    virtual std::vector<RunRow> list(const RunFilter& f = {}) const = 0;
    std::optional<nlohmann::json> report(const std::string& id) const;
    virtual std::optional<std::string> report_text(const std::string& id) const = 0;  // parse it outside any lock
    virtual std::optional<RunRow> row(const std::string& id) const = 0;
    // Rows left "queued" or "running" by an instance that is gone (its lock is free) become
    // "interrupted" for good: the service calls this at start, holding DATA/lock, so rows of
    // an earlier service are always caught, whatever PID it had. Returns how many.
    virtual int mark_dead_interrupted() = 0;
    // The same for one row (a status read found its instance gone).
    virtual void mark_interrupted(const std::string& id) = 0;
    // What messages name the store by: a file path, or a URI without its password.
    virtual std::string describe() const = 0;
};

class SqliteStore : public RunStore {
public:
    // instance: the id this process stamps on the rows it begins (see instance_lock.hpp);
    // "" for a reader (fringe runs).
    explicit SqliteStore(const std::string& db_path, std::string instance = "");
    ~SqliteStore() override;
    SqliteStore(const SqliteStore&) = delete;
    SqliteStore& operator=(const SqliteStore&) = delete;

    void begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
               const std::string& status = "running", const nlohmann::json& provenance = nullptr) override;
    void set_status(const std::string& id, const std::string& status) override;
    void finish(const nlohmann::json& report) override;
    std::vector<RunRow> list(const RunFilter& f = {}) const override;
    std::optional<std::string> report_text(const std::string& id) const override;
    std::optional<RunRow> row(const std::string& id) const override;
    int mark_dead_interrupted() override;
    void mark_interrupted(const std::string& id) override;
    // What every command that opens the folder does first: rows "queued"/"running" whose
    // process is gone (its instance lock unheld, or for rows of an older fringe its PID gone)
    // become "interrupted" for good, and lock files nobody holds (a kill -9 leaves one) are
    // removed. Returns how many rows.
    int reap_dead();
    std::string describe() const override { return path_; }
    const std::string& path() const { return path_; }

    // Store and forward (forward.hpp): when set, every finished report is marked "pending"
    // for the shared store; the forwarder reads them oldest first and records the outcome.
    void set_spool(bool on) { spool_ = on; }
    struct Pending {
        std::string id, report;
    };
    std::vector<Pending> pending_forward(int limit) const;
    int pending_count() const;
    // state: pending, done, conflict, quarantined (a spooled report that cannot be sent:
    // error says why); store: the identity of the shared store that state refers to.
    void set_forwarded(const std::string& id, const std::string& state, const std::string& error = "", const std::string& store = "");
    // Rows forwarded ("done" or "conflict") to a store other than `store`, or before the
    // spool named stores: whether `store` holds them is for `store` to say (forward.cpp).
    struct Forwarded {
        std::string id, report_sha256;
    };
    std::vector<Forwarded> forwarded_elsewhere(const std::string& store, int limit) const;
    int spooled_count() const;  // rows with a report that went through the spool

private:
    void exec(const std::string& sql) const;
    [[noreturn]] void fail() const;
    bool row_alive(const std::string& instance, long long pid) const;
    std::string path_, dir_, instance_;
    sqlite3* db_ = nullptr;
    bool spool_ = false;
};

// $FRINGE_DATA, else $XDG_DATA_HOME/fringe, else ~/.local/share/fringe.
std::string default_data_dir();

// A --since / ?since= value as the store's ISO UTC text: an ISO date or time (2026-11-21,
// 2026-11-21T15:00:00Z), "today", "yesterday" or "Nd" (N days ago); throws ConfigError naming
// "since" for anything else, so a typo is an error, not an empty list.
std::string parse_since(const std::string& v);

}  // namespace fringe
