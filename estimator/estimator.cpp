#include "estimator.hpp"

#include <cmath>
#include <sstream>

namespace fringe::est {

using nlohmann::json;

void to_json(json& j, const EstimatorInfo& e) {
    const auto& t = e.traits;
    json traits{{"assumes_ideal_sinusoids", t.assumes_ideal_sinusoids}, {"told_amplitude", t.told_amplitude}, {"child_process", t.child_process},
                {"learns_over_cycles", t.learns_over_cycles > 0 ? json(t.learns_over_cycles) : json()}};
    if (!t.told_param.empty()) traits["told_param"] = t.told_param;
    j = json{{"name", e.name}, {"summary", e.summary}, {"params", e.params}, {"traits", traits}};
}

EstimatorTraits traits_of(const std::string& name) {
    for (const auto& e : registry())
        if (e.name == name) return e.traits;
    return {};
}

const EstimatorInfo& find(const std::string& name) {
    for (const auto& e : registry())
        if (e.name == name) return e;
    std::string known;
    for (const auto& e : registry()) known += (known.empty() ? "" : ", ") + e.name;
    throw ConfigError("estimator", "unknown estimator '" + name + "' (known: " + known + ")");
}

std::unique_ptr<Estimator> make(const std::string& name, const EstimatorConfig& config) {
    auto e = find(name).make();
    e->reset(config);
    return e;
}

}  // namespace fringe::est
