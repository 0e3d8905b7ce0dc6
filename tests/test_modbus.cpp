// Modbus: board profiles, register codec, read batching, and the driver against the emulated
// board (libmodbus server in a thread) over real TCP on 127.0.0.1, with its faults.
#include "board_sim_thread.hpp"
#include "drivers/sim/board_sim.hpp"
#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "server/engine/preflight.hpp"
#include "server/engine/run.hpp"
#include "server/http/run_manager.hpp"
#include "server/engine/scenario.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/base/constants.hpp"

#include <catch2/catch.hpp>

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <thread>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_modbus_cpp {

using namespace fringe;
using namespace fringe::dev;
using nlohmann::json;
using fringe::test::SimThread;

namespace {

}  // namespace

TEST_CASE("modbus: board profiles load strictly", "[modbus]") {
    const auto aio = load_board("generic-aio");
    CHECK(aio.kind == "analog-io");
    CHECK(aio.find("sin_out")->writable);
    CHECK_FALSE(aio.has_dut_position());
    const auto dut = load_board("dut-interpolator");
    CHECK(dut.has_dut_position());
    CHECK(dut.find("position_count")->type == RegType::S32);

    json j = {{"name", "x"}, {"registers", {{"sin_out", {{"address", 0}}}, {"cos_out", {{"address", 1}}}, {"sin_in", {{"address", 0}, {"table", "input"}}},
                                             {"cos_in", {{"address", 1}, {"table", "input"}}}}}};
    CHECK_NOTHROW(board_from_json(j, ""));
    auto bad = j;
    bad["registers"]["sin_out"]["colour"] = 1;
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("registers.sin_out.colour"));
    bad = j;
    bad["registers"]["tacho"] = {{"address", 3}};
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("registers.tacho: unknown register role"));
    bad = j;
    bad["registers"]["sin_in"]["access"] = "rw";
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("input registers are read-only"));
    bad = j;
    bad["registers"]["sin_out"]["type"] = "f64";
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("registers.sin_out.type"));
    bad = j;
    bad["kind"] = "dut";
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("position_count"));
    CHECK_THROWS_WITH(load_board("no-such-board"), Catch::Contains("generic-aio"));
}

TEST_CASE("modbus: register codec round trips, word order and clamping", "[modbus]") {
    RegisterDef r;
    SECTION("s16 volts, rounding and rails") {
        r.type = RegType::S16;
        r.scale = 1.25 / 32768;
        for (double v : {0.0, 0.5, -0.5, 1.0, -1.25}) CHECK(decode_register(r, encode_register(r, v).data()) == Approx(v).margin(r.scale / 2));
        CHECK(encode_register(r, 5.0)[0] == 32767);
        CHECK(static_cast<std::int16_t>(encode_register(r, -5.0)[0]) == -32768);
        CHECK(encode_register(r, std::nan(""))[0] == 0);
    }
    SECTION("u32 big and little word order") {
        r.type = RegType::U32;
        auto w = encode_register(r, 0x12345678);
        CHECK(w[0] == 0x1234);
        CHECK(w[1] == 0x5678);
        r.low_word_first = true;
        w = encode_register(r, 0x12345678);
        CHECK(w[0] == 0x5678);
        CHECK(w[1] == 0x1234);
        CHECK(decode_register(r, w.data()) == 0x12345678);
    }
    SECTION("s32 negative counts and f32 exact values") {
        r.type = RegType::S32;
        CHECK(decode_register(r, encode_register(r, -123456).data()) == -123456);
        r.type = RegType::F32;
        for (double v : {0.0, -0.75, 1.0 / 1024, 3.5e5}) CHECK(decode_register(r, encode_register(r, v).data()) == v);  // exact in float
        CHECK(decode_register(r, encode_register(r, 0.1).data()) == static_cast<double>(0.1f));
    }
    SECTION("scale and offset") {
        r.type = RegType::U16;
        r.scale = 0.001;
        r.offset = -10;
        CHECK(encode_register(r, 0.0)[0] == 10000);
        CHECK(decode_register(r, encode_register(r, 2.5).data()) == Approx(2.5));
    }
}

