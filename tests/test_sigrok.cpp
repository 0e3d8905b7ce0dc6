// sigrok session files (.sr) as captures, hostile .sr input, and the ABZ readout of a DUT
// against analytic truth (docs/capture-format.md, docs/abz.md).
#include "drivers/abz.hpp"
#include "drivers/capture_file.hpp"
#include "drivers/device.hpp"
#include "server/engine/run.hpp"
#include "server/engine/scenario.hpp"
#include "sr_writer.hpp"
#include "server/http/service.hpp"

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>
#include <zip.h>

#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

// This file's own namespace: the test files compile together as unity files (FRINGE_UNITY).
namespace test_sigrok_cpp {

using namespace fringe;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

constexpr double kTwoPiT = 6.283185307179586;

struct Dir {
    fs::path path;
    Dir() {
        path = fs::temp_directory_path() / ("fringe-sr-" + std::to_string(getpid()) + "-" + std::to_string(std::random_device{}()));
        fs::create_directories(path);
    }
    ~Dir() {
        std::error_code ec;
        fs::remove_all(path, ec);
    }
    std::string operator/(const std::string& name) const { return (path / name).string(); }
};

using fringe::test::write_zip;

std::string floats(const std::vector<float>& v) {
    return std::string(reinterpret_cast<const char*>(v.data()), v.size() * 4);
}

std::string sr_meta(const std::string& device_keys) {
    return "[global]\nsigrok version=0.5.2\n\n[device 1]\n" + device_keys;
}

std::string read_file(const std::string& p) {
    std::ifstream f(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(f), {});
}

std::string error_of(const std::string& path, const CaptureOptions& o = {}) {
    try {
        read_capture(path, nullptr, nullptr, o);
    } catch (const CaptureError& e) {
        (void)json(e.what()).dump();  // valid UTF-8, or this throws
        return e.what();
    }
    return "";
}

// A well-formed analog + logic session: sin/cos on analog3/analog4 (after two logic probes
// and an unused one), chunks of different sizes per channel, a/b in probes 1 and 10
// (unitsize 2).
struct GoodSession {
    std::vector<float> sin, cos;
    std::vector<std::uint16_t> logic;
    std::vector<std::pair<std::string, std::string>> entries;
    explicit GoodSession(std::size_t n = 1000) {
        for (std::size_t i = 0; i < n; ++i) {
            sin.push_back(static_cast<float>(std::sin(0.01 * static_cast<double>(i))));
            cos.push_back(static_cast<float>(std::cos(0.01 * static_cast<double>(i))) + 0.125f);
            logic.push_back(static_cast<std::uint16_t>((i & 1) | ((i >> 1 & 1) << 9) | 0x40));
        }
        const std::string meta = sr_meta(
            "capturefile=logic-1\ntotal probes=10\nsamplerate=1.5 MHz\ntotal analog=2\nprobe1=A0\nprobe10=B0\nprobe7=unused\n"
            "analog11=sin\nanalog12=cos\nunitsize=2\n");
        entries = {{"version", "2"}, {"metadata", meta}};
        // sin in chunks of 300, 300, 400; cos in 1000; logic in 7 uneven chunks.
        for (std::size_t c = 0, at = 0; at < n; ++c) {
            const std::size_t len = std::min<std::size_t>(c < 2 ? 300 : 400, n - at);
            entries.push_back({"analog-1-11-" + std::to_string(c + 1), floats({sin.begin() + static_cast<long>(at), sin.begin() + static_cast<long>(at + len)})});
            at += len;
        }
        entries.push_back({"analog-1-12-1", floats(cos)});
        for (std::size_t c = 0, at = 0; at < n; ++c) {
            const std::size_t len = std::min<std::size_t>(143, n - at);
            entries.push_back({"logic-1-" + std::to_string(c + 1), std::string(reinterpret_cast<const char*>(logic.data() + at), len * 2)});
            at += len;
        }
    }
};

}  // namespace

