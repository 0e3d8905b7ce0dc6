// Fuzz target (c): scenario and encoder JSON (scenario_from_json, encoder_from_json). Input:
// any bytes. Promises: bad input is a ConfigError; what is accepted serializes and reads
// back to the same JSON (reports store scenarios that way) and generates samples without
// a crash or a non-finite value.
#include "fuzz_common.hpp"

#include "server/engine/scenario.hpp"
#include "signal_gen/base/config.hpp"
#include "signal_gen/generator.hpp"
#include "signal_gen/base/json_bounded.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string_view>

using nlohmann::json;
using namespace fringe;

namespace {
const std::string kFixtures = FRINGE_SOURCE_DIR "/fixtures/scenarios";

void check_samples(const Scenario& s) {
    Generator gen(s.encoder, s.motion, s.sample_rate_hz, s.seed, s.t0_s);
    Block b;
    const std::uint64_t total = s.samples();
    for (const std::uint64_t first : {std::uint64_t{0}, total > 64 ? total - 64 : std::uint64_t{0}}) {
        b.resize(static_cast<std::size_t>(std::min<std::uint64_t>(64, total)), s.encoder.index.enabled);
        gen.generate(first, b);
        for (std::size_t i = 0; i < b.size(); ++i)
            if (!std::isfinite(b.sin_v[i]) || !std::isfinite(b.cos_v[i]) || !std::isfinite(b.theta_rad[i]))
                fuzz::fail("accepted scenario generates a non-finite sample at " + std::to_string(first + i) + ": " + json(s).dump());
    }
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    // As the command line reads a scenario file: nesting bounded, no key twice.
    json j;
    try {
        j = parse_json_bounded(std::string_view(reinterpret_cast<const char*>(data), size), "input");
    } catch (const ConfigError&) {
        return 0;
    }
    try {
        const Scenario s = scenario_from_json(j, kFixtures);
        const json once = s;
        const json twice = scenario_from_json(once, kFixtures);
        if (twice != once) fuzz::fail("scenario does not round-trip: " + once.dump() + " vs " + twice.dump());
        check_samples(s);
    } catch (const ConfigError&) {
    } catch (const std::exception& e) {
        fuzz::unexpected(e);
    }
    try {
        const EncoderProfile e = encoder_from_json(j, "encoder");
        const json once = e;
        const json twice = encoder_from_json(once, "encoder");
        if (twice != once) fuzz::fail("encoder does not round-trip: " + once.dump() + " vs " + twice.dump());
    } catch (const ConfigError&) {
    } catch (const std::exception& e) {
        fuzz::unexpected(e);
    }
    return 0;
}