TEST_CASE("modbus: reads are batched per table, at most 125 registers each", "[modbus]") {
    std::vector<RegisterDef> defs;
    for (int a : {0, 1, 2, 200, 260, 324, 500}) {
        RegisterDef d;
        d.address = a;
        d.table = RegTable::Input;
        defs.push_back(d);
    }
    RegisterDef h;
    h.address = 3;
    h.type = RegType::U32;
    defs.push_back(h);
    std::vector<const RegisterDef*> ptrs;
    for (const auto& d : defs) ptrs.push_back(&d);
    const auto b = plan_reads(ptrs);
    REQUIRE(b.size() == 4);
    CHECK(b[0].table == RegTable::Holding);
    CHECK(b[0].count == 2);  // the u32 spans two registers
    CHECK((b[1].address == 0 && b[1].count == 3));
    CHECK((b[2].address == 200 && b[2].count == 125));  // 200..324 exactly 125
    CHECK((b[3].address == 500 && b[3].count == 1));
    for (const auto& x : b) CHECK(x.count <= 125);
    CHECK(plan_reads(ptrs, 1000).size() == 2);
}

TEST_CASE("modbus: the driver against board-sim over TCP", "[modbus][socket]") {
    SECTION("analog I/O module: what is written reads back through the ADC") {
        BoardSimOptions o;
        o.board = "generic-aio";
        o.adc_bits = 16;
        SimThread sim(o);
        REQUIRE(sim.where.rfind("tcp://", 0) == 0);
        auto dev = open(sim.uri("board=generic-aio&settle_s=0"));
        const auto info = dev->info();
        CHECK(info.driver == "modbus");
        CHECK(info.step_mode);
        CHECK_FALSE(info.streaming);
        CHECK_FALSE(info.dut_position);
        const double lsb = 2.5 / 65536;
        for (double th = 0; th < 2 * kPi; th += 0.7) {
            const auto r = dev->step()->measure(std::sin(th), std::cos(th), 0.0, 1);
            // DAC register (1.25/32768 V) then a 16-bit ADC over +-1.25 V: within 1 LSB each
            CHECK(std::fabs(r.sin_v - std::sin(th)) <= 1.01 * lsb);
            CHECK(std::fabs(r.cos_v - std::cos(th)) <= 1.01 * lsb);
            CHECK_FALSE(r.dut_theta_rad);
        }
        // Step mode only: no stream port to write to, no generator, no digitizer, no replay.
        CHECK(dev->stream() == nullptr);
        CHECK(dev->player() == nullptr);
        CHECK(dev->recorder() == nullptr);
        CHECK(dev->replay() == nullptr);
    }
    SECTION("averaging reduces the ADC noise by sqrt(N)") {
        BoardSimOptions o;
        o.noise_v = 1e-3;
        o.adc_bits = 0;
        SimThread sim(o);
        auto dev = open(sim.uri("board=generic-aio&settle_s=0"));
        auto spread = [&](int avg) {
            double s2 = 0;
            const int n = 200;
            for (int i = 0; i < n; ++i) {
                const double d = dev->step()->measure(0.3, -0.2, 0.0, avg).sin_v - 0.3;
                s2 += d * d;
            }
            return std::sqrt(s2 / n);
        };
        const double one = spread(1), sixteen = spread(16);
        CHECK(one == Approx(1e-3).epsilon(0.25));
        CHECK(sixteen == Approx(1e-3 / 4).epsilon(0.3));
    }
    SECTION("DUT board: its on-board atan2 position, count and fraction") {
        BoardSimOptions o;
        o.board = "dut-interpolator";
        o.adc_bits = 0;
        SimThread sim(o);
        auto dev = open(sim.uri("board=dut-interpolator&settle_s=0"));
        CHECK(dev->info().dut_position);
        // Walk two electrical periods forward: the position counts whole periods.
        double last = 0;
        for (int k = 0; k <= 128; ++k) {
            const double th = 2 * kPi * k / 64.0;
            const auto r = dev->step()->measure(std::sin(th), std::cos(th), 0.0, 1);
            REQUIRE(r.dut_theta_rad);
            // f32 drive registers and a 1/65536-period fraction: within 2*pi/65536
            CHECK(std::fabs(*r.dut_theta_rad - th) < 2 * kPi / 65536 * 1.01);
            last = *r.dut_theta_rad;
        }
        CHECK(last == Approx(4 * kPi).margin(1e-4));
    }
    SECTION("DUT flaws show as the classic error: an offset gives a 1x error of o/A") {
        BoardSimOptions o;
        o.board = "dut-interpolator";
        o.adc_bits = 0;
        o.offset_sin_v = 0.01;
        SimThread sim(o);
        auto dev = open(sim.uri("board=dut-interpolator&settle_s=0"));
        double emax = 0;
        for (int k = 0; k < 64; ++k) {
            const double th = 2 * kPi * k / 64.0;
            const auto r = dev->step()->measure(std::sin(th), std::cos(th), 0.0, 1);
            emax = std::max(emax, std::fabs(std::remainder(*r.dut_theta_rad - th, 2 * kPi)));
        }
        CHECK(emax == Approx(0.01).epsilon(0.02));
    }
    SECTION("a Modbus exception names the board, the register and libmodbus's message; no retry") {
        BoardSimOptions o;
        o.exception_every = 3;
        SimThread sim(o);
        auto dev = open(sim.uri("board=generic-aio&settle_s=0&retries=5"));
        // request 1 write, 2 read, 3 write -> exception
        CHECK_NOTHROW(dev->step()->measure(0.1, 0.2, 0.0, 1));
        CHECK_THROWS_WITH(dev->step()->measure(0.1, 0.2, 0.0, 1),
                          Catch::Contains("board generic-aio") && Catch::Contains("write sin_out,cos_out @0") &&
                              Catch::Contains("Slave device or server failure"));
    }
    SECTION("a reply slower than the timeout is retried, then reported") {
        BoardSimOptions o;
        o.delay_ms = 80;
        SimThread sim(o);
        auto dev = open(sim.uri("board=generic-aio&settle_s=0&timeout_ms=20&retries=1"));
        const auto t0 = std::chrono::steady_clock::now();
        CHECK_THROWS_WITH(dev->step()->measure(0.1, 0.2, 0.0, 1), Catch::Contains("timed out") && Catch::Contains("after 2 attempts"));
        CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(2));
    }
    SECTION("a board that goes away mid-run is a device error naming it") {
        BoardSimOptions o;
        o.drop_after = 10;
        SimThread sim(o);
        auto dev = open(sim.uri("board=generic-aio&settle_s=0&timeout_ms=200&retries=2"));
        int ok = 0;
        try {
            for (int i = 0; i < 100; ++i) {
                dev->step()->measure(0.1, 0.2, 0.0, 1);
                ++ok;
            }
            FAIL("no error after the board dropped");
        } catch (const DeviceError& e) {
            CHECK(ok == 5);  // 2 requests per step
            CHECK(std::string(e.what()).find("board generic-aio at 127.0.0.1:") != std::string::npos);
        }
    }
    SECTION("bad settings are configuration errors naming the key") {
        CHECK_THROWS_WITH(open("modbus+tcp://127.0.0.1:1?board=generic-aio&unit=999"), Catch::Contains("device.unit"));
        CHECK_THROWS_WITH(open("modbus+tcp://127.0.0.1:1?board=nope"), Catch::Contains("device.board"));
        CHECK_THROWS_WITH(open("modbus+tcp://127.0.0.1:1?board=generic-aio&colour=red"), Catch::Contains("device.colour"));
        CHECK_THROWS_AS(open("modbus+tcp://127.0.0.1:1?board=generic-aio&timeout_ms=50&retries=0"), DeviceError);  // refused
    }
}

