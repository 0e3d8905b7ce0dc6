#include "pg_store.hpp"

#include "provenance.hpp"

#ifndef FRINGE_NO_POSTGRES
#include <libpq-fe.h>
#endif

namespace fringe {

using nlohmann::json;

namespace {
// libpq's messages end in a newline and continue on tab-indented lines: one line for a log.
std::string one_line(std::string m) {
    while (!m.empty() && (m.back() == '\n' || m.back() == ' ')) m.pop_back();
    for (std::size_t p; (p = m.find("\n\t")) != std::string::npos;) m.replace(p, 2, "; ");
    for (auto& c : m)
        if (c == '\n' || c == '\t') c = ' ';
    return m;
}
}  // namespace

std::string redact_store_uri(const std::string& uri) {
    std::string s = uri;
    // postgresql://user:password@host: the password is between the first ':' after the scheme and '@'.
    if (const auto scheme = s.find("://"); scheme != std::string::npos) {
        const auto at = s.find('@', scheme + 3);
        const auto slash = s.find('/', scheme + 3);
        if (at != std::string::npos && (slash == std::string::npos || at < slash)) {
            const auto colon = s.find(':', scheme + 3);
            if (colon != std::string::npos && colon < at) s.replace(colon + 1, at - colon - 1, "***");
        }
    }
    // ...?password=secret&...
    for (std::size_t p = s.find("password="); p != std::string::npos; p = s.find("password=", p + 1)) {
        if (p > 0 && s[p - 1] != '?' && s[p - 1] != '&' && s[p - 1] != ' ') continue;
        const auto end = s.find_first_of("& ", p);
        s.replace(p + 9, (end == std::string::npos ? s.size() : end) - p - 9, "***");
    }
    return s;
}

#ifndef FRINGE_NO_POSTGRES
void PgConn::ResultDeleter::operator()(pg_result* r) const { PQclear(r); }

PgConn::PgConn(const std::string& uri) : shown_(redact_store_uri(uri)) {
    // The URI's own keys come after the default, so a connect_timeout in it wins.
    const char* keys[] = {"connect_timeout", "dbname", nullptr};
    const char* vals[] = {"5", uri.c_str(), nullptr};
    c_ = PQconnectdbParams(keys, vals, 1);
    if (!c_) throw StoreError("run store " + shown_ + ": out of memory");
    if (PQstatus(c_) != CONNECTION_OK) {
        const std::string msg = one_line(PQerrorMessage(c_));
        PQfinish(c_);
        c_ = nullptr;
        throw StoreError("run store " + shown_ + ": cannot connect: " + msg);
    }
    PQsetNoticeProcessor(c_, [](void*, const char*) {}, nullptr);  // "relation exists, skipping" and the like
}

PgConn::~PgConn() {
    if (c_) PQfinish(c_);
}

bool PgConn::ok() const { return c_ && PQstatus(c_) == CONNECTION_OK; }

PgConn::Result PgConn::exec(const std::string& sql, const std::vector<std::optional<std::string>>& params) {
    if (PQstatus(c_) != CONNECTION_OK) PQreset(c_);  // the server restarted since the last statement
    std::vector<const char*> values;
    std::vector<int> lengths;
    for (const auto& p : params) {
        values.push_back(p ? p->c_str() : nullptr);
        lengths.push_back(p ? static_cast<int>(p->size()) : 0);
    }
    Result r(PQexecParams(c_, sql.c_str(), static_cast<int>(params.size()), nullptr, values.data(), lengths.data(), nullptr, 0));
    const auto st = r ? PQresultStatus(r.get()) : PGRES_FATAL_ERROR;
    if (st != PGRES_COMMAND_OK && st != PGRES_TUPLES_OK) {
        std::string msg = r ? PQresultErrorMessage(r.get()) : "";
        if (msg.empty()) msg = PQerrorMessage(c_);
        throw StoreError("run store " + shown_ + ": " + one_line(msg));
    }
    return r;
}

int PgConn::rows(const Result& r) { return PQntuples(r.get()); }
std::string PgConn::value(const Result& r, int row, int col) {
    return std::string(PQgetvalue(r.get(), row, col), static_cast<std::size_t>(PQgetlength(r.get(), row, col)));
}
bool PgConn::is_null(const Result& r, int row, int col) { return PQgetisnull(r.get(), row, col) != 0; }
#else
// Built with -DFRINGE_POSTGRES=OFF (no libpq): a PostgreSQL --store is refused with this message.
void PgConn::ResultDeleter::operator()(pg_result*) const {}
PgConn::PgConn(const std::string& uri) : shown_(redact_store_uri(uri)) {
    throw StoreError("run store " + shown_ + ": this fringe was built without PostgreSQL (cmake -DFRINGE_POSTGRES=OFF); rebuild with libpq-dev installed");
}
PgConn::~PgConn() = default;
bool PgConn::ok() const { return false; }
PgConn::Result PgConn::exec(const std::string&, const std::vector<std::optional<std::string>>&) { throw StoreError("run store " + shown_ + ": no PostgreSQL in this build"); }
int PgConn::rows(const Result&) { return 0; }
std::string PgConn::value(const Result&, int, int) { return {}; }
bool PgConn::is_null(const Result&, int, int) { return true; }
#endif

namespace {

// jsonb refuses U+0000 in strings (a scenario name may hold one): stored as U+FFFD.
void strip_nul(json& j) {
    if (j.is_string()) {
        auto& s = j.get_ref<std::string&>();
        for (std::size_t p; (p = s.find('\0')) != std::string::npos;) s.replace(p, 1, "\xEF\xBF\xBD");
    } else if (j.is_structured()) {
        for (auto& v : j) strip_nul(v);
    }
}
std::string strip_nul(std::string s) {
    for (std::size_t p; (p = s.find('\0')) != std::string::npos;) s.replace(p, 1, "\xEF\xBF\xBD");
    return s;
}

constexpr const char* kSchema[] = {
    "CREATE TABLE IF NOT EXISTS runs (id text PRIMARY KEY, created_at text NOT NULL, scenario text NOT NULL, dut text NOT NULL DEFAULT '', "
    "dut_part text NOT NULL DEFAULT '', bench text NOT NULL DEFAULT '', host text NOT NULL DEFAULT '', operator text NOT NULL DEFAULT '', "
    "fringe_version text NOT NULL DEFAULT '', scenario_sha256 text NOT NULL DEFAULT '', status text NOT NULL, verdict text, error text, "
    "samples_done bigint, samples_total bigint, device text, report jsonb, report_sha256 text, stored_at timestamptz NOT NULL DEFAULT now())",
    "CREATE INDEX IF NOT EXISTS runs_created ON runs (created_at)",
    "CREATE INDEX IF NOT EXISTS runs_bench ON runs (bench, created_at)",
    "CREATE INDEX IF NOT EXISTS runs_dut ON runs (dut, created_at)",
    // A different report under a stored id: kept here for a person to look at, never merged.
    "CREATE TABLE IF NOT EXISTS run_conflicts (id text NOT NULL, report_sha256 text NOT NULL, bench text NOT NULL DEFAULT '', "
    "host text NOT NULL DEFAULT '', report jsonb, seen_at timestamptz NOT NULL DEFAULT now(), PRIMARY KEY (id, report_sha256))",
};

constexpr const char* kRowColumns = "id, created_at, scenario, dut, status, COALESCE(verdict, ''), COALESCE(error, ''), COALESCE(samples_done, 0), "
                                    "COALESCE(samples_total, 0), COALESCE(device, ''), bench, host, dut_part, operator";

RunRow read_row(const PgConn::Result& r, int i) {
    RunRow row;
    row.id = PgConn::value(r, i, 0);
    row.created_at = PgConn::value(r, i, 1);
    row.scenario = PgConn::value(r, i, 2);
    row.dut = PgConn::value(r, i, 3);
    row.status = PgConn::value(r, i, 4);
    row.verdict = PgConn::value(r, i, 5);
    row.error = PgConn::value(r, i, 6);
    row.done = std::stoull(PgConn::value(r, i, 7));
    row.total = std::stoull(PgConn::value(r, i, 8));
    row.device = PgConn::value(r, i, 9);
    row.bench = PgConn::value(r, i, 10);
    row.host = PgConn::value(r, i, 11);
    row.dut_part = PgConn::value(r, i, 12);
    row.operator_name = PgConn::value(r, i, 13);
    return row;
}

}  // namespace

PgStore::PgStore(const std::string& uri) : conn_(std::make_unique<PgConn>(uri)), uri_(uri) {
    conn_->exec("BEGIN");
    try {
        // Concurrent CREATE ... IF NOT EXISTS can still collide in the catalogue: one at a time.
        conn_->exec("SELECT pg_advisory_xact_lock(7348263511)");
        for (const char* sql : kSchema) conn_->exec(sql);
        conn_->exec("COMMIT");
    } catch (...) {
        if (conn_->ok()) conn_->exec("ROLLBACK");
        throw;
    }
}

PgStore::~PgStore() = default;

std::string PgStore::describe() const { return conn_->describe(); }
bool PgStore::connected() const { return conn_->ok(); }

void PgStore::begin(const std::string& id, const std::string& created_at, const std::string& scenario, const std::string& dut,
                    const std::string& status, const json& prov) {
    const bool has = prov.is_object();
    auto r = conn_->exec(
        "INSERT INTO runs (id, created_at, scenario, dut, status, bench, host, dut_part, operator) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9) "
        "ON CONFLICT (id) DO UPDATE SET status = $5 WHERE runs.report IS NULL RETURNING id",
        {id, created_at, strip_nul(scenario), dut, status, has ? prov.value("bench", std::string()) : "", has ? prov.value("host", std::string()) : "",
         has && prov["dut"].is_object() ? prov["dut"].value("part", std::string()) : "", has ? prov.value("operator", std::string()) : ""});
    if (PgConn::rows(r) == 0) throw StoreError("run store " + describe() + ": run " + id + " is already stored");
}

void PgStore::set_status(const std::string& id, const std::string& status) {
    conn_->exec("UPDATE runs SET status = $2 WHERE id = $1 AND report IS NULL", {id, status});
}

void PgStore::mark_interrupted(const std::string& id) {
    conn_->exec("UPDATE runs SET status = 'interrupted', verdict = 'ABORTED' WHERE id = $1 AND status IN ('queued', 'running')", {id});
}

PgStore::Put PgStore::put(const json& report) {
    json r = report;
    strip_nul(r);
    const std::string sum = report_checksum(r);
    const json& prov = r.contains("provenance") && r["provenance"].is_object() ? r["provenance"] : json::object();
    const json& dutj = prov.contains("dut") && prov["dut"].is_object() ? prov["dut"] : json::object();
    const std::string dev_dut = r["device"].is_object() ? r["device"].value("board_id", std::string()) : std::string();
    std::string dut = r["scenario"].value("dut", std::string());
    if (dut.empty()) dut = dutj.value("serial", std::string());
    if (dut.empty()) dut = dev_dut;
    const json& samples = r.contains("samples") && r["samples"].is_object() ? r["samples"] : json::object();
    const std::string text = canonical_json(r);
    const std::string id = r["id"].get<std::string>();
    const std::string bench = prov.value("bench", std::string()), host = prov.value("host", std::string());
    conn_->exec("BEGIN");
    try {
        // A row begun here without a report (PgStore::begin) is completed; a reported one is never touched.
        auto ins = conn_->exec(
            "INSERT INTO runs (id, created_at, scenario, dut, dut_part, bench, host, operator, fringe_version, scenario_sha256, status, verdict, "
            "error, samples_done, samples_total, device, report, report_sha256) "
            "VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16, $17::jsonb, $18) "
            "ON CONFLICT (id) DO UPDATE SET status = EXCLUDED.status, verdict = EXCLUDED.verdict, error = EXCLUDED.error, "
            "samples_done = EXCLUDED.samples_done, samples_total = EXCLUDED.samples_total, device = EXCLUDED.device, report = EXCLUDED.report, "
            "report_sha256 = EXCLUDED.report_sha256, dut = EXCLUDED.dut, fringe_version = EXCLUDED.fringe_version, "
            "scenario_sha256 = EXCLUDED.scenario_sha256, stored_at = now() WHERE runs.report IS NULL RETURNING id",
            {id, r.value("started_at", std::string()), r["scenario"].value("name", std::string()), dut, dutj.value("part", std::string()), bench, host,
             prov.value("operator", std::string()), r.value("fringe_version", std::string()), prov.value("scenario_sha256", std::string()),
             r.value("status", std::string()), r.value("verdict", std::string()), r["error"].is_string() ? std::optional(r["error"].get<std::string>()) : std::nullopt,
             std::to_string(samples.value("processed", std::uint64_t{0})), std::to_string(samples.value("planned", std::uint64_t{0})),
             r["device"].is_object() ? r["device"].value("uri", std::string()) : std::string(), text, sum});
        Put out = Put::Inserted;
        if (PgConn::rows(ins) == 0) {
            auto have = conn_->exec("SELECT COALESCE(report_sha256, '') FROM runs WHERE id = $1", {id});
            if (PgConn::rows(have) == 1 && PgConn::value(have, 0, 0) == sum) {
                out = Put::Same;
            } else {
                out = Put::Conflict;
                conn_->exec("INSERT INTO run_conflicts (id, report_sha256, bench, host, report) VALUES ($1, $2, $3, $4, $5::jsonb) "
                            "ON CONFLICT DO NOTHING",
                            {id, sum, bench, host, text});
            }
        }
        conn_->exec("COMMIT");
        return out;
    } catch (...) {
        if (conn_->ok()) {
            try {
                conn_->exec("ROLLBACK");
            } catch (const StoreError&) {
            }
        }
        throw;
    }
}

void PgStore::finish(const json& report) {
    if (put(report) == Put::Conflict)
        throw StoreError("run store " + describe() + ": run " + report["id"].get<std::string>() +
                         " is already stored with a different report; this one is kept in run_conflicts");
}

std::vector<RunRow> PgStore::list(const RunFilter& f) const {
    std::string sql = std::string("SELECT ") + kRowColumns + " FROM runs WHERE true";
    std::vector<std::optional<std::string>> p;
    auto add = [&](const char* column_op, const std::string& v) {
        p.push_back(v);
        sql += std::string(" AND ") + column_op + " $" + std::to_string(p.size());
    };
    if (!f.verdict.empty()) add("verdict =", f.verdict);
    if (!f.scenario.empty()) add("scenario =", f.scenario);
    if (!f.since.empty()) add("created_at >=", f.since);
    if (!f.bench.empty()) add("bench =", f.bench);
    if (!f.dut.empty()) add("dut =", f.dut);
    p.push_back(std::to_string(f.limit));
    sql += " ORDER BY created_at DESC, id DESC LIMIT $" + std::to_string(p.size());
    auto r = conn_->exec(sql, p);
    std::vector<RunRow> out;
    for (int i = 0; i < PgConn::rows(r); ++i) out.push_back(read_row(r, i));
    return out;
}

std::optional<std::string> PgStore::report_text(const std::string& id) const {
    auto r = conn_->exec("SELECT report::text FROM runs WHERE id = $1 AND report IS NOT NULL", {id});
    if (PgConn::rows(r) == 0) return std::nullopt;
    return PgConn::value(r, 0, 0);
}

std::optional<RunRow> PgStore::row(const std::string& id) const {
    auto r = conn_->exec(std::string("SELECT ") + kRowColumns + " FROM runs WHERE id = $1", {id});
    if (PgConn::rows(r) == 0) return std::nullopt;
    return read_row(r, 0);
}

std::string PgStore::identity() {
    try {
        auto r = conn_->exec("SELECT system_identifier::text, current_database() FROM pg_control_system()");
        if (PgConn::rows(r) == 1) return "pg:" + PgConn::value(r, 0, 0) + "/" + PgConn::value(r, 0, 1);
    } catch (const StoreError&) {
        if (!conn_->ok()) throw;  // the connection, not the permission
    }
    return "uri:" + describe();
}

std::map<std::string, std::string> PgStore::stored_checksums(const std::vector<std::string>& ids) {
    // One text[] parameter: {"id1","id2"} with " and \ escaped.
    std::string arr = "{";
    for (const auto& id : ids) {
        if (arr.size() > 1) arr += ',';
        arr += '"';
        for (const char c : id) {
            if (c == '"' || c == '\\') arr += '\\';
            arr += c;
        }
        arr += '"';
    }
    arr += '}';
    auto r = conn_->exec("SELECT id, COALESCE(report_sha256, '') FROM runs WHERE id = ANY($1::text[]) AND report IS NOT NULL", {arr});
    std::map<std::string, std::string> out;
    for (int i = 0; i < PgConn::rows(r); ++i) out[PgConn::value(r, i, 0)] = PgConn::value(r, i, 1);
    return out;
}

}  // namespace fringe
