// fringe devices: drivers and their settings, board profiles, and what is reachable.
#include "server/cli/commands.hpp"
#include "drivers/device.hpp"
#include "drivers/modbus_board.hpp"
#include "signal_gen/base/text.hpp"

#include <cstdio>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct DevicesOptions {
    std::vector<std::string> probe;
    bool as_json = false;
};

int run_devices(const DevicesOptions& o) {
    json out{{"drivers", dev::drivers()}, {"boards", json::array()}, {"reachable", json::array()}};
    for (const auto& name : dev::board_names()) {
        try {
            const auto b = dev::load_board(name);
            out["boards"].push_back({{"name", b.name}, {"kind", b.kind}, {"description", b.description}, {"dut_position", b.has_dut_position()}});
        } catch (const std::exception& e) {
            out["boards"].push_back({{"name", name}, {"problem", e.what()}});
        }
    }
    out["reachable"].push_back({{"uri", "loopback:"}, {"ok", true}, {"description", "simulated converter chain"}});
    for (const auto& d : dev::drivers())
        if (d.find)
            for (auto found : d.find()) {
                found["ok"] = true;
                out["reachable"].push_back(found);
            }
    int rc = kExitOk;
    for (const auto& uri : o.probe) {
        try {
            auto d = dev::open(uri);
            out["reachable"].push_back({{"uri", uri}, {"ok", true}, {"info", d->info()}});
        } catch (const std::exception& e) {
            out["reachable"].push_back({{"uri", uri}, {"ok", false}, {"error", e.what()}});
            rc = kExitError;
        }
    }
    if (o.as_json) {
        std::printf("%s\n", out.dump(2).c_str());
        return rc;
    }
    std::printf("drivers:\n");
    for (const auto& d : dev::drivers()) {
        std::printf("  %-12s %s\n", d.scheme.c_str(), d.summary.c_str());
        for (const auto& p : d.settings) {
            json pj = p;
            std::printf("      %-16s %-8s default %s  %s\n", p.name.c_str(), p.unit.empty() ? "-" : p.unit.c_str(),
                        p.default_value.is_null() ? "derived" : p.default_value.dump().c_str(), p.description.c_str());
        }
    }
    std::printf("board profiles (%s):\n", dev::boards_dir().c_str());
    for (const auto& b : out["boards"])
        std::printf("  %-20s %s\n", term_escape(b["name"].get<std::string>()).c_str(),
                    term_escape(b.contains("problem") ? b["problem"].get<std::string>() : b["description"].get<std::string>()).c_str());
    std::printf("reachable:\n");
    // A board's id may be an instrument's *IDN?: escaped for the terminal, like the errors.
    for (const auto& r : out["reachable"])
        std::printf("  %-40s %s\n", term_escape(r["uri"].get<std::string>()).c_str(),
                    term_escape(r["ok"].get<bool>() ? (r.contains("info") ? r["info"]["board_id"].get<std::string>()
                                                                          : r.contains("board_id") ? r["board_id"].get<std::string>() : "ok")
                                                    : r["error"].get<std::string>()).c_str());
    return rc;
}

}  // namespace

Command add_devices(CLI::App& app) {
    auto o = std::make_shared<DevicesOptions>();
    auto* dv = app.add_subcommand("devices", "List drivers with their settings, board profiles, and what is reachable");
    dv->add_option("--probe", o->probe, "Also open this device URI and report it (repeatable)");
    dv->add_flag("--json", o->as_json, "As JSON");
    return {dv, [o] { return run_devices(*o); }};
}

}  // namespace fringe::cli
