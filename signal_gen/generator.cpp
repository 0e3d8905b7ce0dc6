#include "generator.hpp"

#include "fastmath.hpp"
#include "optics.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace fringe {

namespace {
// Front end, channel gains and offsets, additive noise (eta2) and the ADC (MODEL.md 2.5),
// with the constants hoisted so that per-sample loops vectorise.
struct FrontEnd {
    double g_s, g_c, vref_v, off_s_v, off_c_v, sigma_add_v, gain_scale;
    double adc_lo_v, adc_inv_q, adc_q_v, adc_top;
    double adc(double v) const { return Quantizer::quantize(v, adc_lo_v, adc_inv_q, adc_q_v, adc_top); }
    // raw: detector voltage; g: 1 + gain noise; noise: a standard normal.
    template <bool kQuantize>
    double sin_channel(double raw, double g, double noise) const {
        const double v = g_s * (g * raw - vref_v) + off_s_v + sigma_add_v * noise;
        return kQuantize ? adc(v) : v;
    }
    template <bool kQuantize>
    double cos_channel(double raw, double g, double noise) const {
        const double v = g_c * (g * raw - vref_v) + off_c_v + sigma_add_v * noise;
        return kQuantize ? adc(v) : v;
    }
};

struct Inputs {  // per-sample inputs of a tile
    const double* __restrict theta_rad;
    const double* __restrict gain_src;
    const double* __restrict noise_s;
    const double* __restrict noise_c;
};

// Up to two harmonics: raw = dc + a1 (p1 cos th + q1 sin th) + a2 (p2 cos 2th + q2 sin 2th).
struct Harmonics2 {
    double a1, a2, ps1, ps2, qs1, qs2, pc1, pc2, qc1, qc2, dc_v;
};

template <int kM, bool kQuantize>
void synthesize(std::size_t n, const Inputs& in, const Harmonics2 h, const FrontEnd fe,
                double* __restrict s1, double* __restrict c1, double* __restrict vs, double* __restrict vc) {
    // Two passes: the sin/cos polynomial alone vectorises better than fused with the rest.
    for (std::size_t i = 0; i < n; ++i) fast_sincos(in.theta_rad[i], s1[i], c1[i]);
    for (std::size_t i = 0; i < n; ++i) {
        const double S = s1[i], C = c1[i];
        double rs = h.dc_v + h.a1 * (h.ps1 * C + h.qs1 * S);
        double rc = h.dc_v + h.a1 * (h.pc1 * C + h.qc1 * S);
        if constexpr (kM == 2) {
            const double C2 = 2 * C * C - 1, S2 = 2 * S * C;
            rs += h.a2 * (h.ps2 * C2 + h.qs2 * S2);
            rc += h.a2 * (h.pc2 * C2 + h.qc2 * S2);
        }
        const double g = 1.0 + fe.gain_scale * in.gain_src[i];
        vs[i] = fe.sin_channel<kQuantize>(rs, g, in.noise_s[i]);
        vc[i] = fe.cos_channel<kQuantize>(rc, g, in.noise_c[i]);
    }
}
}  // namespace

void Block::resize(std::size_t n, bool with_index) {
    for (auto* v : {&t_s, &sin_v, &cos_v, &phi_rad, &theta_rad, &omega_rad_s}) v->resize(n);
    index_v.resize(with_index ? n : 0);
}

