// Capture files: exact round trips (CSV and binary) and malformed input named by file and line.
#include "drivers/capture_file.hpp"
#include "signal_gen/generator.hpp"
#include "helpers.hpp"

#include <catch2/catch.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_capture_cpp {

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
    // uniform sampling: a gap (a dropped block), or a step the rate does not give, is named
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,1,2\n2e-5,1,2\n5e-5,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:5") && Catch::Contains("3 sample periods at 100000 Hz (from the first two rows)") &&
                                   Catch::Contains("samples are missing here"));
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,1,2\n2.2e-5,1,2\n3.1e-5,1,2\n");  // jitter within 0.3 of a period is read (rounded time stamps)
    CHECK(error_of(path) == "<no error>");
    write_text(sidecar_path(path), R"({"sample_rate_hz": 50000})");
    write_text(path, "t,sin,cos\n0,1,2\n1e-5,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("bad.csv:3") && Catch::Contains("0.5 sample periods at 50000 Hz (the sidecar's sample_rate_hz)"));
    std::filesystem::remove(sidecar_path(path));
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

// ---------------------------------------------------------------- header validation
// (issue 12: a .fcap listing a column twice overflowed a buffer in the estimator)

namespace {
const json kCol = {{"sin", {{"name", "sin"}, {"type", "f64"}, {"unit", "V"}}},
                   {"cos", {{"name", "cos"}, {"type", "f64"}, {"unit", "V"}}},
                   {"theta_true", {{"name", "theta_true"}, {"type", "f64"}, {"unit", "rad"}}},
                   {"omega_true", {{"name", "omega_true"}, {"type", "f64"}, {"unit", "rad/s"}}}};

json fcap_header(const std::vector<std::string>& cols) {
    json h{{"format", "fringe-capture"}, {"version", 1}, {"sample_rate_hz", 1e5}, {"t0_s", 0.0}, {"columns", json::array()}};
    for (const auto& c : cols) h["columns"].push_back(kCol.contains(c) ? kCol[c] : json{{"name", c}, {"type", "f64"}});
    return h;
}

// magic, length, header text as given (may be invalid UTF-8), then `frames` frames of
// `doubles_per_frame` f64 values 0.5, 0.25, ...
void write_fcap(const std::string& path, const std::string& header, std::size_t frames, std::size_t doubles_per_frame) {
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    const auto len = static_cast<std::uint32_t>(header.size());
    f.write("FRNGCAP1", 8);
    f.write(reinterpret_cast<const char*>(&len), 4);
    f << header;
    for (std::size_t i = 0; i < frames * doubles_per_frame; ++i) {
        const double v = 0.5 / static_cast<double>(1 + i % 7);
        f.write(reinterpret_cast<const char*>(&v), 8);
    }
}
void write_fcap(const std::string& path, const json& header, std::size_t frames) {
    write_fcap(path, header.dump(), frames, header["columns"].size());
}

// A message is valid UTF-8 exactly when nlohmann can dump it as a JSON string.
bool valid_utf8(const std::string& s) {
    try {
        (void)json(s).dump();
        return true;
    } catch (const json::type_error&) {
        return false;
    }
}
}  // namespace

TEST_CASE("binary capture: a column listed twice is refused, naming file and column", "[capture][validation]") {
    const std::string dup = GENERATE(std::string("sin"), std::string("cos"), std::string("theta_true"));
    const std::string path = tmp("dup.fcap");
    write_fcap(path, fcap_header({"sin", "cos", "theta_true", dup}), 64);
    const std::string msg = error_of(path);
    CHECK_THAT(msg, Catch::Contains("dup.fcap") && Catch::Contains("duplicate column '" + dup + "'"));
    // The reader refuses before any sample is read: no caller sees a column twice as long.
    CHECK_THROWS_AS(CaptureReader(path), CaptureError);
}

TEST_CASE("CSV: a column listed twice is refused, naming the column", "[capture][validation]") {
    const std::string dup = GENERATE(std::string("t"), std::string("sin"), std::string("cos"), std::string("theta_true"));
    const std::string path = tmp("dup.csv");
    std::filesystem::remove(sidecar_path(path));
    write_text(path, "t,sin,cos,theta_true," + dup + "\n0,1,2,3,4\n");
    CHECK_THAT(error_of(path), Catch::Contains("dup.csv:1") && Catch::Contains("duplicate column '" + dup + "'"));
}

TEST_CASE("binary capture: missing and unknown columns", "[capture][validation]") {
    const std::string path = tmp("cols.fcap");
    write_fcap(path, fcap_header({"sin"}), 4);
    CHECK_THAT(error_of(path), Catch::Contains("cols.fcap") && Catch::Contains("missing column 'cos'"));
    write_fcap(path, fcap_header({"cos", "theta_true"}), 4);
    CHECK_THAT(error_of(path), Catch::Contains("missing column 'sin'"));
    write_fcap(path, fcap_header({"sin", "cos", "speed"}), 4);
    CHECK_THAT(error_of(path), Catch::Contains("columns[2]: unknown column 'speed'"));
    write_fcap(path, fcap_header({"t", "sin", "cos"}), 4);
    CHECK_THAT(error_of(path), Catch::Contains("column 't' is not stored"));
    json h = fcap_header({"sin", "cos"});
    h.erase("columns");
    write_fcap(path, h.dump(), 4, 2);
    CHECK_THAT(error_of(path), Catch::Contains("header.columns missing"));
    h = fcap_header({"sin", "cos"});
    h["columns"][1] = "cos";
    write_fcap(path, h, 4);
    CHECK_THAT(error_of(path), Catch::Contains("header.columns[1] is not an object"));
    h = fcap_header({"sin", "cos"});
    h["columns"][0]["name"] = 7;
    write_fcap(path, h, 4);
    CHECK_THAT(error_of(path), Catch::Contains("header.columns[0].name missing"));
    h = fcap_header({"sin", "cos"});
    h["columns"][0]["type"] = "i16";
    write_fcap(path, h, 4);
    CHECK_THAT(error_of(path), Catch::Contains("unsupported type 'i16'"));
    h = fcap_header({"sin", "cos"});
    h["columns"][1]["unit"] = "mV";
    write_fcap(path, h, 4);
    CHECK_THAT(error_of(path), Catch::Contains("column 'cos' has unit \"mV\", expected 'V'"));
}

TEST_CASE("binary capture: sizes that do not match the file", "[capture][validation]") {
    const std::string path = tmp("size.fcap");
    json h = fcap_header({"sin", "cos"});
    h["samples"] = 100;
    write_fcap(path, h, 60);
    CHECK_THAT(error_of(path), Catch::Contains("size.fcap: truncated payload: header.samples is 100 but the file holds 60 frames"));
    write_fcap(path, h, 101);
    CHECK_THAT(error_of(path), Catch::Contains("size mismatch: header.samples is 100 but the file holds 101 frames"));
    write_fcap(path, h, 100);
    CHECK(read_capture(path).size() == 100);
    h["samples"] = -1;
    write_fcap(path, h, 100);
    CHECK_THAT(error_of(path), Catch::Contains("header.samples must be a non-negative integer"));
    h["samples"] = std::numeric_limits<std::uint64_t>::max();  // frames * frame size would overflow
    write_fcap(path, h, 100);
    CHECK_THAT(error_of(path), Catch::Contains("truncated payload: header.samples is 18446744073709551615"));

    // the header length points past the end of the file, or beyond any sane header
    {
        std::ofstream f(path, std::ios::binary | std::ios::trunc);
        const std::uint32_t len = 1000;
        f.write("FRNGCAP1", 8);
        f.write(reinterpret_cast<const char*>(&len), 4);
        f << R"({"sample_rate_hz": 1})";
    }
    CHECK_THAT(error_of(path), Catch::Contains("truncated header: length 1000 but the file has 33 bytes"));
    {
        std::ofstream f(path, std::ios::binary | std::ios::trunc);
        const std::uint32_t len = 0xFFFFFFF0u;
        f.write("FRNGCAP1", 8);
        f.write(reinterpret_cast<const char*>(&len), 4);
    }
    CHECK_THAT(error_of(path), Catch::Contains("bad header length 4294967280"));
    write_text(path, "FRNGCAP1\x01");
    CHECK_THAT(error_of(path), Catch::Contains("ends inside the header length"));
}

TEST_CASE("binary capture: sample rate and t0 must be finite and in range", "[capture][validation]") {
    const std::string path = tmp("rate.fcap");
    auto with = [&](const std::string& key, const std::string& value_json) {
        std::string h = fcap_header({"sin", "cos"}).dump();
        const std::string k = "\"" + key + "\":";
        const auto at = h.find(k);
        const auto end = h.find_first_of(",}", at);
        h.replace(at + k.size(), end - at - k.size(), value_json);
        write_fcap(path, h, 8, 2);
        return error_of(path);
    };
    CHECK(with("sample_rate_hz", "100000") == "<no error>");
    CHECK_THAT(with("sample_rate_hz", "1e999"), Catch::Contains("header is not a JSON object (number overflow parsing '1e999')"));
    CHECK_THAT(with("sample_rate_hz", "0"), Catch::Contains("header.sample_rate_hz = 0 is outside"));
    CHECK_THAT(with("sample_rate_hz", "-5"), Catch::Contains("header.sample_rate_hz = -5 is outside"));
    CHECK_THAT(with("sample_rate_hz", "1e-300"), Catch::Contains("header.sample_rate_hz = 1e-300 is outside"));
    CHECK_THAT(with("sample_rate_hz", "1e300"), Catch::Contains("header.sample_rate_hz = 1e+300 is outside"));
    CHECK_THAT(with("sample_rate_hz", "\"fast\""), Catch::Contains("header.sample_rate_hz must be a number, got string"));
    CHECK_THAT(with("t0_s", "\"zero\""), Catch::Contains("header.t0_s must be a number"));
    // a key given twice is refused, naming it (the last one used to win)
    CHECK_THAT(with("sample_rate_hz", "1000, \"sample_rate_hz\": 2000"), Catch::Contains("duplicate key 'sample_rate_hz'"));
    CHECK(with("sample_rate_hz", "1e10") == "<no error>");
    CHECK_THAT(with("sample_rate_hz", "1.00001e10"), Catch::Contains("header.sample_rate_hz = 1.00001e+10 is outside [1, 1e+10] Hz"));
    CHECK_THAT(with("t0_s", "-1e10"), Catch::Contains("header.t0_s = -1e+10 is outside [-1e+09, 1e+09] s"));
    CHECK_THAT(with("version", "2"), Catch::Contains("header.version 2 is not supported"));
}

TEST_CASE("NaN samples are errors naming the frame or line", "[capture][validation]") {
    // Decided (docs/capture-format.md): a NaN or infinite sample in any column is an error;
    // no estimator is asked to interpolate through a hole in the data.
    const std::string path = tmp("nan.fcap");
    std::string h = fcap_header({"sin", "cos"}).dump();
    write_fcap(path, h, 4, 2);
    {
        std::fstream f(path, std::ios::binary | std::ios::in | std::ios::out);
        const double nan = std::numeric_limits<double>::quiet_NaN();
        f.seekp(static_cast<std::streamoff>(12 + h.size() + (2 * 2 + 1) * 8));  // frame 2, cos
        f.write(reinterpret_cast<const char*>(&nan), 8);
    }
    CHECK_THAT(error_of(path), Catch::Contains("nan.fcap: frame 2: column cos: NaN"));
    const std::string csv = tmp("nan.csv");
    std::filesystem::remove(sidecar_path(csv));
    const std::string col = GENERATE(std::string("sin"), std::string("cos"), std::string("theta_true"));
    const std::string row = col == "sin" ? "2e-5,NaN,2,3\n" : col == "cos" ? "2e-5,1,nan,3\n" : "2e-5,1,2,nan\n";
    write_text(csv, "t,sin,cos,theta_true\n0,1,2,3\n1e-5,1,2,3\n" + row);
    CHECK_THAT(error_of(csv), Catch::Contains("nan.csv:4: column " + col + ": NaN"));
}

TEST_CASE("CSV: sizes that do not match the sidecar, absurd rates from time stamps", "[capture][validation]") {
    const std::string path = tmp("size.csv");
    write_text(sidecar_path(path), R"({"sample_rate_hz": 1000, "samples": 3})");
    write_text(path, "t,sin,cos\n0,1,2\n0.001,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("size.csv: truncated payload: the sidecar's samples is 3 but the file has 2 rows"));
    write_text(path, "t,sin,cos\n0,1,2\n0.001,1,2\n0.002,1,2\n0.003,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("size mismatch"));
    write_text(path, "t,sin,cos\n0,1,2\n0.001,1,2\n0.002,1,2\n");
    CHECK(read_capture(path).size() == 3);
    write_text(sidecar_path(path), R"({"sample_rate_hz": 1e999})");
    CHECK_THAT(error_of(path), Catch::Contains("size.json: sidecar is not a JSON object (number overflow"));
    std::filesystem::remove(sidecar_path(path));
    write_text(path, "t,sin,cos\n0,1,2\n1e-300,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("size.csv:3: column t: a time step of 1e-300 s gives a sample rate outside"));
    write_text(path, "t,sin,cos\n0,1,2\n10,1,2\n");
    CHECK_THAT(error_of(path), Catch::Contains("size.csv:3"));
}

TEST_CASE("metadata that is not UTF-8 is refused with a clean message", "[capture][validation]") {
    const std::string bad = "caf\xE9 \xFF\xFE";  // Latin-1 and stray bytes
    const std::string path = tmp("latin1.fcap");
    json h = fcap_header({"sin", "cos"});
    h["note"] = "NOTE";
    std::string text = h.dump();
    text.replace(text.find("NOTE"), 4, bad);
    write_fcap(path, text, 4, 2);
    std::string msg = error_of(path);
    CHECK_THAT(msg, Catch::Contains("latin1.fcap: header is not valid UTF-8 (byte"));
    CHECK(valid_utf8(msg));

    const std::string csv = tmp("latin1.csv");
    write_text(csv, "t,sin,cos\n0,1,2\n");
    write_text(sidecar_path(csv), "{\"note\": \"" + bad + "\"}");
    msg = error_of(csv);
    CHECK_THAT(msg, Catch::Contains("latin1.json: sidecar is not valid UTF-8 (byte 13)"));
    CHECK(valid_utf8(msg));
    std::filesystem::remove(sidecar_path(csv));

    // Bytes quoted from the file itself are escaped, never copied raw.
    write_text(csv, "t,sin,cos,\xFF\x01speed\n");
    msg = error_of(csv);
    CHECK_THAT(msg, Catch::Contains("unknown column '\\xFF\\x01speed'"));
    CHECK(valid_utf8(msg));
    write_text(csv, "t,sin,cos\n0,1,2\n1e-5,\xC3\x28" + std::string(100, 'x') + ",2\n");
    msg = error_of(csv);
    CHECK_THAT(msg, Catch::Contains("column sin: not a number: '\\xC3(xxx"));
    CHECK(valid_utf8(msg));
    CHECK(msg.size() < 200);  // quoted cells are cut short

    // Malformed JSON says where, and the message stays clean.
    write_text(sidecar_path(csv), "{\"a\": tru");
    write_text(csv, "t,sin,cos\n0,1,2\n");
    CHECK_THAT(error_of(csv), Catch::Contains("sidecar is not a JSON object (parse error at line 1"));
    write_text(sidecar_path(csv), "[1, 2]");
    CHECK_THAT(error_of(csv), Catch::Contains("sidecar is not a JSON object (got array)"));
    write_text(sidecar_path(csv), "{\"sample_rate_hz\": 1000, \"sample_rate_hz\": 2000}");
    CHECK_THAT(error_of(csv), Catch::Contains("sidecar") && Catch::Contains("duplicate key 'sample_rate_hz'"));
    std::filesystem::remove(sidecar_path(csv));
}

TEST_CASE("capture metadata nesting deeper than 128 levels is refused naming the depth, without recursion", "[capture][validation][hostile]") {
    // A .fcap whose header nests a key 10^6 levels deep (it crashed the service on upload).
    const std::size_t deep = 1000000;
    std::string nested = std::string(deep, '[') + std::string(deep, ']');
    json h = fcap_header({"sin", "cos"});
    std::string text = h.dump();
    text.insert(text.size() - 1, ",\"x\":" + nested);
    write_fcap(tmp("deep.fcap"), text, 3, 2);
    const std::string e = error_of(tmp("deep.fcap"));
    CHECK_THAT(e, Catch::Contains("header nests deeper than 128 levels") && Catch::Contains("level 129 opens at byte"));
    // Exactly 128 levels (the object itself and 127 arrays) is read; 129 is not.
    auto nested_key = [&](std::size_t arrays) {
        std::string t = h.dump();
        t.insert(t.size() - 1, ",\"x\":" + std::string(arrays, '[') + std::string(arrays, ']'));
        return t;
    };
    write_fcap(tmp("d128.fcap"), nested_key(127), 3, 2);
    CHECK(read_capture(tmp("d128.fcap")).size() == 3);
    write_fcap(tmp("d129.fcap"), nested_key(128), 3, 2);
    CHECK_THAT(error_of(tmp("d129.fcap")), Catch::Contains("nests deeper than 128"));
    // Brackets inside strings (escaped quotes too) do not count.
    std::string in_string = h.dump();
    in_string.insert(in_string.size() - 1, ",\"note\":\"\\\"" + std::string(5000, '[') + "\"");
    write_fcap(tmp("str.fcap"), in_string, 3, 2);
    CHECK(read_capture(tmp("str.fcap")).size() == 3);
    // A CSV's sidecar likewise, objects as well as arrays.
    write_text(tmp("deep.csv"), "t,sin,cos\n0,0,1\n0.001,0,1\n");
    std::string side;
    for (std::size_t i = 0; i < 200000; ++i) side += "{\"a\":";
    write_text(tmp("deep.json"), side + "1" + std::string(200000, '}'));
    CHECK_THAT(error_of(tmp("deep.csv")), Catch::Contains("deep.json: sidecar nests deeper than 128 levels"));
    std::filesystem::remove(tmp("deep.json"));
}

TEST_CASE("capture: expanded_bytes is what a reader goes through (uncompressed formats: the file's size)", "[capture]") {
    const std::string path = tmp("size.fcap");
    {
        CaptureWriter w(path, {false, false, false}, json{{"sample_rate_hz", 1e5}});
        w.write(sample_block(1000));
    }
    CaptureReader r(path);
    CHECK(r.expanded_bytes() == std::filesystem::file_size(path));
    write_text(tmp("size.csv"), "t,sin,cos\n0,0,1\n0.001,0,1\n");
    std::filesystem::remove(tmp("size.json"));
    CHECK(CaptureReader(tmp("size.csv")).expanded_bytes() == std::filesystem::file_size(tmp("size.csv")));
}

}  // namespace test_capture_cpp
