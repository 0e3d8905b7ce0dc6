#include "server/analysis/traces.hpp"

#include "signal_gen/base/constants.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace fringe {

using nlohmann::json;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Wrap to (-pi, pi]. Rounding instead of std::remainder: this runs per sample and lane (in a
// pass of its own that vectorises: no branches).
inline double wrap_pi(double x) {
    const double y = x - kTwoPi * std::floor(x * (1 / kTwoPi) + 0.5);
    return y <= -kPi ? y + kTwoPi : (y > kPi ? y - kTwoPi : y);
}

// Where in bucket b its Lissajous point is taken: scattered (a hash of b), so a speed at which the
// bucket length is a whole number of electrical periods cannot put every point at one phase.
std::uint64_t scatter(std::uint64_t b, std::uint64_t len) {
    std::uint64_t x = b + 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    x ^= x >> 31;
    return len > 1 ? x % len : 0;
}

// Plot values to `digits` significant digits: the JSON halves in size, far beyond what a plot resolves.
double sig(double v, int digits = 6) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    return std::strtod(buf, nullptr);
}

json num_or_null(double v, int digits = 6) { return std::isfinite(v) ? json(sig(v, digits)) : json(); }

json minmax_json(const std::vector<double>& lo, const std::vector<double>& hi, std::size_t n) {
    json a = json::array(), b = json::array();
    for (std::size_t i = 0; i < n; ++i) {
        a.push_back(num_or_null(lo[i]));  // +inf: the bucket saw no valid value
        b.push_back(num_or_null(hi[i]));
    }
    return json{{"min", std::move(a)}, {"max", std::move(b)}};
}

}  // namespace

void TraceRecorder::MinMax::resize(std::size_t n) {
    lo.assign(n, kInf);
    hi.assign(n, -kInf);
}

TraceRecorder::TraceRecorder(std::uint64_t total_samples, std::size_t points, std::vector<std::string> labels, double fold_from_s,
                             std::size_t angle_bins)
    : labels_(std::move(labels)), fold_from_s_(fold_from_s), bins_(std::max<std::size_t>(angle_bins, 8)) {
    points = std::max<std::size_t>(points, 1);
    const std::uint64_t total = std::max<std::uint64_t>(total_samples, 1);
    bucket_samples_ = (total + points - 1) / points;
    buckets_ = static_cast<std::size_t>((total + bucket_samples_ - 1) / bucket_samples_);
    t_start_.assign(buckets_, std::numeric_limits<double>::quiet_NaN());
    sin_.resize(buckets_);
    cos_.resize(buckets_);
    err_.resize(labels_.size());
    for (auto& e : err_) e.resize(buckets_);
    pt_sin_.assign(buckets_, std::numeric_limits<double>::quiet_NaN());
    pt_cos_.assign(buckets_, std::numeric_limits<double>::quiet_NaN());
    pt_offset_.resize(buckets_);
    for (std::size_t b = 0; b < buckets_; ++b) pt_offset_[b] = scatter(b, bucket_samples_);
    cyc_sin_.assign(bins_, 0.0);
    cyc_cos_.assign(bins_, 0.0);
    cyc_n_.assign(bins_, 0);
    fold_.resize(labels_.size());
    for (auto& f : fold_) {
        f.sum.assign(bins_, 0.0);
        f.lo.assign(bins_, kInf);
        f.hi.assign(bins_, -kInf);
        f.count.assign(bins_, 0);
    }
}

