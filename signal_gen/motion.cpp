#include "motion.hpp"

#include "signal_gen/base/config.hpp"
#include "fastmath.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <charconv>
#include <map>
#include <cmath>
#include <filesystem>
#include <fstream>

namespace fringe {

using nlohmann::json;

namespace {
// Trapezoid: rest until start_s, accelerate at a to v, cruise for cruise_s, decelerate to
// rest, then hold. Returns (phi - phi0, omega, alpha) at time t.
void trapezoid(const MotionProfile& m, double t, double& dphi, double& w, double& a) {
    const double acc = std::fabs(m.accel_rad_s2);
    const double v = m.velocity_rad_s;
    const double sgn = v < 0 ? -1.0 : 1.0;
    const double ta = acc > 0 ? std::fabs(v) / acc : 0.0;
    const double t1 = m.start_s, t2 = t1 + ta, t3 = t2 + m.cruise_s, t4 = t3 + ta;
    const double d_acc = 0.5 * acc * ta * ta;
    if (t <= t1) { dphi = 0; w = 0; a = 0; return; }
    if (t <= t2) { double u = t - t1; dphi = sgn * 0.5 * acc * u * u; w = sgn * acc * u; a = sgn * acc; return; }
    if (t <= t3) { double u = t - t2; dphi = sgn * d_acc + v * u; w = v; a = 0; return; }
    if (t <= t4) {
        double u = t - t3;
        dphi = sgn * d_acc + v * m.cruise_s + v * u - sgn * 0.5 * acc * u * u;
        w = v - sgn * acc * u; a = -sgn * acc; return;
    }
    dphi = 2 * sgn * d_acc + v * m.cruise_s; w = 0; a = 0;
}
}  // namespace

void MotionProfile::evaluate(const double* t_s, std::size_t n, double* phi, double* omega,
                             double* alpha) const {
    switch (kind) {
    case MotionKind::Constant:
        for (std::size_t i = 0; i < n; ++i) {
            phi[i] = phi0_rad + velocity_rad_s * t_s[i];
            omega[i] = velocity_rad_s;
            alpha[i] = 0.0;
        }
        break;
    case MotionKind::Ramp:
        for (std::size_t i = 0; i < n; ++i) {
            const double t = t_s[i];
            phi[i] = phi0_rad + velocity_rad_s * t + 0.5 * accel_rad_s2 * t * t;
            omega[i] = velocity_rad_s + accel_rad_s2 * t;
            alpha[i] = accel_rad_s2;
        }
        break;
    case MotionKind::Trapezoid:
        for (std::size_t i = 0; i < n; ++i) {
            double d, w, a;
            trapezoid(*this, t_s[i], d, w, a);
            phi[i] = phi0_rad + d;
            omega[i] = w;
            alpha[i] = a;
        }
        break;
    case MotionKind::Sine: {
        const double wf = kTwoPi * freq_hz;
        for (std::size_t i = 0; i < n; ++i) {
            double s, c;
            fast_sincos(wf * t_s[i] + phase_rad, s, c);
            phi[i] = phi0_rad + amplitude_rad * s + velocity_rad_s * t_s[i];
            omega[i] = amplitude_rad * wf * c + velocity_rad_s;
            alpha[i] = -amplitude_rad * wf * wf * s;
        }
        break;
    }
    case MotionKind::Steps:
        for (std::size_t i = 0; i < n; ++i) {
            phi[i] = phi0_rad + step_rad * std::floor(t_s[i] / dwell_s);
            omega[i] = 0.0;
            alpha[i] = 0.0;
        }
        break;
    case MotionKind::Table: {
        const std::size_t m = table_t_s.size();
        for (std::size_t i = 0; i < n; ++i) {
            const double t = t_s[i];
            if (t <= table_t_s.front()) { phi[i] = table_phi_rad.front(); omega[i] = 0; alpha[i] = 0; continue; }
            if (t >= table_t_s.back()) { phi[i] = table_phi_rad.back(); omega[i] = 0; alpha[i] = 0; continue; }
            std::size_t j = static_cast<std::size_t>(std::upper_bound(table_t_s.begin(), table_t_s.end(), t) - table_t_s.begin());
            j = std::min(std::max<std::size_t>(j, 1), m - 1);
            const double slope = (table_phi_rad[j] - table_phi_rad[j - 1]) / (table_t_s[j] - table_t_s[j - 1]);
            phi[i] = table_phi_rad[j - 1] + slope * (t - table_t_s[j - 1]);
            omega[i] = slope;
            alpha[i] = 0.0;
        }
        break;
    }
    }
}

std::string MotionProfile::kind_name() const {
    switch (kind) {
    case MotionKind::Constant: return "constant";
    case MotionKind::Ramp: return "ramp";
    case MotionKind::Trapezoid: return "trapezoid";
    case MotionKind::Sine: return "sine";
    case MotionKind::Steps: return "steps";
    case MotionKind::Table: return "table";
    }
    return "?";
}

namespace {
void read_table(MotionProfile& m, const std::string& file, const std::string& field) {
    std::ifstream in(file);
    if (!in) throw ConfigError(field, "cannot open motion table '" + file + "'");
    std::string line;
    std::size_t lineno = 0;
    bool header_seen = false;
    auto fail = [&](const std::string& msg) {
        throw ConfigError(field, file + ":" + std::to_string(lineno) + ": " + msg);
    };
    while (std::getline(in, line)) {
        ++lineno;
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty() || line[0] == '#') continue;
        if (!header_seen) {
            if (line != "t_s,phi_rad") fail("expected header 't_s,phi_rad', got '" + line + "'");
            header_seen = true;
            continue;
        }
        auto comma = line.find(',');
        if (comma == std::string::npos) fail("expected two columns");
        double t, p;
        auto r1 = std::from_chars(line.data(), line.data() + comma, t);
        auto r2 = std::from_chars(line.data() + comma + 1, line.data() + line.size(), p);
        if (r1.ec != std::errc() || r1.ptr != line.data() + comma || r2.ec != std::errc() ||
            r2.ptr != line.data() + line.size())
            fail("non-numeric cell in '" + line + "'");
        if (!std::isfinite(t) || !std::isfinite(p)) fail("non-finite value");
        if (!m.table_t_s.empty() && t <= m.table_t_s.back()) fail("t_s must increase");
        m.table_t_s.push_back(t);
        m.table_phi_rad.push_back(p);
    }
    if (m.table_t_s.size() < 2) throw ConfigError(field, file + ": needs at least two rows");
}
}  // namespace

