// The fringe command line: each subcommand lives in server/cli/cmd_*.cpp. Exit codes: 0
// success/pass, 1 fail, 2 error.
#include "server/cli/commands.hpp"

#ifdef FRINGE_WITH_USB_EMULATOR
#include "drivers/usb_emulator.hpp"
#include <cstring>
#endif

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

using namespace fringe;

int main(int argc, char** argv) {
#ifdef FRINGE_WITH_USB_EMULATOR
    // fringe-usb-sim: the fringe CLI with an emulated USB board in this process (umockdev;
    // options from $FRINGE_USB_EMULATOR, e.g. "drop_at=40,unplug_after=200"). umockdev's
    // preload must be there from the start: re-exec with it.
    if (const char* pre = std::getenv("LD_PRELOAD"); !pre || !std::strstr(pre, "libumockdev-preload")) {
        setenv("LD_PRELOAD", "libumockdev-preload.so.0", 1);
        const char* asan = std::getenv("ASAN_OPTIONS");
        setenv("ASAN_OPTIONS", (std::string(asan ? asan : "") + ":verify_asan_link_order=0").c_str(), 1);
        execv("/proc/self/exe", argv);
        std::perror("fringe-usb-sim: re-exec under umockdev's preload");
        return 2;
    }
    std::unique_ptr<dev::UsbEmulator> usb_emulator;
    try {
        const char* spec = std::getenv("FRINGE_USB_EMULATOR");
        usb_emulator = std::make_unique<dev::UsbEmulator>(dev::parse_usb_emulator_options(spec ? spec : ""));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 2;
    }
#endif
    auto logger = spdlog::stderr_color_mt("fringe");
    spdlog::set_default_logger(logger);
    spdlog::set_pattern("%^%l%$: %v");

    CLI::App app{"fringe: hardware-in-the-loop test bench for sin/cos encoder interpolation"};
    app.set_version_flag("--version", std::string("fringe ") + FRINGE_VERSION);
    app.require_subcommand(1);
    const std::vector<cli::Command> commands{cli::add_gen(app),   cli::add_estimate(app), cli::add_run(app),       cli::add_runs(app),
                                             cli::add_sweep(app), cli::add_serve(app),    cli::add_board_sim(app), cli::add_devices(app),
                                             cli::add_instrument_sim(app)};

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        int rc = app.exit(e);
        return rc == 0 ? 0 : cli::kExitError;
    }
    try {
        for (const auto& c : commands)
            if (*c.sub) return c.run();
    } catch (const std::exception& e) {  // ConfigError names the file and field
        spdlog::error("{}", e.what());
        return cli::kExitError;
    }
    return cli::kExitError;
}
