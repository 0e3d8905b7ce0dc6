#include "server/store/store.hpp"

#include "server/store/instance_lock.hpp"
#include "server/engine/provenance.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <sqlite3.h>
#include <fcntl.h>
#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <unistd.h>

namespace fringe {

using nlohmann::json;

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
    void bind_u64(int i, std::uint64_t v) { sqlite3_bind_int64(s, i, static_cast<sqlite3_int64>(v)); }
    std::string text(int i) const {
        // By length, not up to a NUL: a scenario name may hold one (it is escaped where shown).
        const auto* p = sqlite3_column_text(s, i);
        return p ? std::string(reinterpret_cast<const char*>(p), static_cast<std::size_t>(sqlite3_column_bytes(s, i))) : std::string();
    }
};
}  // namespace

std::string default_data_dir() {
    if (const char* d = std::getenv("FRINGE_DATA"); d && *d) return d;
    if (const char* x = std::getenv("XDG_DATA_HOME"); x && *x) return std::string(x) + "/fringe";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.local/share/fringe";
    return "fringe-data";
}

SqliteStore::SqliteStore(const std::string& path, std::string instance) : path_(path), instance_(std::move(instance)) {
    const auto dir = std::filesystem::path(path).parent_path();
    dir_ = dir.empty() ? "." : dir.string();
    if (!dir.empty()) std::filesystem::create_directories(dir);
    // Reports and scenarios are private like the token: create the file 0600 before SQLite
    // does (its -wal and -shm take the database's mode), and tighten an older one.
    if (const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600); fd >= 0) {
        struct stat st {};
        if (::fstat(fd, &st) == 0 && (st.st_mode & 077)) ::fchmod(fd, 0600);
        ::close(fd);
    }
    for (const char* suffix : {"-wal", "-shm"}) ::chmod((path + suffix).c_str(), 0600);  // if present
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
    // Columns added after the first release: the owning instance and the report's summary.
    std::vector<std::string> have;
    {
        Stmt st(db_, "PRAGMA table_info(runs)");
        while (sqlite3_step(st.s) == SQLITE_ROW) have.push_back(st.text(1));
    }
    bool backfill = false;
    for (const char* col : {"instance TEXT", "error TEXT", "samples_done INTEGER", "samples_total INTEGER", "device TEXT", "bench TEXT", "host TEXT",
                            "dut_part TEXT", "operator TEXT", "fringe_version TEXT", "scenario_sha256 TEXT", "report_sha256 TEXT",
                            "forward TEXT", "forward_error TEXT", "forward_store TEXT"}) {
        const std::string name = std::string(col).substr(0, std::string(col).find(' '));
        if (std::find(have.begin(), have.end(), name) != have.end()) continue;
        exec(std::string("ALTER TABLE runs ADD COLUMN ") + col);
        backfill = true;
    }
    if (backfill)  // once per database: later reads never parse a report
        exec("UPDATE runs SET error = json_extract(report, '$.error'), samples_done = json_extract(report, '$.samples.processed'), "
             "samples_total = json_extract(report, '$.samples.planned'), device = json_extract(report, '$.device.uri') "
             "WHERE report IS NOT NULL AND json_valid(report)");
}

SqliteStore::~SqliteStore() { sqlite3_close(db_); }

void SqliteStore::exec(const std::string& sql) const {
    char* err = nullptr;
    if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &err) != SQLITE_OK) {
        const std::string msg = err ? err : "?";
        sqlite3_free(err);
        throw StoreError("run store " + path_ + ": " + msg);
    }
}

void SqliteStore::fail() const {
    const std::string msg = std::string("run store ") + path_ + ": " + sqlite3_errmsg(db_);
    const int code = sqlite3_errcode(db_);
    const int sys = sqlite3_system_errno(db_);
    if (code == SQLITE_FULL || (code == SQLITE_IOERR && (sys == ENOSPC || sys == EFBIG || sys == EDQUOT))) throw StoreFull(msg);
    throw StoreError(msg);
}

