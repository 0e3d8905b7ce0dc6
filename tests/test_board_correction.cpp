// A correction written to a Modbus board (docs/modbus.md "Correction registers"): the profile's
// correction roles, the register plan (quantisation, refusals), fringe writing it to the
// emulated DUT board over real TCP on 127.0.0.1 and reading it back, the board applying it
// exactly as atan2 correction=FILE does, and an external child handed the correction's path.
#include "board_sim_thread.hpp"
#include "helpers.hpp"

#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "drivers/sim/board_sim.hpp"
#include "estimator/correction.hpp"
#include "estimator/estimator.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <fstream>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_board_correction_cpp {

using namespace fringe;
using namespace fringe::dev;
using nlohmann::json;
using fringe::test::SimThread;
using fringe::test::TempDir;

namespace {

json fixture_json(const std::string& name) {
    std::ifstream f(std::string(FRINGE_SOURCE_DIR) + "/fixtures/boards/" + name + ".json");
    return json::parse(f);
}

// The board-sim analog path of a DUT board: the f32 drive registers, then gain mismatch and offsets.
struct Flaws {
    double os = 0.03, oc = -0.02, g = 0.04;
    double s(double th) const { return (1 + g / 2) * static_cast<double>(static_cast<float>(std::sin(th))) + os; }
    double c(double th) const { return (1 - g / 2) * static_cast<double>(static_cast<float>(std::cos(th))) + oc; }
    // The angle atan2 reads at the true angle th (unquantised drive).
    double phi(double th) const { return std::atan2((1 + g / 2) * std::sin(th) + os, (1 - g / 2) * std::cos(th) + oc); }
};

// The periodic correction of these flaws in closed form: entry i is c(phi_i) = phi_i - s(phi_i),
// the true angle s at which atan2 reads phi_i (solved by fixed-point iteration).
est::Correction table_for(const Flaws& f, int n) {
    est::Correction c;
    for (int i = 0; i < n; ++i) {
        const double p = kTwoPi * i / n;
        double s = p;
        for (int k = 0; k < 200; ++k) s -= std::remainder(f.phi(s) - p, kTwoPi);
        c.table.push_back(std::remainder(p - s, kTwoPi));
    }
    return c;
}

// What was written, as fringe's own correction (the quantised register values).
est::Correction as_written(const std::vector<RegisterValue>& plan) {
    est::Correction c;
    for (const auto& v : plan) {
        const double q = v.raw * v.reg.scale + v.reg.offset;
        if (v.role == "correction_table_rad") c.table.push_back(q);
        else if (v.role == "correction_offset_rad") c.offset_rad = q;
        else if (v.role == "trim_offset_sin_v") c.has_lissajous = true, c.offset_sin_v = q;
        else if (v.role == "trim_offset_cos_v") c.offset_cos_v = q;
        else if (v.role == "trim_amplitude_sin_v") c.amplitude_sin_v = q;
        else if (v.role == "trim_amplitude_cos_v") c.amplitude_cos_v = q;
        else if (v.role == "trim_phase_rad") c.quadrature_error_rad = q;
    }
    return c;
}

constexpr int kSteps = 256;
double step_angle(int k) { return kTwoPi * (k + 0.37) / kSteps; }

// The board's DUT position error against the drive angle over one period, per step.
std::vector<double> dut_errors(Device& dev) {
    std::vector<double> e;
    for (int k = 0; k < kSteps; ++k) {
        const double th = step_angle(k);
        const auto r = dev.step()->measure(std::sin(th), std::cos(th), 0.0, 1);
        REQUIRE(r.dut_theta_rad);
        e.push_back(std::remainder(*r.dut_theta_rad - th, kTwoPi));
    }
    return e;
}

// fringe's atan2 with correction=FILE on the same analog samples: the error predicted per step.
std::vector<double> predicted_errors(const Flaws& f, const est::Correction& c, const TempDir& dir) {
    const std::string path = (dir.path / "predicted.json").string();
    std::ofstream(path) << c.to_json().dump();
    est::EstimatorConfig cfg;
    cfg.sample_rate_hz = 1000.0;
    cfg.params = {{"correction", path}};
    auto a = est::make("atan2", cfg);
    std::vector<double> e;
    for (int k = 0; k < kSteps; ++k) {
        const double th = step_angle(k), s = f.s(th), co = f.c(th);
        double t = 0, om = 0;
        std::uint8_t v = 0;
        a->process({std::span(&s, 1), std::span(&co, 1)}, {std::span(&t, 1), std::span(&om, 1), std::span(&v, 1)});
        e.push_back(std::remainder(t - th, kTwoPi));
    }
    return e;
}

double rms(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x * x;
    return std::sqrt(s / static_cast<double>(v.size()));
}

// The position registers hold 1/65536 of a period: readings agree with fringe's atan2 to half that.
constexpr double kFraction = kTwoPi / 65536;

std::vector<std::uint16_t> read_holding(RegisterPort& p, int address, int count) {
    std::vector<std::uint16_t> w(static_cast<std::size_t>(count));
    p.read_words(RegTable::Holding, address, count, w.data(), "test read");
    return w;
}

}  // namespace

