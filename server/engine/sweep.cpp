#include "server/engine/sweep.hpp"

#include "server/engine/limits.hpp"
#include "server/engine/provenance.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/base/config.hpp"

#include <atomic>
#include <cstdlib>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <mutex>
#include <sstream>
#include <thread>

#ifndef FRINGE_VERSION
#define FRINGE_VERSION "dev"
#endif

namespace fringe {

using nlohmann::json;
namespace fs = std::filesystem;

void set_by_path(json& j, const std::string& path, const json& value) {
    json* cur = &j;
    std::size_t pos = 0;
    while (pos <= path.size()) {
        std::size_t dot = path.find('.', pos);
        if (dot == std::string::npos) dot = path.size();
        std::string seg = path.substr(pos, dot - pos);
        std::vector<std::size_t> idx;
        while (!seg.empty() && seg.back() == ']') {
            const auto open = seg.rfind('[');
            if (open == std::string::npos) throw ConfigError(path, "unbalanced [ ]");
            idx.insert(idx.begin(), static_cast<std::size_t>(std::stoul(seg.substr(open + 1, seg.size() - open - 2))));
            seg = seg.substr(0, open);
        }
        if (seg.empty()) throw ConfigError(path, "empty path segment");
        if (!cur->is_object()) throw ConfigError(path, "'" + seg + "' is inside something that is not an object");
        cur = &(*cur)[seg];
        for (auto i : idx) {
            if (!cur->is_array() || i >= cur->size()) throw ConfigError(path, "index [" + std::to_string(i) + "] does not exist in the base scenario");
            cur = &(*cur)[i];
        }
        if (dot == path.size()) break;
        if (cur->is_null()) *cur = json::object();
        pos = dot + 1;
    }
    *cur = value;
}

Sweep load_sweep(const std::string& path) {
    const json j = load_json_file(path);
    const std::string dir = fs::path(path).parent_path().string();
    JsonReader r(j, "");
    Sweep s;
    s.name = r.string("name", fs::path(path).stem().string());
    s.description = r.string("description", "");
    s.jobs = static_cast<int>(r.integer("jobs", 0, 0, 1024));
    std::string base_file;
    s.base = resolve_json_ref(r.raw("base"), dir, &base_file);
    const std::string base_dir = base_file.empty() ? dir : fs::path(base_file).parent_path().string();
    // Inline the encoder so rows can set its keys.
    if (s.base.contains("encoder")) s.base["encoder"] = resolve_json_ref(s.base["encoder"], base_dir);
    s.base_dir = base_dir;
    const json& cols = r.raw("columns");
    if (!cols.is_array() || cols.empty()) throw ConfigError("columns", "expected a non-empty array of {estimator, metric}");
    for (std::size_t i = 0; i < cols.size(); ++i) {
        JsonReader c(cols[i], "columns[" + std::to_string(i) + "]");
        s.columns.push_back({c.string("estimator"), c.string("metric")});
        c.finish();
        if (!find_metric(s.columns.back().metric)) throw ConfigError("columns[" + std::to_string(i) + "].metric", "unknown metric '" + s.columns.back().metric + "'");
    }
    if (r.has("references")) {
        for (const auto& n : r.raw("references")) s.reference_names.push_back(n.get<std::string>());
    }
    if (r.has("rows")) {
        const json& rows = r.raw("rows");
        for (std::size_t i = 0; i < rows.size(); ++i) {
            JsonReader rr(rows[i], "rows[" + std::to_string(i) + "]");
            SweepRow row;
            row.label = rr.string("label", "row " + std::to_string(i + 1));
            if (rr.has("set")) row.set = rr.raw("set");
            if (rr.has("reference")) row.reference = rr.raw("reference");
            rr.finish();
            s.rows.push_back(row);
        }
    }
    if (r.has("grid")) {  // cartesian product, first key varies slowest
        const json& g = r.raw("grid");
        std::vector<std::pair<std::string, json>> axes;
        for (const auto& [k, v] : g.items()) {
            if (!v.is_array() || v.empty()) throw ConfigError("grid." + k, "expected a non-empty array of values");
            axes.push_back({k, v});
        }
        std::size_t total = 1;
        for (const auto& a : axes) total *= a.second.size();
        for (std::size_t n = 0; n < total; ++n) {
            SweepRow row;
            std::size_t rem = n;
            std::string label;
            for (std::size_t a = axes.size(); a-- > 0;) {
                const auto& vals = axes[a].second;
                const json& v = vals[rem % vals.size()];
                rem /= vals.size();
                row.set[axes[a].first] = v;
            }
            for (const auto& a : axes) label += (label.empty() ? "" : ", ") + a.first + "=" + row.set[a.first].dump();
            row.label = label;
            s.rows.push_back(row);
        }
    }
    r.finish();
    if (s.rows.empty()) throw ConfigError("rows", "a sweep needs rows or a grid");
    // Plan every row now, so a typo fails before hours of running; the plans are kept for the
    // rows' runs.
    s.plans = std::make_shared<std::vector<std::unique_ptr<RunPlan>>>();
    for (std::size_t i = 0; i < s.rows.size(); ++i) {
        json sc = s.base;
        try {
            for (const auto& [k, v] : s.rows[i].set.items()) set_by_path(sc, k, v);
            s.plans->push_back(std::make_unique<RunPlan>(plan_run(scenario_from_json(sc, s.base_dir))));
        } catch (const ConfigError& e) {
            throw e.prefixed("rows[" + std::to_string(i) + "] (" + s.rows[i].label + ")");
        }
    }
    return s;
}

SweepResult sweep_result(const Sweep& s, const SweepRow& row, const json& rep) {
    SweepResult res;
    res.row = row;
    res.status = rep.value("status", std::string("error"));
    res.verdict = rep.value("verdict", std::string("ERROR"));
    if (rep.contains("error") && rep["error"].is_string()) res.error = rep["error"];
    for (const auto& c : s.columns) {
        std::optional<double> v;
        std::optional<std::pair<double, double>> iv;
        if (const auto m = find_metric(c.metric); m && m->run_level) {  // the run's alignment, once
            v = run_metric_value(c.metric, rep);
            res.values.push_back(v);
            res.intervals.push_back(iv);
            continue;
        }
        for (const auto& e : rep.value("estimators", json::array()))
            if (e["label"] == c.estimator) {
                v = lane_metric_value(c.metric, e);
                if (v) iv = lane_metric_interval(c.metric, e, *v);
            }
        res.values.push_back(v);
        res.intervals.push_back(iv);
    }
    res.wall_s = rep.value("wall_s", 0.0);
    return res;
}

std::vector<SweepResult> run_sweep(const Sweep& s, int jobs, const std::function<void(std::size_t, std::size_t)>& progress,
                                   const std::vector<std::size_t>* rows, const SweepExecute& execute) {
    std::vector<std::size_t> all;
    if (!rows) {
        for (std::size_t k = 0; k < s.rows.size(); ++k) all.push_back(k);
        rows = &all;
    }
    std::vector<SweepResult> out(rows->size());
    std::atomic<std::size_t> next{0}, done{0};
    std::mutex mu;
    auto worker = [&] {
        for (std::size_t j; (j = next++) < rows->size();) {
            const std::size_t i = (*rows)[j];
            SweepResult res;
            res.row = s.rows[i];
            const auto t0 = std::chrono::steady_clock::now();
            try {
                // The plan load_sweep made for this row, else a new one.
                std::unique_ptr<RunPlan> kept = s.plans && i < s.plans->size() ? std::move((*s.plans)[i]) : nullptr;
                if (!kept) {
                    json sc = s.base;
                    for (const auto& [k, v] : s.rows[i].set.items()) set_by_path(sc, k, v);
                    kept = std::make_unique<RunPlan>(plan_run(scenario_from_json(sc, s.base_dir)));
                }
                RunPlan plan = std::move(*kept);
                const json rep = execute ? execute(i, std::move(plan)) : execute_run(std::move(plan));
                res = sweep_result(s, s.rows[i], rep);
            } catch (const std::exception& e) {
                res.status = "error";
                res.verdict = "ERROR";
                res.error = e.what();
                res.values.assign(s.columns.size(), std::nullopt);
            }
            res.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            out[j] = std::move(res);
            const std::size_t d = ++done;
            if (progress) {
                std::lock_guard<std::mutex> lock(mu);
                progress(d, rows->size());
            }
        }
    };
    int n = jobs > 0 ? jobs : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    n = std::min<int>(n, static_cast<int>(rows->size()));
    std::vector<std::thread> pool;
    for (int k = 0; k < n; ++k) pool.emplace_back(worker);
    for (auto& t : pool) t.join();
    return out;
}

std::string sweep_digest(const Sweep& s, const std::string& version) {
    json rows = json::array();
    for (const auto& r : s.rows) rows.push_back(r.set);
    // The version is part of what decides a run: after an upgrade the same sweep file gets new
    // ids, so --collect never returns rows another version computed.
    return sha256_hex(canonical_json(json{{"base", s.base}, {"rows", rows}, {"fringe_version", version}}));
}

std::string sweep_digest(const Sweep& s) { return sweep_digest(s, FRINGE_VERSION); }

std::string sweep_run_id(const Sweep& s, std::size_t k) {
    char n[32];
    std::snprintf(n, sizeof n, "%04zu", k);
    return "sweep-" + sweep_digest(s).substr(0, 16) + "-" + n;
}

Shard parse_shard(const std::string& text) {
    const auto slash = text.find('/');
    auto num = [&](const std::string& t) -> std::size_t {
        if (t.empty() || t.size() > 9 || t.find_first_not_of("0123456789") != std::string::npos)
            throw ConfigError("shard", "expected I/N with whole numbers, 0 <= I < N (e.g. 0/3); got '" + text + "'");
        return static_cast<std::size_t>(std::stoul(t));
    };
    if (slash == std::string::npos) throw ConfigError("shard", "expected I/N with whole numbers, 0 <= I < N (e.g. 0/3); got '" + text + "'");
    Shard sh{num(text.substr(0, slash)), num(text.substr(slash + 1))};
    if (sh.count == 0 || sh.index >= sh.count) throw ConfigError("shard", "expected 0 <= I < N; got '" + text + "'");
    return sh;
}

std::optional<Shard> shard_from_env(std::size_t count_hint) {
    auto env = [](const char* n) -> std::string {
        const char* v = std::getenv(n);
        return v ? v : "";
    };
    if (const std::string id = env("SLURM_ARRAY_TASK_ID"); !id.empty()) {
        const std::string count = env("SLURM_ARRAY_TASK_COUNT"), min = env("SLURM_ARRAY_TASK_MIN");
        if (count.empty()) throw ConfigError("shard", "SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not: give --shard I/N");
        const Shard raw = parse_shard("0/" + count);
        const std::size_t i = parse_shard(id + "/999999999").index - (min.empty() ? 0 : parse_shard(min + "/999999999").index);
        return parse_shard(std::to_string(i) + "/" + std::to_string(raw.count));
    }
    if (const std::string idx = env("JOB_COMPLETION_INDEX"); !idx.empty()) {
        std::string count = count_hint ? std::to_string(count_hint) : env("FRINGE_SHARD_COUNT");
        if (count.empty()) throw ConfigError("shard", "JOB_COMPLETION_INDEX is set but not the number of shards: give --shard-count N (the Job's completions) or FRINGE_SHARD_COUNT");
        return parse_shard(idx + "/" + count);
    }
    return std::nullopt;
}

namespace {
std::string fmt(std::optional<double> v) {
    if (!v) return "";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3g", *v);
    return buf;
}
std::optional<double> ref(const SweepRow& r, const std::string& name) {
    if (r.reference.contains(name) && r.reference[name].is_number()) return r.reference[name].get<double>();
    return std::nullopt;
}
}  // namespace

std::string sweep_csv(const Sweep& s, const std::vector<SweepResult>& rs) {
    std::ostringstream o;
    o.precision(6);
    o << "label";
    for (const auto& c : s.columns) o << "," << c.estimator << ":" << c.metric;
    for (const auto& n : s.reference_names) o << "," << n;
    // Each column's 95 % interval (empty where the metric has none: counts, extremes, bounds).
    for (const auto& c : s.columns) o << "," << c.estimator << ":" << c.metric << ":lo95," << c.estimator << ":" << c.metric << ":hi95";
    o << ",verdict,wall_s\n";
    for (const auto& r : rs) {
        o << '"' << r.row.label << '"';
        for (const auto& v : r.values) { o << ","; if (v) o << *v; }
        for (const auto& n : s.reference_names) { o << ","; if (auto x = ref(r.row, n)) o << *x; }
        for (std::size_t i = 0; i < s.columns.size(); ++i) {
            const auto iv = i < r.intervals.size() ? r.intervals[i] : std::nullopt;
            o << ",";
            if (iv) o << iv->first;
            o << ",";
            if (iv) o << iv->second;
        }
        o << "," << r.verdict << "," << r.wall_s << "\n";
    }
    return o.str();
}

std::string sweep_markdown(const Sweep& s, const std::vector<SweepResult>& rs) {
    std::ostringstream o;
    o << "| row |";
    for (const auto& c : s.columns) {
        const auto m = find_metric(c.metric);
        o << " " << c.estimator << " " << c.metric << (m && !m->unit.empty() ? " (" + m->unit + ")" : std::string()) << " |";
    }
    for (const auto& n : s.reference_names) o << " " << n << " |";
    if (!s.reference_names.empty()) o << " measured / " << s.reference_names.front() << " |";
    o << "\n|---|";
    for (std::size_t i = 0; i < s.columns.size() + s.reference_names.size() + (s.reference_names.empty() ? 0 : 1); ++i) o << "---|";
    o << "\n";
    for (const auto& r : rs) {
        o << "| " << r.row.label << (r.error.empty() ? "" : " (" + r.verdict + ": " + r.error + ")") << " |";
        for (std::size_t i = 0; i < r.values.size(); ++i) {
            o << " " << fmt(r.values[i]);
            // "± h": half the width of the value's 95 % interval
            if (i < r.intervals.size() && r.intervals[i]) o << " ± " << fmt((r.intervals[i]->second - r.intervals[i]->first) / 2);
            o << " |";
        }
        for (const auto& n : s.reference_names) o << " " << fmt(ref(r.row, n)) << " |";
        if (!s.reference_names.empty()) {
            const auto m = r.values.empty() ? std::nullopt : r.values.front();
            const auto x = ref(r.row, s.reference_names.front());
            o << " " << (m && x && *x != 0 ? fmt(*m / *x) : std::string()) << " |";
        }
        o << "\n";
    }
    return o.str();
}

}  // namespace fringe