TEST_CASE("modbus: profile format extensions (checks, init, write function, bits over range)", "[modbus]") {
    const json base = {{"name", "x"},
                       {"registers",
                        {{"sin_out", {{"address", 1000}, {"type", "f32"}, {"offset", -2.5}, {"bits", 12}, {"range", {0.0, 5.0}}}},
                         {"cos_out", {{"address", 1002}, {"type", "f32"}, {"offset", -2.5}, {"bits", 12}, {"range", {0.0, 5.0}}}},
                         {"sin_in", {{"address", 0}, {"type", "f32"}, {"offset", -2.5}, {"bits", 16}, {"range", {-10.0, 10.0}}}},
                         {"cos_in", {{"address", 2}, {"type", "f32"}, {"offset", -2.5}}}}},
                       {"checks", {{{"name", "TEST"}, {"address", 55100}, {"type", "u32"}, {"expect", 1122867}}}},
                       {"init", {{{"name", "AIN0_RANGE"}, {"address", 40000}, {"type", "f32"}, {"value", 10.0}}}}};
    const auto b = board_from_json(base, "");
    const auto& so = *b.find("sin_out");
    CHECK(so.write_function == 16);
    CHECK(so.step() == Approx(5.0 / 4096));
    CHECK(so.symmetric_range() == Approx(2.5));  // 0..5 V around a 2.5 V zero
    CHECK(so.raw_of(0.5) == Approx(3.0));
    CHECK(b.find("sin_in")->step() == Approx(20.0 / 65536));
    CHECK(b.find("sin_in")->symmetric_range() == Approx(7.5));  // -12.5..7.5 V of signal
    CHECK(b.find("cos_in")->step() == 0.0);                     // a float with no stated resolution
    REQUIRE(b.checks.size() == 1);
    CHECK(b.checks[0].expect == 1122867);
    REQUIRE(b.init.size() == 1);
    CHECK((b.init[0].reg.role == "AIN0_RANGE" && b.init[0].value == 10.0 && b.init[0].reg.type == RegType::F32));

    auto bad = base;
    bad["write_function"] = 5;
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("write_function") && Catch::Contains("16"));
    bad = base;
    bad["registers"]["sin_out"]["write_function"] = 6;
    CHECK(board_from_json(bad, "").find("sin_out")->write_function == 6);
    bad = base;
    bad["registers"]["cos_in"]["bits"] = 16;  // bits with no range to divide
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("registers.cos_in.bits"));
    bad = base;
    bad["registers"]["sin_out"]["range"] = {5.0, 0.0};
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("registers.sin_out.range"));
    bad = base;
    bad["checks"][0]["tolerence"] = 1;  // a misspelt key, named with a suggestion
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("checks[0].tolerence") && Catch::Contains("did you mean 'tolerance'"));
    bad = base;
    bad["init"][0].erase("value");
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("init[0].value"));
    bad = base;
    bad["init"][0]["type"] = "u16";
    bad["init"][0]["value"] = 70000;  // would clamp to 65535
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("init[0].value: must be an integer in 0..65535"));
    bad["init"][0]["value"] = 8.5;
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("init[0].value"));
    bad = base;
    bad["init"][0]["table"] = "input";
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("init[0].table"));
    bad = base;
    bad["init"] = json::object();
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("init: expected an array"));
    bad = base;
    bad["wordorder"] = "big";
    CHECK_THROWS_WITH(board_from_json(bad, ""), Catch::Contains("wordorder") && Catch::Contains("did you mean 'word_order'"));

    // The shipped LabJack profiles: the same map, different converters.
    const auto t7 = load_board("labjack-t7"), t4 = load_board("labjack-t4"), t8 = load_board("labjack-t8");
    for (const auto* p : {&t7, &t4, &t8}) {
        CHECK(p->find("sin_out")->address == 1000);
        CHECK(p->find("cos_out")->address == 1002);
        CHECK(p->find("sin_in")->address == 0);
        CHECK(p->find("cos_in")->address == 2);
        CHECK(p->find("sin_out")->type == RegType::F32);
        CHECK_FALSE(p->find("sin_out")->low_word_first);
        CHECK(p->checks.size() == 2);
    }
    CHECK(t7.find("sin_out")->step() == Approx(5.0 / 4096));
    CHECK(t4.find("sin_out")->step() == Approx(5.0 / 1024));
    CHECK(t8.find("sin_out")->step() == Approx(10.1 / 65536));
    CHECK(t7.checks[1].expect == 7);
    CHECK(t4.checks[1].expect == 4);
    CHECK(t8.checks[1].expect == 8);
}

