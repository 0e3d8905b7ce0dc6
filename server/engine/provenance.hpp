// Where a run came from, for a store shared by many benches (docs/schema.md "provenance"):
// bench, host, DUT serial and part, operator, fringe version and a checksum of the scenario;
// plus the helpers the shared store needs (SHA-256, canonical JSON, UUIDv7 run ids).
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <string_view>

namespace fringe {

struct Scenario;

// Per process (fringe run options) or per service (fringe serve options); a scenario's own
// "dut" / "dut_part" keys win over dut / dut_part here.
struct ProvenanceDefaults {
    std::string bench;     // default $FRINGE_BENCH, else the host name
    std::string host;      // gethostname()
    std::string dut;       // DUT serial
    std::string dut_part;  // DUT part number
    std::string operator_name;  // default $USER, else $LOGNAME, else ""
};
ProvenanceDefaults provenance_defaults();

// {"bench","host","dut":{"serial","part"},"operator","fringe_version","scenario_sha256"}.
nlohmann::json make_provenance(const ProvenanceDefaults& d, const Scenario& sc);

// Lower-case hex SHA-256 (FIPS 180-4).
std::string sha256_hex(std::string_view data);
// Keys sorted (nlohmann's object is ordered by key), no whitespace, invalid UTF-8 replaced.
std::string canonical_json(const nlohmann::json& j);
// The checksum that decides "same report" when a run is forwarded: SHA-256 of the canonical
// report without what differs between two executions of the same run (started_at,
// finished_at, wall_s, provenance), so a retried deterministic sweep row is the same report.
std::string report_checksum(const nlohmann::json& report);

// RFC 9562 UUIDv7: 48 bits of Unix milliseconds then 74 random bits. Unique across hosts
// without coordination, and its text sorts by creation time.
std::string new_uuid7();

}  // namespace fringe
