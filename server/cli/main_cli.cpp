// The body of the fringe command line's main() (main_cli.hpp).
#include "server/cli/main_cli.hpp"

#include "server/cli/commands.hpp"
#include "signal_gen/base/text.hpp"

#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <memory>
#include <string>
#include <vector>

namespace fringe::cli {
namespace main_cli_cpp {
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
}  // namespace main_cli_cpp

int run_main(int argc, char** argv) {
    auto logger = spdlog::stderr_color_mt("fringe");
    spdlog::set_default_logger(logger);
    auto formatter = std::make_unique<spdlog::pattern_formatter>();
    formatter->add_flag<main_cli_cpp::TerminalPayload>('*').set_pattern("%^%l%$: %*");
    logger->set_formatter(std::move(formatter));

    CLI::App app{"fringe: hardware-in-the-loop test bench for sin/cos encoder interpolation"};
    app.set_version_flag("--version", std::string("fringe ") + FRINGE_VERSION);
    app.require_subcommand(1);
    const std::vector<Command> commands{add_gen(app),   add_estimate(app), add_run(app),       add_runs(app),
                                        add_sweep(app), add_serve(app),    add_board_sim(app), add_devices(app),
                                        add_instrument_sim(app), add_metrics(app), add_calibrate(app),
                                        add_write_correction(app)};

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        int rc = app.exit(e);
        return rc == 0 ? 0 : kExitError;
    }
    try {
        for (const auto& c : commands)
            if (*c.sub) return c.run();
    } catch (const std::exception& e) {  // ConfigError names the file and field
        spdlog::error("{}", e.what());
        return kExitError;
    }
    return kExitError;
}
}  // namespace fringe::cli
