#include "server/engine/provenance.hpp"

#include "server/engine/scenario.hpp"

#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <pwd.h>
#include <unistd.h>

#ifndef FRINGE_VERSION
#define FRINGE_VERSION "dev"
#endif

namespace fringe {

using nlohmann::json;

namespace {
std::string env(const char* name) {
    const char* v = std::getenv(name);
    return v ? v : "";
}

constexpr std::array<std::uint32_t, 64> kK = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5, 0xd807aa98, 0x12835b01, 0x243185be,
    0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174, 0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa,
    0x5cb0a9dc, 0x76f988da, 0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967, 0x27b70a85,
    0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85, 0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3,
    0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070, 0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f,
    0x682e6ff3, 0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};
inline std::uint32_t rotr(std::uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }

void sha256_block(std::array<std::uint32_t, 8>& h, const unsigned char* p) {
    std::uint32_t w[64];
    for (int i = 0; i < 16; ++i)
        w[i] = (std::uint32_t(p[4 * i]) << 24) | (std::uint32_t(p[4 * i + 1]) << 16) | (std::uint32_t(p[4 * i + 2]) << 8) | p[4 * i + 3];
    for (int i = 16; i < 64; ++i) {
        const std::uint32_t s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >> 3);
        const std::uint32_t s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >> 10);
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    std::uint32_t a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], k = h[7];
    for (int i = 0; i < 64; ++i) {
        const std::uint32_t t1 = k + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + kK[i] + w[i];
        const std::uint32_t t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
        k = g; g = f; f = e; e = d + t1; d = c; c = b; b = a; a = t1 + t2;
    }
    h[0] += a; h[1] += b; h[2] += c; h[3] += d; h[4] += e; h[5] += f; h[6] += g; h[7] += k;
}
}  // namespace

std::string sha256_hex(std::string_view data) {
    std::array<std::uint32_t, 8> h = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
    const auto* p = reinterpret_cast<const unsigned char*>(data.data());
    std::size_t n = data.size();
    while (n >= 64) { sha256_block(h, p); p += 64; n -= 64; }
    unsigned char tail[128] = {};
    std::copy(p, p + n, tail);
    tail[n] = 0x80;
    const std::size_t len = n + 9 <= 64 ? 64 : 128;
    const std::uint64_t bits = static_cast<std::uint64_t>(data.size()) * 8;
    for (int i = 0; i < 8; ++i) tail[len - 1 - i] = static_cast<unsigned char>(bits >> (8 * i));
    sha256_block(h, tail);
    if (len == 128) sha256_block(h, tail + 64);
    char out[65];
    for (int i = 0; i < 8; ++i) std::snprintf(out + 8 * i, 9, "%08x", h[i]);
    return std::string(out, 64);
}

std::string canonical_json(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

namespace {
// PostgreSQL's jsonb keeps numbers as numeric, which has no negative zero and no exponent:
// -0.0 comes back as 0, and 1e+18 as 1000000000000000000 (read back as an integer). The
// checksum is of the form that survives jsonb: a whole-valued double within 64 bits is hashed
// as that integer (-0.0 as 0), so a report read back from the store still matches its own.
void jsonb_form(json& j) {
    if (j.is_number_float()) {
        const double x = j.get<double>();
        if (std::isfinite(x) && x == std::trunc(x)) {
            if (x >= 0 && x < 18446744073709551616.0) j = static_cast<std::uint64_t>(x);
            else if (x < 0 && x >= -9223372036854775808.0) j = static_cast<std::int64_t>(x);
        }
    } else if (j.is_structured()) {
        for (auto& v : j) jsonb_form(v);
    }
}
}  // namespace

std::string report_checksum(const json& report) {
    json r = report;
    for (const char* k : {"started_at", "finished_at", "wall_s", "provenance"}) r.erase(k);
    jsonb_form(r);
    return sha256_hex(canonical_json(r));
}

ProvenanceDefaults provenance_defaults() {
    ProvenanceDefaults d;
    char host[256] = {};
    if (gethostname(host, sizeof host - 1) == 0) d.host = host;
    d.bench = env("FRINGE_BENCH");
    if (d.bench.empty()) d.bench = d.host;
    d.operator_name = env("USER");
    if (d.operator_name.empty()) d.operator_name = env("LOGNAME");
    if (d.operator_name.empty())
        if (const passwd* pw = getpwuid(geteuid()); pw && pw->pw_name) d.operator_name = pw->pw_name;  // a service or cron job has no $USER
    return d;
}

json make_provenance(const ProvenanceDefaults& d, const Scenario& sc) {
    return {{"bench", d.bench},
            {"host", d.host},
            {"dut", {{"serial", sc.dut.empty() ? d.dut : sc.dut}, {"part", sc.dut_part.empty() ? d.dut_part : sc.dut_part}}},
            {"operator", d.operator_name},
            {"fringe_version", FRINGE_VERSION},
            {"scenario_sha256", sha256_hex(canonical_json(json(sc)))}};
}

std::string new_uuid7() {
    const auto ms = static_cast<std::uint64_t>(
        std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch()).count());
    static thread_local std::mt19937_64 rng{(static_cast<std::uint64_t>(std::random_device{}()) << 32) ^ std::random_device{}()};
    const std::uint64_t r1 = rng(), r2 = rng();
    unsigned char b[16];
    for (int i = 0; i < 6; ++i) b[i] = static_cast<unsigned char>(ms >> (8 * (5 - i)));
    b[6] = static_cast<unsigned char>(0x70 | ((r1 >> 8) & 0x0f));  // version 7
    b[7] = static_cast<unsigned char>(r1);
    b[8] = static_cast<unsigned char>(0x80 | ((r2 >> 56) & 0x3f));  // variant 10
    for (int i = 9; i < 16; ++i) b[i] = static_cast<unsigned char>(r2 >> (8 * (15 - i)));
    char out[37];
    std::snprintf(out, sizeof out, "%02x%02x%02x%02x-%02x%02x-%02x%02x-%02x%02x-%02x%02x%02x%02x%02x%02x", b[0], b[1], b[2], b[3], b[4], b[5], b[6],
                  b[7], b[8], b[9], b[10], b[11], b[12], b[13], b[14], b[15]);
    return out;
}

}  // namespace fringe