TEST_CASE("board correction: the profile's correction registers load strictly", "[modbus][calibration]") {
    const auto dut = load_board("dut-interpolator");
    REQUIRE(dut.has_correction());
    CHECK(dut.find("correction_table_rad")->count == 64);
    CHECK(dut.find("correction_table_rad")->type == RegType::S16);
    CHECK(dut.find("correction_enable"));
    CHECK_FALSE(load_board("generic-aio").has_correction());
    auto bad = [](const std::function<void(json&)>& edit) {
        json j = fixture_json("dut-interpolator");
        edit(j);
        return board_from_json(j, "b");
    };
    CHECK_NOTHROW(bad([](json&) {}));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"].erase("count"); }), Catch::Contains("b.registers.correction_table_rad.count"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"].erase("scale"); }),
                      Catch::Contains("b.registers.correction_table_rad.scale") && Catch::Contains("rad per LSB"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"]["cuont"] = 3; }), Catch::Contains("cuont"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"]["type"] = "u16"; }), Catch::Contains("correction_table_rad.type"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"]["type"] = "int"; }), Catch::Contains("correction_table_rad.type"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_offset_rad"]["count"] = 2; }), Catch::Contains("correction_offset_rad.count") && Catch::Contains("only correction_table_rad"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["trim_phase_rad"].erase("scale"); }), Catch::Contains("trim_phase_rad.scale"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"].erase("trim_phase_rad"); }), Catch::Contains("missing trim_phase_rad"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"]["table"] = "input"; }), Catch::Contains("correction_table_rad"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_enable"]["access"] = "w"; }), Catch::Contains("correction_enable.access"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"]["address"] = 190; }), Catch::Contains("overlaps"));
    CHECK_THROWS_WITH(bad([](json& j) { j["registers"]["correction_table_rad"]["count"] = 70000; }), Catch::Contains("correction_table_rad.count"));
    CHECK_THROWS_WITH(bad([](json& j) {
                          j["registers"].erase("correction_table_rad");
                      }),
                      Catch::Contains("correction_offset_rad") && Catch::Contains("needs a correction_table_rad"));
    json aio = fixture_json("generic-aio");
    aio["registers"]["correction_enable"] = {{"address", 300}, {"type", "u16"}};
    CHECK_THROWS_WITH(board_from_json(aio, "b"), Catch::Contains("dut board"));
}