TEST_CASE("sigrok: a session's channels read as columns, exactly, across chunk boundaries", "[sigrok][capture]") {
    Dir d;
    GoodSession g;
    write_zip(d / "s.sr", g.entries);
    CaptureOptions o;
    o.channels = parse_channel_map("a=A0,b=B0");
    CaptureReader r(d / "s.sr", o);
    CHECK(r.sample_rate_hz() == 1.5e6);
    CHECK(r.columns().abz());
    CHECK_FALSE(r.columns().theta_true);
    CaptureData chunk;
    std::size_t k = 0;
    while (r.read(37, chunk)) {  // odd blocks straddle every chunk boundary
        for (std::size_t i = 0; i < chunk.size(); ++i, ++k) {
            REQUIRE(chunk.sin_v[i] == static_cast<double>(g.sin[k]));
            REQUIRE(chunk.cos_v[i] == static_cast<double>(g.cos[k]));
            REQUIRE(chunk.a[i] == static_cast<double>(g.logic[k] & 1));
            REQUIRE(chunk.b[i] == static_cast<double>(g.logic[k] >> 9 & 1));
            REQUIRE(chunk.t_s[i] == static_cast<double>(k) / 1.5e6);
        }
    }
    CHECK(k == 1000);
    // The legacy single logic entry "logic-1" reads too; the bare-number rate form as well.
    write_zip(d / "legacy.sr", {{"version", "1"}, {"metadata", sr_meta("capturefile=logic-1\ntotal probes=2\nsamplerate=48000\ntotal analog=2\n"
                                                                         "probe1=a\nprobe2=b\nanalog3=sin\nanalog4=cos\nunitsize=1\n")},
                                {"logic-1", std::string("\x00\x01\x03\x02", 4)}, {"analog-1-3-1", floats({1, 2, 3, 4})}, {"analog-1-4-1", floats({5, 6, 7, 8})}});
    double fs = 0;
    const CaptureData all = read_capture(d / "legacy.sr", nullptr, &fs);
    CHECK(fs == 48000);
    CHECK(all.a == std::vector<double>{0, 1, 1, 0});
    CHECK(all.b == std::vector<double>{0, 0, 1, 1});
    CHECK(all.cos_v == std::vector<double>{5, 6, 7, 8});
}

TEST_CASE("sigrok: hostile sessions are refused with the problem named", "[sigrok][capture][hostile]") {
    Dir d;
    const std::string meta = sr_meta("samplerate=100 kHz\ntotal analog=2\nanalog1=sin\nanalog2=cos\n");
    auto with = [&](std::vector<std::pair<std::string, std::string>> e) {
        write_zip(d / "h.sr", e);
        return error_of(d / "h.sr");
    };
    const std::string four = floats({0.5f, 0.25f, 1, 2});
    // the good one first: the cases below differ from it in one thing
    CHECK(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}).empty());

    std::ofstream(d / "junk.sr") << "this is not a zip";
    CHECK_THAT(error_of(d / "junk.sr"), Catch::Contains("not a sigrok session file (a ZIP archive)"));
    CHECK_THAT(with({{"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}), Catch::Contains("no 'version' entry"));
    CHECK_THAT(with({{"version", "3"}, {"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}), Catch::Contains("version '3' is not supported"));
    CHECK_THAT(with({{"version", "2"}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}), Catch::Contains("no 'metadata' entry"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", sr_meta("total analog=2\nanalog1=sin\nanalog2=cos\n")}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}),
               Catch::Contains("has no samplerate"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", sr_meta("samplerate=fast\ntotal analog=2\nanalog1=sin\nanalog2=cos\n")}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}),
               Catch::Contains("samplerate 'fast'"));
    // a gap in the chunk sequence
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-1-3", four}, {"analog-1-2-1", four}}),
               Catch::Contains("missing chunk analog-1-1-2"));
    // a channel with no chunks at all, and mismatched lengths
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four}}), Catch::Contains("channel 'cos' (analog2) has no data"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-2-1", floats({1, 2, 3})}}),
               Catch::Contains("length mismatch") && Catch::Contains("4 samples") && Catch::Contains("has 3"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four + "xy"}, {"analog-1-2-1", four}}), Catch::Contains("not whole float32 samples"));
    // non-UTF-8: an entry name, a channel name
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-2-1", four}, {"x\xff\xfe", "1"}}),
               Catch::Contains("not UTF-8") && Catch::Contains("\\xFF"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta + "analog3=\xc3\x28\n"}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}),
               Catch::Contains("metadata is not valid UTF-8"));
    // NaN in a channel
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", floats({0, std::nanf(""), 0, 0})}, {"analog-1-2-1", four}}),
               Catch::Contains("sample 1") && Catch::Contains("NaN"));
    // two devices, a malformed chunk name, logic without unitsize, a probe beyond total probes
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta + "[device 2]\nsamplerate=1 kHz\n"}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}),
               Catch::Contains("only one device"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", four}, {"analog-1-2-1", four}, {"analog-1-x-1", four}}),
               Catch::Contains("malformed entry name 'analog-1-x-1'"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta + "total probes=2\nprobe1=a\nprobe2=b\n"}, {"analog-1-1-1", four}, {"analog-1-2-1", four},
                     {"logic-1-1", std::string(4, '\0')}}),
               Catch::Contains("need unitsize"));
    CHECK_THAT(with({{"version", "2"}, {"metadata", meta + "total probes=1\nprobe2=a\n"}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}),
               Catch::Contains("probe2 is beyond total probes = 1"));
    // channels not named sin/cos: the error lists them and says how to map
    const std::string scope = sr_meta("samplerate=100 kHz\ntotal analog=2\nanalog1=CH1\nanalog2=CH2\n");
    CHECK_THAT(with({{"version", "2"}, {"metadata", scope}, {"analog-1-1-1", four}, {"analog-1-2-1", four}}),
               Catch::Contains("no channel for column 'sin'") && Catch::Contains("CH1 (analog1)") && Catch::Contains("sin=CH1,cos=CH2"));
    CaptureOptions o;
    o.channels = parse_channel_map("sin=CH2,cos=CH1");
    CHECK(read_capture(d / "h.sr", nullptr, nullptr, o).sin_v == std::vector<double>{0.5, 0.25, 1, 2});
    o.channels = parse_channel_map("sin=CH3,cos=CH1");
    CHECK_THAT(error_of(d / "h.sr", o), Catch::Contains("mapped to channel 'CH3', which the session does not have"));
    o.channels = parse_channel_map("sin=CH1,cos=CH1");
    CHECK_THAT(error_of(d / "h.sr", o), Catch::Contains("channel 'CH1' is mapped to two columns"));
    CHECK_THROWS_WITH(parse_channel_map("phase=CH1"), Catch::Contains("unknown column 'phase'"));
}

