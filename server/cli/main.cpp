// The fringe command line: each subcommand lives in server/cli/cmd_*.cpp, main() in
// main_cli.cpp (compiled once for both executables). Exit codes: 0 success/pass, 1 fail, 2 error.
#include "server/cli/main_cli.hpp"

#ifdef FRINGE_WITH_USB_EMULATOR
#include "drivers/sim/usb_emulator.hpp"
#include "signal_gen/base/text.hpp"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <memory>
#include <string>
#include <unistd.h>
#endif

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
    std::unique_ptr<fringe::dev::UsbEmulator> usb_emulator;
    try {
        const char* spec = std::getenv("FRINGE_USB_EMULATOR");
        usb_emulator = std::make_unique<fringe::dev::UsbEmulator>(fringe::dev::parse_usb_emulator_options(spec ? spec : ""));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", fringe::term_escape(e.what(), true).c_str());
        return 2;
    }
#endif
    return fringe::cli::run_main(argc, argv);
}