TEST_CASE("board correction: the register plan quantises, and refuses what does not fit, naming it", "[modbus][calibration]") {
    const auto dut = load_board("dut-interpolator");
    const Flaws f;
    est::Correction c = table_for(f, 64);
    c.offset_rad = 0.001;
    const auto plan = plan_correction_writes(dut, c);
    REQUIRE(plan.size() == 1 + 64 + 1 + 5 + 1);
    CHECK(plan.front().role == "correction_enable");
    CHECK(plan.front().raw == 0);
    CHECK(plan.back().role == "correction_enable");
    CHECK(plan.back().raw == 1);
    for (int i = 0; i < 64; ++i) {
        const auto& v = plan[static_cast<std::size_t>(1 + i)];
        CHECK(v.label() == "correction_table_rad[" + std::to_string(i) + "]");
        CHECK(v.address == 256 + i);
        CHECK(std::fabs(v.raw * v.reg.scale - c.table[static_cast<std::size_t>(i)]) <= v.reg.scale / 2 + 1e-15);
    }
    // No Lissajous stage: the neutral trims.
    CHECK(plan[68].role == "trim_amplitude_sin_v");
    CHECK(plan[68].raw == 32768);
    // The export states the order and every value.
    const json j = json::parse(modbus_writes_json(dut, plan));
    CHECK(j["schema"] == "fringe.modbus_writes");
    CHECK(j["writes"].size() == plan.size());
    CHECK(j["writes"][1]["address"] == 256);
    CHECK(j["writes"][1]["type"] == "s16");
    const std::string csv = modbus_writes_csv(dut, plan);
    CHECK(csv.find("role,index,address,table,type,function,raw,words,value,unit") != std::string::npos);
    CHECK(csv.find("\ncorrection_table_rad,63,319,holding,s16,16,") != std::string::npos);

    est::Correction big = c;
    big.table[17] = 3.5;  // beyond s16 at 2*pi/65536 rad per LSB (3.14 rad)
    CHECK_THROWS_WITH(plan_correction_writes(dut, big), Catch::Contains("correction_table_rad[17] = 3.5") && Catch::Contains("outside s16") &&
                                                            Catch::Contains("nothing written"));
    est::Correction few = table_for(f, 32);
    CHECK_THROWS_WITH(plan_correction_writes(dut, few), Catch::Contains("32 entries") && Catch::Contains("--table-size 64"));
    CHECK_THROWS_WITH(plan_correction_writes(load_board("generic-aio"), c), Catch::Contains("declares no correction registers"));
    // A board without trims cannot take a Lissajous stage; without an offset register the offset is in every entry.
    json j2 = fixture_json("dut-interpolator");
    for (const char* t : {"trim_offset_sin_v", "trim_offset_cos_v", "trim_amplitude_sin_v", "trim_amplitude_cos_v", "trim_phase_rad", "correction_offset_rad"}) j2["registers"].erase(t);
    const auto bare = board_from_json(j2, "bare");
    est::Correction lis = c;
    lis.has_lissajous = true;
    CHECK_THROWS_WITH(plan_correction_writes(bare, lis), Catch::Contains("--no-lissajous"));
    // An amplitude that rounds to raw 0 at its register's scale is refused before anything is
    // written (the board refused it after enable was cleared, and was left uncorrected).
    est::Correction tiny = c;
    tiny.has_lissajous = true;
    tiny.amplitude_sin_v = 1e-6;
    tiny.amplitude_cos_v = 1.0;
    CHECK_THROWS_WITH(plan_correction_writes(dut, tiny), Catch::Contains("trim_amplitude_sin_v") && Catch::Contains("must stay positive"));
    const auto folded = plan_correction_writes(bare, c);
    REQUIRE(folded.size() == 66);
    CHECK(folded[1].raw == std::nearbyint((c.table[0] + 0.001) / folded[1].reg.scale));
}