Generator::Generator(EncoderProfile encoder, MotionProfile motion, double sample_rate_hz,
                     std::uint64_t seed, double t0_s)
    : enc_(std::move(encoder)), motion_(std::move(motion)), fs_(sample_rate_hz), t0_(t0_s),
      noise_(seed, 1, 3) {
    if (!(fs_ > 0)) throw std::invalid_argument("sample rate must be positive");
    const double delta = enc_.lissajous.quadrature_error_rad;
    if (enc_.model == ModelKind::Diffraction) {
        // V_s = Vmax[w/2 + sum B_m cos(m(theta - pi/2))], V_c = Vmax[w/2 + sum B_m cos(m(theta + delta))]
        M_ = optics::harmonic_count(enc_.kappa_max());
        dc_v_ = enc_.vmax_v * enc_.aperture_w_rad / 2.0;
        for (int m = 1; m <= M_; ++m) {
            p_s_.push_back(std::cos(m * kPi / 2));
            q_s_.push_back(std::sin(m * kPi / 2));
            p_c_.push_back(std::cos(m * delta));
            q_c_.push_back(-std::sin(m * delta));
        }
    } else {
        // shape(x) = sin x + sum h_m sin(m x + psi_m); V_s = A shape(theta),
        // V_c = A shape(theta + pi/2 + delta). sin(m(theta + s) + psi) = S_m cos(ms + psi) + C_m sin(ms + psi)
        M_ = 1;
        for (const auto& h : enc_.harmonics) M_ = std::max(M_, h.order);
        dc_v_ = 0.0;
        p_s_.assign(M_, 0.0); q_s_.assign(M_, 0.0); p_c_.assign(M_, 0.0); q_c_.assign(M_, 0.0);
        amp_nominal_.assign(M_, 0.0);
        auto add = [&](int m, double h, double psi) {
            const double shift_c = m * (kPi / 2 + delta) + psi;
            p_s_[m - 1] += h * std::sin(psi);
            q_s_[m - 1] += h * std::cos(psi);
            p_c_[m - 1] += h * std::sin(shift_c);
            q_c_[m - 1] += h * std::cos(shift_c);
        };
        add(1, 1.0, 0.0);
        for (const auto& h : enc_.harmonics) add(h.order, h.amplitude_rel, h.phase_rad);
    }
    amp_nominal_.resize(M_);
    set_amplitudes(enc_.kappa_nominal(), amp_nominal_.data());
}

void Generator::set_amplitudes(double kappa, double* amp) const {
    if (enc_.model == ModelKind::Diffraction) {
        for (int m = 1; m <= M_; ++m)
            amp[m - 1] = enc_.vmax_v * optics::aperture_coefficient(m, kappa, enc_.aperture_w_rad);
    } else {
        for (int m = 1; m <= M_; ++m) amp[m - 1] = enc_.vmax_v;
    }
}

void Generator::raw_channels(double theta, double kappa, double& vs, double& vc) const {
    std::vector<double> amp(M_);
    set_amplitudes(kappa, amp.data());
    vs = vc = dc_v_;
    for (int m = 1; m <= M_; ++m) {
        const double C = std::cos(m * theta), S = std::sin(m * theta);
        vs += amp[m - 1] * (p_s_[m - 1] * C + q_s_[m - 1] * S);
        vc += amp[m - 1] * (p_c_[m - 1] * C + q_c_[m - 1] * S);
    }
}

void Generator::clean_channels(double theta, double kappa, double& vs, double& vc) const {
    raw_channels(theta, kappa, vs, vc);
    const auto& l = enc_.lissajous;
    const double vref = enc_.reference_v();
    vs = (1.0 + l.gain_mismatch / 2) * (vs - vref) + l.offset_sin_v;
    vc = (1.0 - l.gain_mismatch / 2) * (vc - vref) + l.offset_cos_v;
}

void Generator::generate(std::uint64_t first, Block& out) {
    const std::size_t n = out.size();
    for (auto* v : {&out.sin_v, &out.cos_v, &out.phi_rad, &out.theta_rad, &out.omega_rad_s})
        if (v->size() != n) throw std::invalid_argument("Generator::generate: Block not sized");
    if (enc_.index.enabled && out.index_v.size() != n)
        throw std::invalid_argument("Generator::generate: Block has no index channel");
    // Tiles small enough that the passes below stay in L1/L2.
    constexpr std::size_t kTile = 1024;
    for (auto* v : {&alpha_, &s1_, &c1_, &noise_s_, &noise_c_, &noise_g_, &kappa_}) v->resize(kTile);
    for (std::size_t off = 0; off < n; off += kTile) {
        const std::size_t m = std::min(kTile, n - off);
        Tile tile{out.t_s.data() + off, out.sin_v.data() + off, out.cos_v.data() + off,
                  out.index_v.empty() ? nullptr : out.index_v.data() + off, out.phi_rad.data() + off,
                  out.theta_rad.data() + off, out.omega_rad_s.data() + off};
        generate_tile(first + off, m, tile);
    }
}