namespace {
bool process_gone(long long pid) { return pid > 0 && kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH; }
}  // namespace

bool SqliteStore::row_alive(const std::string& instance, long long pid) const {
    if (instance.empty()) return !process_gone(pid);  // a row of an older fringe: only its PID to go by
    if (instance == instance_) return true;
    return instance_alive(dir_, instance);
}

void SqliteStore::begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
                        const std::string& status, const nlohmann::json& prov) {
    // A row without a report (an interrupted run of a deterministic sweep id) is taken over.
    if (auto old = row(id); old && old->dead) mark_interrupted(id);
    Stmt st(db_, "INSERT INTO runs (id, created_at, scenario, dut, status, pid, instance, bench, host, dut_part, operator) "
                 "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11) ON CONFLICT(id) DO UPDATE SET created_at = ?2, scenario = ?3, dut = ?4, "
                 "status = ?5, pid = ?6, instance = ?7, bench = ?8, host = ?9, dut_part = ?10, operator = ?11, verdict = NULL, error = NULL "
                 "WHERE runs.report IS NULL AND runs.status NOT IN ('queued', 'running')");
    st.bind(1, id); st.bind(2, created_at); st.bind(3, scenario); st.bind(4, dut); st.bind(5, status);
    st.bind(6, static_cast<long long>(getpid()));
    st.bind(7, instance_);
    const bool has = prov.is_object();
    st.bind(8, has ? prov.value("bench", std::string()) : std::string());
    st.bind(9, has ? prov.value("host", std::string()) : std::string());
    st.bind(10, has && prov["dut"].is_object() ? prov["dut"].value("part", std::string()) : std::string());
    st.bind(11, has ? prov.value("operator", std::string()) : std::string());
    if (sqlite3_step(st.s) != SQLITE_DONE) fail();
    if (sqlite3_changes(db_) == 0) throw StoreError("run store " + path_ + ": run " + id + " is already stored (or running)");
}

void SqliteStore::set_status(const std::string& id, const std::string& status) {
    Stmt st(db_, "UPDATE runs SET status = ?2 WHERE id = ?1");
    st.bind(1, id); st.bind(2, status);
    if (sqlite3_step(st.s) != SQLITE_DONE) fail();
}

namespace {
constexpr const char* kRowColumns = "id, created_at, scenario, dut, status, COALESCE(verdict, ''), COALESCE(pid, 0), COALESCE(instance, ''), "
                                    "COALESCE(error, ''), COALESCE(samples_done, 0), COALESCE(samples_total, 0), COALESCE(device, ''), "
                                    "COALESCE(bench, ''), COALESCE(host, ''), COALESCE(dut_part, ''), COALESCE(operator, ''), COALESCE(forward, ''), "
                                    "COALESCE(forward_store, '')";
RunRow read_row(const Stmt& st) {
    RunRow r;
    r.id = st.text(0);
    r.created_at = st.text(1);
    r.scenario = st.text(2);
    r.dut = st.text(3);
    r.status = st.text(4);
    r.verdict = st.text(5);
    r.error = st.text(8);
    r.done = static_cast<std::uint64_t>(sqlite3_column_int64(st.s, 9));
    r.total = static_cast<std::uint64_t>(sqlite3_column_int64(st.s, 10));
    r.device = st.text(11);
    r.bench = st.text(12);
    r.host = st.text(13);
    r.dut_part = st.text(14);
    r.operator_name = st.text(15);
    r.forward = st.text(16);
    r.forward_store = st.text(17);
    return r;
}
const char* kInterruptedError = "interrupted: the process that ran it stopped without finishing (killed, or the machine went down)";
}  // namespace

