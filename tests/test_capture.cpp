// Capture files: exact round trips (CSV and binary) and malformed input named by file and line.
#include "drivers/capture_file.hpp"
#include "signal_gen/generator.hpp"
#include "helpers.hpp"

#include <catch2/catch.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>

using namespace fringe;
using nlohmann::json;

namespace {
Block sample_block(std::size_t n) {
    EncoderProfile e = test::clean_diffraction(1.1149, 2.8713);
    e.noise.sigma_add_v = 2e-4;
    e.index.enabled = true;
    return test::generate(e, test::constant_electrical(106.7, 1024), 1e5, n);
}
std::string tmp(const std::string& name) {
    auto dir = std::filesystem::temp_directory_path() / "fringe-capture-tests";
    std::filesystem::create_directories(dir);
    return (dir / name).string();
}
void write_text(const std::string& path, const std::string& text) {
    std::ofstream f(path, std::ios::trunc);
    f << text;
}
std::string error_of(const std::string& path) {
    try {
        read_capture(path);
    } catch (const CaptureError& e) {
        return e.what();
    }
    return "<no error>";
}
}  // namespace

TEST_CASE("capture round trip is exact", "[capture]") {
    const std::string ext = GENERATE(std::string(".csv"), std::string(".fcap"));
    const std::string path = tmp("roundtrip" + ext);
    Block b = sample_block(10000);
    {
        CaptureWriter w(path, {true, true, true}, json{{"sample_rate_hz", 1e5}, {"t0_s", 0.0}, {"seed", 3}});
        // two writes: the file is a stream of blocks
        Block first = b, second = b;
        for (auto* v : {&first.t_s, &first.sin_v, &first.cos_v, &first.theta_rad, &first.omega_rad_s, &first.index_v, &first.phi_rad})
            v->resize(4000);
        w.write(first);
        for (auto* v : {&second.t_s, &second.sin_v, &second.cos_v, &second.theta_rad, &second.omega_rad_s, &second.index_v, &second.phi_rad})
            v->erase(v->begin(), v->begin() + 4000);
        w.write(second);
        CHECK(w.frames() == 10000);
    }
    json meta;
    double fs = 0;
    CaptureData d = read_capture(path, &meta, &fs);
    CHECK(fs == 1e5);
    CHECK(meta["seed"] == 3);
    CHECK(d.t_s == b.t_s);
    CHECK(d.sin_v == b.sin_v);
    CHECK(d.cos_v == b.cos_v);
    CHECK(d.theta_true_rad == b.theta_rad);
    CHECK(d.omega_true_rad_s == b.omega_rad_s);
    CHECK(d.index_v == b.index_v);
}

TEST_CASE("CSV without sidecar or truth is accepted, rate from time stamps", "[capture]") {
    const std::string path = tmp("plain.csv");
    std::filesystem::remove(sidecar_path(path));
    write_text(path, "t,sin,cos\n0,0.1,0.9\n0.001,0.2,0.8\n0.002,0.3,0.7\n");
    CaptureReader r(path);
    CHECK_FALSE(r.columns().theta_true);
    CaptureData d;
    REQUIRE(r.read(100, d));
    CHECK(d.size() == 3);
    CHECK(r.sample_rate_hz() == Approx(1000.0));
    CHECK_FALSE(r.read(100, d));
}

TEST_CASE("malformed captures are named by file and line", "[capture]") {
    const std::string path = tmp("bad.csv");
    std::filesystem::remove(sidecar_path(path));
    write_text(path, "t,sin\n0,1\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:1") && Catch::Contains("missing column 'cos'"));
    write_text(path, "t,sin,cos,speed\n");
    CHECK_THAT(error_of(path), Catch::Contains("unknown column 'speed'"));
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,abc,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:3") && Catch::Contains("column sin: not a number: 'abc'"));
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,nan,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:3") && Catch::Contains("NaN"));
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,1,2\n1e-5,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:4") && Catch::Contains("time does not increase"));
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,1\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:3") && Catch::Contains("expected 3 cells"));
    write_text(path, "t,sin,cos\n0,1,2,3\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:2") && Catch::Contains("more cells"));
    write_text(path, "");
    CHECK_THAT(error_of(path), Catch::Contains("empty file"));
    CHECK_THAT(error_of(tmp("nope.csv")), Catch::Contains("cannot open"));
    CHECK_THAT(error_of(tmp("x.wav")), Catch::Contains("unknown capture format"));
    write_text(path, "t,sin,cos\n0,1,2\n");
    write_text(sidecar_path(path), "{not json");
    CHECK_THAT(error_of(path), Catch::Contains("sidecar is not a JSON object"));
    std::filesystem::remove(sidecar_path(path));
}

TEST_CASE("binary capture: bad magic and a truncated tail are reported", "[capture]") {
    const std::string path = tmp("cut.fcap");
    Block b = sample_block(100);
    {
        CaptureWriter w(path, {true, false, false}, json{{"sample_rate_hz", 1e5}});
        w.write(b);
    }
    // Cut a frame in half, as a killed writer would.
    const auto size = std::filesystem::file_size(path);
    std::filesystem::resize_file(path, size - 12);
    CHECK_THAT(error_of(path), Catch::Contains("truncated") && Catch::Contains("after frame 99"));
    write_text(path, "RIFF....");
    CHECK_THAT(error_of(path), Catch::Contains("bad magic"));
    CHECK_THROWS_AS(CaptureWriter(path, {}, json::object()), CaptureError);  // binary needs a rate
}
