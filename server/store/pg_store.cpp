#include "server/store/pg_store.hpp"

#include "server/engine/provenance.hpp"

#include <spdlog/spdlog.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>

#ifndef FRINGE_NO_POSTGRES
#include <libpq-fe.h>
#include <poll.h>
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

namespace {
bool is_hex(char c) { return std::isxdigit(static_cast<unsigned char>(c)) != 0; }

// %XX decoded; a '%' without two hex digits after it stays as it is.
std::string pct_decode(const std::string& s) {
    std::string out;
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (s[i] == '%' && i + 2 < s.size() && is_hex(s[i + 1]) && is_hex(s[i + 2])) {
            out += static_cast<char>(std::stoi(s.substr(i + 1, 2), nullptr, 16));
            i += 2;
        } else {
            out += s[i];
        }
    }
    return out;
}

// A query parameter's key: letters, digits, '_' or %XX, then '='.
bool key_at(const std::string& s, std::size_t p) {
    std::size_t i = p;
    while (i < s.size() && (std::isalnum(static_cast<unsigned char>(s[i])) || s[i] == '_' || s[i] == '%')) ++i;
    return i > p && i < s.size() && s[i] == '=';
}

// Where password values are in a URI's query or in conninfo text: [begin, end) of each value
// (quotes included) after a key that percent-decodes to "password" in any case (%70assword=).
// A value runs to the next "&key=" or " key=", so an '&' or a space inside it stays hidden.
std::vector<std::pair<std::size_t, std::size_t>> password_ranges(const std::string& s) {
    std::vector<std::pair<std::size_t, std::size_t>> out;
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (i > 0 && s[i - 1] != '?' && s[i - 1] != '&' && s[i - 1] != ' ' && s[i - 1] != '\t') continue;
        if (!key_at(s, i)) continue;
        const auto eq = s.find('=', i);
        std::string key = pct_decode(s.substr(i, eq - i));
        for (auto& c : key) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        if (key != "password") continue;
        std::size_t v = eq + 1, e = v;
        if (v < s.size() && s[v] == '\'') {  // conninfo: 'quoted \' value'
            e = v + 1;
            while (e < s.size() && s[e] != '\'') e += s[e] == '\\' ? 2 : 1;
            e = std::min(e + 1, s.size());
        } else {
            while (e < s.size() && !((s[e] == '&' || s[e] == ' ') && key_at(s, e + 1))) ++e;
        }
        out.emplace_back(v, e);
        i = e;
    }
    return out;
}

std::string redact_password_keys(std::string s) {
    const auto ranges = password_ranges(s);
    for (auto it = ranges.rbegin(); it != ranges.rend(); ++it) s.replace(it->first, it->second - it->first, "***");
    return s;
}

// The password values a URI or conninfo text carries, as written (secrets to scrub).
std::vector<std::string> password_values(const std::string& s) {
    std::vector<std::string> out;
    if (const auto scheme = s.find("://"); scheme != std::string::npos) {
        const auto at = s.rfind('@');
        if (at != std::string::npos && at > scheme) {
            const auto colon = s.find(':', scheme + 3);
            if (colon != std::string::npos && colon < at) out.push_back(s.substr(colon + 1, at - colon - 1));
        }
    }
    for (const auto& [b, e] : password_ranges(s)) {
        std::string v = s.substr(b, e - b);
        if (v.size() >= 2 && v.front() == '\'' && v.back() == '\'') v = v.substr(1, v.size() - 2);
        out.push_back(v);
    }
    return out;
}
}  // namespace

std::string redact_store_uri(const std::string& uri) {
    std::string s = uri;
    // postgresql://user:password@host: from the first ':' after the scheme to the LAST '@' (a raw
    // '@' or '/' in the password is hidden too; at worst more than the password is).
    if (const auto scheme = s.find("://"); scheme != std::string::npos) {
        const auto at = s.rfind('@');
        if (at != std::string::npos && at > scheme) {
            const auto colon = s.find(':', scheme + 3);
            if (colon != std::string::npos && colon < at) s.replace(colon + 1, at - colon - 1, "***");
        }
    }
    return redact_password_keys(s);
}