TEST_CASE("modbus: LabJack T7 profile against board-sim (checks, offset to mid-scale, range, word order)", "[modbus][socket]") {
    BoardSimOptions o;
    o.board = "labjack-t7";
    o.adc_bits = 0;
    SimThread sim(o);
    REQUIRE(sim.where.rfind("tcp://", 0) == 0);
    SECTION("steps read back through the offset registers; the converter comes from the profile") {
        auto dev = open(sim.uri("board=labjack-t7&settle_s=0"));
        const auto c = dev->info().converter;
        CHECK(c.dac_q_v() == Approx(5.0 / 4096));
        CHECK(c.adc_q_v() == Approx(20.0 / 65536));
        CHECK(c.dac_bits == 12);
        CHECK(c.adc_bits == 16);
        CHECK(c.dac_range_v == Approx(2.5));
        CHECK(c.note.find("sin_out 12 bits over 0..5 V") != std::string::npos);
        for (double th = 0; th < 2 * kPi; th += 0.7) {
            const auto r = dev->step()->measure(1.1 * std::sin(th), 1.1 * std::cos(th), 0.0, 1);
            CHECK(r.sin_v == Approx(1.1 * std::sin(th)).margin(1e-6));  // f32 registers at 2.5 V +- 1.1 V
            CHECK(r.cos_v == Approx(1.1 * std::cos(th)).margin(1e-6));
        }
        // 2.6 V of signal needs 5.1 V from a 0..5 V DAC: an error, not a clipped step.
        CHECK_THROWS_WITH(dev->step()->measure(2.6, 0.0, 0.0, 1), Catch::Contains("sin_out = 2.6 V needs 5.1") && Catch::Contains("outside its range 0..5"));
    }
    SECTION("the wrong word order fails at open, naming the check and the swap") {
        auto j = json::parse(std::ifstream(boards_dir() + "/labjack-t7.json"));
        j["word_order"] = "little";
        const auto path = std::filesystem::temp_directory_path() / ("fringe-lj-little-" + std::to_string(::getpid()) + ".json");
        std::ofstream(path) << j.dump();
        CHECK_THROWS_WITH(open(sim.uri("board=" + path.string() + "&settle_s=0")),
                          Catch::Contains("check TEST @55100 reads 573767697, expected 1122867") &&
                              Catch::Contains("with the words swapped it reads 1122867: the profile's word_order 'little' is not the board's"));
        std::filesystem::remove(path);
    }
    SECTION("a T4 profile on this board names the product id it found") {
        CHECK_THROWS_WITH(open(sim.uri("board=labjack-t4&settle_s=0")), Catch::Contains("check PRODUCT_ID @60000 reads 7, expected 4"));
    }
}

