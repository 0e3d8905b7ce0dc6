#include "server/analysis/scoring.hpp"

#include "signal_gen/fastmath.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace fringe {

Scorer::Scorer(double settle_s) : Scorer(ScoringOptions{settle_s}) {}

Scorer::Scorer(ScoringOptions o) : o_(o) {
    o_.max_harmonic = std::clamp(o_.max_harmonic, 1, kMaxHarmonic);
    const std::size_t m = 2 * static_cast<std::size_t>(o_.max_harmonic) + 1;
    sum_cos_.assign(m, 0.0);
    sum_sin_.assign(m, 0.0);
    sum_ecos_.assign(static_cast<std::size_t>(o_.max_harmonic) + 1, 0.0);
    sum_esin_.assign(static_cast<std::size_t>(o_.max_harmonic) + 1, 0.0);
    fine_.assign(kFineBins, FineBin{});
    m_.harmonics_requested = o_.max_harmonic;
}

namespace {

// Chan's merge of a block's count, mean and sum of squared deviations into running ones: the
// two-pass block moments are exact to rounding and need no division per sample (Welford's do).
void merge_moments(std::uint64_t& n, double& mean, double& m2, std::size_t nb, double mean_b, double m2_b) {
    if (!nb) return;
    const double na = static_cast<double>(n), nbd = static_cast<double>(nb), nt = na + nbd;
    const double delta = mean_b - mean;
    mean += delta * (nbd / nt);
    m2 += m2_b + delta * delta * (na * nbd / nt);
    n += nb;
}

// Mean and sum of squared deviations of x[0..n) (two passes).
void block_moments(const double* x, std::size_t n, double& mean, double& m2) {
    double s = 0;
#pragma omp simd reduction(+ : s)
    for (std::size_t i = 0; i < n; ++i) s += x[i];
    const double mu = n ? s / static_cast<double>(n) : 0.0;
    double q = 0;
#pragma omp simd reduction(+ : q)
    for (std::size_t i = 0; i < n; ++i) { const double d = x[i] - mu; q += d * d; }
    mean = mu;
    m2 = q;
}

}  // namespace

