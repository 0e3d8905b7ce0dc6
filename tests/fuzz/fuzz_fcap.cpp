// Fuzz target (a): the .fcap reader and `fringe estimate` on what it reads. Input: the file.
#include "capture_check.hpp"

#include <cstdint>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string path = fringe::fuzz::scratch_dir() + "/in.fcap";
    fringe::fuzz::write_file(path, reinterpret_cast<const char*>(data), size);
    fringe::fuzz::check_capture(path);
    return 0;
}
