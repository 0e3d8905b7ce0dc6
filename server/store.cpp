#include "store.hpp"

#include <sqlite3.h>

#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <unistd.h>

namespace fringe {

namespace {
struct Stmt {
    sqlite3_stmt* s = nullptr;
    Stmt(sqlite3* db, const std::string& sql) {
        if (sqlite3_prepare_v2(db, sql.c_str(), -1, &s, nullptr) != SQLITE_OK)
            throw StoreError(std::string("run store: ") + sqlite3_errmsg(db) + " in: " + sql);
    }
    ~Stmt() { sqlite3_finalize(s); }
    void bind(int i, const std::string& v) { sqlite3_bind_text(s, i, v.c_str(), static_cast<int>(v.size()), SQLITE_TRANSIENT); }
    void bind(int i, long long v) { sqlite3_bind_int64(s, i, v); }
    std::string text(int i) const {
        const auto* p = sqlite3_column_text(s, i);
        return p ? reinterpret_cast<const char*>(p) : "";
    }
};
}  // namespace

std::string default_data_dir() {
    if (const char* d = std::getenv("FRINGE_DATA"); d && *d) return d;
    if (const char* x = std::getenv("XDG_DATA_HOME"); x && *x) return std::string(x) + "/fringe";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.local/share/fringe";
    return "fringe-data";
}

RunStore::RunStore(const std::string& path) : path_(path) {
    const auto dir = std::filesystem::path(path).parent_path();
    if (!dir.empty()) std::filesystem::create_directories(dir);
    if (sqlite3_open(path.c_str(), &db_) != SQLITE_OK) {
        const std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
        sqlite3_close(db_);
        db_ = nullptr;
        throw StoreError("run store " + path + ": " + msg);
    }
    sqlite3_busy_timeout(db_, 5000);
    exec("PRAGMA journal_mode=WAL");
    exec("PRAGMA synchronous=FULL");
    exec("CREATE TABLE IF NOT EXISTS runs (id TEXT PRIMARY KEY, created_at TEXT NOT NULL, scenario TEXT NOT NULL, "
         "dut TEXT NOT NULL, status TEXT NOT NULL, verdict TEXT, pid INTEGER, report TEXT)");
    exec("CREATE INDEX IF NOT EXISTS runs_created ON runs(created_at)");
}

RunStore::~RunStore() { sqlite3_close(db_); }

void RunStore::exec(const std::string& sql) const {
    char* err = nullptr;
    if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &err) != SQLITE_OK) {
        const std::string msg = err ? err : "?";
        sqlite3_free(err);
        throw StoreError("run store " + path_ + ": " + msg);
    }
}

namespace {
bool process_gone(long long pid) { return pid > 0 && kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH; }
}  // namespace

void RunStore::begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
                     const std::string& status) {
    Stmt st(db_, "INSERT INTO runs (id, created_at, scenario, dut, status, pid) VALUES (?, ?, ?, ?, ?, ?)");
    st.bind(1, id); st.bind(2, created_at); st.bind(3, scenario); st.bind(4, dut); st.bind(5, status);
    st.bind(6, static_cast<long long>(getpid()));
    if (sqlite3_step(st.s) != SQLITE_DONE) throw StoreError(std::string("run store: ") + sqlite3_errmsg(db_));
}

void RunStore::set_status(const std::string& id, const std::string& status) {
    Stmt st(db_, "UPDATE runs SET status = ?2 WHERE id = ?1");
    st.bind(1, id); st.bind(2, status);
    if (sqlite3_step(st.s) != SQLITE_DONE) throw StoreError(std::string("run store: ") + sqlite3_errmsg(db_));
}

std::optional<RunRow> RunStore::row(const std::string& id) const {
    Stmt st(db_, "SELECT id, created_at, scenario, dut, status, COALESCE(verdict, ''), COALESCE(pid, 0) FROM runs WHERE id = ?1");
    st.bind(1, id);
    if (sqlite3_step(st.s) != SQLITE_ROW) return std::nullopt;
    RunRow r{st.text(0), st.text(1), st.text(2), st.text(3), st.text(4), st.text(5)};
    if ((r.status == "running" || r.status == "queued") && process_gone(sqlite3_column_int64(st.s, 6))) r.status = "interrupted";
    return r;
}

