// Internal: each estimator family appends its entries to the registry (an explicit list
// rather than static self-registration, which a static library's linker would drop).
#pragma once

#include "estimator.hpp"

namespace fringe::est {
void register_arctangent(std::vector<EstimatorInfo>& r);
void register_tracking_loop(std::vector<EstimatorInfo>& r);
void register_ekf(std::vector<EstimatorInfo>& r);
void register_ekf_auto(std::vector<EstimatorInfo>& r);
void register_external(std::vector<EstimatorInfo>& r);
}  // namespace fringe::est
