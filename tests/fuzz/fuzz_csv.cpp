// Fuzz target (b): the CSV reader with its JSON sidecar, and `fringe estimate` on what it
// reads. Input: the CSV bytes, optionally followed by "\n#sidecar\n" and the sidecar's bytes.
#include "capture_check.hpp"

#include <cstdint>
#include <string_view>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string dir = fringe::fuzz::scratch_dir();
    const std::string_view in(reinterpret_cast<const char*>(data), size);
    constexpr std::string_view kSep = "\n#sidecar\n";
    const auto sep = in.find(kSep);
    const std::string_view csv = in.substr(0, sep);
    fringe::fuzz::write_file(dir + "/in.csv", csv.data(), csv.size());
    std::error_code ec;
    if (sep == std::string_view::npos) {
        std::filesystem::remove(dir + "/in.json", ec);
    } else {
        const std::string_view side = in.substr(sep + kSep.size());
        fringe::fuzz::write_file(dir + "/in.json", side.data(), side.size());
    }
    fringe::fuzz::check_capture(dir + "/in.csv");
    return 0;
}