void TraceRecorder::add(std::size_t m, const double* t_s, const double* sin_v, const double* cos_v, const double* theta_true_rad,
                        const std::uint8_t* truth_known, const std::vector<const double*>& err_rad) {
    const std::size_t lanes = std::min(err_rad.size(), labels_.size());
    // The true-angle bin of each sample that enters the folds (-1: not folded), once for all lanes:
    // the true angle wrapped to [0, 2 pi) in a pass that vectorises (an unfolded sample's angle
    // taken as 0, its bin -1).
    abin_.resize(m);
    std::int32_t* bin_of = abin_.data();
    const double nb = static_cast<double>(bins_), from = fold_from_s_;
    auto bins = [&](auto known) {
#pragma omp simd
        for (std::size_t i = 0; i < m; ++i) {
            const double th = theta_true_rad[i];
            const bool fold = known(i) && (th - th) == 0.0 && t_s[i] >= from;  // th - th: NaN unless finite
            const double turns = (fold ? th : 0.0) * (1 / kTwoPi);
            const double b = std::trunc((turns - std::floor(turns)) * nb);
            bin_of[i] = fold ? static_cast<std::int32_t>(b < nb ? b : nb - 1) : -1;
        }
    };
    if (truth_known) bins([&](std::size_t i) { return truth_known[i] != 0; });
    else bins([](std::size_t) { return true; });
    // The cycle sums in order, a bin's consecutive samples summed in registers (the same
    // additions in the same order as one bin update a sample, without a store between them).
    {
        std::size_t i = 0;
        while (i < m) {
            const std::int32_t ab = bin_of[i];
            if (ab < 0) { ++i; continue; }
            const auto b = static_cast<std::size_t>(ab);
            double cs = cyc_sin_[b], cc = cyc_cos_[b];
            std::uint64_t cn = cyc_n_[b];
            for (; i < m && bin_of[i] == ab; ++i) {
                const double sv = sin_v[i], cv = cos_v[i];
                if ((sv - sv) == 0.0 && (cv - cv) == 0.0) {
                    cs += sv;
                    cc += cv;
                    ++cn;
                }
            }
            cyc_sin_[b] = cs;
            cyc_cos_[b] = cc;
            cyc_n_[b] = cn;
        }
    }
    // Each lane's error wrapped, in a pass of its own.
    wrapped_.resize(lanes);
    for (std::size_t j = 0; j < lanes; ++j) {
        wrapped_[j].resize(m);
        const double* e = err_rad[j];
        double* w = wrapped_[j].data();
        for (std::size_t k = 0; k < m; ++k) w[k] = wrap_pi(e[k]);
    }
    // Each lane's folds by angle bin, a bin's consecutive samples in registers as above.
    for (std::size_t j = 0; j < lanes; ++j) {
        const double* e = err_rad[j];
        const double* wr = wrapped_[j].data();
        Fold& f = fold_[j];
        std::size_t i = 0;
        while (i < m) {
            const std::int32_t ab = bin_of[i];
            if (ab < 0) { ++i; continue; }
            const auto b = static_cast<std::size_t>(ab);
            double sum = f.sum[b], lo = f.lo[b], hi = f.hi[b];
            std::uint64_t cnt = f.count[b];
            for (; i < m && bin_of[i] == ab; ++i) {
                if (!((e[i] - e[i]) == 0.0)) continue;  // invalid sample or unknown truth
                const double w = wr[i];
                sum += w;
                ++cnt;
                if (w < lo) lo = w;
                if (w > hi) hi = w;
            }
            f.sum[b] = sum;
            f.lo[b] = lo;
            f.hi[b] = hi;
            f.count[b] = cnt;
        }
    }
    // Bucket by bucket: no division per sample. Minima and maxima in any order are the same.
    constexpr double kInfV = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < m;) {
        const std::uint64_t idx = n_ + i;
        const auto b = static_cast<std::size_t>(std::min<std::uint64_t>(idx / bucket_samples_, buckets_ - 1));
        const std::uint64_t off = idx - static_cast<std::uint64_t>(b) * bucket_samples_;
        // the last bucket also takes the samples past the plan
        const std::size_t len = b + 1 == buckets_ ? m - i : static_cast<std::size_t>(std::min<std::uint64_t>(m - i, bucket_samples_ - off));
        if (b >= used_) used_ = b + 1;
        if (std::isnan(t_start_[b])) t_start_[b] = t_s[i];
        double slo = sin_.lo[b], shi = sin_.hi[b], clo = cos_.lo[b], chi = cos_.hi[b];
#pragma omp simd reduction(min : slo, clo) reduction(max : shi, chi)
        for (std::size_t k = i; k < i + len; ++k) {
            const double sv = sin_v[k], cv = cos_v[k];
            const bool sf = (sv - sv) == 0.0, cf = (cv - cv) == 0.0;
            slo = std::min(slo, sf ? sv : kInfV);
            shi = std::max(shi, sf ? sv : -kInfV);
            clo = std::min(clo, cf ? cv : kInfV);
            chi = std::max(chi, cf ? cv : -kInfV);
        }
        sin_.lo[b] = slo; sin_.hi[b] = shi; cos_.lo[b] = clo; cos_.hi[b] = chi;
        if (pt_offset_[b] >= off && pt_offset_[b] < off + len) {
            const std::size_t k = i + static_cast<std::size_t>(pt_offset_[b] - off);
            if (std::isfinite(sin_v[k]) && std::isfinite(cos_v[k])) { pt_sin_[b] = sin_v[k]; pt_cos_[b] = cos_v[k]; }
        }
        for (std::size_t j = 0; j < lanes; ++j) {
            const double* e = err_rad[j];
            const double* wr = wrapped_[j].data();
            double lo = err_[j].lo[b], hi = err_[j].hi[b];
#pragma omp simd reduction(min : lo) reduction(max : hi)
            for (std::size_t k = i; k < i + len; ++k) {
                const double ek = e[k], w = wr[k];
                const bool ok = (ek - ek) == 0.0;  // invalid sample or unknown truth: NaN
                lo = std::min(lo, ok ? w : kInfV);
                hi = std::max(hi, ok ? w : -kInfV);
            }
            err_[j].lo[b] = lo;
            err_[j].hi[b] = hi;
        }
        i += len;
    }
    block_first_ = n_;
    n_ += m;
}