void Scorer::add(std::size_t n, const double* t, const double* th_true, const double* om_true,
                 const double* th_hat, const double* om_hat, const std::uint8_t* valid) {
    if (!n) return;
    if (!have_t0_) { t0_ = t[0]; have_t0_ = true; }
    m_.samples += n;
    // The raw error and whether it is usable (finite and marked valid), and how many samples
    // are unlocked (unusable, or off by more than the lock threshold once wrapped): one pass
    // of plain arithmetic that vectorises (rounding by adding 1.5*2^52, no remainder()).
    constexpr double kRound = 6755399441055744.0;
    blk_e_.resize(n);
    blk_ok_.resize(n);
    std::size_t unlocked = 0, before_settle = 0;
    double* be = blk_e_.data();
    std::uint8_t* bok = blk_ok_.data();
    const double thr = o_.lock_threshold_rad, t0 = t0_, settle = o_.settle_s;
#pragma omp simd reduction(+ : unlocked, before_settle)
    for (std::size_t i = 0; i < n; ++i) {
        const double e = th_hat[i] - th_true[i];
        const bool ok = valid[i] != 0 && (e - e) == 0.0;  // e - e is NaN for inf and NaN
        const double turns = e * (1 / kTwoPi);
        const double wrapped = e - kTwoPi * ((turns + kRound) - kRound);
        be[i] = e;
        bok[i] = ok;
        unlocked += !ok || std::fabs(wrapped) > thr || std::fabs(turns) > 1e15;
        before_settle += t[i] - t0 < settle;
    }
    // Lock: locked from the sample after the last unlocked one (searched from the end, only when
    // there is one); a block without any continues the lock or starts it at its first sample.
    if (unlocked) {
        std::size_t last = n;
        for (std::size_t i = n; i-- > 0;) {
            const double e = blk_e_[i];
            if (!blk_ok_[i] || std::fabs(wrap_pi(e)) > o_.lock_threshold_rad) { last = i; break; }
        }
        if (last < n) {
            locked_now_ = last + 1 < n;
            if (locked_now_) first_t_after_ = t[last + 1];
        } else if (!locked_now_) {
            locked_now_ = true;
            first_t_after_ = t[0];
        }
    } else if (!locked_now_) {
        locked_now_ = true;
        first_t_after_ = t[0];
    }
    // The samples at or after the settle time, in order (the whole block once settled).
    const double* e_after = blk_e_.data();
    const double* th_after = th_true;
    const double* omt_after = om_true;
    const double* omh_after = om_hat;
    const std::uint8_t* ok_after = blk_ok_.data();
    std::size_t na = n;
    if (before_settle) {
        sel_e_.clear(); sel_th_.clear(); sel_omt_.clear(); sel_omh_.clear(); sel_ok_.clear();
        for (std::size_t i = 0; i < n; ++i) {
            if (t[i] - t0_ < o_.settle_s) continue;
            sel_e_.push_back(blk_e_[i]);
            sel_th_.push_back(th_true[i]);
            sel_ok_.push_back(blk_ok_[i]);
            if (om_true) sel_omt_.push_back(om_true[i]);
            if (om_hat) sel_omh_.push_back(om_hat[i]);
        }
        na = sel_e_.size();
        e_after = sel_e_.data();
        th_after = sel_th_.data();
        ok_after = sel_ok_.data();
        omt_after = om_true ? sel_omt_.data() : nullptr;
        omh_after = om_hat ? sel_omh_.data() : nullptr;
    }
    if (!na) return;
    m_.after_settle += na;
    std::size_t good = 0;
    for (std::size_t i = 0; i < na; ++i) good += ok_after[i];
    m_.invalid_after_settle += na - good;
    // The rate: its truth over the usable samples where it is known, and the estimate's error.
    if (omt_after) {
        // Local accumulators (members written through `this` could alias the inputs: a reload
        // and a store per sample), summed in the same order.
        rate_d_.resize(na);
        double* rd = rate_d_.data();
        std::size_t nd = 0;
        double s_om = sum_omega_true_, s_abs = sum_abs_omega_true_;
        std::uint64_t n_om = n_omega_true_, nonfinite = 0;
        // Every sample usable with both rates finite (the common case): one pass that
        // vectorises (the sums in another order than sample by sample: last bits only).
        std::size_t finite = 0;
        if (good == na && omh_after) {
#pragma omp simd reduction(+ : finite)
            for (std::size_t i = 0; i < na; ++i) {
                const double d = omh_after[i] - omt_after[i];
                finite += (d - d) == 0.0;  // NaN unless both are finite
            }
        }
        const bool all_finite = finite == na;
        if (all_finite) {
            double so = 0, sa = 0;
#pragma omp simd reduction(+ : so, sa)
            for (std::size_t i = 0; i < na; ++i) {
                so += omt_after[i];
                sa += std::fabs(omt_after[i]);
                rd[i] = omh_after[i] - omt_after[i];
            }
            s_om += so;
            s_abs += sa;
            n_om += na;
            nd = na;
        }
        for (std::size_t i = 0; i < na && !all_finite; ++i) {
            if (!ok_after[i] || !std::isfinite(omt_after[i])) continue;
            s_om += omt_after[i];
            s_abs += std::fabs(omt_after[i]);
            ++n_om;
            if (omh_after) {
                const double d = omh_after[i] - omt_after[i];
                if (!std::isfinite(d)) { ++nonfinite; continue; }
                rd[nd++] = d;
            }
        }
        sum_omega_true_ = s_om;
        sum_abs_omega_true_ = s_abs;
        n_omega_true_ = n_om;
        m_.omega_nonfinite += nonfinite;
        double mb = 0, qb = 0;
        block_moments(rd, nd, mb, qb);
        merge_moments(om_n_, om_mean_, om_m2_, nd, mb, qb);
    }
    // Unusable samples carry 0 (the error array is handed on as it stands).
    if (good < na) {
        double* e = e_after == blk_e_.data() ? blk_e_.data() : sel_e_.data();
        for (std::size_t i = 0; i < na; ++i) if (!ok_after[i]) e[i] = 0.0;
    }
    if (decided_) return process(na, e_after, th_after, ok_after);
    pending_e_.insert(pending_e_.end(), e_after, e_after + na);
    pending_th_.insert(pending_th_.end(), th_after, th_after + na);
    pending_ok_.insert(pending_ok_.end(), ok_after, ok_after + na);
    pending_good_ += good;
    if (pending_good_ >= kMedianWindow) decide();
}

void Scorer::decide() {
    std::vector<double> tmp;
    for (std::size_t k = 0; k < pending_e_.size(); ++k)
        if (pending_ok_[k]) tmp.push_back(pending_e_[k]);
    if (!tmp.empty()) {
        std::nth_element(tmp.begin(), tmp.begin() + static_cast<long>(tmp.size() / 2), tmp.end());
        const double median_rad = tmp[tmp.size() / 2];
        // Whole cycles are removed only while the error keeps its precision: an estimate 1e308
        // rad off (a constant output, a corrupted correction) would otherwise lose the truth in
        // rounding, and its error would become exactly 0 after the removal (a false PASS).
        if (std::fabs(median_rad) <= kMaxRemovableRad) offset_rad_ = kTwoPi * std::round(median_rad / kTwoPi);
        else m_.unremoved_error_rad = median_rad;
    }
    decided_ = true;
    if (!pending_e_.empty()) process(pending_e_.size(), pending_e_.data(), pending_th_.data(), pending_ok_.data());
    pending_e_ = {};
    pending_th_ = {};
    pending_ok_ = {};
}