std::string redact_store_text(const std::string& text, const std::string& uri) {
    std::string s = text;
    // The URI itself wherever it appears, then any password value left (a libpq message may
    // quote a part of the URI, decoded or not).
    if (!uri.empty())
        for (std::size_t p = s.find(uri); p != std::string::npos; p = s.find(uri, p + 1)) s.replace(p, uri.size(), redact_store_uri(uri));
    s = redact_password_keys(s);
    for (const auto& pw : password_values(uri)) {
        for (const std::string& secret : {pw, pct_decode(pw)}) {
            if (secret.size() < 3 || secret == "***") continue;  // too short to find without mangling the text
            for (std::size_t p = s.find(secret); p != std::string::npos; p = s.find(secret, p + 3)) s.replace(p, secret.size(), "***");
        }
    }
    return s;
}

std::string store_uri_problem(const std::string& uri) {
    std::vector<std::string> bad;
    for (std::size_t i = 0; i < uri.size(); ++i) {
        if (uri[i] != '%') continue;
        if (i + 2 >= uri.size() || !is_hex(uri[i + 1]) || !is_hex(uri[i + 2])) {
            bad.push_back("a '%' not followed by two hex digits (write a '%' in a user, password or value as %25)");
            break;
        }
        if (uri[i + 1] == '0' && uri[i + 2] == '0') {
            bad.push_back("%00 (a NUL byte, which libpq refuses)");
            break;
        }
    }
    if (const auto scheme = uri.find("://"); scheme != std::string::npos) {
        // libpq takes the userinfo up to the first '@' or '/' after the scheme: a raw '@' or
        // '/' in the password makes it connect somewhere else, with a part of the password as
        // the host or database name.
        const auto q = uri.find('?', scheme + 3);
        const std::string head = uri.substr(scheme + 3, q == std::string::npos ? std::string::npos : q - scheme - 3);
        const auto first_at = head.find('@'), last_at = head.rfind('@');
        if (first_at != std::string::npos) {
            if (first_at != last_at) bad.push_back("more than one '@' before the host (write an '@' in a user or password as %40)");
            const auto slash = head.find('/');
            if (slash != std::string::npos && slash < last_at) bad.push_back("a '/' before the '@' (write a '/' in a user or password as %2F)");
        }
    }
    std::string out;
    for (const auto& b : bad) out += (out.empty() ? "" : "; ") + b;
    return out;
}

double store_timeout_s() {
    if (const char* e = std::getenv("FRINGE_STORE_TIMEOUT_S")) {
        char* end = nullptr;
        const double v = std::strtod(e, &end);
        if (end != e && *end == '\0' && std::isfinite(v) && v >= 0.1 && v <= 3600) return v;
        spdlog::warn("FRINGE_STORE_TIMEOUT_S='{}' is not a number of seconds from 0.1 to 3600; using 10", e);
    }
    return 10.0;
}

#ifndef FRINGE_NO_POSTGRES
void PgConn::ResultDeleter::operator()(pg_result* r) const { PQclear(r); }

PgConn::PgConn(const std::string& uri) : uri_(uri), shown_(redact_store_uri(uri)) {
    if (const std::string bad = store_uri_problem(uri); !bad.empty()) throw StoreError("run store " + shown_ + ": the URI holds " + bad);
    connect();
}

void PgConn::connect() {
    const double t_s = store_timeout_s();
    // The URI's own keys come after the defaults, so a connect_timeout in it wins. Keepalives
    // find a peer whose host is gone; tcp_user_timeout bounds unacknowledged sends (TCP only).
    const std::string connect_s = std::to_string(std::max(1, static_cast<int>(std::min(5.0, t_s))));
    const std::string user_timeout_ms = std::to_string(static_cast<long>(t_s * 1000));
    const char* keys[] = {"connect_timeout", "keepalives", "keepalives_idle", "keepalives_interval", "keepalives_count", "tcp_user_timeout", "dbname", nullptr};
    const char* vals[] = {connect_s.c_str(), "1", "10", "5", "3", user_timeout_ms.c_str(), uri_.c_str(), nullptr};
    c_ = PQconnectdbParams(keys, vals, 1);
    if (!c_) throw StoreError("run store " + shown_ + ": out of memory");
    if (PQstatus(c_) != CONNECTION_OK) {
        const std::string msg = redact_store_text(one_line(PQerrorMessage(c_)), uri_);
        PQfinish(c_);
        c_ = nullptr;
        throw StoreUnreachable("run store " + shown_ + ": cannot connect: " + msg);
    }
    PQsetNoticeProcessor(c_, [](void*, const char*) {}, nullptr);  // "relation exists, skipping" and the like
    if (PQsetnonblocking(c_, 1) != 0) fail("cannot make the connection non-blocking", false);
    // Server-side bounds: a statement, a lock wait and an idle open transaction (a client that
    // froze mid-transaction) never hold the database for longer.
    const long ms = static_cast<long>(t_s * 1000);
    exec("SELECT set_config('statement_timeout', $1, false), set_config('lock_timeout', $2, false), "
         "set_config('idle_in_transaction_session_timeout', $3, false)",
         {std::to_string(ms), std::to_string(std::max(100L, ms / 2)), std::to_string(std::max(1000L, 6 * ms))});
}

