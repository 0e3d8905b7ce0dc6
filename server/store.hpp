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
    std::string error, device;             // from the report, once finished
    std::uint64_t done = 0, total = 0;     // samples processed / planned, once finished
    bool dead = false;                     // stored as queued/running, but its instance is gone
};

struct RunFilter {
    std::string verdict;  // empty: any
    std::string scenario;
    std::string since;    // ISO time, inclusive
    int limit = 100;
};

class RunStore {
public:
    // instance: the id this process stamps on the rows it begins (see instance_lock.hpp);
    // "" for a reader (fringe runs).
    explicit RunStore(const std::string& db_path, std::string instance = "");
    ~RunStore();
    RunStore(const RunStore&) = delete;
    RunStore& operator=(const RunStore&) = delete;

    // status "running" (the CLI) or "queued" (the service); the row records this process.
    void begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
               const std::string& status = "running");
    void set_status(const std::string& id, const std::string& status);
    void finish(const nlohmann::json& report);  // by report["id"]; inserts if begin() was not called
    std::vector<RunRow> list(const RunFilter& f = {}) const;
    std::optional<nlohmann::json> report(const std::string& id) const;
    std::optional<std::string> report_text(const std::string& id) const;  // parse it outside any lock
    std::optional<RunRow> row(const std::string& id) const;
    // Rows left "queued" or "running" by an instance that is gone (its lock is free) become
    // "interrupted" for good: the service calls this at start, holding DATA/lock, so rows of
    // an earlier service are always caught, whatever PID it had. Returns how many.
    int mark_dead_interrupted();
    // The same for one row (a status read found its instance gone).
    void mark_interrupted(const std::string& id);
    const std::string& path() const { return path_; }

private:
    void exec(const std::string& sql) const;
    [[noreturn]] void fail() const;
    bool row_alive(const std::string& instance, long long pid) const;
    std::string path_, dir_, instance_;
    sqlite3* db_ = nullptr;
};

// $FRINGE_DATA, else $XDG_DATA_HOME/fringe, else ~/.local/share/fringe.
std::string default_data_dir();

}  // namespace fringe