TEST_CASE("modbus: the preflight warns when the signal does not fit a unipolar DAC around its zero", "[modbus][preflight]") {
    const Scenario sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/labjack-t7-step.json");
    DeviceInfo d;
    d.driver = "modbus";
    d.converter.known = true;
    d.converter.dac_range_v = 2.5;  // the T7 profile: 0..5 V around 2.5 V
    d.converter.adc_range_v = 7.5;
    auto dac_clip = [&] {
        for (const auto& f : preflight_device(sc, d))
            if (f.code == "clipping" && f.message.find("DAC spans") != std::string::npos) return true;
        return false;
    };
    CHECK_FALSE(dac_clip());        // the paper encoder's ~1.1 V fits
    d.converter.dac_range_v = 0.5;  // a DAC with +-0.5 V of room does not
    CHECK(dac_clip());
}

// The bench's faults on the real driver path: board-sim's fault options, libmodbus over TCP.
namespace {
double since_s(std::chrono::steady_clock::time_point t0) { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); }
}  // namespace

TEST_CASE("modbus faults: a reply 50 ms past the timeout is discarded and the request retried", "[modbus][modbus-faults][socket]") {
    BoardSimOptions o;
    o.board = "generic-aio";
    o.adc_bits = 0;
    o.delay_ms = 150;  // timeout 100 ms: 50 ms late
    o.delay_from = 4;  // the read of step 2
    o.delay_count = 1;
    SimThread sim(o);
    auto dev = open(sim.uri("board=generic-aio&settle_s=0&timeout_ms=100&retries=2"));
    for (int k = 0; k < 6; ++k) {
        const double s = 0.1 * k - 0.2, c = 0.3 - 0.05 * k;
        StepResult r;
        REQUIRE_NOTHROW(r = dev->step()->measure(s, c, 0.0, 1));
        // the late reply (to an abandoned request) is never taken for a later one's answer
        CHECK(r.sin_v == Approx(s).margin(1e-4));
        CHECK(r.cos_v == Approx(c).margin(1e-4));
    }
}

