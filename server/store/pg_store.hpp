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

#include "server/store/store.hpp"

#include <map>
#include <memory>
#include <vector>

struct pg_conn;
struct pg_result;

namespace fringe {

// The shared store did not answer within its deadline (frozen, or the network is gone), or
// cannot be reached at all: the service answers 503 for what only it could tell.
class StoreUnreachable : public StoreError {
public:
    using StoreError::StoreError;
};

// "postgresql://fringe:secret@db/runs" -> "postgresql://fringe:***@db/runs": what messages
// name the store by. Errs on the side of hiding: the userinfo up to the last '@' (a raw '@' or
// '/' in a password), a password=... query parameter (also a percent-encoded key such as
// %70assword=) up to the next parameter, and password=... in key=value conninfo text
// (quoted or not), wherever they appear in the text.
std::string redact_store_uri(const std::string& uri);
// Any text (a libpq message, a log line) with every occurrence of the store's password (raw,
// percent-encoded or decoded) replaced by ***, after redact_store_uri.
std::string redact_store_text(const std::string& text, const std::string& uri);
// A PostgreSQL URI libpq would misread (a raw '@' or '/' in the user or password, a '%' not
// followed by two hex digits, %00): a message saying what to percent-encode, never the
// value; "" when it is fine.
std::string store_uri_problem(const std::string& uri);
// The per-statement deadline (seconds): FRINGE_STORE_TIMEOUT_S, else 10. Server side it is the
// statement_timeout (lock_timeout half of it); client side, the longest wait for the server
// to take or send a byte (a frozen server is "unreachable" after it, its connection dropped).
double store_timeout_s();

// A small RAII wrapper around libpq's connection and results.
class PgConn {
public:
    // Connects (connect_timeout min(5 s, the statement deadline) unless the URI sets one) and
    // sets statement_timeout, lock_timeout and idle_in_transaction_session_timeout; throws
    // StoreUnreachable (cannot connect, or no answer in time) or StoreError, naming the URI
    // without its password and libpq's message (also without it).
    explicit PgConn(const std::string& uri);
    ~PgConn();
    PgConn(const PgConn&) = delete;
    PgConn& operator=(const PgConn&) = delete;

    struct ResultDeleter {
        void operator()(pg_result* r) const;
    };
    using Result = std::unique_ptr<pg_result, ResultDeleter>;
    // One statement with $1..$n text parameters (nullopt: SQL NULL); throws StoreError
    // naming the store and libpq's message when it fails, StoreUnreachable when the server
    // takes no byte or sends none for store_timeout_s() (non-blocking I/O polled with that
    // deadline; the connection is then dropped and the next statement reconnects).
    Result exec(const std::string& sql, const std::vector<std::optional<std::string>>& params = {});
    bool ok() const;  // the connection is up (a failed statement may have found it lost)
    const std::string& describe() const { return shown_; }

    static int rows(const Result& r);
    static std::string value(const Result& r, int row, int col);
    static bool is_null(const Result& r, int row, int col);

private:
    void connect();
    void drop();
    [[noreturn]] void fail(const std::string& what, bool unreachable);
    pg_conn* c_ = nullptr;
    std::string uri_, shown_;
};

class PgStore : public RunStore {
public:
    // Connects and checks that the tables exist (to_regclass: a role with only SELECT, or
    // INSERT + SELECT, or a read replica uses them as they are); creates them only when one is
    // missing (under an advisory lock: many shards start at once). A role that may not create
    // them gets an error saying so: the owner creates them once (any fringe command with its
    // --store, or the SQL in docs/schema.md).
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
    // After a failed statement inside BEGIN: ROLLBACK if the connection still stands (its own
    // failure is ignored: the caller rethrows the first error).
    void rollback_quietly();
    std::unique_ptr<PgConn> conn_;
    std::string uri_;
};

}  // namespace fringe