void Scorer::process(std::size_t n, const double* e_raw, const double* th_all, const std::uint8_t* ok) {
    // The scored errors (the 2*pi multiple removed) and their angles, compacted; e_ keeps the
    // full-length sequence for the sink, 0 where not scored.
    // Every sample usable (the common case): the angles as they are, the errors in one pass.
    es_.resize(n);
    std::size_t usable = 0;
#pragma omp simd reduction(+ : usable)
    for (std::size_t i = 0; i < n; ++i) usable += ok[i] != 0;
    std::size_t ns = 0;
    const double* th = th_all;
    if (usable == n) {
        double* es = es_.data();
        const double off = offset_rad_;
#pragma omp simd
        for (std::size_t i = 0; i < n; ++i) es[i] = e_raw[i] - off;
        if (sink_) e_.assign(es_.begin(), es_.begin() + static_cast<std::ptrdiff_t>(n));
        ns = n;
    } else {
        if (sink_) e_.assign(n, 0.0);
        th_.resize(n);
        for (std::size_t i = 0; i < n; ++i) {
            if (!ok[i]) continue;
            const double e = e_raw[i] - offset_rad_;
            if (sink_) e_[i] = e;
            es_[ns] = e;
            th_[ns] = th_all[i];
            ++ns;
        }
        th = th_.data();
    }
    if (ns) {
        const double* es = es_.data();
        double mb = 0, qb = 0;
        block_moments(es, ns, mb, qb);
        std::uint64_t scored = m_.scored;
        merge_moments(scored, mean_, m2_, ns, mb, qb);
        m_.scored = scored;
        double lo = min_e_, hi = max_e_, se = 0, se2 = 0, travel = have_last_th_ ? std::fabs(th[0] - last_th_) : 0.0;
        std::uint64_t slipped = 0;
#pragma omp simd reduction(min : lo) reduction(max : hi) reduction(+ : slipped, se, se2)
        for (std::size_t i = 0; i < ns; ++i) {
            const double e = es[i];
            lo = std::min(lo, e);
            hi = std::max(hi, e);
            slipped += std::fabs(e) > kPi;
            se += e;
            se2 += e * e;
        }
#pragma omp simd reduction(+ : travel)
        for (std::size_t i = 1; i < ns; ++i) travel += std::fabs(th[i] - th[i - 1]);
        min_e_ = lo;
        max_e_ = hi;
        m_.slipped_samples += slipped;
        m_.cycles_scored += travel / kTwoPi;
        sum_e_ += se;
        sum_e2_ += se2;
        last_th_ = th[ns - 1];
        have_last_th_ = true;
        // Batch means of 64 scored samples, carried across blocks.
        for (std::size_t i = 0; i < ns;) {
            const std::size_t take = std::min<std::size_t>(static_cast<std::size_t>(kBatch0 - batch0_n_), ns - i);
            double sb = 0;
            for (std::size_t k = 0; k < take; ++k) sb += es[i + k];
            batch0_sum_ += sb;
            batch0_n_ += static_cast<int>(take);
            i += take;
            if (batch0_n_ == kBatch0) { batch_done(batch0_sum_); batch0_sum_ = 0; batch0_n_ = 0; }
        }
        // Into the fine angle bins: per bin the count and the power sums of the offset u from
        // the bin centre, plain and weighted by e (harmonic_sums() expands from them).
        // First each sample's bin and offset (a pass that vectorises), then the sums, each bin's
        // ten as two vector additions (element by element: the same sums in the same order).
        constexpr double kBinWidthRad = kTwoPi / kFineBins;
        fine_bin_.resize(ns);
        fine_u_.resize(ns);
        std::int32_t* fb = fine_bin_.data();
        double* fu = fine_u_.data();
#pragma omp simd
        for (std::size_t i = 0; i < ns; ++i) {
            const double turns = th[i] * (1 / kTwoPi);
            const double pos = (turns - std::floor(turns)) * kFineBins;  // [0, kFineBins], up to rounding
            // the bin: pos truncated, within [0, kFineBins - 1] (0 for a NaN)
            double b = std::trunc(pos);
            b = b >= 0 ? (b > kFineBins - 1 ? kFineBins - 1 : b) : 0.0;
            fu[i] = (pos - (b + 0.5)) * kBinWidthRad;
            fb[i] = static_cast<std::int32_t>(b);
        }
        typedef double V8 __attribute__((vector_size(64)));
        typedef double V2 __attribute__((vector_size(16)));
        static_assert(sizeof(FineBin) == 10 * sizeof(double));
        // Neighbouring samples mostly share a bin (a bin is 1/8192 of a cycle): a bin's sums stay
        // in registers while its samples last (a store and a reload per sample would chain each
        // addition to the one before through memory), added in the same order.
        FineBin* fine = fine_.data();
        for (std::size_t i = 0; i < ns;) {
            const std::int32_t bin = fb[i];
            auto* f = reinterpret_cast<unsigned char*>(&fine[bin]);  // p[0..4], q[0..4]
            V8 s8;
            V2 s2;
            std::memcpy(&s8, f, sizeof s8);
            std::memcpy(&s2, f + sizeof s8, sizeof s2);
            do {
                const double u = fu[i];
                const double u2 = u * u, u3 = u2 * u, u4 = u2 * u2, ee = es[i];
                s8 += V8{1, u, u2, u3, u4, ee, ee * u, ee * u2};
                s2 += V2{ee * u3, ee * u4};
                ++i;
            } while (i < ns && fb[i] == bin);
            std::memcpy(f, &s8, sizeof s8);
            std::memcpy(f + sizeof s8, &s2, sizeof s2);
        }
    }
    if (sink_) sink_(n, e_.data(), ok);
}

