#include "common.hpp"

#include "signal_gen/optics.hpp"

namespace fringe::est {

void Calibration::prepare() {
    if (!(amplitude_sin_v > 0) || !(amplitude_cos_v > 0))
        throw ConfigError("params.amplitude_sin_v", "calibration amplitudes must be positive");
    if (!(std::fabs(quadrature_error_rad) < kPi / 2))
        throw ConfigError("params.quadrature_error_rad", "must be within (-pi/2, pi/2)");
    inv_as_ = 1.0 / amplitude_sin_v;
    inv_ac_ = 1.0 / amplitude_cos_v;
    sin_d_ = std::sin(quadrature_error_rad);
    inv_cos_d_ = 1.0 / std::cos(quadrature_error_rad);
}

nlohmann::json Calibration::to_json() const {
    return {{"offset_sin_v", offset_sin_v}, {"offset_cos_v", offset_cos_v},
            {"amplitude_sin_v", amplitude_sin_v}, {"amplitude_cos_v", amplitude_cos_v},
            {"quadrature_error_rad", quadrature_error_rad}};
}

std::vector<ParamInfo> calibration_params() {
    const char* from = "default: from the encoder profile (zero / 1 without one)";
    return {
        {"offset_sin_v", "V", ParamType::Number, nullptr, -10, 10, {}, std::string("sin channel offset; ") + from},
        {"offset_cos_v", "V", ParamType::Number, nullptr, -10, 10, {}, std::string("cos channel offset; ") + from},
        {"amplitude_sin_v", "V", ParamType::Number, nullptr, 1e-9, 100, {}, std::string("sin fundamental amplitude; ") + from},
        {"amplitude_cos_v", "V", ParamType::Number, nullptr, 1e-9, 100, {}, std::string("cos fundamental amplitude; ") + from},
        {"quadrature_error_rad", "rad", ParamType::Number, nullptr, -1.5, 1.5, {}, std::string("cos channel phase error delta; ") + from},
    };
}

Calibration nominal_calibration(const std::optional<EncoderProfile>& encoder, const Params& p) {
    Calibration c;
    if (encoder) {
        const auto& e = *encoder;
        const double gs = 1.0 + e.lissajous.gain_mismatch / 2, gc = 1.0 - e.lissajous.gain_mismatch / 2;
        const double amp = e.fundamental_amplitude_v();
        const double dc = e.model == ModelKind::Diffraction ? e.vmax_v * e.aperture_w_rad / 2 : 0.0;
        c.offset_sin_v = gs * (dc - e.reference_v()) + e.lissajous.offset_sin_v;
        c.offset_cos_v = gc * (dc - e.reference_v()) + e.lissajous.offset_cos_v;
        c.amplitude_sin_v = gs * amp;
        c.amplitude_cos_v = gc * amp;
        c.quadrature_error_rad = e.lissajous.quadrature_error_rad;
    }
    if (auto v = p.optional_number("offset_sin_v")) c.offset_sin_v = *v;
    if (auto v = p.optional_number("offset_cos_v")) c.offset_cos_v = *v;
    if (auto v = p.optional_number("amplitude_sin_v")) c.amplitude_sin_v = *v;
    if (auto v = p.optional_number("amplitude_cos_v")) c.amplitude_cos_v = *v;
    if (auto v = p.optional_number("quadrature_error_rad")) c.quadrature_error_rad = *v;
    c.prepare();
    return c;
}

ParamInfo acquisition_param() {
    return {"acquisition_samples", "samples", ParamType::Integer, 200, 2, 1e7, {},
            "initialisation: line fit to the unwrapped atan2 over this many samples (output invalid meanwhile)"};
}

void Acquisition::reset(std::size_t n, double sample_rate_hz, const Calibration& cal) {
    n_ = n < 2 ? 2 : n;
    k_ = 0;
    fs_ = sample_rate_hz;
    cal_ = cal;
    unwrap_.reset();
    first_ = last_ = sk_ = skk_ = sy_ = sky_ = 0.0;
}

bool Acquisition::add(double s, double c) {
    double sn, cn;
    cal_.normalise(s, c, sn, cn);
    last_ = unwrap_(fast_atan2(sn, cn));
    if (k_ == 0) first_ = last_;
    const double k = static_cast<double>(k_), y = last_ - first_;
    sk_ += k; skk_ += k * k; sy_ += y; sky_ += k * y;
    ++k_;
    if (k_ < n_) return false;
    const double n = static_cast<double>(n_);
    const double slope = (n * sky_ - sk_ * sy_) / (n * skk_ - sk_ * sk_);  // rad/sample
    const double icpt = (sy_ - slope * sk_) / n;
    theta_ = first_ + icpt + slope * (n - 1.0);
    omega_ = slope * fs_;
    return true;
}

}  // namespace fringe::est
