// Run history in SQLite (embedded, WAL, synchronous=FULL): one row per run with id, time,
// scenario, DUT/board id, status, verdict and the complete report. A run is inserted as
// "running" when it starts and its report is written in one transaction when it ends, so a
// killed process loses no completed report; a "running" row whose process is gone is listed
// as "interrupted".
#pragma once

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

struct sqlite3;

namespace fringe {

class StoreError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct RunRow {
    std::string id, created_at, scenario, dut, status, verdict;
};

struct RunFilter {
    std::string verdict;  // empty: any
    std::string scenario;
    std::string since;    // ISO time, inclusive
    int limit = 100;
};

class RunStore {
public:
    explicit RunStore(const std::string& db_path);
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
    std::optional<RunRow> row(const std::string& id) const;
    // Rows left "queued" or "running" by a process that is gone become "interrupted" for
    // good (the service calls this at start). Returns how many.
    int mark_dead_interrupted();
    const std::string& path() const { return path_; }

private:
    void exec(const std::string& sql) const;
    std::string path_;
    sqlite3* db_ = nullptr;
};

// $FRINGE_DATA, else $XDG_DATA_HOME/fringe, else ~/.local/share/fringe.
std::string default_data_dir();

}  // namespace fringe