MotionProfile motion_from_json(const json& j, const std::string& base_dir, int lines_per_rev,
                               const std::string& path) {
    JsonReader r(j, path);
    MotionProfile m;
    const std::string kind = r.choice("kind", "constant", {"constant", "ramp", "trapezoid", "sine", "steps", "table"});
    // A key this kind does not take is named first, with the keys it does take: a speed given as
    // "speed_rpm" was reported as velocity_rad_s missing, which does not say what was wrong.
    {
        static const std::map<std::string, std::vector<std::string>> keys = {
            {"constant", {"kind", "phi0_rad", "velocity_rad_s", "electrical_freq_hz"}},
            {"ramp", {"kind", "phi0_rad", "velocity_rad_s", "accel_rad_s2"}},
            {"trapezoid", {"kind", "phi0_rad", "velocity_rad_s", "accel_rad_s2", "start_s", "cruise_s"}},
            {"sine", {"kind", "phi0_rad", "amplitude_rad", "freq_hz", "phase_rad", "velocity_rad_s"}},
            {"steps", {"kind", "phi0_rad", "step_rad", "dwell_s"}},
            {"table", {"kind", "phi0_rad", "file"}}};
        const auto& known = keys.at(kind);
        for (auto it = j.begin(); it != j.end(); ++it) {
            if (std::find(known.begin(), known.end(), it.key()) != known.end()) continue;
            std::string list;
            for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
            std::string hint;
            if (it.key().find("rpm") != std::string::npos)
                hint = "; speeds are in rad/s (velocity_rad_s = rpm x 2 pi / 60: 600 rpm is 62.83 rad/s)";
            throw ConfigError(r.path_of(it.key()), "unknown key for a " + kind + " motion (its keys: " + list + ")" + hint);
        }
    }
    m.phi0_rad = r.number("phi0_rad", 0.0, -1e6, 1e6);
    constexpr double kMaxV = 1e6, kMaxA = 1e9;
    if (kind == "constant") {
        m.kind = MotionKind::Constant;
        if (r.has("electrical_freq_hz")) {
            if (r.has("velocity_rad_s")) throw ConfigError(r.path_of("electrical_freq_hz"), "give velocity_rad_s or electrical_freq_hz, not both");
            m.velocity_rad_s = kTwoPi * r.number("electrical_freq_hz", -1e9, 1e9) / lines_per_rev;
        } else {
            m.velocity_rad_s = r.number("velocity_rad_s", -kMaxV, kMaxV);
        }
    } else if (kind == "ramp") {
        m.kind = MotionKind::Ramp;
        m.velocity_rad_s = r.number("velocity_rad_s", 0.0, -kMaxV, kMaxV);
        m.accel_rad_s2 = r.number("accel_rad_s2", -kMaxA, kMaxA);
    } else if (kind == "trapezoid") {
        m.kind = MotionKind::Trapezoid;
        m.velocity_rad_s = r.number("velocity_rad_s", -kMaxV, kMaxV);
        m.accel_rad_s2 = r.number("accel_rad_s2", 1e-9, kMaxA);
        m.start_s = r.number("start_s", 0.0, 0.0, 1e6);
        m.cruise_s = r.number("cruise_s", 0.0, 0.0, 1e6);
    } else if (kind == "sine") {
        m.kind = MotionKind::Sine;
        m.amplitude_rad = r.number("amplitude_rad", 0.0, 1e6);
        m.freq_hz = r.number("freq_hz", 0.0, 1e6);
        m.phase_rad = r.number("phase_rad", 0.0, -1e3, 1e3);
        m.velocity_rad_s = r.number("velocity_rad_s", 0.0, -kMaxV, kMaxV);
    } else if (kind == "steps") {
        m.kind = MotionKind::Steps;
        m.step_rad = r.number("step_rad", -1e3, 1e3);
        m.dwell_s = r.number("dwell_s", 1e-9, 1e6);
    } else {
        m.kind = MotionKind::Table;
        m.table_file = r.string("file");
        std::filesystem::path p(m.table_file);
        if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
        read_table(m, p.string(), r.path_of("file"));
    }
    r.finish();
    return m;
}

void to_json(json& j, const MotionProfile& m) {
    j = json{{"kind", m.kind_name()}, {"phi0_rad", m.phi0_rad}};
    switch (m.kind) {
    case MotionKind::Constant: j["velocity_rad_s"] = m.velocity_rad_s; break;
    case MotionKind::Ramp: j["velocity_rad_s"] = m.velocity_rad_s; j["accel_rad_s2"] = m.accel_rad_s2; break;
    case MotionKind::Trapezoid:
        j["velocity_rad_s"] = m.velocity_rad_s; j["accel_rad_s2"] = m.accel_rad_s2;
        j["start_s"] = m.start_s; j["cruise_s"] = m.cruise_s; break;
    case MotionKind::Sine:
        j["amplitude_rad"] = m.amplitude_rad; j["freq_hz"] = m.freq_hz; j["phase_rad"] = m.phase_rad;
        j["velocity_rad_s"] = m.velocity_rad_s; break;
    case MotionKind::Steps: j["step_rad"] = m.step_rad; j["dwell_s"] = m.dwell_s; break;
    case MotionKind::Table: j["file"] = m.table_file; break;
    }
}

}  // namespace fringe