std::optional<RunRow> SqliteStore::row(const std::string& id) const {
    Stmt st(db_, std::string("SELECT ") + kRowColumns + " FROM runs WHERE id = ?1");
    st.bind(1, id);
    if (sqlite3_step(st.s) != SQLITE_ROW) return std::nullopt;
    RunRow r = read_row(st);
    if ((r.status == "running" || r.status == "queued") && !row_alive(st.text(7), sqlite3_column_int64(st.s, 6))) {
        r.status = "interrupted";
        r.verdict = "ABORTED";
        r.error = kInterruptedError;
        r.dead = true;
    }
    return r;
}

int SqliteStore::mark_dead_interrupted() {
    std::vector<std::string> dead;
    {
        Stmt st(db_, "SELECT id, COALESCE(instance, '') FROM runs WHERE status IN ('queued', 'running')");
        while (sqlite3_step(st.s) == SQLITE_ROW) {
            const std::string inst = st.text(1);
            // Rows without an instance come from an older fringe: gone, since we hold the folder.
            if (inst.empty() || (inst != instance_ && !instance_alive(dir_, inst))) dead.push_back(st.text(0));
        }
    }
    for (const auto& id : dead) mark_interrupted(id);
    return static_cast<int>(dead.size());
}

int SqliteStore::reap_dead() {
    std::vector<std::string> dead;
    {
        Stmt st(db_, "SELECT id, COALESCE(instance, ''), COALESCE(pid, 0) FROM runs WHERE status IN ('queued', 'running')");
        while (sqlite3_step(st.s) == SQLITE_ROW)
            if (!row_alive(st.text(1), sqlite3_column_int64(st.s, 2))) dead.push_back(st.text(0));
    }
    for (const auto& id : dead) mark_interrupted(id);
    // After the rows: a lock file removed says "gone" to every later reader as well.
    remove_stale_instance_locks(dir_);
    return static_cast<int>(dead.size());
}

void SqliteStore::mark_interrupted(const std::string& id) {
    Stmt st(db_, "UPDATE runs SET status = 'interrupted', verdict = 'ABORTED', pid = NULL, error = ?2 WHERE id = ?1 AND status IN ('queued', 'running')");
    st.bind(1, id);
    st.bind(2, std::string(kInterruptedError));
    if (sqlite3_step(st.s) != SQLITE_DONE) fail();
}

void SqliteStore::finish(const nlohmann::json& r) {
    const std::string dut = r["device"].is_object() ? r["device"].value("board_id", std::string()) : std::string();
    const std::string scen_dut = r["scenario"].value("dut", std::string());
    const json& prov = r.contains("provenance") && r["provenance"].is_object() ? r["provenance"] : json::object();
    const std::string prov_dut = prov.contains("dut") && prov["dut"].is_object() ? prov["dut"].value("serial", std::string()) : std::string();
    Stmt st(db_, "INSERT INTO runs (id, created_at, scenario, dut, status, verdict, pid, report, error, samples_done, samples_total, device, "
                 "bench, host, dut_part, operator, fringe_version, scenario_sha256, report_sha256, forward) "
                 "VALUES (?1, ?2, ?3, ?4, ?5, ?6, NULL, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, ?19) "
                 "ON CONFLICT(id) DO UPDATE SET status = ?5, verdict = ?6, pid = NULL, report = ?7, dut = ?4, error = ?8, "
                 "samples_done = ?9, samples_total = ?10, device = ?11, bench = ?12, host = ?13, dut_part = ?14, operator = ?15, "
                 "fringe_version = ?16, scenario_sha256 = ?17, report_sha256 = ?18, forward = ?19, forward_error = NULL, forward_store = NULL");
    st.bind(1, r["id"].get<std::string>());
    st.bind(2, r.value("started_at", std::string()));
    st.bind(3, r["scenario"].value("name", std::string()));
    st.bind(4, !scen_dut.empty() ? scen_dut : !prov_dut.empty() ? prov_dut : dut);
    st.bind(5, r.value("status", std::string()));
    st.bind(6, r.value("verdict", std::string()));
    // A device's message may quote bytes that are not UTF-8: stored as U+FFFD, the report is kept.
    st.bind(7, r.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace));
    // The summary a status query shows, so it never parses the report again.
    st.bind(8, r["error"].is_string() ? r["error"].get<std::string>() : std::string());
    const json& samples = r.contains("samples") && r["samples"].is_object() ? r["samples"] : json::object();
    st.bind_u64(9, samples.value("processed", std::uint64_t{0}));
    st.bind_u64(10, samples.value("planned", std::uint64_t{0}));
    st.bind(11, r.contains("device") && r["device"].is_object() ? r["device"].value("uri", std::string()) : std::string());
    st.bind(12, prov.value("bench", std::string()));
    st.bind(13, prov.value("host", std::string()));
    st.bind(14, prov.contains("dut") && prov["dut"].is_object() ? prov["dut"].value("part", std::string()) : std::string());
    st.bind(15, prov.value("operator", std::string()));
    st.bind(16, r.value("fringe_version", std::string()));
    st.bind(17, prov.value("scenario_sha256", std::string()));
    st.bind(18, report_checksum(r));
    if (spool_) st.bind(19, std::string("pending"));
    if (sqlite3_step(st.s) != SQLITE_DONE) fail();
}

