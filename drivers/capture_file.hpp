// Capture files (docs/capture-format.md):
//  - CSV: header row, columns t (s), sin, cos (V), optional theta_true (rad, unwrapped
//    electrical phase), omega_true (rad/s), index (V); a JSON sidecar <stem>.json beside it.
//  - Binary .fcap: magic "FRNGCAP1", u32 LE header length, JSON header, then fixed-size
//    little-endian frames; time is implicit (t0_s + k/sample_rate_hz).
//  - sigrok session .sr (sigrok_file.hpp): channels mapped to columns by name, an optional
//    sidecar <stem>.json as for CSV; time is implicit.
//  - Optional digital columns a, b, z (0 or 1): a DUT's quadrature output (drivers/abz.hpp).
// Malformed input throws CaptureError naming file and line (or frame). The readers check
// the header before reading a sample (docs/capture-format.md "What the readers check"):
// every present column has exactly one value per frame.
#pragma once

#include "signal_gen/generator.hpp"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace fringe {

class SigrokSession;

class CaptureError : public std::runtime_error {
public:
    // Messages quote file contents: bytes that are not valid UTF-8, and control characters,
    // become \xNN, so a message is always valid UTF-8 (JSON error bodies, terminals).
    explicit CaptureError(const std::string& message);
};

// A capture whose sample data would expand beyond CaptureOptions::max_expanded_bytes: refused
// before any of it is decompressed (ZIP bombs). The message names both sizes.
class CaptureTooLarge : public CaptureError {
public:
    CaptureTooLarge(const std::string& message, std::uint64_t expanded, std::uint64_t limit)
        : CaptureError(message), expanded_bytes(expanded), limit_bytes(limit) {}
    std::uint64_t expanded_bytes, limit_bytes;
};

// Byte offset of the first byte of s that is not valid UTF-8 (RFC 3629), nullopt if none.
std::optional<std::size_t> first_invalid_utf8_at(const std::string& s);

// Limits shared by both formats (the scenario schema's ranges, docs/schema.md).
constexpr double kCaptureMinRateHz = 1.0, kCaptureMaxRateHz = 1e10;
constexpr double kCaptureMaxAbsT0_s = 1e9;
// The most sample data a compressed capture (.sr) may expand to unless a reader is told
// otherwise (`fringe estimate --max-expanded-mb`, `fringe serve --max-upload-expanded-mb`).
constexpr std::uint64_t kCaptureDefaultMaxExpandedBytes = 512ull << 20;
// JSON metadata (a sidecar, a .fcap header) may nest arrays and objects this deep, no deeper.
constexpr std::size_t kCaptureMaxJsonDepth = 128;

struct CaptureColumns {
    bool theta_true = false;
    bool omega_true = false;
    bool index = false;
    bool a = false, b = false, z = false;  // digital: a DUT's A/B/Z quadrature lines
    bool abz() const { return a && b; }
};

// A chunk (or all) of a capture, structure of arrays. Optional columns are empty when absent.
struct CaptureData {
    std::vector<double> t_s, sin_v, cos_v, theta_true_rad, omega_true_rad_s, index_v;
    std::vector<double> a, b, z;  // digital columns, 0 or 1 (read only: the writer does not write them)
    std::size_t size() const { return t_s.size(); }
    void clear();
};

enum class CaptureFormat { Csv, Binary, Sigrok };
CaptureFormat capture_format_for(const std::string& path);  // by extension: .csv, .fcap, .sr
std::string sidecar_path(const std::string& csv_path);      // x.csv -> x.json (x.sr -> x.json)

// How a reader takes columns from a file whose channels are named by someone else (.sr):
// column -> channel name, for the columns whose channel is not named like the column.
struct CaptureOptions {
    std::map<std::string, std::string> channels;
    // A .sr's sample data (the declared sizes of the members read) beyond this is refused with
    // CaptureTooLarge before anything is inflated; and no member is ever inflated past its
    // declared size. .fcap and CSV are not compressed: their size on disk is their data.
    std::uint64_t max_expanded_bytes = kCaptureDefaultMaxExpandedBytes;
};
// The options a capture: device URI's settings give (its column channels, max_expanded_mb).
CaptureOptions capture_options_from_uri(const nlohmann::json& settings);
// "sin=CH1,cos=CH2" (a CLI option, a URI setting) to a channel map; throws CaptureError.
std::map<std::string, std::string> parse_channel_map(const std::string& text);

class CaptureWriter {
public:
    // meta is written as the sidecar (CSV) or header (binary); sample_rate_hz and t0_s are
    // required for binary, recommended for CSV.
    CaptureWriter(const std::string& path, CaptureColumns cols, nlohmann::json meta);
    ~CaptureWriter();
    void write(const Block& b);  // uses b.theta_rad / omega_rad_s / index_v as truth columns
    void write(const CaptureData& d);
    void close();                // flush; the destructor closes too
    std::uint64_t frames() const { return frames_; }

private:
    void write_rows(std::size_t n, const double* t, const double* s, const double* c,
                    const double* th, const double* om, const double* ix);
    std::string path_;
    CaptureFormat fmt_;
    CaptureColumns cols_;
    std::ofstream out_;
    std::uint64_t frames_ = 0;
    double fs_ = 0, t0_ = 0;
    std::string buf_;
};

class CaptureReader {
public:
    explicit CaptureReader(const std::string& path, const CaptureOptions& options = {});
    ~CaptureReader();
    // Reads up to max_frames into out (replacing its contents); false at end of file.
    bool read(std::size_t max_frames, CaptureData& out);
    const CaptureColumns& columns() const { return cols_; }
    const nlohmann::json& meta() const { return meta_; }  // sidecar/header (may be empty object)
    // From the metadata, or estimated from the first two time stamps (CSV); 0 if unknown.
    double sample_rate_hz() const { return fs_; }
    const std::string& path() const { return path_; }
    // Bytes of sample data the reader goes through in all: a .sr's members as declared (what
    // they expand to), a .fcap's payload, a CSV's size (what an upload quota counts).
    std::uint64_t expanded_bytes() const { return expanded_bytes_; }

private:
    bool read_csv(std::size_t max_frames, CaptureData& out);
    bool read_bin(std::size_t max_frames, CaptureData& out);
    bool read_sr(std::size_t max_frames, CaptureData& out);
    std::string path_;
    CaptureFormat fmt_;
    CaptureColumns cols_;
    nlohmann::json meta_ = nlohmann::json::object();
    std::ifstream in_;
    double fs_ = 0, t0_ = 0;
    std::uint64_t expanded_bytes_ = 0;
    // CSV state
    std::vector<int> col_map_;  // file column -> field id
    std::size_t line_ = 0;
    std::uint64_t rows_ = 0;
    bool done_ = false;
    std::optional<std::uint64_t> expected_frames_;  // the metadata's "samples", when given
    double last_t_ = 0;
    bool have_last_ = false;
    bool rate_from_t_ = false;  // fs_ came from the first two time stamps (no sidecar rate)
    // binary state
    std::vector<int> bin_fields_;
    std::vector<int> bin_sizes_;
    std::size_t frame_bytes_ = 0;
    std::uint64_t frame_ = 0, total_frames_ = 0;
    // sigrok state
    std::unique_ptr<SigrokSession> sr_;
    std::map<std::string, std::vector<double>> sr_cols_;
};

// Whole capture in memory (tests and small files; the service validates uploads block by block).
CaptureData read_capture(const std::string& path, nlohmann::json* meta = nullptr, double* sample_rate_hz = nullptr,
                         const CaptureOptions& options = {});

}  // namespace fringe