// Sums of cos(m th), sin(m th) (m = 0..2K) and of e*cos(k th), e*sin(k th) (k = 1..K) from the
// fine angle bins: with th = c + u (c the bin centre), exp(j m th) = exp(j m c) exp(j m u) and
// exp(j m u) = sum_p (j m u)^p / p! to p = 4, so each bin's power sums of u give its share. The
// truncation is below |m u|^5 / 120 <= (2K pi / kFineBins)^5 / 120, 2e-12 relative at K = 16
// (the sums are exact to that, where summing cos(m th) sample by sample cost 32 passes a sample).
void Scorer::harmonic_sums() {
    const int K = o_.max_harmonic, M = 2 * K;
    std::fill(sum_cos_.begin(), sum_cos_.end(), 0.0);
    std::fill(sum_sin_.begin(), sum_sin_.end(), 0.0);
    std::fill(sum_ecos_.begin(), sum_ecos_.end(), 0.0);
    std::fill(sum_esin_.begin(), sum_esin_.end(), 0.0);
    for (int b = 0; b < kFineBins; ++b) {
        const FineBin& f = fine_[static_cast<std::size_t>(b)];
        if (f.p[0] == 0) continue;
        const double centre = (static_cast<double>(b) + 0.5) * (kTwoPi / kFineBins);
        const double zr = std::cos(centre), zi = std::sin(centre);
        double pr = 1, pi = 0;  // exp(j m centre), by recurrence
        for (int m = 0; m <= M; ++m) {
            const double md = m, m2 = md * md, m3 = m2 * md, m4 = m2 * m2;
            // sum over the bin of exp(j m u) = re + j im
            const double re = f.p[0] - m2 / 2 * f.p[2] + m4 / 24 * f.p[4];
            const double im = md * f.p[1] - m3 / 6 * f.p[3];
            const auto mi = static_cast<std::size_t>(m);
            sum_cos_[mi] += pr * re - pi * im;
            sum_sin_[mi] += pr * im + pi * re;
            if (m >= 1 && m <= K) {
                const double qre = f.q[0] - m2 / 2 * f.q[2] + m4 / 24 * f.q[4];
                const double qim = md * f.q[1] - m3 / 6 * f.q[3];
                sum_ecos_[mi] += pr * qre - pi * qim;
                sum_esin_[mi] += pr * qim + pi * qre;
            }
            const double nr = pr * zr - pi * zi;
            pi = pr * zi + pi * zr;
            pr = nr;
        }
    }
}

// A completed batch of 64 samples (sum of e, rad): record its mean at level 0 and carry the sum
// up, where two batches make one of the next level.
void Scorer::batch_done(double sum) {
    double size = kBatch0;
    for (int l = 0; l < kBatchLevels; ++l, size *= 2) {
        BatchLevel& b = batches_[l];
        if (l > 0) {
            b.partial += sum;
            if (++b.parts < 2) return;
            sum = b.partial;
            b.partial = 0;
            b.parts = 0;
        }
        const double m = sum / size;
        b.s1 += m;
        b.s2 += m * m;
        ++b.n;
    }
}

