#include "server/engine/interface_profile.hpp"

#include "server/analysis/metrics.hpp"
#include "signal_gen/base/config.hpp"

#include <cmath>

namespace fringe {

using nlohmann::json;

namespace {

// [lo, hi] with null for an open side.
void read_pair(const json& j, const std::string& field, std::optional<double>& lo, std::optional<double>& hi) {
    if (!j.is_array() || j.size() != 2) throw ConfigError(field, "expected [lo, hi] (null for an open side)");
    for (std::size_t i = 0; i < 2; ++i) {
        if (j[i].is_null()) continue;
        if (!j[i].is_number() || !std::isfinite(j[i].get<double>())) throw ConfigError(field, "expected a finite number or null");
        (i == 0 ? lo : hi) = j[i].get<double>();
    }
    if (!lo && !hi) throw ConfigError(field, "a band needs at least one side");
    if (lo && hi && *lo > *hi) throw ConfigError(field, "lo is above hi");
}

json pair_json(const std::optional<double>& lo, const std::optional<double>& hi) {
    return json::array({lo ? json(*lo) : json(), hi ? json(*hi) : json()});
}

}  // namespace

InterfaceProfile interface_from_json(const json& j, const std::string& path) {
    if (!j.is_object()) throw ConfigError(path, "expected an interface profile object");
    JsonReader r(j, path);
    InterfaceProfile p;
    p.name = r.string("name");
    if (p.name.empty() || p.name.size() > 200) throw ConfigError(r.path_of("name"), "a name of 1 to 200 characters");
    p.description = r.string("description", "");
    p.source = r.string("source", "");
    const json& bands = r.raw("bands");
    r.finish();  // an unknown key is named before what it may have been meant to say
    if (!bands.is_object()) throw ConfigError(r.path_of("bands"), "expected an object of bands by metric name");
    if (bands.empty()) throw ConfigError(r.path_of("bands"), "no bands: a profile grades at least one signal metric");
    if (bands.size() > 64) throw ConfigError(r.path_of("bands"), "at most 64 bands");
    for (const auto& [metric, b] : bands.items()) {
        const std::string field = r.path_of("bands") + "." + metric;
        const auto mi = find_metric(metric);
        if (!mi || !mi->run_level || mi->group != "signal")
            throw ConfigError(field, "'" + metric + "' is not a signal-quality metric (fringe metrics lists them: signal_*)");
        JsonReader br(b, field);
        InterfaceBand band;
        band.metric = metric;
        read_pair(br.raw("spec"), field + ".spec", band.spec_lo, band.spec_hi);
        if (br.has("mounting")) {
            read_pair(br.raw("mounting"), field + ".mounting", band.mount_lo, band.mount_hi);
            band.has_mounting = true;
            const bool inside = (!band.spec_lo || (band.mount_lo && *band.mount_lo >= *band.spec_lo)) &&
                                (!band.spec_hi || (band.mount_hi && *band.mount_hi <= *band.spec_hi));
            if (!inside) throw ConfigError(field + ".mounting", "the mounting tolerance must lie inside the specification");
        }
        br.finish();
        p.bands.push_back(std::move(band));
    }
    return p;
}

void to_json(json& j, const InterfaceProfile& p) {
    json bands = json::object();
    for (const auto& b : p.bands) {
        json x{{"spec", pair_json(b.spec_lo, b.spec_hi)}};
        if (b.has_mounting) x["mounting"] = pair_json(b.mount_lo, b.mount_hi);
        bands[b.metric] = x;
    }
    j = json{{"name", p.name}, {"bands", bands}};
    if (!p.description.empty()) j["description"] = p.description;
    if (!p.source.empty()) j["source"] = p.source;
}

}  // namespace fringe
