#include "motion.hpp"
#include "keys.hpp"

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

const std::vector<MotionKindKeys>& motion_kinds() {
    constexpr double kMaxV = 1e6, kMaxA = 1e9;  // shaft speed (rad/s) and acceleration (rad/s^2)
    auto phi0 = [] { return key_number("phi0_rad", "rad", 0.0, -1e6, 1e6, "shaft angle at t = 0"); };
    auto velocity = [&](json def, const char* what) { return key_number("velocity_rad_s", "rad/s", std::move(def), -kMaxV, kMaxV, what); };
    static const std::vector<MotionKindKeys> kinds = {
        {"constant", "constant speed",
         KeyTable({velocity(nullptr, "shaft speed (or electrical_freq_hz)"),
                   key_number("electrical_freq_hz", "Hz", nullptr, -1e9, 1e9, "signal frequency instead of velocity_rad_s"), phi0()})},
        {"ramp", "constant acceleration",
         KeyTable({velocity(0.0, "initial shaft speed"), key_number("accel_rad_s2", "rad/s^2", nullptr, -kMaxA, kMaxA, "acceleration"), phi0()})},
        {"trapezoid", "rest, accelerate, cruise, decelerate, rest",
         KeyTable({velocity(nullptr, "cruise speed"), key_number("accel_rad_s2", "rad/s^2", nullptr, 1e-9, kMaxA, "acceleration"),
                   key_number("start_s", "s", 0.0, 0.0, 1e6, "rest before the move"), key_number("cruise_s", "s", 0.0, 0.0, 1e6, "time at cruise speed"),
                   phi0()})},
        {"sine", "oscillation (with reversals) on an optional drift",
         KeyTable({key_number("amplitude_rad", "rad", nullptr, 0.0, 1e6, "oscillation amplitude (shaft)"),
                   key_number("freq_hz", "Hz", nullptr, 0.0, 1e6, "oscillation frequency"), key_number("phase_rad", "rad", 0.0, -1e3, 1e3, "phase"),
                   velocity(0.0, "drift speed"), phi0()})},
        {"steps", "quasi-static steps",
         KeyTable({key_number("step_rad", "rad", nullptr, -1e3, 1e3, "step (shaft)"), key_number("dwell_s", "s", nullptr, 1e-9, 1e6, "time per step"), phi0()})},
        {"table", "shaft angle from a CSV file t_s,phi_rad (linear between rows)",
         KeyTable({key_string("file", nullptr, "the CSV file, relative to the scenario's folder", false), phi0()}), false},
    };
    return kinds;
}

MotionProfile motion_from_json(const json& j, const std::string& base_dir, int lines_per_rev,
                               const std::string& path) {
    JsonReader r(j, path);
    MotionProfile m;
    std::vector<std::string> names;
    for (const auto& k : motion_kinds()) names.push_back(k.kind);
    const std::string kind = r.choice("kind", "constant", names);
    const KeyTable& keys = std::find_if(motion_kinds().begin(), motion_kinds().end(), [&](const MotionKindKeys& k) { return k.kind == kind; })->keys;
    // A key this kind does not take is named first, with the keys it does take: a speed given as
    // "speed_rpm" was reported as velocity_rad_s missing, which does not say what was wrong.
    for (auto it = j.begin(); it != j.end(); ++it) {
        if (it.key() == "kind") continue;
        bool known = false;
        for (const auto& k : keys.keys()) known |= k.param.name == it.key();
        if (known) continue;
        std::string list = "kind";
        for (const auto& k : keys.keys()) list += ", " + k.param.name;
        std::string hint;
        if (it.key().find("rpm") != std::string::npos)
            hint = "; speeds are in rad/s (velocity_rad_s = rpm x 2 pi / 60: 600 rpm is 62.83 rad/s)";
        throw ConfigError(r.path_of(it.key()), "unknown key for a " + kind + " motion (its keys: " + list + ")" + hint);
    }
    m.phi0_rad = keys.number(r, "phi0_rad");
    if (kind == "constant") {
        m.kind = MotionKind::Constant;
        if (r.has("electrical_freq_hz")) {
            if (r.has("velocity_rad_s")) throw ConfigError(r.path_of("electrical_freq_hz"), "give velocity_rad_s or electrical_freq_hz, not both");
            m.velocity_rad_s = kTwoPi * keys.number(r, "electrical_freq_hz") / lines_per_rev;
        } else {
            m.velocity_rad_s = keys.number(r, "velocity_rad_s");
        }
    } else if (kind == "ramp") {
        m.kind = MotionKind::Ramp;
        m.velocity_rad_s = keys.number(r, "velocity_rad_s");
        m.accel_rad_s2 = keys.number(r, "accel_rad_s2");
    } else if (kind == "trapezoid") {
        m.kind = MotionKind::Trapezoid;
        m.velocity_rad_s = keys.number(r, "velocity_rad_s");
        m.accel_rad_s2 = keys.number(r, "accel_rad_s2");
        m.start_s = keys.number(r, "start_s");
        m.cruise_s = keys.number(r, "cruise_s");
    } else if (kind == "sine") {
        m.kind = MotionKind::Sine;
        m.amplitude_rad = keys.number(r, "amplitude_rad");
        m.freq_hz = keys.number(r, "freq_hz");
        m.phase_rad = keys.number(r, "phase_rad");
        m.velocity_rad_s = keys.number(r, "velocity_rad_s");
    } else if (kind == "steps") {
        m.kind = MotionKind::Steps;
        m.step_rad = keys.number(r, "step_rad");
        m.dwell_s = keys.number(r, "dwell_s");
    } else {
        m.kind = MotionKind::Table;
        m.table_file = keys.string(r, "file");
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
