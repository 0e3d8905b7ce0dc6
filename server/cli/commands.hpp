// The fringe subcommands, one file each (server/cli/cmd_*.cpp).
#pragma once

#include "common.hpp"

namespace fringe::cli {

Command add_gen(CLI::App& app);
Command add_estimate(CLI::App& app);
Command add_run(CLI::App& app);
Command add_runs(CLI::App& app);
Command add_sweep(CLI::App& app);
Command add_serve(CLI::App& app);
Command add_board_sim(CLI::App& app);
Command add_devices(CLI::App& app);
Command add_instrument_sim(CLI::App& app);
Command add_metrics(CLI::App& app);
Command add_calibrate(CLI::App& app);
Command add_write_correction(CLI::App& app);

}  // namespace fringe::cli
