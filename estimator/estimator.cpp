#include "estimator.hpp"

#include <cmath>
#include <sstream>

namespace fringe::est {

using nlohmann::json;

void to_json(json& j, const EstimatorInfo& e) {
    j = json{{"name", e.name}, {"summary", e.summary}, {"params", e.params}};
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