TEST_CASE("board correction: fringe writes it to the emulated DUT, reads it back, and the DUT's error drops as predicted", "[modbus][calibration][socket]") {
    TempDir dir("fringe-board-corr");
    const Flaws f;
    BoardSimOptions o;
    o.board = "dut-interpolator";
    o.adc_bits = 0;
    o.offset_sin_v = f.os;
    o.offset_cos_v = f.oc;
    o.gain_mismatch = f.g;
    SECTION("a table of the angle error (written in one request), neutral trims") {
        SimThread sim(o);
        auto dev = open(sim.uri("board=dut-interpolator&settle_s=0"));
        const auto before = dut_errors(*dev);
        const auto plan = write_correction(*dev->registers(), table_for(f, 64));
        const auto after = dut_errors(*dev);
        const auto predicted = predicted_errors(f, as_written(plan), dir);
        double worst = 0;
        for (int k = 0; k < kSteps; ++k) worst = std::max(worst, std::fabs(after[static_cast<std::size_t>(k)] - predicted[static_cast<std::size_t>(k)]));
        CHECK(worst <= kFraction / 2 * 1.05);
        CHECK(rms(before) > 0.02);
        CHECK(rms(after) == Approx(rms(predicted)).margin(kFraction / 4));
        CHECK(rms(after) < 1e-4);
        CHECK(rms(before) / rms(after) > 300);
        std::printf("board correction (table): DUT error %.4g rad rms before, %.4g after (predicted %.4g)\n", rms(before), rms(after), rms(predicted));
        // What was written reads back.
        const auto words = read_holding(*dev->registers(), 256, 64);
        for (int i = 0; i < 64; ++i) CHECK(words[static_cast<std::size_t>(i)] == plan[static_cast<std::size_t>(1 + i)].words[0]);
        // correction_enable = 0 takes it off again.
        const std::uint16_t zero = 0;
        dev->registers()->write_words(200, std::span(&zero, 1), 16, "test");
        CHECK(rms(dut_errors(*dev)) == Approx(rms(before)).margin(kFraction));
    }
    SECTION("Lissajous trims of the flaws, a zero table") {
        SimThread sim(o);
        auto dev = open(sim.uri("board=dut-interpolator&settle_s=0"));
        const auto before = dut_errors(*dev);
        est::Correction c;
        c.has_lissajous = true;
        c.offset_sin_v = f.os;
        c.offset_cos_v = f.oc;
        c.amplitude_sin_v = 1 + f.g / 2;
        c.amplitude_cos_v = 1 - f.g / 2;
        c.table.assign(64, 0.0);
        const auto plan = write_correction(*dev->registers(), c);
        const auto after = dut_errors(*dev);
        const auto predicted = predicted_errors(f, as_written(plan), dir);
        double worst = 0;
        for (int k = 0; k < kSteps; ++k) worst = std::max(worst, std::fabs(after[static_cast<std::size_t>(k)] - predicted[static_cast<std::size_t>(k)]));
        CHECK(worst <= kFraction / 2 * 1.05);
        CHECK(rms(after) < 1e-4);
        std::printf("board correction (trims): DUT error %.4g rad rms before, %.4g after (predicted %.4g)\n", rms(before), rms(after), rms(predicted));
    }
    SECTION("a table written one entry per request (function 6)") {
        json j = fixture_json("dut-interpolator");
        j["registers"]["correction_table_rad"]["write_function"] = 6;
        const std::string path = (dir.path / "dut-fc6.json").string();
        std::ofstream(path) << j.dump();
        o.board = path;
        SimThread sim(o);
        auto dev = open(sim.uri("board=" + path + "&settle_s=0"));
        const auto before = dut_errors(*dev);
        const auto plan = write_correction(*dev->registers(), table_for(f, 64));
        const auto after = dut_errors(*dev);
        const auto predicted = predicted_errors(f, as_written(plan), dir);
        CHECK(rms(after) == Approx(rms(predicted)).margin(kFraction / 4));
        CHECK(rms(before) / rms(after) > 300);
        // 1 enable + 64 table + 1 offset + 5 trims + 1 enable writes, reads back in 1 + 7 + 1 requests,
        // 256 + 256 steps of 2 requests each.
        CHECK(sim.finish() == 72 + 9 + 4 * kSteps);
    }
}

TEST_CASE("board correction: hostile cases are errors naming the register, and a refused plan writes nothing", "[modbus][calibration][socket]") {
    const Flaws f;
    BoardSimOptions o;
    o.board = "dut-interpolator";
    o.adc_bits = 0;
    SECTION("a table too large for its type: nothing written") {
        SimThread sim(o);
        auto dev = open(sim.uri("board=dut-interpolator&settle_s=0"));
        est::Correction c = table_for(f, 64);
        c.table[40] = -4.0;
        CHECK_THROWS_WITH(write_correction(*dev->registers(), c), Catch::Contains("correction_table_rad[40]") && Catch::Contains("outside s16"));
        for (auto w : read_holding(*dev->registers(), 200, 120)) CHECK(w == 0);
    }
    SECTION("an entry count that is not the board's: nothing written") {
        SimThread sim(o);
        auto dev = open(sim.uri("board=dut-interpolator&settle_s=0"));
        CHECK_THROWS_WITH(write_correction(*dev->registers(), table_for(f, 128)), Catch::Contains("128 entries") && Catch::Contains("64"));
        for (auto w : read_holding(*dev->registers(), 200, 120)) CHECK(w == 0);
    }
    SECTION("a board without correction registers") {
        o.board = "generic-aio";
        SimThread sim(o);
        CHECK_THROWS_WITH(write_correction(sim.uri("board=generic-aio"), table_for(f, 64)), Catch::Contains("declares no correction registers"));
    }
    SECTION("a board killed in the middle of the table (one entry per request): the error names the entry") {
        TempDir dir("fringe-board-corr");
        json j = fixture_json("dut-interpolator");
        j["registers"]["correction_table_rad"]["write_function"] = 6;
        const std::string path = (dir.path / "dut-fc6.json").string();
        std::ofstream(path) << j.dump();
        o.board = path;
        o.drop_after = 1 + 9;  // enable = 0, entries 0..8; entry 9 finds the board gone
        SimThread sim(o);
        CHECK_THROWS_WITH(write_correction(sim.uri("board=" + path + "&timeout_ms=100&retries=1"), table_for(f, 64)),
                          Catch::Contains("write correction_table_rad[9] @265"));
    }
    SECTION("a board killed during the table's block write: the error names the block") {
        o.drop_after = 1;
        SimThread sim(o);
        CHECK_THROWS_WITH(write_correction(sim.uri("board=dut-interpolator&timeout_ms=100&retries=1"), table_for(f, 64)),
                          Catch::Contains("board dut-interpolator at 127.0.0.1:") && Catch::Contains("write correction_table_rad[0..63] @256+64"));
    }
    SECTION("a correction the board refuses clears its enable, and fringe says so") {
        // Amplitude registers in f32 take 1e-9 V (fringe's plan sees a positive amplitude); the
        // board's interpolator refuses it (below 1e-6 V) and clears correction_enable.
        TempDir d;
        json j = fixture_json("dut-interpolator");
        for (const char* r : {"trim_amplitude_sin_v", "trim_amplitude_cos_v"}) {
            j["registers"][r]["type"] = "f32";
            j["registers"][r]["scale"] = 1.0;
        }
        j["registers"]["trim_amplitude_cos_v"]["address"] = 208;
        const std::string profile = (d.path / "dut-f32.json").string();
        std::ofstream(profile) << j.dump();
        o.board = profile;
        SimThread sim(o);
        est::Correction c = table_for(f, 64);
        c.has_lissajous = true;
        c.amplitude_sin_v = 1e-9;
        CHECK_THROWS_WITH(write_correction(sim.uri("board=" + profile), c), Catch::Contains("refused the correction"));
    }
    SECTION("an amplitude that rounds to 0 at its register's scale: refused before anything is written") {
        SimThread sim(o);
        est::Correction c = table_for(f, 64);
        c.has_lissajous = true;
        c.amplitude_sin_v = 1e-6;
        CHECK_THROWS_WITH(write_correction(sim.uri("board=dut-interpolator"), c), Catch::Contains("must stay positive") && Catch::Contains("nothing written"));
        CHECK(sim.finish() == 0);
    }
    SECTION("an exception reply is final and named") {
        o.exception_every = 3;  // enable = 0, table, then the offset gets the exception
        SimThread sim(o);
        CHECK_THROWS_WITH(write_correction(sim.uri("board=dut-interpolator"), table_for(f, 64)),
                          Catch::Contains("write correction_offset_rad @201+1") && Catch::Contains("Slave device or server failure"));
    }
}

