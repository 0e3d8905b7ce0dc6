#include "device.hpp"

#include "signal_gen/config.hpp"

namespace fringe::dev {

void register_loopback(std::vector<DriverInfo>& r);
void register_capture(std::vector<DriverInfo>& r);
void register_modbus(std::vector<DriverInfo>& r);
void register_usb(std::vector<DriverInfo>& r);
void register_scpi(std::vector<DriverInfo>& r);

const char* to_string(StreamStatus s) {
    switch (s) {
        case StreamStatus::Ok: return "ok";
        case StreamStatus::Timeout: return "timeout";
        case StreamStatus::Overflow: return "overflow";
        case StreamStatus::Underflow: return "underflow";
        case StreamStatus::Error: return "error";
    }
    return "?";
}

void to_json(nlohmann::json& j, const DeviceInfo& d) {
    j = {{"driver", d.driver}, {"uri", d.uri}, {"description", d.description}, {"board_id", d.board_id},
         {"streaming", d.streaming}, {"step_mode", d.step_mode}, {"dut_position", d.dut_position},
         {"latency_samples", d.latency_samples}, {"settings", d.settings}, {"converter", d.converter}};
    if (d.can_play || d.can_record) {
        j["can_play"] = d.can_play;
        j["can_record"] = d.can_record;
        j["own_clock"] = d.own_clock;
        j["max_play_samples"] = d.max_play_samples;
    }
}

void to_json(nlohmann::json& j, const ConverterInfo& c) {
    j = {{"known", c.known}, {"dac_bits", c.dac_bits}, {"dac_range_v", c.dac_range_v}, {"adc_bits", c.adc_bits},
         {"adc_range_v", c.adc_range_v}, {"dac_step_v", c.dac_q_v()}, {"adc_step_v", c.adc_q_v()}, {"noise_at_adc_v", c.noise_at_adc_v}, {"added_noise_v", c.added_noise_v}};
    if (!c.note.empty()) j["note"] = c.note;
}

void to_json(nlohmann::json& j, const DriverInfo& d) {
    j = {{"scheme", d.scheme}, {"summary", d.summary}, {"settings", d.settings}};
}

const std::vector<DriverInfo>& drivers() {
    static const std::vector<DriverInfo> all = [] {
        std::vector<DriverInfo> r;
        register_loopback(r);
        register_capture(r);
        register_modbus(r);
        register_usb(r);
        register_scpi(r);
        return r;
    }();
    return all;
}

namespace {
struct ParsedUri {
    const DriverInfo* drv;
    std::string path;
    nlohmann::json settings;
};

ParsedUri parse_uri(const std::string& uri) {
    const auto colon = uri.find(':');
    if (colon == std::string::npos || colon == 0)
        throw ConfigError("device", "'" + uri + "' is not a device URI (scheme:path?key=value, e.g. loopback:)");
    const std::string scheme = uri.substr(0, colon);
    std::string rest = uri.substr(colon + 1), query;
    if (const auto q = rest.find('?'); q != std::string::npos) {
        query = rest.substr(q + 1);
        rest = rest.substr(0, q);
    }
    const DriverInfo* drv = nullptr;
    for (const auto& d : drivers())
        if (d.scheme == scheme) drv = &d;
    if (!drv) {
        std::string known;
        for (const auto& d : drivers()) known += (known.empty() ? "" : ", ") + d.scheme;
        throw ConfigError("device", "unknown driver '" + scheme + "' (known: " + known + ")");
    }
    std::vector<std::string> kv;
    std::size_t pos = 0;
    while (pos < query.size()) {
        auto amp = query.find('&', pos);
        if (amp == std::string::npos) amp = query.size();
        if (amp > pos) kv.push_back(query.substr(pos, amp - pos));
        pos = amp + 1;
    }
    const nlohmann::json given = parse_param_assignments(drv->settings, kv, "device");
    const Params p = resolve_params(drv->settings, given, "device");
    return {drv, rest, p.json()};
}
}  // namespace

UriParts check_uri(const std::string& uri) {
    auto p = parse_uri(uri);
    return {p.drv->scheme, p.path, p.settings};
}

std::unique_ptr<Device> open(const std::string& uri) {
    auto p = parse_uri(uri);
    return p.drv->open(uri, p.path, p.settings);
}

}  // namespace fringe::dev
