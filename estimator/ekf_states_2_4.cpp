// EkfN (ekf_impl.hpp) for 2, 3, 4 states.
#include "ekf_impl.hpp"

namespace fringe::est::ekf_detail {

std::unique_ptr<Ekf::Impl> make_states_2_4(const Ekf::Options& o, const ChannelModel* m) {
    switch (o.layout.n) {
        case 2: return std::make_unique<EkfN<2>>(o, m);
        case 3: return std::make_unique<EkfN<3>>(o, m);
        case 4: return std::make_unique<EkfN<4>>(o, m);
    }
    return nullptr;
}

}  // namespace fringe::est::ekf_detail
