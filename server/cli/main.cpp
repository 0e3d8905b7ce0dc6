// The fringe command line: each subcommand lives in server/cli/cmd_*.cpp. Exit codes: 0
// success/pass, 1 fail, 2 error.
#include "server/cli/commands.hpp"

#ifdef FRINGE_WITH_USB_EMULATOR
#include "drivers/sim/usb_emulator.hpp"
#include <cstring>
#endif

#include "signal_gen/base/text.hpp"

#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

using namespace fringe;

namespace {
// Errors and warnings carry text from devices, files and clients (instrument error queues,
// *IDN?, scenario names): escaped for the terminal, so none of it acts on the operator's screen.
class TerminalPayload : public spdlog::custom_flag_formatter {
public:
    void format(const spdlog::details::log_msg& msg, const std::tm&, spdlog::memory_buf_t& dest) override {
        const std::string e = term_escape(std::string_view(msg.payload.data(), msg.payload.size()), true);
        dest.append(e.data(), e.data() + e.size());
    }
    std::unique_ptr<custom_flag_formatter> clone() const override { return std::make_unique<TerminalPayload>(); }
};
}  // namespace

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
        std::fprintf(stderr, "error: %s\n", term_escape(e.what(), true).c_str());
        return 2;
    }
#endif
    auto logger = spdlog::stderr_color_mt("fringe");
    spdlog::set_default_logger(logger);
    auto formatter = std::make_unique<spdlog::pattern_formatter>();
    formatter->add_flag<TerminalPayload>('*').set_pattern("%^%l%$: %*");
    logger->set_formatter(std::move(formatter));

    CLI::App app{"fringe: hardware-in-the-loop test bench for sin/cos encoder interpolation"};
    app.set_version_flag("--version", std::string("fringe ") + FRINGE_VERSION);
    app.require_subcommand(1);
    const std::vector<cli::Command> commands{cli::add_gen(app),   cli::add_estimate(app), cli::add_run(app),       cli::add_runs(app),
                                             cli::add_sweep(app), cli::add_serve(app),    cli::add_board_sim(app), cli::add_devices(app),
                                             cli::add_instrument_sim(app), cli::add_metrics(app), cli::add_calibrate(app),
                                             cli::add_write_correction(app)};

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