void TraceRecorder::add_points(std::size_t lane, std::size_t n, const std::uint32_t* frame, const double* t_s, const double* theta_true_rad,
                               const double* err_rad) {
    if (lane >= err_.size() || buckets_ == 0) return;
    const double nb = static_cast<double>(bins_);
    Fold& f = fold_[lane];
    for (std::size_t k = 0; k < n; ++k) {
        const double e = err_rad[k];
        if (!std::isfinite(e)) continue;
        const double w = wrap_pi(e);
        const std::uint64_t idx = std::min<std::uint64_t>(block_first_ + frame[k], n_ == 0 ? 0 : n_ - 1);
        const auto b = static_cast<std::size_t>(std::min<std::uint64_t>(idx / bucket_samples_, buckets_ - 1));
        if (b >= used_) used_ = b + 1;
        if (std::isnan(t_start_[b])) t_start_[b] = t_s[k];
        err_[lane].put(b, w);
        const double th = theta_true_rad[k];
        if (!std::isfinite(th) || !(t_s[k] >= fold_from_s_)) continue;
        const double turns = th * (1 / kTwoPi);
        const double x = std::trunc((turns - std::floor(turns)) * nb);
        const auto ab = static_cast<std::size_t>(x < nb ? x : nb - 1);
        f.sum[ab] += w;
        ++f.count[ab];
        if (w < f.lo[ab]) f.lo[ab] = w;
        if (w > f.hi[ab]) f.hi[ab] = w;
    }
}

json TraceRecorder::to_json() const {
    const std::size_t n = used_;
    json t = json::array();
    for (std::size_t b = 0; b < n; ++b) t.push_back(num_or_null(t_start_[b], 10));
    json errs = json::object();
    for (std::size_t j = 0; j < labels_.size(); ++j) errs[labels_[j]] = minmax_json(err_[j].lo, err_[j].hi, n);
    json ps = json::array(), pc = json::array();
    for (std::size_t b = 0; b < n; ++b)
        if (std::isfinite(pt_sin_[b])) { ps.push_back(sig(pt_sin_[b])); pc.push_back(sig(pt_cos_[b])); }
    json th = json::array(), cs = json::array(), cc = json::array();
    for (std::size_t k = 0; k < bins_; ++k) {
        th.push_back(sig((static_cast<double>(k) + 0.5) * kTwoPi / static_cast<double>(bins_), 8));
        const double cnt = static_cast<double>(cyc_n_[k]);
        cs.push_back(cyc_n_[k] ? json(sig(cyc_sin_[k] / cnt)) : json());
        cc.push_back(cyc_n_[k] ? json(sig(cyc_cos_[k] / cnt)) : json());
    }
    json folds = json::object();
    for (std::size_t j = 0; j < labels_.size(); ++j) {
        const Fold& f = fold_[j];
        json mean = json::array(), lo = json::array(), hi = json::array(), count = json::array();
        for (std::size_t k = 0; k < bins_; ++k) {
            const bool any = f.count[k] > 0;
            mean.push_back(any ? json(sig(f.sum[k] / static_cast<double>(f.count[k]))) : json());
            lo.push_back(any ? json(sig(f.lo[k])) : json());
            hi.push_back(any ? json(sig(f.hi[k])) : json());
            count.push_back(f.count[k]);
        }
        folds[labels_[j]] = json{{"mean", std::move(mean)}, {"min", std::move(lo)}, {"max", std::move(hi)}, {"count", std::move(count)}};
    }
    return json{{"kind", "envelope"},
                {"bucket_samples", bucket_samples_},
                {"samples", n_},
                {"t_s", std::move(t)},
                {"sin_v", minmax_json(sin_.lo, sin_.hi, n)},
                {"cos_v", minmax_json(cos_.lo, cos_.hi, n)},
                {"error_rad", std::move(errs)},
                {"lissajous", {{"points", {{"sin_v", std::move(ps)}, {"cos_v", std::move(pc)}}},
                               {"cycle", {{"theta_rad", th}, {"sin_v", std::move(cs)}, {"cos_v", std::move(cc)}}}}},
                {"by_angle", {{"theta_rad", th}, {"error_rad", std::move(folds)}}}};
}

}  // namespace fringe
