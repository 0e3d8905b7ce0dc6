#include "abz.hpp"
#include "signal_gen/base/constants.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

namespace fringe {

namespace {
long long floor_mod(long long x, long long m) {
    const long long r = x % m;
    return r < 0 ? r + m : r;
}

// Quadrature phase 0..3 of a sample: 00 -> 0, 10 -> 1, 11 -> 2, 01 -> 3 (A leads B forward).
int phase_of(double a, double b) {
    const bool A = a != 0, B = b != 0;
    return A ? (B ? 2 : 1) : (B ? 3 : 0);
}
}  // namespace

AbzDecoder::AbzDecoder(AbzConfig c) : cfg_(c) {
    if (c.interpolation < 1) throw std::invalid_argument("ABZ readout: the interpolation factor must be at least 1");
    counts_per_cycle_ = 4LL * c.interpolation;
    step_ = kTwoPi / static_cast<double>(counts_per_cycle_);
}

void AbzDecoder::process(std::size_t n, const double* t, const double* a, const double* b, const double* z,
                         const double* theta_true, double* out) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    for (std::size_t i = 0; i < n; ++i) {
        const int p = phase_of(a[i], b[i]);
        const bool zi = z && z[i] != 0;
        if (!started_) {
            started_ = true;
            prev_phase_ = p;
            prev_z_ = zi;
            count_ = p;
            if (!z && theta_true && std::isfinite(theta_true[0 + i])) {
                // Home from truth: the A/B state gives the count mod 4, truth the A/B period.
                const double x = (theta_true[i] - cfg_.offset_rad) / step_ - 0.5;
                count_ = p + 4 * static_cast<long long>(std::llround((x - p) / 4.0));
                synced_ = true;
                st_.reference = "truth";
            } else if (!z) {
                synced_ = true;  // relative: no truth to home against
            }
        } else {
            const int d = static_cast<int>(floor_mod(p - prev_phase_, 4));
            if (d != 0) {
                ++st_.edges;
                if (have_edge_) {
                    const double dt = t[i] - last_edge_t_;
                    if (st_.edges == 2 || dt < st_.min_edge_interval_s) st_.min_edge_interval_s = dt;
                }
                have_edge_ = true;
                last_edge_t_ = t[i];
            }
            if (d == 2) {  // both lines changed: direction unknown, the count is lost
                ++st_.illegal_transitions;
                synced_ = false;
                last_dir_ = 0;
            } else if (d != 0) {
                const int dir = d == 1 ? 1 : -1;
                // Leaving the index cell: Z should have been high in it.
                if (z && synced_ && floor_mod(count_ - cfg_.index_count, counts_per_cycle_) == 0 && !z_in_cell_ && !zi) ++st_.missed_index;
                count_ += dir;
                z_in_cell_ = false;
                (dir > 0 ? st_.forward : st_.backward)++;
                if (last_dir_ != 0 && dir != last_dir_) ++st_.reversals;
                last_dir_ = dir;
            }
            prev_phase_ = p;
            if (zi && !prev_z_) {  // index: check the count, reset it when it is off
                ++st_.index_pulses;
                long long err = floor_mod(count_ - cfg_.index_count, counts_per_cycle_);
                if (err >= counts_per_cycle_ / 2) err -= counts_per_cycle_;
                if (!synced_) {
                    synced_ = true;
                    if (st_.reference == "index") ++st_.resyncs;
                    st_.reference = "index";
                } else if (err != 0) {
                    ++st_.index_errors;
                    if (std::llabs(err) > st_.max_index_error_counts) st_.max_index_error_counts = std::llabs(err);
                }
                count_ -= err;  // nearest count that is index_count mod 4N: keeps the cycle
            }
            if (zi) z_in_cell_ = true;
            prev_z_ = zi;
        }
        ++st_.samples;
        if (synced_) {
            out[i] = (static_cast<double>(count_) + 0.5) * step_ + cfg_.offset_rad;
        } else {
            out[i] = nan;
            ++st_.invalid_samples;
        }
    }
}

nlohmann::json AbzDecoder::to_json() const {
    return {{"interpolation", cfg_.interpolation},
            {"counts_per_cycle", counts_per_cycle_},
            {"step_rad", step_},
            {"index_count", cfg_.index_count},
            {"offset_rad", cfg_.offset_rad},
            {"reference", st_.reference},
            {"samples", st_.samples},
            {"edges", st_.edges},
            {"forward", st_.forward},
            {"backward", st_.backward},
            {"reversals", st_.reversals},
            {"illegal_transitions", st_.illegal_transitions},
            {"index_pulses", st_.index_pulses},
            {"index_errors", st_.index_errors},
            {"missed_index", st_.missed_index},
            {"max_index_error_counts", st_.max_index_error_counts},
            {"resyncs", st_.resyncs},
            {"invalid_samples", st_.invalid_samples},
            {"min_edge_interval_s", st_.edges >= 2 ? nlohmann::json(st_.min_edge_interval_s) : nlohmann::json()},
            {"final_count", count_}};
}

}  // namespace fringe