int RunStore::mark_dead_interrupted() {
    std::vector<std::string> dead;
    {
        Stmt st(db_, "SELECT id, COALESCE(pid, 0) FROM runs WHERE status IN ('queued', 'running')");
        while (sqlite3_step(st.s) == SQLITE_ROW)
            if (process_gone(sqlite3_column_int64(st.s, 1))) dead.push_back(st.text(0));
    }
    for (const auto& id : dead) {
        Stmt st(db_, "UPDATE runs SET status = 'interrupted', verdict = 'ABORTED', pid = NULL WHERE id = ?1");
        st.bind(1, id);
        if (sqlite3_step(st.s) != SQLITE_DONE) throw StoreError(std::string("run store: ") + sqlite3_errmsg(db_));
    }
    return static_cast<int>(dead.size());
}

void RunStore::finish(const nlohmann::json& r) {
    const std::string dut = r["device"].is_object() ? r["device"].value("board_id", std::string()) : std::string();
    const std::string scen_dut = r["scenario"].value("dut", std::string());
    Stmt st(db_, "INSERT INTO runs (id, created_at, scenario, dut, status, verdict, pid, report) VALUES (?1, ?2, ?3, ?4, ?5, ?6, NULL, ?7) "
                 "ON CONFLICT(id) DO UPDATE SET status = ?5, verdict = ?6, pid = NULL, report = ?7, dut = ?4");
    st.bind(1, r["id"].get<std::string>());
    st.bind(2, r.value("started_at", std::string()));
    st.bind(3, r["scenario"].value("name", std::string()));
    st.bind(4, scen_dut.empty() ? dut : scen_dut);
    st.bind(5, r.value("status", std::string()));
    st.bind(6, r.value("verdict", std::string()));
    // A device's message may quote bytes that are not UTF-8: stored as U+FFFD, the report is kept.
    st.bind(7, r.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace));
    if (sqlite3_step(st.s) != SQLITE_DONE) throw StoreError(std::string("run store: ") + sqlite3_errmsg(db_));
}

std::vector<RunRow> RunStore::list(const RunFilter& f) const {
    std::string sql = "SELECT id, created_at, scenario, dut, status, COALESCE(verdict, ''), COALESCE(pid, 0) FROM runs WHERE 1";
    if (!f.verdict.empty()) sql += " AND verdict = ?1";
    if (!f.scenario.empty()) sql += " AND scenario = ?2";
    if (!f.since.empty()) sql += " AND created_at >= ?3";
    sql += " ORDER BY created_at DESC, id DESC LIMIT ?4";
    Stmt st(db_, sql);
    if (!f.verdict.empty()) st.bind(1, f.verdict);
    if (!f.scenario.empty()) st.bind(2, f.scenario);
    if (!f.since.empty()) st.bind(3, f.since);
    st.bind(4, static_cast<long long>(f.limit));
    std::vector<RunRow> out;
    while (sqlite3_step(st.s) == SQLITE_ROW) {
        RunRow r{st.text(0), st.text(1), st.text(2), st.text(3), st.text(4), st.text(5)};
        // A run whose process is gone never completed: report it as interrupted.
        if ((r.status == "running" || r.status == "queued") && process_gone(sqlite3_column_int64(st.s, 6))) r.status = "interrupted";
        out.push_back(std::move(r));
    }
    return out;
}

std::optional<nlohmann::json> RunStore::report(const std::string& id) const {
    Stmt st(db_, "SELECT report FROM runs WHERE id = ?1");
    st.bind(1, id);
    if (sqlite3_step(st.s) != SQLITE_ROW || sqlite3_column_type(st.s, 0) == SQLITE_NULL) return std::nullopt;
    return nlohmann::json::parse(st.text(0));
}

}  // namespace fringe