ErrorMetrics Scorer::finish() {
    if (!decided_) decide();
    ErrorMetrics m = m_;
    m.removed_cycles = offset_rad_ / kTwoPi;
    if (n_omega_true_) m.mean_abs_omega_true_rad_s = sum_abs_omega_true_ / static_cast<double>(n_omega_true_);
    if (m.scored) {
        m.mean_rad = mean_;
        m.std_rad = m.scored > 1 ? std::sqrt(m2_ / static_cast<double>(m.scored - 1)) : 0.0;
        m.rms_rad = std::sqrt(mean_ * mean_ + m2_ / static_cast<double>(m.scored));
        m.max_abs_rad = std::max(std::fabs(min_e_), std::fabs(max_e_));
        m.max_dev_rad = std::max(max_e_ - mean_, mean_ - min_e_);
        // Harmonics. A function sampled at N distinct angles determines at most N/2 of them;
        // a quarter keeps the fit well conditioned. Fewer than one whole cycle leaves part of
        // the circle unseen, where no order can be told apart from the others.
        harmonic_sums();
        int covered = 0;  // angle bins of kAngleBins visited
        constexpr int kFinePerBin = kFineBins / kAngleBins;
        for (int c = 0; c < kAngleBins; ++c) {
            bool any = false;
            for (int k = 0; k < kFinePerBin; ++k) any |= fine_[static_cast<std::size_t>(c * kFinePerBin + k)].p[0] > 0;
            covered += any;
        }
        if (m.cycles_scored < 1.0) {
            m.harmonics_note = "the scored samples cover " + std::to_string(m.cycles_scored).substr(0, 5) +
                               " electrical cycles: harmonics need at least one whole cycle to be told apart";
        } else {
            // The highest order the visited angles support: start from a quarter of the bins
            // visited and lower it until the normal equations are well conditioned (samples
            // at a few distinct angles, as with synchronous sampling, support only a few).
            // Never more unknowns than a quarter of the scored samples, so the fit is not of noise.
            const auto by_samples = static_cast<int>(std::min<std::uint64_t>(64, (m.scored / 4 > 1 ? (m.scored / 4 - 1) / 2 : 0)));
            const int K0 = std::min({o_.max_harmonic, std::max(1, covered / 4), std::max(1, by_samples)});
            auto C = [&](int k) { return sum_cos_[static_cast<std::size_t>(std::abs(k))]; };
            auto S = [&](int k) { return k < 0 ? -sum_sin_[static_cast<std::size_t>(-k)] : sum_sin_[static_cast<std::size_t>(k)]; };
            for (int K = K0; K >= 1 && m.harmonics.empty(); --K) {
                const int P = 2 * K + 1;
                Eigen::MatrixXd A(P, P);
                Eigen::VectorXd y(P);
                // column 0: 1; column 2j-1: cos j th; column 2j: sin j th
                A(0, 0) = C(0);
                y(0) = sum_e_;
                for (int j = 1; j <= K; ++j) {
                    A(0, 2 * j - 1) = A(2 * j - 1, 0) = C(j);
                    A(0, 2 * j) = A(2 * j, 0) = S(j);
                    y(2 * j - 1) = sum_ecos_[static_cast<std::size_t>(j)];
                    y(2 * j) = sum_esin_[static_cast<std::size_t>(j)];
                    for (int k = 1; k <= K; ++k) {
                        A(2 * j - 1, 2 * k - 1) = 0.5 * (C(j - k) + C(j + k));
                        A(2 * j, 2 * k) = 0.5 * (C(j - k) - C(j + k));
                        A(2 * j - 1, 2 * k) = 0.5 * (S(k + j) + S(k - j));  // cos j * sin k
                        A(2 * k, 2 * j - 1) = A(2 * j - 1, 2 * k);
                    }
                }
                Eigen::LDLT<Eigen::MatrixXd> ldlt(A);
                const Eigen::VectorXd d = ldlt.vectorD();
                if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !(d.minCoeff() > 1e-9 * d.maxCoeff())) continue;
                const Eigen::VectorXd b = ldlt.solve(y);
                for (int k = 1; k <= K; ++k) {
                    const double a = b(2 * k - 1), c = b(2 * k);
                    m.harmonics.push_back({k, std::hypot(a, c), std::atan2(c, a)});
                }
                // What the fit leaves, from the same least squares: the residual sum of squares
                // is sum e^2 - b'y at the solution. Over a non-integer number of cycles the
                // harmonics are not orthogonal, so var - sum(a_k^2)/2 would be wrong (it was).
                const double rss = std::max(0.0, sum_e2_ - b.dot(y));
                m.harmonic_power_fraction = m2_ > 0 ? std::clamp(1.0 - rss / m2_, 0.0, 1.0) : 0.0;
                m.broadband_rms_rad = std::sqrt(rss / static_cast<double>(m.scored));
                if (K < o_.max_harmonic)
                    m.harmonics_note = "orders above " + std::to_string(K) + "x not fitted: " +
                                       (K == by_samples && K < covered / 4 ? std::to_string(m.scored) + " scored samples support no more (at most a quarter as many unknowns)"
                                                                           : "the scored samples visit too few distinct electrical angles (" + std::to_string(covered) + " of " +
                                                                                 std::to_string(kAngleBins) + " angle bins) to separate more");
            }
            if (m.harmonics.empty()) m.harmonics_note = "the scored samples visit too few distinct electrical angles to separate harmonics";
        }
        // Correlation time from batch means (the Bartlett estimate of the spectral density at 0).
        const double var = m2_ / static_cast<double>(m.scored);
        if (var > 0) {
            auto tau_at = [&](int l) {
                const BatchLevel& b = batches_[l];
                const double nb = static_cast<double>(b.n);
                const double vb = std::max(0.0, (b.s2 - b.s1 * b.s1 / nb) / (nb - 1));
                return static_cast<double>(kBatch0) * std::ldexp(1.0, l) * vb / var;
            };
            for (int l = kBatchLevels - 1; l >= 0; --l) {
                if (batches_[l].n < 32) continue;
                m.correlation_samples = std::clamp(tau_at(l), 1.0, static_cast<double>(m.scored));
                m.correlation_batch = static_cast<std::uint64_t>(kBatch0) << l;
                break;
            }
            // A short run (no level with 32 batches): batches too short to see a tracker's
            // correlation, so the largest tau of any level with at least 4 batches (conservative;
            // the interval is marked approximate).
            if (!m.correlation_samples) {
                for (int l = 0; l < kBatchLevels && batches_[l].n >= 4; ++l) {
                    const double t = tau_at(l);
                    if (!m.correlation_samples || t > *m.correlation_samples) {
                        m.correlation_samples = t;
                        m.correlation_batch = static_cast<std::uint64_t>(kBatch0) << l;
                    }
                }
                if (m.correlation_samples) {
                    m.correlation_samples = std::clamp(*m.correlation_samples, 1.0, static_cast<double>(m.scored));
                    m.correlation_approximate = true;
                }
            }
        }
        if (om_n_) {
            m.have_rate = true;
            m.omega_error_mean_rad_s = om_mean_;
            m.omega_error_std_rad_s = om_n_ > 1 ? std::sqrt(om_m2_ / static_cast<double>(om_n_ - 1)) : 0.0;
        }
        if (n_omega_true_) {
            const double mean_omega = sum_omega_true_ / static_cast<double>(n_omega_true_);
            if (std::fabs(mean_omega) > 1e-9) m.lag_s = -mean_ / mean_omega;
        }
    }
    if (locked_now_) m.lock_time_s = first_t_after_ - t0_;
    return m;
}