TEST_CASE("sigrok: declared sizes are capped and never read past (ZIP bombs, lying headers)", "[sigrok][capture][hostile]") {
    Dir d;
    const std::string meta = sr_meta("samplerate=100 kHz\ntotal analog=2\nanalog1=sin\nanalog2=cos\n");
    std::vector<float> v(4096, 0.0f);  // compresses well: its deflate stream is small
    write_zip(d / "z.sr", {{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", floats(v)}, {"analog-1-2-1", floats(v)}});
    const std::string good = read_file(d / "z.sr");
    REQUIRE(error_of(d / "z.sr").empty());
    // Rewrite the declared uncompressed size of both data entries, in the local headers
    // (offset 22) and the central directory (offset 24), as a hostile writer would.
    auto patched = [&](std::uint32_t size) {
        std::string s = good;
        const std::uint32_t real = 4096 * 4;
        for (std::size_t p = 0; (p = s.find("PK", p)) != std::string::npos; p += 2) {
            const bool local = s.compare(p, 4, "PK\x03\x04") == 0, central = s.compare(p, 4, "PK\x01\x02") == 0;
            if (!local && !central) continue;
            const std::size_t at = p + (local ? 22 : 24);
            std::uint32_t cur;
            std::memcpy(&cur, s.data() + at, 4);
            if (cur == real) std::memcpy(s.data() + at, &size, 4);
        }
        std::ofstream(d / "p.sr", std::ios::binary) << s;
        return error_of(d / "p.sr");
    };
    // two channels of nearly 4 GiB each: refused before anything is inflated
    CHECK_THAT(patched(0xFFFFFFF0u), Catch::Contains("declares 8589934560 bytes uncompressed (8192 MiB), more than the 512 MiB allowed") &&
                                         Catch::Contains("ZIP bombs"));
    CHECK_THROWS_AS(read_capture(d / "p.sr"), CaptureTooLarge);
    // an entry that inflates to more than it declares is refused, not read on
    const std::string more = patched(4096);
    CHECK_FALSE(more.empty());
    CHECK_THAT(more, Catch::Contains("decompresses to more than its declared size") && Catch::Contains("entry 'analog-1-"));
    // and one that declares more than it holds
    const std::string fewer = patched(4096 * 8);
    CHECK_FALSE(fewer.empty());
    CHECK_THAT(fewer, Catch::Contains("before its declared size") && Catch::Contains("entry 'analog-1-"));
}

TEST_CASE("capture: digital a/b/z columns in CSV and .fcap", "[capture][abz]") {
    Dir d;
    std::ofstream(d / "ok.csv") << "t,sin,cos,a,b,z\n0,0,1,0,0,1\n1e-3,0.1,1,1,0,0\n2e-3,0.2,1,1,1,0\n";
    const CaptureData c = read_capture(d / "ok.csv");
    CHECK(c.a == std::vector<double>{0, 1, 1});
    CHECK(c.z == std::vector<double>{1, 0, 0});
    std::ofstream(d / "lvl.csv") << "t,sin,cos,a,b\n0,0,1,0,0\n1e-3,0.1,1,0.5,0\n";
    CHECK_THAT(error_of(d / "lvl.csv"), Catch::Contains("lvl.csv:3: column a: a logic level must be 0 or 1"));
    std::ofstream(d / "lone.csv") << "t,sin,cos,a\n0,0,1,0\n";
    CHECK_THAT(error_of(d / "lone.csv"), Catch::Contains("a and b come together"));
    // .fcap with u8 digital columns
    json h{{"sample_rate_hz", 1000.0},
           {"columns", json::array({{{"name", "sin"}, {"type", "f32"}}, {{"name", "cos"}, {"type", "f32"}}, {{"name", "a"}, {"type", "u8"}}, {{"name", "b"}, {"type", "u8"}}})}};
    const std::string hs = h.dump();
    std::string f = "FRNGCAP1";
    const std::uint32_t len = static_cast<std::uint32_t>(hs.size());
    f.append(reinterpret_cast<const char*>(&len), 4);
    f += hs;
    for (int i = 0; i < 3; ++i) {
        const float s = 0.5f * static_cast<float>(i), co = 1;
        f.append(reinterpret_cast<const char*>(&s), 4);
        f.append(reinterpret_cast<const char*>(&co), 4);
        f += static_cast<char>(i & 1);
        f += static_cast<char>(i >> 1 & 1);
    }
    std::ofstream(d / "d.fcap", std::ios::binary) << f;
    const CaptureData b = read_capture(d / "d.fcap");
    CHECK(b.a == std::vector<double>{0, 1, 0});
    CHECK(b.b == std::vector<double>{0, 0, 1});
    f[f.size() - 1] = 2;
    std::ofstream(d / "d2.fcap", std::ios::binary) << f;
    CHECK_THAT(error_of(d / "d2.fcap"), Catch::Contains("frame 2: column b: a logic level must be 0 or 1"));
}

namespace {

// An ideal DUT: count = floor((theta - offset)/step), A/B the Gray code of count mod 4, Z one
// count wide where count = index_count mod 4N (docs/abz.md).
struct Lines {
    std::vector<double> t, theta, a, b, z;
};
Lines ideal_dut(const std::vector<double>& theta, double fs, int N, long long index_count = 0) {
    Lines l;
    const long long C = 4LL * N;
    const double step = kTwoPiT / static_cast<double>(C);
    static const int A[4] = {0, 1, 1, 0}, B[4] = {0, 0, 1, 1};
    for (std::size_t i = 0; i < theta.size(); ++i) {
        const long long c = static_cast<long long>(std::floor(theta[i] / step));
        const long long m4 = ((c % 4) + 4) % 4, mc = (((c - index_count) % C) + C) % C;
        l.t.push_back(static_cast<double>(i) / fs);
        l.theta.push_back(theta[i]);
        l.a.push_back(A[m4]);
        l.b.push_back(B[m4]);
        l.z.push_back(mc == 0 ? 1 : 0);
    }
    return l;
}

struct Decoded {
    std::vector<double> th;
    AbzStats st;
};
Decoded decode(const Lines& l, int N, bool with_z, bool with_truth, long long index_count = 0) {
    AbzDecoder dec(AbzConfig{N, index_count, 0.0});
    Decoded d;
    d.th.resize(l.t.size());
    // in uneven blocks: the decoder's state carries across
    for (std::size_t at = 0; at < l.t.size();) {
        const std::size_t n = std::min<std::size_t>(777, l.t.size() - at);
        dec.process(n, l.t.data() + at, l.a.data() + at, l.b.data() + at, with_z ? l.z.data() + at : nullptr,
                    with_truth ? l.theta.data() + at : nullptr, d.th.data() + at);
        at += n;
    }
    d.st = dec.stats();
    return d;
}

// Error statistics over the valid samples, after removing one constant multiple of 2*pi.
struct ErrStats {
    double rms = 0, mean = 0, max_abs = 0;
    std::size_t valid = 0;
};
ErrStats errors(const Decoded& d, const Lines& l, std::size_t from = 0) {
    ErrStats s;
    double k = NAN;
    double sum = 0, sum2 = 0;
    for (std::size_t i = from; i < d.th.size(); ++i) {
        if (!std::isfinite(d.th[i])) continue;
        double e = d.th[i] - l.theta[i];
        if (std::isnan(k)) k = kTwoPiT * std::round(e / kTwoPiT);
        e -= k;
        sum += e;
        sum2 += e * e;
        s.max_abs = std::max(s.max_abs, std::fabs(e));
        ++s.valid;
    }
    s.mean = sum / static_cast<double>(s.valid);
    s.rms = std::sqrt(sum2 / static_cast<double>(s.valid));
    return s;
}

}  // namespace

TEST_CASE("abz: an ideal DUT decodes to within the quantisation step, rms step/sqrt(12)", "[abz]") {
    const double fs = 1e6;
    for (int N : {1, 4, 16, 250}) {
        // constant speed with a slow wobble: 37.3 electrical cycles in 200000 samples; the
        // phase is irrational to the count grid, so the cells are sampled uniformly
        std::vector<double> th(200000);
        for (std::size_t i = 0; i < th.size(); ++i) {
            const double t = static_cast<double>(i) / fs;
            th[i] = 0.1234 + kTwoPiT * 186.5 * t + 0.3 * std::sin(kTwoPiT * 7 * t);
        }
        const Lines l = ideal_dut(th, fs, N);
        const double step = kTwoPiT / (4.0 * N);
        for (bool with_z : {false, true}) {
            CAPTURE(N, with_z);
            const Decoded d = decode(l, N, with_z, true);
            const ErrStats e = errors(d, l);
            CHECK(d.st.illegal_transitions == 0);
            CHECK(d.st.index_errors == 0);
            CHECK(d.st.missed_index == 0);
            CHECK(d.st.reference == (with_z ? "index" : "truth"));
            CHECK(e.max_abs <= step / 2 * (1 + 1e-9));
            CHECK(std::fabs(e.mean) < 0.05 * step);
            // uniform quantisation error: rms step/sqrt(12), within the sampling of 1e5+ cells
            CHECK(e.rms == Approx(step / std::sqrt(12.0)).epsilon(0.03));
            if (with_z) {
                CHECK(d.st.index_pulses >= 37);
                CHECK(d.st.invalid_samples > 0);  // before the first index
            } else {
                CHECK(d.st.invalid_samples == 0);
                CHECK(e.valid == th.size());
            }
        }
    }
}

TEST_CASE("abz: direction reversals are followed and counted", "[abz]") {
    const double fs = 1e5;
    const int N = 8;
    std::vector<double> th(100000);
    // 10 oscillations of +-3.1 electrical cycles: 20 reversals
    for (std::size_t i = 0; i < th.size(); ++i) th[i] = 0.05 + 3.1 * kTwoPiT * std::sin(kTwoPiT * 10 * static_cast<double>(i) / fs + 0.3);
    const Lines l = ideal_dut(th, fs, N);
    const Decoded d = decode(l, N, true, true);
    const ErrStats e = errors(d, l);
    const double step = kTwoPiT / (4.0 * N);
    CHECK(d.st.illegal_transitions == 0);
    CHECK(d.st.index_errors == 0);
    CHECK(d.st.reversals == 20);
    CHECK(d.st.missed_index == 0);  // reversals inside the index cell too
    CHECK(e.max_abs <= step / 2 * (1 + 1e-9));
    // net count = the change of floor(theta/step) from start to end
    const long long net = static_cast<long long>(std::floor(th.back() / step)) - static_cast<long long>(std::floor(th.front() / step));
    CHECK(static_cast<long long>(d.st.forward) - static_cast<long long>(d.st.backward) == net);
}

TEST_CASE("abz: an illegal transition invalidates the position until the index re-synchronises it", "[abz]") {
    const double fs = 1e5;
    const int N = 4;
    std::vector<double> th(20000);
    for (std::size_t i = 0; i < th.size(); ++i) th[i] = kTwoPiT * 50 * static_cast<double>(i) / fs;  // 10 cycles, 200 counts
    Lines l = ideal_dut(th, fs, N);
    // A glitch: at an edge, both lines flip (the DUT skipped a state for one sample).
    std::size_t at = 0;
    for (std::size_t i = 9000; i < l.t.size(); ++i)
        if (l.a[i] != l.a[i - 1] || l.b[i] != l.b[i - 1]) { at = i; break; }
    REQUIRE(at > 0);
    l.a[at] = 1 - l.a[at - 1];
    l.b[at] = 1 - l.b[at - 1];
    const double step = kTwoPiT / (4.0 * N);
    SECTION("with Z: invalid from the glitch to the next index, then right again") {
        const Decoded d = decode(l, N, true, true);
        CHECK(d.st.illegal_transitions >= 1);
        CHECK(d.st.resyncs == 1);
        std::size_t next_index = 0;
        for (std::size_t i = at + 1; i < l.t.size(); ++i)
            if (l.z[i] && !l.z[i - 1]) { next_index = i; break; }
        REQUIRE(next_index > at);
        CHECK(std::isnan(d.th[at]));
        CHECK(std::isnan(d.th[next_index - 1]));
        CHECK(std::isfinite(d.th[next_index]));
        const ErrStats e = errors(d, l, next_index);
        CHECK(e.max_abs <= step / 2 * (1 + 1e-9));
        CHECK(d.st.index_errors == 0);
    }
    SECTION("without Z: invalid to the end, never guessed") {
        const Decoded d = decode(l, N, false, true);
        CHECK(d.st.illegal_transitions >= 1);
        for (std::size_t i = at; i < l.t.size(); ++i) REQUIRE(std::isnan(d.th[i]));
        CHECK(d.st.invalid_samples == l.t.size() - at);
        CHECK(errors(d, l).max_abs <= step / 2 * (1 + 1e-9));
    }
}

TEST_CASE("abz: an index at the wrong count is an index error, and the count is reset there", "[abz]") {
    const double fs = 1e5;
    const int N = 4;
    std::vector<double> th(20000);
    for (std::size_t i = 0; i < th.size(); ++i) th[i] = kTwoPiT * 50 * static_cast<double>(i) / fs;
    const Lines l = ideal_dut(th, fs, N, 0);
    // The decoder is told the index is at count 1: every index after the first is off by one
    // (the first one sets the reference).
    const Decoded d = decode(l, N, true, true, 1);
    CHECK(d.st.index_pulses >= 9);
    CHECK(d.st.index_errors == 0);  // consistent with itself: the reference moved by one count
    // A DUT that loses one count mid-way (it misses an edge: its A/B hold one state longer and
    // the count stays behind): the next index finds the count one off and resets it.
    Lines lost = l;
    long long shift = 0;
    const long long C = 4LL * N;
    static const int A[4] = {0, 1, 1, 0}, B[4] = {0, 0, 1, 1};
    const double step = kTwoPiT / static_cast<double>(C);
    for (std::size_t i = 0; i < lost.t.size(); ++i) {
        if (i == 10000) shift = 1;
        const long long c = static_cast<long long>(std::floor(th[i] / step)) - shift;
        const long long m4 = ((c % 4) + 4) % 4;
        lost.a[i] = A[m4];
        lost.b[i] = B[m4];
    }
    // the lost count: around i = 10000 the count stands still for one step (no illegal jump)
    const Decoded e = decode(lost, N, true, true, 0);
    CHECK(e.st.illegal_transitions == 0);
    CHECK(e.st.index_errors >= 1);
    CHECK(e.st.max_index_error_counts == 1);
}

TEST_CASE("abz: an index pulse that never comes is a missed index, and the count stays valid", "[abz]") {
    const double fs = 1e5;
    const int N = 4;
    std::vector<double> th(20000);
    for (std::size_t i = 0; i < th.size(); ++i) th[i] = kTwoPiT * 50 * static_cast<double>(i) / fs;  // 10 cycles
    Lines l = ideal_dut(th, fs, N, 0);
    // Z stays low through the 6th index cell (a broken Z line for one cycle) and the 8th.
    const std::vector<double> z = l.z;
    std::size_t pulses = 0;
    for (std::size_t i = 1; i < z.size(); ++i) {
        if (z[i] && !z[i - 1]) ++pulses;
        if (z[i] && (pulses == 6 || pulses == 8)) l.z[i] = 0;
    }
    REQUIRE(pulses >= 9);
    const Decoded d = decode(l, N, true, true);
    CHECK(d.st.missed_index == 2);
    CHECK(d.st.index_errors == 0);
    CHECK(d.st.illegal_transitions == 0);
    const double step = kTwoPiT / (4.0 * N);
    std::size_t first = 0;
    while (!std::isfinite(d.th[first])) ++first;
    const ErrStats e = errors(d, l, first);
    CHECK(e.valid == l.t.size() - first);  // nothing invalidated: the count was right all along
    CHECK(e.max_abs <= step / 2 * (1 + 1e-9));
}

TEST_CASE("run: a capture's ABZ lines grade the DUT as the dut lane", "[run][abz][capture]") {
    Dir d;
    const double fs = 100000;
    const int N = 16;
    std::vector<double> th(30000);
    for (std::size_t i = 0; i < th.size(); ++i) th[i] = 0.2 + kTwoPiT * 500 * static_cast<double>(i) / fs;
    Lines l = ideal_dut(th, fs, N);
    auto write_csv = [&](const std::string& path, const Lines& x) {
        std::ofstream f(path);
        f << "t,sin,cos,theta_true,a,b,z\n";
        f.precision(17);
        for (std::size_t i = 0; i < x.t.size(); ++i)
            f << x.t[i] << "," << std::sin(x.theta[i]) << "," << std::cos(x.theta[i]) << "," << x.theta[i] << "," << x.a[i] << "," << x.b[i] << "," << x.z[i] << "\n";
        std::ofstream(sidecar_path(path)) << json{{"sample_rate_hz", fs}, {"t0_s", 0.0}}.dump();
    };
    write_csv(d / "abz.csv", l);
    Scenario sc = load_scenario(std::string(FRINGE_SOURCE_DIR) + "/fixtures/scenarios/fig10c-loopback.json");
    sc.sample_rate_hz = fs;
    sc.duration_s = 0.3;
    sc.settle_s = 0.01;
    sc.estimators = {{"atan2", "atan2", json::object(), std::nullopt}};
    sc.limits = {{"dut", "rms_rad", 0.03, std::nullopt, 0.0}, {"dut", "abz_illegal_transitions", 0.0, std::nullopt, 0.0}};
    sc.device = "capture:" + (d / "abz.csv");
    {
        // the factor is required
        const json r = execute_run(sc);
        CHECK(r["status"] == "error");
        CHECK_THAT(r["error"].get<std::string>(), Catch::Contains("interpolation=N"));
    }
    sc.device = "capture:" + (d / "abz.csv") + "?interpolation=16";
    json r = execute_run(sc);
    REQUIRE(r["status"] == "done");
    REQUIRE(r["estimators"].size() == 2);
    const json& dut = r["estimators"][1];
    CHECK(dut["label"] == "dut");
    const double step = kTwoPiT / 64;
    CHECK(dut["metrics"]["rms"]["rad"].get<double>() == Approx(step / std::sqrt(12.0)).epsilon(0.05));
    CHECK(dut["metrics"]["max_abs"]["rad"].get<double>() <= step / 2 * (1 + 1e-9));
    CHECK(dut["metrics"]["abz"]["illegal_transitions"] == 0);
    CHECK(dut["metrics"]["abz"]["reference"] == "index");
    CHECK(r["verdict"] == "PASS");
    CHECK(r["device"]["dut_position"] == true);
    // a glitch: the illegal transition fails the limit that names it, and is an error in the report
    for (std::size_t i = 15001; i < l.t.size(); ++i)
        if (l.a[i] != l.a[i - 1] || l.b[i] != l.b[i - 1]) {
            l.a[i] = 1 - l.a[i - 1];
            l.b[i] = 1 - l.b[i - 1];
            break;
        }
    write_csv(d / "abz.csv", l);
    r = execute_run(sc);
    REQUIRE(r["status"] == "done");
    CHECK(r["estimators"][1]["metrics"]["abz"]["illegal_transitions"].get<int>() >= 1);
    CHECK(r["verdict"] == "FAIL");
    bool warned = false;
    for (const auto& w : r["warnings"]) warned |= w["code"] == "dut_illegal_transitions" && w["severity"] == "error";
    CHECK(warned);
    // a Z pulse lost (no glitch): a missed index, named by its limit and warned
    l = ideal_dut(th, fs, N);
    const std::vector<double> z = l.z;
    std::size_t pulses = 0;
    for (std::size_t i = 1; i < z.size(); ++i) {
        if (z[i] && !z[i - 1]) ++pulses;
        if (z[i] && pulses == 50) l.z[i] = 0;
    }
    REQUIRE(pulses > 60);
    write_csv(d / "abz.csv", l);
    sc.limits = {{"dut", "abz_missed_index", 0.0, std::nullopt, 0.0}};
    r = execute_run(sc);
    REQUIRE(r["status"] == "done");
    CHECK(r["estimators"][1]["metrics"]["abz"]["missed_index"] == 1);
    CHECK(r["estimators"][1]["metrics"]["abz"]["index_errors"] == 0);
    CHECK(r["verdict"] == "FAIL");
    warned = false;
    for (const auto& w : r["warnings"]) warned |= w["code"] == "dut_missed_index";
    CHECK(warned);
}

TEST_CASE("service: a .sr upload is sniffed, stored and evaluated", "[service][sigrok]") {
    Dir d;
    GoodSession g(3000);
    // sin/cos only: the logic lines are named A0/B0 and not mapped (ignored)
    write_zip(d / "up.sr", g.entries);
    ServiceConfig c;
    c.data_dir = d / "data";
    c.fixtures_dir = FRINGE_SOURCE_DIR "/fixtures";
    c.web_dir = FRINGE_SOURCE_DIR "/web";
    c.token = "0123456789abcdef0123456789abcdef";
    c.workers = 1;
    c.max_upload_bytes = 8 << 20;
    Service s(c);
    auto req = [&](const std::string& m, const std::string& target, const std::string& body) {
        HttpRequest r;
        r.method = m;
        r.target = target;
        r.body = body;
        r.headers["authorization"] = "Bearer " + c.token;
        return s.handle(r);
    };
    const auto up = req("POST", "/api/v1/captures", read_file(d / "up.sr"));
    REQUIRE(up.status == 201);
    const json info = json::parse(up.body);
    CHECK(info["format"] == "sr");
    CHECK(info["samples"] == 3000);
    CHECK(info["sample_rate_hz"] == 1.5e6);
    const auto ev = req("POST", "/api/v1/captures/" + info["id"].get<std::string>() + "/evaluate", R"({"estimator":"atan2","settle_s":0})");
    CHECK(ev.status == 200);
    CHECK(json::parse(ev.body)["estimators"][0]["name"] == "atan2");
    CHECK(json::parse(ev.body)["capture"]["has_truth"] == false);  // no theta_true channel: estimates only, no verdict
    CHECK(json::parse(ev.body)["verdict"].is_null());
    // a damaged one: 400 bad_capture naming the problem, and nothing kept
    std::string broken = read_file(d / "up.sr");
    broken.resize(broken.size() / 2);
    const auto bad = req("POST", "/api/v1/captures", broken);
    CHECK(bad.status == 400);
    CHECK(json::parse(bad.body)["error"]["code"] == "bad_capture");
    CHECK_THAT(json::parse(bad.body)["error"]["message"].get<std::string>(), Catch::Contains("upload"));
    CHECK(json::parse(req("GET", "/api/v1/captures", "").body)["captures"].size() == 1);
}

TEST_CASE("sigrok: the expanded-size limit is the caller's and is checked before inflating", "[sigrok][capture][hostile]") {
    Dir d;
    const std::string meta = sr_meta("samplerate=100 kHz\ntotal analog=2\nanalog1=sin\nanalog2=cos\n");
    const std::vector<float> mib(1 << 18, 0.0f);  // 1 MiB of zeros per channel: a 2 KB archive
    write_zip(d / "z.sr", {{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", floats(mib)}, {"analog-1-2-1", floats(mib)}});
    REQUIRE(fs::file_size(d / "z.sr") < 20000);
    CaptureOptions o;
    o.max_expanded_bytes = 2 << 20;  // exactly what it holds
    CaptureReader r(d / "z.sr", o);
    CHECK(r.expanded_bytes() == 2u << 20);
    o.max_expanded_bytes = (2 << 20) - 1;
    try {
        CaptureReader too(d / "z.sr", o);
        FAIL("a capture over the limit was opened");
    } catch (const CaptureTooLarge& e) {
        CHECK(e.expanded_bytes == 2u << 20);
        CHECK(e.limit_bytes == (2u << 20) - 1);
        CHECK_THAT(std::string(e.what()), Catch::Contains("declares 2097152 bytes uncompressed (2 MiB), more than the 2 MiB allowed"));
    }
    // The channels not read do not count: sin and cos only, the third channel is ignored.
    const std::string meta3 = sr_meta("samplerate=100 kHz\ntotal analog=3\nanalog1=sin\nanalog2=cos\nanalog3=other\n");
    write_zip(d / "three.sr", {{"version", "2"}, {"metadata", meta3}, {"analog-1-1-1", floats(mib)}, {"analog-1-2-1", floats(mib)},
                               {"analog-1-3-1", floats(mib)}});
    o.max_expanded_bytes = 2 << 20;
    CHECK(CaptureReader(d / "three.sr", o).expanded_bytes() == 2u << 20);
}

TEST_CASE("service: uploads are validated block by block within an expanded-size limit and quota", "[service][sigrok][hostile]") {
    Dir d;
    const std::string meta = sr_meta("samplerate=100 kHz\ntotal analog=2\nanalog1=sin\nanalog2=cos\n");
    const std::vector<float> mib(1 << 18, 0.0f);
    write_zip(d / "z.sr", {{"version", "2"}, {"metadata", meta}, {"analog-1-1-1", floats(mib)}, {"analog-1-2-1", floats(mib)}});
    ServiceConfig c;
    c.data_dir = d / "data";
    c.fixtures_dir = FRINGE_SOURCE_DIR "/fixtures";
    c.web_dir = FRINGE_SOURCE_DIR "/web";
    c.token = "0123456789abcdef0123456789abcdef";
    c.workers = 1;
    c.max_upload_expanded_bytes = 1 << 20;
    c.upload_quota_bytes = 3 << 20;
    auto up = [&](Service& s, const std::string& body) {
        HttpRequest r;
        r.method = "POST";
        r.target = "/api/v1/captures";
        r.body = body;
        r.headers["authorization"] = "Bearer " + c.token;
        return s.handle(r);
    };
    const std::string zip = read_file(d / "z.sr");
    {
        Service s(c);
        const auto r = up(s, zip);
        CHECK(r.status == 413);
        const json e = json::parse(r.body)["error"];
        CHECK(e["code"] == "capture_too_large");
        CHECK_THAT(e["message"].get<std::string>(), Catch::Contains("upload: the sample data declares 2097152 bytes") &&
                                                         Catch::Contains("more than the 1 MiB allowed") && Catch::Contains("--max-upload-expanded-mb"));
    }
    c.max_upload_expanded_bytes = 2 << 20;
    Service s(c);
    const auto first = up(s, zip);
    REQUIRE(first.status == 201);
    const json info = json::parse(first.body);
    CHECK(info["samples"] == 1 << 18);
    CHECK(info["expanded_bytes"] == 2 << 20);
    CHECK(info["bytes"].get<std::uint64_t>() < 20000);
    // On disk the two together are a few KB; expanded they are 4 MiB, over the 3 MiB quota.
    const auto second = up(s, zip);
    CHECK(second.status == 507);
    CHECK(json::parse(second.body)["error"]["code"] == "quota_exceeded");
    CHECK_THAT(json::parse(second.body)["error"]["message"].get<std::string>(), Catch::Contains("expands to 2097152 bytes"));
    std::size_t kept = 0;
    for (const auto& e : fs::directory_iterator(d / "data/captures")) kept += e.path().extension() == ".sr";
    CHECK(kept == 1);
}

TEST_CASE("sigrok: an archive declaring a huge central directory is refused before libzip opens it", "[sigrok][capture][hostile]") {
    Dir d;
    GoodSession g(100);
    write_zip(d / "g.sr", g.entries);
    std::string s = read_file(d / "g.sr");
    const auto eocd = s.rfind(std::string("PK\x05\x06", 4));
    REQUIRE(eocd != std::string::npos);
    const std::uint32_t big = 17u << 20;  // the central directory's size
    std::memcpy(s.data() + eocd + 12, &big, 4);
    std::ofstream(d / "big.sr", std::ios::binary) << s;
    CHECK_THAT(error_of(d / "big.sr"), Catch::Contains("a central directory of 17825792 bytes (at most 65536 entries and 16 MiB)"));
}

}  // namespace test_sigrok_cpp
