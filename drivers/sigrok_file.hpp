// sigrok session files (.sr, docs/capture-format.md "sigrok session files"), read with libzip:
// a ZIP holding `version` ("1" or "2"), an INI `metadata` ([device 1]: samplerate, total
// probes, total analog, probeN / analogK channel names, unitsize) and the sample chunks
// `logic-1-N` (packed logic, unitsize bytes per sample, probe k in bit k-1) and
// `analog-1-K-N` (float32 little-endian, channel analogK), N = 1, 2, ... in order.
//
// fringe columns are taken from channels by name: a column's channel is named like the column
// (sin, cos, theta_true, omega_true, index: analog; a, b, z: logic) unless a channel map names
// another. Chunks are streamed per channel; nothing is decompressed beyond an entry's declared
// size, and the declared sizes together are capped (zip bombs: max_data_bytes, CaptureTooLarge),
// as is the number of entries (libzip keeps each in memory), so memory and time stay bounded.
// Malformed files throw CaptureError naming the file and the problem.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace fringe {

constexpr std::uint64_t kSigrokMaxMetadataBytes = 1u << 20;
// Entries in one archive, and bytes of its central directory, at most, checked before libzip
// opens it (sigrok writes one entry per chunk of a channel; libzip holds every entry in memory,
// about 300 bytes each: 262 144 tiny entries, a 28 MB file, took it 80 MB).
constexpr std::uint64_t kSigrokMaxEntries = 1u << 16;
constexpr std::uint64_t kSigrokMaxDirectoryBytes = 16u << 20;

class SigrokSession {
public:
    // columns: the fringe columns to look for, each "analog" or "logic" (the logic ones are a,
    // b, z). channel_for: column -> channel name where it differs from the column's name; a
    // column named there must exist, the others are optional here (the caller checks which
    // are required).
    // max_data_bytes: the declared (uncompressed) sample data of the channels read, all chunks
    // together, at most; more is refused with CaptureTooLarge before anything is inflated.
    SigrokSession(const std::string& path, const std::map<std::string, std::string>& channel_for, std::uint64_t max_data_bytes);
    ~SigrokSession();
    SigrokSession(const SigrokSession&) = delete;
    SigrokSession& operator=(const SigrokSession&) = delete;

    double sample_rate_hz() const { return fs_hz_; }
    std::uint64_t frames() const { return frames_; }
    // Declared uncompressed bytes of the sample data read (all channels read, all chunks).
    std::uint64_t data_bytes() const { return data_bytes_; }
    bool has(const std::string& column) const;
    // The session's channels, "name (analogK)" / "name (probeN)", for messages and metadata.
    const std::vector<std::string>& channel_list() const { return channel_list_; }
    // Next n frames (n <= frames left) of every present column, appended to out[column].
    void read(std::size_t n, std::map<std::string, std::vector<double>>& out);

    struct Impl;

private:
    std::unique_ptr<Impl> impl_;
    double fs_hz_ = 0;
    std::uint64_t frames_ = 0;
    std::uint64_t data_bytes_ = 0;
    std::vector<std::string> channel_list_;
};

// True for the columns read from logic channels (a, b, z).
bool sigrok_logic_column(const std::string& column);

}  // namespace fringe