void Generator::generate_tile(std::uint64_t first, std::size_t n, const Tile& out) {
    double* t = out.t_s;
    for (std::size_t i = 0; i < n; ++i) t[i] = t0_ + static_cast<double>(first + i) / fs_;
    motion_.evaluate(t, n, out.phi_rad, out.omega_rad_s, alpha_.data());

    // Geometry (MODEL.md 2.4): theta = n*(phi + (e1/r) sin(phi + psi1)),
    // rho = r - e1 cos(phi + psi1), D = (d1+d2)/2 + (d1-d2)/2 cos(phi + psiD).
    const double lines = enc_.lines_per_rev;
    const double* phi = out.phi_rad;
    double* theta = out.theta_rad;
    double* omega = out.omega_rad_s;
    const bool geo = enc_.geometry_varies();
    const bool kappa_varies = geo && enc_.model == ModelKind::Diffraction;
    if (geo) {
        const double er = enc_.e1_cm / enc_.radius_cm;
        const double cp1 = std::cos(enc_.e1_phase_rad), sp1 = std::sin(enc_.e1_phase_rad);
        const double cpd = std::cos(enc_.gap_phase_rad), spd = std::sin(enc_.gap_phase_rad);
        const double dmean = 0.5 * (enc_.gap_d1_cm + enc_.gap_d2_cm), dhalf = 0.5 * (enc_.gap_d1_cm - enc_.gap_d2_cm);
        for (std::size_t i = 0; i < n; ++i) {
            double sp, cp;
            fast_sincos(phi[i], sp, cp);
            const double s_e = sp * cp1 + cp * sp1;   // sin(phi + psi1)
            const double c_e = cp * cp1 - sp * sp1;   // cos(phi + psi1)
            const double c_d = cp * cpd - sp * spd;   // cos(phi + psiD)
            theta[i] = lines * (phi[i] + er * s_e);
            omega[i] = lines * (1.0 + er * c_e) * omega[i];
            if (kappa_varies)
                kappa_[i] = enc_.kappa_at(dmean + dhalf * c_d, enc_.radius_cm - enc_.e1_cm * c_e);
        }
    } else {
        for (std::size_t i = 0; i < n; ++i) {
            theta[i] = lines * phi[i];
            omega[i] = lines * omega[i];
        }
    }

    // Noise: streams 0, 1 additive (sin, cos), 2 gain.
    double* nz_copy[3] = {noise_s_.data(), noise_c_.data(), noise_g_.data()};
    const double* nz[3] = {noise_s_.data(), noise_c_.data(), noise_g_.data()};
    const NoiseConfig& nc = enc_.noise;
    const bool any_noise = nc.sigma_add_v > 0 || nc.sigma_gain > 0;
    if (any_noise && !noise_.view(first, n, nz)) noise_.fill(first, n, nz_copy);
    if (!any_noise)
        for (auto* v : {&noise_s_, &noise_c_, &noise_g_}) std::fill(v->begin(), v->begin() + static_cast<std::ptrdiff_t>(n), 0.0);

    // Gain noise and drift (eta1): g = 1 + gain_scale * gain_src[i].
    const double* gain_src = nz[2];
    double gain_scale = nc.sigma_gain;
    if (nc.drift_amplitude != 0.0) {
        const double wd = kTwoPi * nc.drift_freq_hz;
        for (std::size_t i = 0; i < n; ++i) {
            double sd, cd;
            fast_sincos(wd * t[i] + nc.drift_phase_rad, sd, cd);
            noise_g_[i] = nc.sigma_gain * nz[2][i] + nc.drift_amplitude * sd;
        }
        gain_src = noise_g_.data();
        gain_scale = 1.0;  // exact: the same numbers as scaling in place
    }

    const auto& l = enc_.lissajous;
    const Quantizer adc = enc_.adc;
    const FrontEnd fe{1.0 + l.gain_mismatch / 2, 1.0 - l.gain_mismatch / 2, enc_.reference_v(),
                      l.offset_sin_v, l.offset_cos_v, nc.sigma_add_v, gain_scale,
                      adc.min_v, adc.ideal() ? 0.0 : adc.inv_step(), adc.ideal() ? 0.0 : adc.step_v(),
                      adc.ideal() ? 0.0 : adc.max_code()};
    const Inputs in{theta, gain_src, nz[0], nz[1]};
    double* vs = out.sin_v;
    double* vc = out.cos_v;
    const int M = M_;
    double amp_local[64];
    std::vector<double> amp_heap;
    double* amp = amp_local;
    if (M > 64) { amp_heap.resize(M); amp = amp_heap.data(); }
    std::copy(amp_nominal_.begin(), amp_nominal_.end(), amp);

    // |theta| small enough for the vectorised sin/cos?
    int in_range = 1;  // an integer AND vectorises; a floating max reduction does not
    for (std::size_t i = 0; i < n; ++i) in_range &= std::fabs(theta[i]) < kFastSinCosMaxArg;

    if (in_range && !kappa_varies && (M == 1 || (M == 2 && enc_.model == ModelKind::Diffraction))) {
        // The common cases (the ideal model without harmonics or kappa <= 1; the paper's
        // 1 < kappa <= 1.5): sin/cos, then one vectorised pass from there to the ADC's output.
        auto second = [&](const std::vector<double>& v) { return M == 2 ? v[1] : 0.0; };
        const Harmonics2 h{amp[0], M == 2 ? amp[1] : 0.0, p_s_[0], second(p_s_), q_s_[0], second(q_s_),
                           p_c_[0], second(p_c_), q_c_[0], second(q_c_), dc_v_};
        using Synth = decltype(&synthesize<1, false>);
        constexpr Synth kSynth[2][2] = {{synthesize<1, false>, synthesize<1, true>},
                                        {synthesize<2, false>, synthesize<2, true>}};
        kSynth[M - 1][adc.ideal() ? 0 : 1](n, in, h, fe, s1_.data(), c1_.data(), vs, vc);
    } else {
        // Any number of harmonics, kappa per sample, or huge |theta| (libm's sin/cos).
        double* s1 = s1_.data();
        double* c1 = c1_.data();
        if (in_range) {
            for (std::size_t i = 0; i < n; ++i) fast_sincos(theta[i], s1[i], c1[i]);
        } else {
            for (std::size_t i = 0; i < n; ++i) { s1[i] = std::sin(theta[i]); c1[i] = std::cos(theta[i]); }
        }
        const double dc = dc_v_;
        const double* ps = p_s_.data(); const double* qs = q_s_.data();
        const double* pc = p_c_.data(); const double* qc = q_c_.data();
        for (std::size_t i = 0; i < n; ++i) {
            if (kappa_varies) set_amplitudes(kappa_[i], amp);
            const double C = c1[i], S = s1[i];
            double Cm = C, Sm = S, Cp = 1.0, Sp = 0.0;  // cos/sin of m*theta and (m-1)*theta
            double rs = dc, rc = dc;
            for (int m = 0; m < M; ++m) {
                rs += amp[m] * (ps[m] * Cm + qs[m] * Sm);
                rc += amp[m] * (pc[m] * Cm + qc[m] * Sm);
                const double Cn = 2 * C * Cm - Cp, Sn = 2 * C * Sm - Sp;
                Cp = Cm; Sp = Sm; Cm = Cn; Sm = Sn;
            }
            vs[i] = rs;
            vc[i] = rc;
        }
        const bool quantize = !adc.ideal();
        for (std::size_t i = 0; i < n; ++i) {
            const double g = 1.0 + fe.gain_scale * gain_src[i];
            const double s = fe.sin_channel<false>(vs[i], g, nz[0][i]);
            const double c = fe.cos_channel<false>(vc[i], g, nz[1][i]);
            vs[i] = quantize ? fe.adc(s) : s;
            vc[i] = quantize ? fe.adc(c) : c;
        }
    }

    if (out.index_v) {
        const IndexConfig& ix = enc_.index;
        const double width_mech = ix.width_elec_rad / lines;
        for (std::size_t i = 0; i < n; ++i) {
            double d = phi[i] - ix.position_rad;
            d -= kTwoPi * std::floor(d / kTwoPi);
            out.index_v[i] = d < width_mech ? ix.high_v : 0.0;
        }
    }
}

}  // namespace fringe
