// A test's own writer of sigrok session files (.sr: a ZIP of version, metadata and sample
// chunks; docs/capture-format.md), so tests build captures no decoder has seen.
#pragma once

#include <zip.h>

#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace fringe::test {

// A ZIP written with libzip, entries in the given order. Throws std::runtime_error.
inline void write_zip(const std::string& path, const std::vector<std::pair<std::string, std::string>>& entries) {
    std::filesystem::remove(path);
    int err = 0;
    zip_t* za = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &err);
    if (!za) throw std::runtime_error("zip_open " + path + " failed: " + std::to_string(err));
    std::vector<std::string> keep;  // libzip reads the buffers at zip_close
    keep.reserve(entries.size());
    for (const auto& [name, data] : entries) {
        keep.push_back(data);
        zip_source_t* src = zip_source_buffer(za, keep.back().data(), keep.back().size(), 0);
        if (!src || zip_file_add(za, name.c_str(), src, ZIP_FL_ENC_RAW) < 0) {
            if (src) zip_source_free(src);
            zip_discard(za);
            throw std::runtime_error("zip: cannot add " + name + " to " + path);
        }
    }
    if (zip_close(za) != 0) throw std::runtime_error("zip_close " + path + " failed");
}

// Logic channels (each a vector of 0/1 of the same length, at most 8) as a .sr session at rate_hz,
// channel k named names[k] (probe k+1).
inline void write_logic_sr(const std::string& path, double rate_hz, const std::vector<std::string>& names,
                           const std::vector<const std::vector<double>*>& lines) {
    const std::size_t n = lines.empty() ? 0 : lines[0]->size();
    std::string data(n, '\0');
    for (std::size_t k = 0; k < lines.size(); ++k)
        for (std::size_t i = 0; i < n; ++i)
            if ((*lines[k])[i] != 0) data[i] = static_cast<char>(data[i] | (1 << k));
    std::string meta = "[global]\nsigrok version=0.5.2\n\n[device 1]\ncapturefile=logic-1\ntotal probes=" + std::to_string(names.size()) +
                       "\nsamplerate=" + std::to_string(static_cast<long long>(rate_hz)) + "\nunitsize=1\n";
    for (std::size_t k = 0; k < names.size(); ++k) meta += "probe" + std::to_string(k + 1) + "=" + names[k] + "\n";
    write_zip(path, {{"version", "2"}, {"metadata", meta}, {"logic-1-1", data}});
}

}  // namespace fringe::test