std::vector<SqliteStore::Pending> SqliteStore::pending_forward(int limit) const {
    Stmt st(db_, "SELECT id, report FROM runs WHERE forward = 'pending' AND report IS NOT NULL ORDER BY created_at, id LIMIT ?1");
    st.bind(1, static_cast<long long>(limit));
    std::vector<Pending> out;
    while (sqlite3_step(st.s) == SQLITE_ROW) out.push_back({st.text(0), st.text(1)});
    return out;
}

int SqliteStore::pending_count() const {
    Stmt st(db_, "SELECT COUNT(*) FROM runs WHERE forward = 'pending'");
    return sqlite3_step(st.s) == SQLITE_ROW ? static_cast<int>(sqlite3_column_int64(st.s, 0)) : 0;
}

void SqliteStore::set_forwarded(const std::string& id, const std::string& state, const std::string& error, const std::string& store) {
    Stmt st(db_, "UPDATE runs SET forward = ?2, forward_error = ?3, forward_store = ?4 WHERE id = ?1");
    st.bind(1, id); st.bind(2, state); st.bind(3, error); st.bind(4, store);
    if (sqlite3_step(st.s) != SQLITE_DONE) fail();
}

std::vector<SqliteStore::Forwarded> SqliteStore::forwarded_elsewhere(const std::string& store, int limit) const {
    Stmt st(db_, "SELECT id, COALESCE(report_sha256, '') FROM runs WHERE forward IN ('done', 'conflict') AND report IS NOT NULL "
                 "AND COALESCE(forward_store, '') != ?1 ORDER BY created_at, id LIMIT ?2");
    st.bind(1, store);
    st.bind(2, static_cast<long long>(limit));
    std::vector<Forwarded> out;
    while (sqlite3_step(st.s) == SQLITE_ROW) out.push_back({st.text(0), st.text(1)});
    return out;
}

int SqliteStore::spooled_count() const {
    Stmt st(db_, "SELECT COUNT(*) FROM runs WHERE forward IN ('pending', 'done', 'conflict') AND report IS NOT NULL");
    return sqlite3_step(st.s) == SQLITE_ROW ? static_cast<int>(sqlite3_column_int64(st.s, 0)) : 0;
}