void PgConn::drop() {
    if (c_) PQfinish(c_);
    c_ = nullptr;
}

void PgConn::fail(const std::string& what, bool unreachable) {
    std::string msg = c_ ? one_line(PQerrorMessage(c_)) : std::string();
    msg = redact_store_text(msg.empty() ? what : what + ": " + msg, uri_);
    drop();  // a connection in an unknown state is never reused
    if (unreachable) throw StoreUnreachable("run store " + shown_ + ": " + msg);
    throw StoreError("run store " + shown_ + ": " + msg);
}

PgConn::~PgConn() { drop(); }

bool PgConn::ok() const { return c_ && PQstatus(c_) == CONNECTION_OK; }

PgConn::Result PgConn::exec(const std::string& sql, const std::vector<std::optional<std::string>>& params) {
    if (!c_) {
        connect();  // dropped after a timeout, or never made
    } else if (PQstatus(c_) != CONNECTION_OK) {
        drop();  // the server restarted since the last statement
        connect();
    }
    std::vector<const char*> values;
    std::vector<int> lengths;
    for (const auto& p : params) {
        values.push_back(p ? p->c_str() : nullptr);
        lengths.push_back(p ? static_cast<int>(p->size()) : 0);
    }
    if (!PQsendQueryParams(c_, sql.c_str(), static_cast<int>(params.size()), nullptr, values.data(), lengths.data(), nullptr, 0))
        fail("cannot send the statement", PQstatus(c_) != CONNECTION_OK);
    // Send and receive without blocking: each wait for the socket is bounded, so a server that
    // stops answering (SIGSTOP, a hung host) costs at most store_timeout_s() per wait, not forever.
    const int timeout_ms = static_cast<int>(store_timeout_s() * 1000);
    auto wait = [&](short events) {
        pollfd p{PQsocket(c_), events, 0};
        int n;
        do n = ::poll(&p, 1, timeout_ms);
        while (n < 0 && errno == EINTR);
        if (n == 0) fail("no answer within " + std::to_string(timeout_ms / 1000.0).substr(0, 4) + " s (FRINGE_STORE_TIMEOUT_S); the database is "
                         "frozen, overloaded or cut off", true);
        if (n < 0) fail(std::string("poll: ") + std::strerror(errno), true);
    };
    for (;;) {
        const int f = PQflush(c_);
        if (f == 0) break;
        if (f < 0) fail("cannot send the statement", true);
        wait(POLLIN | POLLOUT);
        if (!PQconsumeInput(c_)) fail("connection lost", true);
    }
    Result r;
    for (;;) {
        while (PQisBusy(c_)) {
            wait(POLLIN);
            if (!PQconsumeInput(c_)) fail("connection lost", true);
        }
        Result next(PQgetResult(c_));
        if (!next) break;
        if (!r || PQresultStatus(next.get()) == PGRES_FATAL_ERROR) r = std::move(next);  // the first, or the error
    }
    const auto st = r ? PQresultStatus(r.get()) : PGRES_FATAL_ERROR;
    if (st != PGRES_COMMAND_OK && st != PGRES_TUPLES_OK) {
        std::string msg = r ? PQresultErrorMessage(r.get()) : "";
        if (msg.empty()) msg = PQerrorMessage(c_);
        // A statement or lock wait cut short by its timeout: the database is there but stuck.
        const char* state = r ? PQresultErrorField(r.get(), PG_DIAG_SQLSTATE) : nullptr;
        const bool stuck = state && (std::string(state) == "57014" || std::string(state) == "55P03");
        const bool lost = PQstatus(c_) != CONNECTION_OK;
        msg = redact_store_text(one_line(msg), uri_);
        if (lost) drop();
        if (stuck || lost) throw StoreUnreachable("run store " + shown_ + ": " + msg);
        throw StoreError("run store " + shown_ + ": " + msg);
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
PgConn::PgConn(const std::string& uri) : uri_(uri), shown_(redact_store_uri(uri)) {
    throw StoreError("run store " + shown_ + ": this fringe was built without PostgreSQL (cmake -DFRINGE_POSTGRES=OFF); rebuild with libpq-dev installed");
}
PgConn::~PgConn() = default;
void PgConn::connect() {}
void PgConn::drop() {}
void PgConn::fail(const std::string& what, bool) { throw StoreError("run store " + shown_ + ": " + what); }
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
    // Use is separate from creation: a role with only SELECT (or INSERT + SELECT), or a read
    // replica, finds the tables there and creates nothing.
    auto have = conn_->exec("SELECT to_regclass('runs') IS NOT NULL AND to_regclass('run_conflicts') IS NOT NULL");
    if (PgConn::rows(have) == 1 && PgConn::value(have, 0, 0) == "t") return;
    try {
        conn_->exec("BEGIN");
        try {
            // Concurrent CREATE ... IF NOT EXISTS can still collide in the catalogue: one at a time.
            conn_->exec("SELECT pg_advisory_xact_lock(7348263511)");
            for (const char* sql : kSchema) conn_->exec(sql);
            conn_->exec("COMMIT");
        } catch (...) {
            rollback_quietly();
            throw;
        }
    } catch (const StoreUnreachable&) {
        throw;
    } catch (const StoreError& e) {
        throw StoreError(std::string(e.what()) + " (the tables runs and run_conflicts are missing and could not be created: create them once as a role "
                                                 "that may, with any fringe command given that role's --store, or with the SQL in docs/scale.md)");
    }
}

PgStore::~PgStore() = default;

void PgStore::rollback_quietly() {
    if (!conn_->ok()) return;
    try {
        conn_->exec("ROLLBACK");
    } catch (const StoreError&) {
    }
}

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
    // Plain INSERT ... DO NOTHING first: a role with only INSERT + SELECT forwards (ON CONFLICT DO
    // UPDATE would need UPDATE even when there is no conflict).
    const std::vector<std::optional<std::string>> values{
        id, r.value("started_at", std::string()), r["scenario"].value("name", std::string()), dut, dutj.value("part", std::string()), bench, host,
        prov.value("operator", std::string()), r.value("fringe_version", std::string()), prov.value("scenario_sha256", std::string()),
        r.value("status", std::string()), r.value("verdict", std::string()), r["error"].is_string() ? std::optional(r["error"].get<std::string>()) : std::nullopt,
        std::to_string(samples.value("processed", std::uint64_t{0})), std::to_string(samples.value("planned", std::uint64_t{0})),
        r["device"].is_object() ? r["device"].value("uri", std::string()) : std::string(), text, sum};
    conn_->exec("BEGIN");
    try {
        auto ins = conn_->exec(
            "INSERT INTO runs (id, created_at, scenario, dut, dut_part, bench, host, operator, fringe_version, scenario_sha256, status, verdict, "
            "error, samples_done, samples_total, device, report, report_sha256) "
            "VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16, $17::jsonb, $18) ON CONFLICT (id) DO NOTHING RETURNING id",
            values);
        Put out = Put::Inserted;
        if (PgConn::rows(ins) == 0) {
            auto have = conn_->exec("SELECT COALESCE(report_sha256, ''), report IS NULL FROM runs WHERE id = $1", {id});
            if (PgConn::rows(have) == 1 && PgConn::value(have, 0, 1) == "t") {
                // A row begun here without a report (PgStore::begin) is completed; a reported one is never touched.
                conn_->exec("UPDATE runs SET status = $2, verdict = $3, error = $4, samples_done = $5, samples_total = $6, device = $7, "
                            "report = $8::jsonb, report_sha256 = $9, dut = $10, fringe_version = $11, scenario_sha256 = $12, stored_at = now() "
                            "WHERE id = $1 AND report IS NULL",
                            {values[0], values[10], values[11], values[12], values[13], values[14], values[15], values[16], values[17], values[3],
                             values[8], values[9]});
            } else if (PgConn::rows(have) == 1 && PgConn::value(have, 0, 0) == sum) {
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
        rollback_quietly();
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
