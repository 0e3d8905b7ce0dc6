// Plot traces of a run with bounded size that never alias (issue 11): every sample of the run
// enters per-bucket min/max envelopes and per-angle folds at the full rate, instead of every
// stride-th sample entering a polyline. Memory and JSON size depend on `points` and `angle_bins`,
// never on the run length.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace fringe {

class TraceRecorder {
public:
    static constexpr std::size_t kAngleBins = 256;
    // total_samples: the planned length (buckets are laid over it; a shorter run leaves the tail
    // empty, samples past the plan fall into the last bucket). fold_from_s: samples before this
    // time (e.g. the settle time) enter the time envelopes but not the angle folds, so a lock
    // transient does not swamp the per-angle min/max.
    TraceRecorder(std::uint64_t total_samples, std::size_t points, std::vector<std::string> labels,
                  double fold_from_s = -std::numeric_limits<double>::infinity(), std::size_t angle_bins = kAngleBins);
    // One block of m frames at full rate. err_rad[j] points at lane j's theta_hat - theta_true (unwrapped;
    // the recorder wraps to (-pi, pi]); NaN where the lane's sample is invalid or truth is unknown.
    // truth_known may be null (all known).
    void add(std::size_t m, const double* t_s, const double* sin_v, const double* cos_v, const double* theta_true_rad,
             const std::uint8_t* truth_known, const std::vector<const double*>& err_rad);
    // Points of one lane that are not at the frames (a DUT's words, each at its own latch
    // instant), after the add() of the block they fall in: frame[k] is the frame of that block
    // the point is drawn at (its time bucket), theta_true_rad[k] the truth at the point itself
    // (its angle bin), err_rad[k] theta_hat - theta_true there (NaN: not scored), t_s[k] its time
    // (the folds start at fold_from_s).
    void add_points(std::size_t lane, std::size_t n, const std::uint32_t* frame, const double* t_s, const double* theta_true_rad,
                    const double* err_rad);
    // {"kind":"envelope", "bucket_samples", "t_s", "sin_v":{min,max}, "cos_v":{min,max}, "error_rad":{label:{min,max}},
    //  "lissajous":{"points":{sin_v,cos_v}, "cycle":{theta_rad,sin_v,cos_v}}, "by_angle":{theta_rad, error_rad:{label:{mean,min,max,count}}}}
    nlohmann::json to_json() const;
    std::uint64_t samples() const { return n_; }

private:
    struct MinMax {
        std::vector<double> lo, hi;
        void resize(std::size_t n);
        void put(std::size_t b, double v) {
            if (v < lo[b]) lo[b] = v;
            if (v > hi[b]) hi[b] = v;
        }
    };
    struct Fold {  // per angle bin, full rate
        std::vector<double> sum, lo, hi;
        std::vector<std::uint64_t> count;
    };
    std::uint64_t bucket_samples_ = 1;
    std::size_t buckets_ = 0;      // buckets laid over the plan
    std::size_t used_ = 0;         // buckets touched so far
    std::vector<std::string> labels_;
    double fold_from_s_;
    std::size_t bins_;
    std::uint64_t n_ = 0;          // samples added
    std::uint64_t block_first_ = 0;  // index of the last add()'s first sample
    std::vector<double> t_start_;
    MinMax sin_, cos_;
    std::vector<MinMax> err_;
    std::vector<double> pt_sin_, pt_cos_;        // one real sample pair per bucket (Lissajous points)
    std::vector<std::uint64_t> pt_offset_;       // its offset within the bucket (scattered)
    std::vector<double> cyc_sin_, cyc_cos_;      // sums per true-angle bin
    std::vector<std::uint64_t> cyc_n_;
    std::vector<Fold> fold_;
    std::vector<std::int32_t> abin_;  // block scratch: each sample's true-angle bin, -1 when not folded
    std::vector<std::vector<double>> wrapped_;  // block scratch: each lane's error wrapped to (-pi, pi]
};

}  // namespace fringe
