// Motion profiles: closed forms, continuity, rate = d(angle)/dt.
#include "signal_gen/base/config.hpp"
#include "signal_gen/motion.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_motion_cpp {

using namespace fringe;
using Catch::Matchers::WithinAbs;
using Catch::Matchers::WithinRel;
using nlohmann::json;

namespace {
struct Traj { std::vector<double> t, phi, w, a; };
Traj eval(const MotionProfile& m, double t_end, std::size_t n) {
    Traj r;
    r.t.resize(n); r.phi.resize(n); r.w.resize(n); r.a.resize(n);
    for (std::size_t i = 0; i < n; ++i) r.t[i] = t_end * static_cast<double>(i) / static_cast<double>(n - 1);
    m.evaluate(r.t.data(), n, r.phi.data(), r.w.data(), r.a.data());
    return r;
}
// omega must be the derivative of phi and alpha that of omega (central differences, away
// from the kinks).
void check_derivatives(const Traj& r, double tol_w, double tol_a) {
    for (std::size_t i = 1; i + 1 < r.t.size(); ++i) {
        const double h = r.t[i + 1] - r.t[i - 1];
        if (r.a[i - 1] != r.a[i + 1]) continue;  // a kink between the neighbours
        REQUIRE_THAT(r.w[i], WithinAbs((r.phi[i + 1] - r.phi[i - 1]) / h, tol_w));
        REQUIRE_THAT(r.a[i], WithinAbs((r.w[i + 1] - r.w[i - 1]) / h, tol_a));
    }
}
}  // namespace

TEST_CASE("ramp and trapezoid follow constant-acceleration kinematics", "[motion]") {
    json j = {{"kind", "trapezoid"}, {"velocity_rad_s", 3.0}, {"accel_rad_s2", 10.0}, {"start_s", 0.1}, {"cruise_s", 0.5}};
    MotionProfile m = motion_from_json(j, "", 1024);
    Traj r = eval(m, 1.5, 15001);
    check_derivatives(r, 1e-6, 1e-6);
    // Total travel: accel + decel 2 * v^2/(2a) plus cruise v*T
    CHECK_THAT(r.phi.back(), WithinRel(3.0 * 3.0 / 10.0 + 3.0 * 0.5, 1e-12));
    CHECK(r.w.back() == 0.0);
    // continuity of phi and omega everywhere
    for (std::size_t i = 1; i < r.t.size(); ++i) {
        REQUIRE(std::fabs(r.phi[i] - r.phi[i - 1]) < 3.0 * 1e-4 + 1e-12);
        REQUIRE(std::fabs(r.w[i] - r.w[i - 1]) < 10.0 * 1e-4 + 1e-12);
    }
    json jr = {{"kind", "ramp"}, {"velocity_rad_s", -1.0}, {"accel_rad_s2", 4.0}, {"phi0_rad", 0.5}};
    Traj rr = eval(motion_from_json(jr, "", 1024), 2.0, 2001);
    check_derivatives(rr, 1e-9, 1e-9);
    CHECK_THAT(rr.phi.back(), WithinAbs(0.5 - 2.0 + 0.5 * 4.0 * 4.0, 1e-12));
}

TEST_CASE("sinusoidal oscillation reverses direction", "[motion]") {
    json j = {{"kind", "sine"}, {"amplitude_rad", 0.01}, {"freq_hz", 5.0}};
    Traj r = eval(motion_from_json(j, "", 1024), 1.0, 100001);
    check_derivatives(r, 1e-6, 1e-3);
    int reversals = 0;
    for (std::size_t i = 1; i < r.w.size(); ++i) reversals += (r.w[i] > 0) != (r.w[i - 1] > 0);
    CHECK(reversals == 10);  // two per period, 5 periods
    CHECK_THAT(*std::max_element(r.phi.begin(), r.phi.end()), WithinAbs(0.01, 1e-9));
}

TEST_CASE("constant motion from an electrical frequency", "[motion]") {
    json j = {{"kind", "constant"}, {"electrical_freq_hz", 100.0}};
    MotionProfile m = motion_from_json(j, "", 1000);
    CHECK_THAT(m.velocity_rad_s * 1000, WithinRel(2 * 3.141592653589793 * 100, 1e-15));
    json both = {{"kind", "constant"}, {"electrical_freq_hz", 100.0}, {"velocity_rad_s", 1.0}};
    CHECK_THROWS_AS(motion_from_json(both, "", 1000), ConfigError);
}

TEST_CASE("quasi-static steps hold each angle for the dwell time", "[motion]") {
    json j = {{"kind", "steps"}, {"step_rad", 0.001}, {"dwell_s", 0.01}, {"phi0_rad", 1.0}};
    Traj r = eval(motion_from_json(j, "", 1024), 0.0999, 1000);
    CHECK(r.phi.front() == 1.0);
    CHECK_THAT(r.phi.back(), WithinAbs(1.009, 1e-12));
    for (double w : r.w) REQUIRE(w == 0.0);
}

TEST_CASE("table motion interpolates a CSV, bad tables are named", "[motion]") {
    const std::string path = "motion_table_test.csv";
    { std::ofstream f(path); f << "t_s,phi_rad\n0,0\n1,2\n3,0\n"; }
    json j = {{"kind", "table"}, {"file", path}};
    MotionProfile m = motion_from_json(j, "", 1024);
    double t[3] = {0.5, 2.0, 5.0}, phi[3], w[3], a[3];
    m.evaluate(t, 3, phi, w, a);
    CHECK(phi[0] == 1.0);
    CHECK(w[0] == 2.0);
    CHECK(phi[1] == 1.0);
    CHECK(w[1] == -1.0);
    CHECK(phi[2] == 0.0);
    { std::ofstream f(path); f << "t_s,phi_rad\n0,0\n1,x\n"; }
    CHECK_THROWS_WITH(motion_from_json(j, "", 1024), Catch::Contains("motion_table_test.csv:3") && Catch::Contains("non-numeric"));
    { std::ofstream f(path); f << "t_s,phi_rad\n0,0\n0,1\n"; }
    CHECK_THROWS_WITH(motion_from_json(j, "", 1024), Catch::Contains("t_s must increase"));
    std::remove(path.c_str());
    CHECK_THROWS_WITH(motion_from_json(j, "", 1024), Catch::Contains("motion.file") && Catch::Contains("cannot open"));
}

}  // namespace test_motion_cpp
