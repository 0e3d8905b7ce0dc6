// ABZ quadrature readout of a DUT (docs/abz.md): decodes A/B edges (and the Z index) sampled
// from logic channels into the DUT's electrical position, so an interpolator IC with an
// incremental output is scored as the run's `dut` lane.
//
// Conventions (docs/abz.md):
//  - N = interpolation factor: A/B periods per electrical cycle; 4N counts per cycle, one
//    count = step = 2*pi/(4N) rad.
//  - Forward (increasing theta) is A leading B: states (A,B) 00 -> 10 -> 11 -> 01 -> 00.
//  - Count c means the DUT's position is in [c*step, (c+1)*step) + offset_rad; the decoded
//    position is the cell's centre, (c + 0.5)*step + offset_rad, so an ideal DUT's error is
//    uniform in +-step/2 (rms step/sqrt(12)).
//  - Z: one count wide, high while c = index_count (mod 4N). At each rising edge the count is
//    checked against index_count (mod 4N); a mismatch is an index error and the count is
//    reset to the index. With a Z channel the position is invalid until the first index.
//  - Without Z, the A/B state fixes the count mod 4, and truth at the first sample picks which
//    A/B period of the electrical cycle (the DUT is "homed" there); with no truth the count
//    starts at the A/B state (relative position).
//  - With Z and a known count, the count leaving the index cell without Z having been high in
//    it is a missed index: counted (the count itself stays valid: nothing says it is wrong).
//  - Both A and B changing between two samples is an illegal transition: counted, and the
//    position is invalid until the next index re-synchronises it (never guessed; without Z it
//    stays invalid to the end of the capture).
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>

namespace fringe {

struct AbzConfig {
    int interpolation = 0;          // N (>= 1): A/B periods per electrical cycle
    long long index_count = 0;      // the count at the Z index, mod 4N
    double offset_rad = 0;          // electrical angle of count 0's lower edge
};

struct AbzStats {
    std::uint64_t samples = 0, edges = 0, forward = 0, backward = 0, reversals = 0;
    std::uint64_t illegal_transitions = 0;  // both A and B changed between two samples
    std::uint64_t index_pulses = 0, index_errors = 0;
    std::uint64_t missed_index = 0;         // the count crossed the index cell with no Z pulse (with Z, synced)
    long long max_index_error_counts = 0;   // largest |count - index_count| (mod 4N) at an index
    std::uint64_t invalid_samples = 0;      // no valid position (before sync, after an illegal transition)
    std::uint64_t resyncs = 0;              // index pulses that restored a lost position
    double min_edge_interval_s = 0;         // shortest time between two edges (0: fewer than two edges)
    std::string reference = "none";         // "index", "truth" or "none"
};

class AbzDecoder {
public:
    explicit AbzDecoder(AbzConfig c);  // throws std::invalid_argument for N < 1
    // n samples: a, b (0/1), z (0/1, null without a Z channel), t_s (times), theta_true (null
    // when unknown; used only to home a decoder without Z at its first sample). Writes the
    // DUT's position (rad, NaN where invalid) to theta_out.
    void process(std::size_t n, const double* t_s, const double* a, const double* b, const double* z,
                 const double* theta_true, double* theta_out_rad);
    const AbzStats& stats() const { return st_; }
    double step_rad() const { return step_; }
    long long count() const { return count_; }
    nlohmann::json to_json() const;

private:
    AbzConfig cfg_;
    long long counts_per_cycle_;
    double step_;
    AbzStats st_;
    bool started_ = false, synced_ = false, prev_z_ = false;
    bool z_in_cell_ = false;  // Z was high since the count entered the index cell
    int prev_phase_ = 0, last_dir_ = 0;
    long long count_ = 0;
    double last_edge_t_ = 0;
    bool have_edge_ = false;
};

}  // namespace fringe
