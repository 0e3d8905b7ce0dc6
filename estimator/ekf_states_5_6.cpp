// EkfN (ekf_impl.hpp) for 5, 6 states.
#include "ekf_impl.hpp"

namespace fringe::est::ekf_detail {

std::unique_ptr<Ekf::Impl> make_states_5_6(const Ekf::Options& o, const ChannelModel* m) {
    switch (o.layout.n) {
        case 5: return std::make_unique<EkfN<5>>(o, m);
        case 6: return std::make_unique<EkfN<6>>(o, m);
    }
    return nullptr;
}

}  // namespace fringe::est::ekf_detail
