#include "registry_parts.hpp"

#include <algorithm>
#include <stdexcept>

namespace fringe::est {

namespace {
std::vector<EstimatorInfo>& all() {
    static std::vector<EstimatorInfo> r = [] {
        std::vector<EstimatorInfo> v;
        register_arctangent(v);
        register_tracking_loop(v);
        register_ekf(v);
        register_ekf_auto(v);
        register_external(v);
        return v;
    }();
    return r;
}
}  // namespace

const std::vector<EstimatorInfo>& registry() { return all(); }

void register_estimator(EstimatorInfo info) {
    if (info.name.empty() || !info.make) throw std::invalid_argument("an estimator needs a name and a factory");
    for (const auto& e : all())
        if (e.name == info.name) throw std::invalid_argument("an estimator named '" + info.name + "' is already registered");
    all().push_back(std::move(info));
}

void unregister_estimator(const std::string& name) {
    auto& r = all();
    r.erase(std::remove_if(r.begin(), r.end(), [&](const EstimatorInfo& e) { return e.name == name; }), r.end());
}

}  // namespace fringe::est
