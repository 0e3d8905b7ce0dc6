// Fuzz target (e): the sigrok session (.sr) reader, the ABZ readout and `fringe estimate` on
// what they read. Input: either a ZIP file as is (starts with "PK"), or a list of entries
// "@@NAME\n<bytes>" that this target packs into a ZIP with libzip, so the mutations reach the
// metadata, chunk naming and sizes behind the archive layer (a raw ZIP's CRCs stop most).
#include "capture_check.hpp"

#include <zip.h>

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace {

void pack(std::string_view in, const std::string& path) {
    std::filesystem::remove(path);
    int err = 0;
    zip_t* za = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
    if (!za) fringe::fuzz::fail("zip_open for writing failed");
    std::vector<std::string> keep;  // read by libzip at zip_close
    keep.reserve(64);
    std::size_t pos = in.find("@@");
    while (pos != std::string_view::npos && keep.size() < 64) {
        const std::size_t nl = in.find('\n', pos);
        if (nl == std::string_view::npos) break;
        const std::string name(in.substr(pos + 2, nl - pos - 2));
        std::size_t next = in.find("\n@@", nl + 1);
        const std::size_t end = next == std::string_view::npos ? in.size() : next;
        keep.emplace_back(in.substr(nl + 1, end - nl - 1));
        zip_source_t* src = zip_source_buffer(za, keep.back().data(), keep.back().size(), 0);
        // A name libzip refuses (empty, a duplicate) is left out: the reader is under test.
        if (src && zip_file_add(za, name.c_str(), src, ZIP_FL_ENC_RAW) < 0) zip_source_free(src);
        pos = next == std::string_view::npos ? next : next + 1;
    }
    if (zip_close(za) != 0) {
        zip_discard(za);
        fringe::fuzz::write_file(path, "", 0);
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string path = fringe::fuzz::scratch_dir() + "/in.sr";
    const std::string_view in(reinterpret_cast<const char*>(data), size);
    if (in.substr(0, 2) == "PK") fringe::fuzz::write_file(path, in.data(), in.size());
    else pack(in, path);
    fringe::fuzz::check_capture(path);
    return 0;
}
