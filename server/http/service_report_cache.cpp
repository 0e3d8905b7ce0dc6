// Stored reports as clients read them (service.hpp): parsed and rendered once (JSON, JUnit,
// HTML, traces), kept in a small LRU cache, served as artifacts.
#include "server/http/service_internal.hpp"

#include "server/analysis/metrics.hpp"
#include "server/report/report_formats.hpp"


namespace fringe {

using namespace service_detail;

std::shared_ptr<const Service::Cached> Service::cached_report(const std::string& id) {
    {
        std::lock_guard<std::mutex> l(cache_mu_);
        if (auto it = cache_.find(id); it != cache_.end()) {
            lru_.splice(lru_.begin(), lru_, it->second.second);
            return it->second.first;
        }
    }
    std::optional<std::string> text;
    {
        std::lock_guard<std::mutex> l(store_mu_);
        text = store_->report_text(id);
    }
    if (!text) return nullptr;
    std::optional<json> rep = parse_json_bounded(*text, "the stored report of run " + id, kMaxStoredJsonDepth);  // outside the store lock
    text.reset();
    auto c = std::make_shared<Cached>();
    // The service's folders by short names (capture:ID plays DATA/captures/ID.fcap).
    c->json_full = public_text(dump_safe(*rep));
    json traces = rep->contains("traces") ? (*rep)["traces"] : json::object();
    json slim = *rep;
    slim.erase("traces");
    // Plot data stays out of the plain report.json as the traces do (hundreds of KB per estimator):
    // /traces and ?traces=1 carry it.
    for (auto& e : slim["estimators"]) e.erase("spectrum");
    c->json = public_text(dump_safe(slim));
    json tr{{"id", id}, {"traces", traces}, {"estimators", json::array()}};
    for (const auto& e : (*rep)["estimators"])
        tr["estimators"].push_back({{"label", e.value("label", "")}, {"name", e.value("name", "")},
                                    {"harmonics", e.contains("metrics") ? e["metrics"].value("harmonics", json::array()) : json::array()},
                                    {"spectrum", e.value("spectrum", json())}});  // null in reports older than issue 11
    c->traces = dump_safe(tr);
    c->metrics = public_text(dump_safe(report_metrics_json(*rep)));
    c->xml = public_text(junit_xml(*rep));
    c->html = public_text(report_html(*rep));
    std::lock_guard<std::mutex> l(cache_mu_);
    if (auto it = cache_.find(id); it != cache_.end()) return it->second.first;
    lru_.push_front(id);
    cache_[id] = {c, lru_.begin()};
    while (cache_.size() > kReportCache) {
        cache_.erase(lru_.back());
        lru_.pop_back();
    }
    return c;
}

HttpResponse Service::run_artifact(const std::string& id, const std::string& what, const std::map<std::string, std::string>& query) {
    for (const auto& [k, v] : query)
        if (!(k == "traces" && what == "report.json") && k != "download")
            throw ConfigError(k, "unknown query parameter");
    auto c = cached_report(id);
    if (!c) {
        auto s = run_state(id);
        if (!s) return json_error(404, "not_found", "no run " + id, "id");
        return json_error(409, "not_finished", "run " + id + " is " + s->status + ": its report is written when it ends");
    }
    HttpResponse r;
    if (what == "report.json") r.body = query.count("traces") && query.at("traces") != "0" ? c->json_full : c->json;
    else if (what == "traces") r.body = c->traces;
    else if (what == "metrics") r.body = c->metrics;
    else if (what == "report.xml") {
        r.content_type = "application/xml";
        r.body = c->xml;
    } else {
        r.content_type = "text/html; charset=utf-8";
        r.body = c->html;
        // Self-contained page: inline styles and SVG only.
        r.headers.emplace_back("Content-Security-Policy", "default-src 'none'; style-src 'unsafe-inline'; img-src data:");
    }
    if (query.count("download"))
        r.headers.emplace_back("Content-Disposition", "attachment; filename=\"fringe-" + id + "-" + (what == "traces" ? "traces.json" : what == "metrics" ? "metrics.json" : what) + "\"");
    return r;
}

}  // namespace fringe