TEST_CASE("modbus faults: a reply trickled a byte every 400 ms ends within (retries + 1) x timeout", "[modbus][modbus-faults][socket]") {
    BoardSimOptions o;
    o.trickle_ms = 400;
    SimThread sim(o);
    auto dev = open(sim.uri("board=generic-aio&settle_s=0&timeout_ms=300&retries=1"));
    const auto t0 = std::chrono::steady_clock::now();
    CHECK_THROWS_WITH(dev->step()->measure(0.1, 0.2, 0.0, 1), Catch::Contains("write sin_out,cos_out @0") && Catch::Contains("timed out") && Catch::Contains("after 2 attempts"));
    const double took = since_s(t0);
    CHECK(took < 0.6 + 0.3);  // 2 x 300 ms, and the reconnect
    CHECK(took > 0.5);
}

TEST_CASE("modbus faults: a cancel is seen while a frozen board is retried", "[modbus][modbus-faults][socket]") {
    BoardSimOptions o;
    o.freeze_after = 2;  // answers one step, then never again
    SimThread sim(o);
    auto dev = open(sim.uri("board=generic-aio&settle_s=0&timeout_ms=300&retries=20"));
    std::atomic<bool> cancel{false};
    dev->set_cancel(&cancel);
    CHECK_NOTHROW(dev->step()->measure(0.1, 0.2, 0.0, 1));
    std::thread t([&] {
        std::this_thread::sleep_for(std::chrono::milliseconds(500));
        cancel = true;
    });
    const auto t0 = std::chrono::steady_clock::now();
    CHECK_THROWS_AS(dev->step()->measure(0.1, 0.2, 0.0, 1), Cancelled);
    const double took = since_s(t0);
    t.join();
    CHECK(took < 0.5 + 0.3 + 0.1);  // within one attempt's timeout of the cancel (21 x 300 ms without it)
}

TEST_CASE("modbus faults: a board restarted on its port is reconnected with backoff and the step redone", "[modbus][modbus-faults][socket]") {
    BoardSimOptions o;
    o.board = "generic-aio";
    o.adc_bits = 0;
    o.restart_after = 3;  // request 4, the read of step 2, finds the board restarting
    o.restart_down_ms = 300;
    SimThread sim(o);
    auto dev = open(sim.uri("board=generic-aio&settle_s=0&timeout_ms=250&retries=3"));
    for (int k = 0; k < 5; ++k) {
        const double s = 0.1 * k + 0.05, c = -0.2;
        StepResult r;
        const auto t0 = std::chrono::steady_clock::now();
        REQUIRE_NOTHROW(r = dev->step()->measure(s, c, 0.0, 1));
        // the restarted board lost its drive registers: a reading of them would be 0
        CHECK(r.sin_v == Approx(s).margin(1e-4));
        CHECK(r.cos_v == Approx(c).margin(1e-4));
        if (k == 1) CHECK(since_s(t0) > 0.29);  // it waited for the board
    }
}

