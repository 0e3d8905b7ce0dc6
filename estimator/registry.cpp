#include "registry_parts.hpp"

namespace fringe::est {

const std::vector<EstimatorInfo>& registry() {
    static const std::vector<EstimatorInfo> all = [] {
        std::vector<EstimatorInfo> r;
        register_arctangent(r);
        register_tracking_loop(r);
        register_ekf(r);
        register_ekf_auto(r);
        register_external(r);
        return r;
    }();
    return all;
}

}  // namespace fringe::est