void ConventionCheck::add(std::size_t n, const double* th_true, const double* th_hat, const std::uint8_t* valid) {
    constexpr double kHalfTurnDeg = 180.0;
    // Local accumulators: members written through `this` inside the loop could alias the
    // input arrays, and the compiler would reload and store them every sample.
    bool have = have_;
    double last_true = last_true_, last_hat = last_hat_, lo = min_hat_, hi = max_hat_;
    double sdt = sum_abs_dtrue_, sdh = sum_abs_dhat_, dsdt = deg_sum_abs_dtrue_, dsdh = deg_sum_abs_dhat_;
    std::uint64_t pairs = 0, wraps = 0, djumps = 0;
    // Every sample valid and finite (the common case): the pairs in passes that vectorise (the
    // sums in eight lanes, not in order: they only decide between units, last bits do not matter).
    std::size_t bad = 0;
#pragma omp simd reduction(+ : bad)
    for (std::size_t i = 0; i < n; ++i) bad += !valid[i] || !((th_true[i] - th_true[i]) == 0.0) || !((th_hat[i] - th_hat[i]) == 0.0);
    const bool all_usable = n > 1 && bad == 0;
    if (all_usable) {
        std::size_t i0 = 0;
        if (!have) {  // the block's first sample starts the pairs
            lo = std::min(lo, th_hat[0]);
            hi = std::max(hi, th_hat[0]);
            i0 = 1;
        }
        const double* pt = th_true;
        const double* ph = th_hat;
        const double lt = last_true, lh = last_hat;
#pragma omp simd reduction(min : lo) reduction(max : hi) reduction(+ : sdt, sdh, dsdt, dsdh, pairs, wraps, djumps)
        for (std::size_t i = i0; i < n; ++i) {
            // the same arithmetic as the loop below, written out: through a lambda that
            // updates the sums by reference GCC no longer vectorises it (2x slower, measured)
            const double tt = pt[i], hh = ph[i];
            const double dt = tt - (i ? pt[i - 1] : lt), dh = hh - (i ? ph[i - 1] : lh);
            const double adt = std::fabs(dt), adh = std::fabs(dh);
            lo = std::min(lo, hh);
            hi = std::max(hi, hh);
            ++pairs;
            sdt += adt;
            sdh += adh;
            wraps += std::fabs(std::fabs(dh - dt) - kTwoPi) < 0.5;
            const bool jump = adh > kHalfTurnDeg;
            djumps += jump;
            dsdt += jump ? 0.0 : adt;
            dsdh += jump ? 0.0 : adh;
        }
        have = true;
        last_true = th_true[n - 1];
        last_hat = th_hat[n - 1];
    }
    for (std::size_t i = 0; i < n && !all_usable; ++i) {
        const double tt = th_true[i], hh = th_hat[i];
        if (!valid[i] || !((tt - tt) == 0.0) || !((hh - hh) == 0.0)) { have = false; continue; }  // invalid or not finite
        lo = std::min(lo, hh);
        hi = std::max(hi, hh);
        if (have) {
            const double dt = tt - last_true, dh = hh - last_hat;
            const double adt = std::fabs(dt), adh = std::fabs(dh);
            ++pairs;
            sdt += adt;
            sdh += adh;
            wraps += std::fabs(std::fabs(dh - dt) - kTwoPi) < 0.5;
            const bool jump = adh > kHalfTurnDeg;
            djumps += jump;
            dsdt += jump ? 0.0 : adt;
            dsdh += jump ? 0.0 : adh;
        }
        have = true;
        last_true = tt;
        last_hat = hh;
    }
    have_ = have;
    last_true_ = last_true;
    last_hat_ = last_hat;
    min_hat_ = lo;
    max_hat_ = hi;
    sum_abs_dtrue_ = sdt;
    sum_abs_dhat_ = sdh;
    deg_sum_abs_dtrue_ = dsdt;
    deg_sum_abs_dhat_ = dsdh;
    pairs_ += pairs;
    wrap_jumps_ += wraps;
    deg_jumps_ += djumps;
    deg_pairs_ += pairs - djumps;
}

