// EkfN (ekf_impl.hpp) for 7 states.
#include "ekf_impl.hpp"

namespace fringe::est::ekf_detail {

std::unique_ptr<Ekf::Impl> make_states_7(const Ekf::Options& o, const ChannelModel* m) {
    switch (o.layout.n) {
        case 7: return std::make_unique<EkfN<7>>(o, m);
    }
    return nullptr;
}

}  // namespace fringe::est::ekf_detail