TEST_CASE("modbus faults: a NaN after good readings names the reading and the register, not the word order", "[modbus][modbus-faults][socket]") {
    BoardSimOptions o;
    o.board = "labjack-t7";
    o.adc_bits = 0;
    o.nan_adc_after = 60;
    SimThread sim(o);
    auto dev = open(sim.uri("board=labjack-t7&settle_s=0"));
    int ok = 0;
    try {
        for (int k = 0; k < 100; ++k, ++ok) dev->step()->measure(0.5, 0.5, 0.0, 1);
        FAIL("no error");
    } catch (const DeviceError& e) {
        const std::string m = e.what();
        CHECK(ok == 60);
        CHECK(m.find("sin_in @0 reads nan") != std::string::npos);
        CHECK(m.find("at reading 61, after 60 good readings") != std::string::npos);
        CHECK(m.find("not a number") != std::string::npos);
        CHECK(m.find("word_order") == std::string::npos);
    }
}

TEST_CASE("device lock: one owner per resolved device", "[modbus][device-lock][socket]") {
    BoardSimOptions o;
    SimThread sim(o);
    const std::string port = sim.where.substr(sim.where.rfind(':') + 1);
    CHECK(DeviceLock::key_for("modbus+tcp://127.0.0.1:" + port + "?board=generic-aio") ==
          DeviceLock::key_for("modbus+tcp://127.1:" + port + "?board=generic-aio&timeout_ms=100"));
    CHECK(DeviceLock::key_for("modbus+tcp://127.0.0.1:" + port + "?board=generic-aio") != DeviceLock::key_for("modbus+tcp://127.0.0.1:" + port + "?board=generic-aio&unit=2"));
    CHECK(DeviceLock::key_for("loopback:").empty());
    // the service's queue waits on the same key: two spellings of one board queue behind each other
    CHECK(device_key("modbus+tcp://127.0.0.1:" + port + "?board=generic-aio") == device_key("modbus+tcp://127.1:" + port + "?board=generic-aio&average=2"));
    auto a = open("modbus+tcp://127.0.0.1:" + port + "?board=generic-aio");
    // the same thread (one run opening an instrument twice) shares it; another thread does not
    std::string other;
    std::thread t([&] {
        try {
            auto b = open("modbus+tcp://127.1:" + port + "?board=generic-aio");
        } catch (const DeviceError& e) {
            other = e.what();
        }
    });
    t.join();
    CHECK(other.find("busy: modbus-tcp:127.0.0.1:" + port + ":unit1 is in use by another run of this process (pid " + std::to_string(::getpid())) != std::string::npos);
    a.reset();
    std::thread t2([&] { CHECK_NOTHROW(open("modbus+tcp://127.1:" + port + "?board=generic-aio")); });  // released on close
    t2.join();
}

TEST_CASE("modbus faults: a step that fails keeps every step measured before it in the partial report", "[modbus][modbus-faults][socket]") {
    const std::string dir = FRINGE_SOURCE_DIR;
    Scenario sc = load_scenario(dir + "/fixtures/scenarios/modbus-step-sweep.json");
    // Requests per step of this board: count what opening it and 10 steps take.
    long long at_open = 0, per_step = 0;
    {
        BoardSimOptions o;
        o.board = "dut-interpolator";
        SimThread a(o), b(o);
        { auto d = open(a.uri("board=dut-interpolator&settle_s=0")); }
        {
            auto d = open(b.uri("board=dut-interpolator&settle_s=0"));
            for (int k = 0; k < 10; ++k) d->step()->measure(0.1, 0.2, 0.0, 1);
        }
        at_open = a.finish();
        per_step = (b.finish() - at_open) / 10;
        REQUIRE(per_step >= 2);
    }
    BoardSimOptions o;
    o.board = "dut-interpolator";
    o.noise_v = 2e-4;
    o.drop_after = at_open + 20 * per_step + 1;  // step 21 (the 5th of the second block) fails
    SimThread sim(o);
    sc.device = sim.uri("board=dut-interpolator&timeout_ms=100&retries=1");
    const json r = execute_run(sc);
    CHECK(r["status"] == "error");
    CHECK(r["verdict"] == "ERROR");
    CHECK(r["error"].get<std::string>().find("board dut-interpolator at 127.0.0.1:") != std::string::npos);
    CHECK(r["samples"]["processed"] == 20);  // 16 before: the block's 4 measured steps were dropped
}

}  // namespace test_modbus_cpp