std::vector<ConventionCheck::Finding> ConventionCheck::findings() const {
    std::vector<Finding> f;
    constexpr double kDeg = 180.0 / kPi;
    auto fmt = [](double v) {
        char b[32];
        std::snprintf(b, sizeof b, "%.4g", v);
        return std::string(b);
    };
    // Degrees first: wrapped degrees also jump, by 360, and the 2*pi test must not name them radians.
    if (deg_sum_abs_dtrue_ > 0.1 && deg_pairs_ > 10) {
        const double ratio = deg_sum_abs_dhat_ / deg_sum_abs_dtrue_;
        if (std::fabs(ratio / kDeg - 1) < 0.1) {
            std::string how = "theta changes " + fmt(ratio) + " times as fast as the truth (180/pi = 57.3): the output looks like degrees";
            if (deg_jumps_ > 0) {
                const char* range = min_hat_ >= -1e-9 && max_hat_ <= 360.0 + 1e-9 ? ", wrapped to [0, 360)"
                                    : min_hat_ >= -180.0 - 1e-9 && max_hat_ <= 180.0 + 1e-9 ? ", wrapped to (-180, 180]"
                                                                                                : ", wrapped";
                how += std::string(range) + " (" + std::to_string(deg_jumps_) + " jumps of 360 between consecutive samples)";
                f.push_back({"estimates_in_degrees_wrapped", how + "; theta must be unwrapped radians"});
            } else {
                f.push_back({"estimates_in_degrees", how + "; theta must be in radians"});
            }
            return f;
        }
    }
    if (wrap_jumps_ > 0)
        f.push_back({"estimates_wrapped", "theta jumps by 2*pi between consecutive samples " + std::to_string(wrap_jumps_) +
                                              " times while the truth does not: the output looks wrapped; theta must be unwrapped (continuous across cycles)"});
    else if (sum_abs_dtrue_ > 0.1 && pairs_ > 10) {
        const double ratio = sum_abs_dhat_ / sum_abs_dtrue_;
        if (std::fabs(ratio / kDeg - 1) < 0.1)
            f.push_back({"estimates_in_degrees", "theta changes " + fmt(ratio) + " times as fast as the truth (180/pi = 57.3): the output looks like degrees; theta must be in radians"});
    }
    return f;
}

nlohmann::json angle_units(double rad, int lines) {
    nlohmann::json j{{"rad", rad}, {"percent_period", rad / kTwoPi * 100.0}};
    j["arcsec_mech"] = lines > 0 ? nlohmann::json(rad / lines * (180.0 / kPi) * 3600.0) : nlohmann::json();
    return j;
}

namespace {

constexpr double kZ95 = 1.959963984540054;  // two-sided 95 % normal quantile

// Chi-square quantile with nu degrees of freedom at normal quantile z (Wilson-Hilferty; within
// 1 % of the exact value for nu >= 3).
double chi2_quantile(double nu, double z) {
    const double a = 2.0 / (9.0 * nu);
    const double c = 1.0 - a + z * std::sqrt(a);
    return nu * c * c * c;
}

}  // namespace