TEST_CASE("board correction: an external child gets the correction file's absolute path as FRINGE_CORRECTION", "[calibration][external]") {
    TempDir dir("fringe-ext-corr");
    const std::string path = (dir.path / "corr.json").string();
    std::ofstream(path) << table_for(Flaws{}, 64).to_json().dump();
    std::vector<double> s(200), c(200), th(200), om(200);
    std::vector<std::uint8_t> v(200);
    for (std::size_t i = 0; i < s.size(); ++i) s[i] = std::sin(0.01 * static_cast<double>(i)), c[i] = std::cos(0.01 * static_cast<double>(i));
    auto run = [&](const json& params) {
        est::EstimatorConfig cfg;
        cfg.sample_rate_hz = 1000;
        cfg.params = params;
        auto e = est::make("external", cfg);
        e->process({s, c}, {th, om, v});
        return th.back();
    };
    const std::string child = FRINGE_EXTERNAL_DEFECTS;
    // The child exits 4 unless FRINGE_CORRECTION is an absolute path to the file its configuration names.
    CHECK(run({{"command", child + " correction"}, {"correction", path}}) == Approx(0.01 * 199).margin(1e-9));
    CHECK_THROWS_WITH(run({{"command", child + " correction"}}), Catch::Contains("status 4"));
    // A relative path reaches the child absolute.
    const auto cwd = std::filesystem::current_path();
    std::filesystem::current_path(dir.path);
    CHECK_NOTHROW(run({{"command", child + " correction"}, {"correction", "corr.json"}}));
    std::filesystem::current_path(cwd);
    // Without the parameter, a FRINGE_CORRECTION in fringe's own environment does not leak to the child.
    ::setenv("FRINGE_CORRECTION", path.c_str(), 1);
    CHECK_NOTHROW(run({{"command", child + " no-correction"}}));
    ::unsetenv("FRINGE_CORRECTION");
    // A malformed file is refused before the child starts, naming the parameter.
    std::ofstream(dir.path / "bad.json") << R"({"schema": "nope"})";
    CHECK_THROWS_WITH(run({{"command", child + " correction"}, {"correction", (dir.path / "bad.json").string()}}), Catch::Contains("params.correction"));
}

}  // namespace test_board_correction_cpp