std::vector<RunRow> SqliteStore::list(const RunFilter& f) const {
    std::string sql = std::string("SELECT ") + kRowColumns + " FROM runs WHERE 1";
    if (!f.verdict.empty()) sql += " AND verdict = ?1";
    if (!f.scenario.empty()) sql += " AND scenario = ?2";
    if (!f.since.empty()) sql += " AND created_at >= ?3";
    if (!f.bench.empty()) sql += " AND bench = ?5";
    if (!f.dut.empty()) sql += " AND dut = ?6";
    sql += " ORDER BY created_at DESC, id DESC LIMIT ?4";
    Stmt st(db_, sql);
    if (!f.verdict.empty()) st.bind(1, f.verdict);
    if (!f.scenario.empty()) st.bind(2, f.scenario);
    if (!f.since.empty()) st.bind(3, f.since);
    if (!f.bench.empty()) st.bind(5, f.bench);
    if (!f.dut.empty()) st.bind(6, f.dut);
    st.bind(4, static_cast<long long>(f.limit));
    std::vector<RunRow> out;
    while (sqlite3_step(st.s) == SQLITE_ROW) {
        RunRow r = read_row(st);
        // A run whose instance is gone never completed: report it as interrupted.
        if ((r.status == "running" || r.status == "queued") && !row_alive(st.text(7), sqlite3_column_int64(st.s, 6))) {
            r.status = "interrupted";
            r.verdict = "ABORTED";
        }
        out.push_back(std::move(r));
    }
    return out;
}

std::optional<std::string> SqliteStore::report_text(const std::string& id) const {
    Stmt st(db_, "SELECT report FROM runs WHERE id = ?1");
    st.bind(1, id);
    if (sqlite3_step(st.s) != SQLITE_ROW || sqlite3_column_type(st.s, 0) == SQLITE_NULL) return std::nullopt;
    return st.text(0);
}

std::optional<nlohmann::json> RunStore::report(const std::string& id) const {
    auto t = report_text(id);
    if (!t) return std::nullopt;
    return parse_json_bounded(*t, "the stored report of run " + id, kMaxStoredJsonDepth);
}

// --since: an ISO date or time (2026-11-21, 2026-11-21T15:00:00Z), "today", "yesterday" or
// "Nd" (N days ago), as the store's ISO UTC text; anything else is an error, not an empty list.
std::string parse_since(const std::string& v) {
    auto day_start = [](std::time_t t) {
        std::tm tm{};
        gmtime_r(&t, &tm);
        char b[32];
        std::strftime(b, sizeof b, "%Y-%m-%dT00:00:00Z", &tm);
        return std::string(b);
    };
    const std::time_t now = std::time(nullptr);
    if (v == "today") return day_start(now);
    if (v == "yesterday") return day_start(now - 86400);
    if (v.size() >= 2 && v.back() == 'd' && v.find_first_not_of("0123456789") == v.size() - 1)
        return day_start(now - 86400 * static_cast<std::time_t>(std::stoll(v.substr(0, v.size() - 1))));
    std::tm tm{};
    const char* end = strptime(v.c_str(), "%Y-%m-%d", &tm);
    if (end) {
        // strptime takes any day 1-31 in any month: 2026-02-30 is no date, not March 2nd
        std::tm back{}, norm = tm;
        const std::time_t t = timegm(&norm);
        gmtime_r(&t, &back);
        if (back.tm_year != tm.tm_year || back.tm_mon != tm.tm_mon || back.tm_mday != tm.tm_mday)
            throw ConfigError("since", "'" + v + "' is not a date (month " + std::to_string(tm.tm_mon + 1) + " of " + std::to_string(tm.tm_year + 1900) +
                                           " has no day " + std::to_string(tm.tm_mday) + ")");
    }
    if (end && *end == 0) return v + "T00:00:00Z";
    if (end && (*end == 'T' || *end == ' ')) {
        const char* e2 = strptime(end + 1, "%H:%M", &tm);
        if (e2 && *e2 == ':') e2 = strptime(e2 + 1, "%S", &tm);
        if (e2 && (*e2 == 0 || (e2[0] == 'Z' && e2[1] == 0))) {
            char b[32];
            std::strftime(b, sizeof b, "%Y-%m-%dT%H:%M:%SZ", &tm);
            return b;
        }
    }
    throw ConfigError("since", "expected a date or time in UTC (2026-11-21, 2026-11-21T15:00:00Z), today, yesterday or Nd (N days ago); got '" + v + "'");
}

}  // namespace fringe