nlohmann::json uncertainty_json(const ErrorMetrics& m) {
    using nlohmann::json;
    json u{{"confidence", 0.95},
           {"method", "the error's correlation time tau = S(0)/variance from batch means (docs/model.md#uncertainty); "
                      "independent samples = scored / tau; std and broadband rms by chi-square, mean and harmonics by the normal law, rms by the delta method"}};
    if (!m.scored || !m.correlation_samples) {
        u["note"] = m.scored ? "too few scored samples to estimate the error's correlation time (at least 4 batches of 64)" : "nothing scored";
        return u;
    }
    const double tau = *m.correlation_samples, nu = static_cast<double>(m.scored) / tau;
    u["correlation_samples"] = tau;
    u["correlation_batch_samples"] = m.correlation_batch;
    u["independent_samples"] = nu;
    if (m.correlation_approximate)
        u["note"] = "approximate: fewer than 2048 scored samples, too few to resolve the error's correlation time; tau is the largest of the batch lengths tried (a longer run narrows and firms the interval)";
    if (nu < 3) {
        u["note"] = "fewer than 3 independent samples: no interval";
        return u;
    }
    const double sigma = m.std_rad, mu = m.mean_rad;
    auto pair = [](double lo, double hi) { return json::array({lo, hi}); };
    const double chi_hi = chi2_quantile(nu, kZ95), chi_lo = chi2_quantile(nu, -kZ95);
    auto spread = [&](double s) { return pair(s * std::sqrt(nu / chi_hi), s * std::sqrt(nu / std::max(chi_lo, 1e-300))); };
    u["mean_rad"] = pair(mu - kZ95 * sigma / std::sqrt(nu), mu + kZ95 * sigma / std::sqrt(nu));
    u["std_rad"] = spread(sigma);
    // rms^2 = mu^2 + sigma^2; var(rms^2) ~ (2 sigma^4 + 4 mu^2 sigma^2) / nu
    const double r2 = m.rms_rad * m.rms_rad, sd_r2 = std::sqrt((2 * sigma * sigma * sigma * sigma + 4 * mu * mu * sigma * sigma) / nu);
    u["rms_rad"] = pair(std::sqrt(std::max(0.0, r2 - kZ95 * sd_r2)), std::sqrt(r2 + kZ95 * sd_r2));
    if (!m.harmonics.empty()) {
        u["broadband_rms_rad"] = spread(m.broadband_rms_rad);
        // a least-squares cos/sin coefficient over nu independent samples of the residual: sd sigma_b sqrt(2/nu)
        const double sd_a = m.broadband_rms_rad * std::sqrt(2.0 / nu);
        json h = json::array();
        for (const auto& x : m.harmonics)
            h.push_back({{"order", x.order}, {"amplitude_rad", pair(std::max(0.0, x.amplitude_rad - kZ95 * sd_a), x.amplitude_rad + kZ95 * sd_a)}});
        u["harmonics"] = h;
    }
    return u;
}

nlohmann::json to_json(const ErrorMetrics& m, int lines) {
    using nlohmann::json;
    // Statistics of nothing are not zero: without scored samples they are null.
    auto stat = [&](double v) { return m.scored ? angle_units(v, lines) : json(); };
    json j{{"samples", m.samples}, {"scored", m.scored}, {"invalid_after_settle", m.invalid_after_settle},
           {"removed_cycles", m.removed_cycles}, {"slipped_samples", m.scored ? json(m.slipped_samples) : json()},
           {"mean", stat(m.mean_rad)}, {"std", stat(m.std_rad)},
           {"rms", stat(m.rms_rad)}, {"max_abs", stat(m.max_abs_rad)},
           {"max_dev", stat(m.max_dev_rad)}};
    if (m.unremoved_error_rad != 0)
        j["cycles_not_removed"] = {{"median_error_rad", m.unremoved_error_rad},
                                   {"why", "the estimate is further from the truth than 1e9 rad: removing whole cycles would round "
                                           "the error away; scored as it is"}};
    const auto vf = m.valid_fraction();
    j["evidence"] = {{"samples_after_settle", m.after_settle}, {"scored_samples", m.scored},
                     {"scored_cycles", m.cycles_scored}, {"valid_fraction", vf ? json(*vf) : json()}};
    auto h = json::array();
    for (const auto& x : m.harmonics)
        h.push_back({{"order", x.order}, {"amplitude", angle_units(x.amplitude_rad, lines)}, {"phase_rad", x.phase_rad}});
    j["harmonics"] = h;
    j["harmonic_analysis"] = {{"orders_requested", m.harmonics_requested},
                              {"orders_fitted", static_cast<int>(m.harmonics.size())},
                              {"power_fraction", m.harmonics.empty() ? json() : json(m.harmonic_power_fraction)},
                              {"broadband_rms_rad", m.harmonics.empty() ? json() : json(m.broadband_rms_rad)},
                              {"note", m.harmonics_note.empty() ? json() : json(m.harmonics_note)}};
    if (m.have_rate) j["omega_error"] = {{"mean_rad_s", m.omega_error_mean_rad_s}, {"std_rad_s", m.omega_error_std_rad_s}};
    if (m.omega_nonfinite) j["omega_nonfinite_samples"] = m.omega_nonfinite;
    j["lag_s"] = m.lag_s ? json(*m.lag_s) : json();
    j["lock_time_s"] = m.lock_time_s ? json(*m.lock_time_s) : json();
    j["uncertainty"] = uncertainty_json(m);
    return j;
}

}  // namespace fringe
