// The fringe command line's main(), shared by `fringe` and `fringe-usb-sim` (main.cpp): compiled
// once in fringe_cli, where CLI11 and spdlog are already compiled, instead of once per executable.
#pragma once

namespace fringe::cli {
// Sets up logging, parses the command line and runs the subcommand; returns the exit code.
int run_main(int argc, char** argv);
}  // namespace fringe::cli
