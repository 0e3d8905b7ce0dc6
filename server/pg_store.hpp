// The run history in PostgreSQL, shared by many benches (libpq; parameterised queries only:
// every value a user or a report supplies travels as a PQexecParams parameter, never inside
// the SQL text). Reports are stored as jsonb with a SHA-256 checksum of their results
// (provenance.hpp, report_checksum). Writes are idempotent by run id: the same report again
// is a no-op, a different report under a stored id is recorded in run_conflicts and never
// overwrites the stored one.
//
// Benches do not write here directly: they write their local SQLite first and forward
// (forward.hpp), so an outage of the database loses nothing. Readers (fringe runs --store,
// fringe sweep --collect) and the forwarder use this class.
#pragma once

#include "store.hpp"

#include <map>
#include <memory>
#include <vector>

struct pg_conn;
struct pg_result;

namespace fringe {

// "postgresql://fringe:secret@db/runs" -> "postgresql://fringe:***@db/runs" (also a
// password=... query parameter): what messages name the store by.
std::string redact_store_uri(const std::string& uri);

// A small RAII wrapper around libpq's connection and results.
class PgConn {
public:
    // Connects (connect_timeout 5 s unless the URI sets one); throws StoreError naming the
    // URI without its password and libpq's message.
    explicit PgConn(const std::string& uri);
    ~PgConn();
    PgConn(const PgConn&) = delete;
    PgConn& operator=(const PgConn&) = delete;

    struct ResultDeleter {
        void operator()(pg_result* r) const;
    };
    using Result = std::unique_ptr<pg_result, ResultDeleter>;
    // One statement with $1..$n text parameters (nullopt: SQL NULL); throws StoreError
    // naming the store and libpq's message when it fails.
    Result exec(const std::string& sql, const std::vector<std::optional<std::string>>& params = {});
    bool ok() const;  // the connection is up (a failed statement may have found it lost)
    const std::string& describe() const { return shown_; }

    static int rows(const Result& r);
    static std::string value(const Result& r, int row, int col);
    static bool is_null(const Result& r, int row, int col);

private:
    pg_conn* c_ = nullptr;
    std::string shown_;
};

class PgStore : public RunStore {
public:
    // Connects and creates the tables if missing (under an advisory lock: many shards start at once).
    explicit PgStore(const std::string& uri);
    ~PgStore() override;

    void begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
               const std::string& status = "running", const nlohmann::json& provenance = nullptr) override;
    void set_status(const std::string& id, const std::string& status) override;
    void finish(const nlohmann::json& report) override;  // put(), a conflict throws
    std::vector<RunRow> list(const RunFilter& f = {}) const override;
    std::optional<std::string> report_text(const std::string& id) const override;
    std::optional<RunRow> row(const std::string& id) const override;
    // Liveness of a row cannot be judged across hosts: rows are forwarded once finished.
    int mark_dead_interrupted() override { return 0; }
    void mark_interrupted(const std::string& id) override;
    std::string describe() const override;

    enum class Put { Inserted, Same, Conflict };
    // The idempotent write: INSERT ... ON CONFLICT (id) DO NOTHING, then the stored checksum
    // decides Same or Conflict (the latter is recorded in run_conflicts).
    Put put(const nlohmann::json& report);
    bool connected() const;
    // Which store this is, whatever URI reached it: "pg:" + the server's system identifier
    // (pg_control_system(): new with every initdb, so a fresh or replaced server differs) +
    // "/" + the database name. When that function is not allowed, "uri:" + the URI without
    // its password.
    std::string identity();
    // Of these run ids, the ones stored here with a report, each with its report_sha256.
    std::map<std::string, std::string> stored_checksums(const std::vector<std::string>& ids);

private:
    std::unique_ptr<PgConn> conn_;
    std::string uri_;
};

}  // namespace fringe
