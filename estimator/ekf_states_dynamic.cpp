// EkfN (ekf_impl.hpp) for 8..9 states (one dynamic instantiation of capacity 9).
#include "ekf_impl.hpp"

namespace fringe::est::ekf_detail {

std::unique_ptr<Ekf::Impl> make_states_dynamic(const Ekf::Options& o, const ChannelModel* m) {
    switch (o.layout.n) {
        case 8: case 9: return std::make_unique<EkfN<Eigen::Dynamic, kMaxStates>>(o, m);
    }
    return nullptr;
}

}  // namespace fringe::est::ekf_detail
