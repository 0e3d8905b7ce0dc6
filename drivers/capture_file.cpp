#include "capture_file.hpp"

#include "signal_gen/base/json_bounded.hpp"

#include "sigrok_file.hpp"

#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <sstream>

namespace fringe {

using nlohmann::json;

namespace {
constexpr char kMagic[8] = {'F', 'R', 'N', 'G', 'C', 'A', 'P', '1'};
enum Field { kT = 0, kSin, kCos, kTheta, kOmega, kIndex, kA, kB, kZ, kFieldCount };
const char* const kNames[kFieldCount] = {"t", "sin", "cos", "theta_true", "omega_true", "index", "a", "b", "z"};
const char* const kUnits[kFieldCount] = {"s", "V", "V", "rad", "rad/s", "V", "logic", "logic", "logic"};
bool digital(int f) { return f == kA || f == kB || f == kZ; }

std::vector<double>& field_vec(CaptureData& d, int f) {
    switch (f) {
    case kT: return d.t_s;
    case kSin: return d.sin_v;
    case kCos: return d.cos_v;
    case kTheta: return d.theta_true_rad;
    case kOmega: return d.omega_true_rad_s;
    case kA: return d.a;
    case kB: return d.b;
    case kZ: return d.z;
    default: return d.index_v;
    }
}

static_assert(std::endian::native == std::endian::little, "capture I/O assumes a little-endian host");

void append_number(std::string& s, double v) {
    char tmp[32];
    auto r = std::to_chars(tmp, tmp + sizeof tmp, v);
    s.append(tmp, r.ptr);
}
}  // namespace

void CaptureData::clear() {
    for (auto* v : {&t_s, &sin_v, &cos_v, &theta_true_rad, &omega_true_rad_s, &index_v, &a, &b, &z}) v->clear();
}

CaptureFormat capture_format_for(const std::string& path) {
    auto ext = std::filesystem::path(path).extension().string();
    if (ext == ".csv") return CaptureFormat::Csv;
    if (ext == ".fcap") return CaptureFormat::Binary;
    if (ext == ".sr") return CaptureFormat::Sigrok;
    throw CaptureError(path + ": unknown capture format '" + ext + "' (use .csv, .fcap or .sr)");
}

std::string sidecar_path(const std::string& csv_path) {
    return std::filesystem::path(csv_path).replace_extension(".json").string();
}

// ---------------------------------------------------------------- writer

CaptureWriter::CaptureWriter(const std::string& path, CaptureColumns cols, json meta)
    : path_(path), fmt_(capture_format_for(path)), cols_(cols) {
    if (fmt_ == CaptureFormat::Sigrok) throw CaptureError(path + ": fringe reads sigrok session files but does not write them (use .csv or .fcap)");
    if (cols_.a || cols_.b || cols_.z) throw CaptureError(path + ": the capture writer does not write digital columns (a, b, z)");
    if (meta.is_null()) meta = json::object();
    fs_ = meta.value("sample_rate_hz", 0.0);
    t0_ = meta.value("t0_s", 0.0);
    json units = {{"t", "s"}, {"sin", "V"}, {"cos", "V"}};
    if (cols_.theta_true) units["theta_true"] = "rad";
    if (cols_.omega_true) units["omega_true"] = "rad/s";
    if (cols_.index) units["index"] = "V";
    meta["units"] = units;
    meta["format"] = "fringe-capture";
    meta["version"] = 1;
    out_.open(path, std::ios::binary | std::ios::trunc);
    if (!out_) throw CaptureError(path + ": cannot open for writing: " + std::strerror(errno));
    if (fmt_ == CaptureFormat::Csv) {
        std::ofstream side(sidecar_path(path), std::ios::trunc);
        if (!side) throw CaptureError(sidecar_path(path) + ": cannot open for writing");
        side << meta.dump(2) << "\n";
        std::string header = "t,sin,cos";
        if (cols_.theta_true) header += ",theta_true";
        if (cols_.omega_true) header += ",omega_true";
        if (cols_.index) header += ",index";
        out_ << header << "\n";
    } else {
        if (!(fs_ > 0)) throw CaptureError(path + ": binary captures need sample_rate_hz in the metadata");
        json cols_json = json::array({{{"name", "sin"}, {"type", "f64"}, {"unit", "V"}}, {{"name", "cos"}, {"type", "f64"}, {"unit", "V"}}});
        if (cols_.theta_true) cols_json.push_back({{"name", "theta_true"}, {"type", "f64"}, {"unit", "rad"}});
        if (cols_.omega_true) cols_json.push_back({{"name", "omega_true"}, {"type", "f64"}, {"unit", "rad/s"}});
        if (cols_.index) cols_json.push_back({{"name", "index"}, {"type", "f64"}, {"unit", "V"}});
        meta["columns"] = cols_json;
        const std::string h = meta.dump();
        const std::uint32_t len = static_cast<std::uint32_t>(h.size());
        out_.write(kMagic, 8);
        out_.write(reinterpret_cast<const char*>(&len), 4);
        out_.write(h.data(), static_cast<std::streamsize>(h.size()));
    }
    if (!out_) throw CaptureError(path + ": write failed");
}

CaptureWriter::~CaptureWriter() {
    try { close(); } catch (...) {}
}

void CaptureWriter::close() {
    if (out_.is_open()) {
        out_.flush();
        out_.close();
    }
}

void CaptureWriter::write(const Block& b) {
    write_rows(b.size(), b.t_s.data(), b.sin_v.data(), b.cos_v.data(),
               cols_.theta_true ? b.theta_rad.data() : nullptr,
               cols_.omega_true ? b.omega_rad_s.data() : nullptr,
               cols_.index ? b.index_v.data() : nullptr);
}

void CaptureWriter::write(const CaptureData& d) {
    auto need = [&](bool on, const std::vector<double>& v, const char* name) -> const double* {
        if (!on) return nullptr;
        if (v.size() != d.size()) throw CaptureError(path_ + ": column " + name + " missing in data");
        return v.data();
    };
    write_rows(d.size(), d.t_s.data(), d.sin_v.data(), d.cos_v.data(),
               need(cols_.theta_true, d.theta_true_rad, "theta_true"),
               need(cols_.omega_true, d.omega_true_rad_s, "omega_true"),
               need(cols_.index, d.index_v, "index"));
}

void CaptureWriter::write_rows(std::size_t n, const double* t, const double* s, const double* c,
                               const double* th, const double* om, const double* ix) {
    if (!out_.is_open()) throw CaptureError(path_ + ": writer is closed");
    buf_.clear();
    if (fmt_ == CaptureFormat::Csv) {
        for (std::size_t i = 0; i < n; ++i) {
            append_number(buf_, t[i]); buf_ += ',';
            append_number(buf_, s[i]); buf_ += ',';
            append_number(buf_, c[i]);
            if (th) { buf_ += ','; append_number(buf_, th[i]); }
            if (om) { buf_ += ','; append_number(buf_, om[i]); }
            if (ix) { buf_ += ','; append_number(buf_, ix[i]); }
            buf_ += '\n';
        }
    } else {
        for (std::size_t i = 0; i < n; ++i) {
            auto put = [&](double v) { buf_.append(reinterpret_cast<const char*>(&v), 8); };
            put(s[i]); put(c[i]);
            if (th) put(th[i]);
            if (om) put(om[i]);
            if (ix) put(ix[i]);
        }
    }
    out_.write(buf_.data(), static_cast<std::streamsize>(buf_.size()));
    out_.flush();  // a killed run leaves every completed block on disk
    if (!out_) throw CaptureError(path_ + ": write failed after " + std::to_string(frames_) + " frames");
    frames_ += n;
}

// ---------------------------------------------------------------- reader

namespace {
// Length of the valid UTF-8 sequence at p (left bytes available), 0 if it is not one
// (overlong forms, surrogates and code points above U+10FFFF are invalid, as in RFC 3629).
std::size_t utf8_sequence(const unsigned char* p, std::size_t left) {
    const unsigned b = p[0];
    if (b < 0x80) return 1;
    std::size_t n;
    unsigned lo = 0x80, hi = 0xBF;  // range of the second byte
    if (b >= 0xC2 && b <= 0xDF) n = 2;
    else if (b == 0xE0) { n = 3; lo = 0xA0; }
    else if ((b >= 0xE1 && b <= 0xEC) || b == 0xEE || b == 0xEF) n = 3;
    else if (b == 0xED) { n = 3; hi = 0x9F; }
    else if (b == 0xF0) { n = 4; lo = 0x90; }
    else if (b >= 0xF1 && b <= 0xF3) n = 4;
    else if (b == 0xF4) { n = 4; hi = 0x8F; }
    else return 0;
    if (left < n || p[1] < lo || p[1] > hi) return 0;
    for (std::size_t k = 2; k < n; ++k)
        if (p[k] < 0x80 || p[k] > 0xBF) return 0;
    return n;
}

std::optional<std::size_t> first_invalid_utf8(const std::string& s) {
    const auto* p = reinterpret_cast<const unsigned char*>(s.data());
    for (std::size_t i = 0; i < s.size();) {
        const std::size_t n = utf8_sequence(p + i, s.size() - i);
        if (n == 0) return i;
        i += n;
    }
    return std::nullopt;
}

std::string escape_message(const std::string& s) {
    std::string out;
    out.reserve(s.size());
    const auto* p = reinterpret_cast<const unsigned char*>(s.data());
    for (std::size_t i = 0; i < s.size();) {
        std::size_t n = utf8_sequence(p + i, s.size() - i);
        if (n == 0 || (n == 1 && (p[i] < 0x20 || p[i] == 0x7F))) {
            char hex[5];
            std::snprintf(hex, sizeof hex, "\\x%02X", p[i]);
            out += hex;
            n = 1;
        } else {
            out.append(s, i, n);
        }
        i += n;
    }
    return out;
}

// File contents quoted in a message: short, and escaped by CaptureError.
std::string quote(const std::string& s) {
    constexpr std::size_t kMax = 40;
    return "'" + (s.size() > kMax ? s.substr(0, kMax) + "..." : s) + "'";
}

constexpr std::uint32_t kMaxMetaBytes = 64u << 20;

// Byte offset where the arrays and objects of a JSON text first nest deeper than max_depth,
// nullopt if they never do. One pass, no recursion: brackets inside strings do not count. A
// text that is not JSON may be misread here, but only past the point where the parser would
// refuse it anyway, so the parser never goes deeper than this says.
std::optional<std::size_t> json_too_deep_at(const std::string& text, std::size_t max_depth) {
    std::size_t depth = 0;
    bool in_string = false, escaped = false;
    for (std::size_t i = 0; i < text.size(); ++i) {
        const char c = text[i];
        if (in_string) {
            if (escaped) escaped = false;
            else if (c == '\\') escaped = true;
            else if (c == '"') in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '[' || c == '{') {
            if (++depth > max_depth) return i;
        } else if ((c == ']' || c == '}') && depth > 0) {
            --depth;
        }
    }
    return std::nullopt;
}

// Metadata (sidecar or .fcap header): UTF-8, a JSON object. `where` names it in messages.
json parse_meta(const std::string& text, const std::string& where) {
    if (auto bad = first_invalid_utf8(text))
        throw CaptureError(where + " is not valid UTF-8 (byte " + std::to_string(*bad) + ")");
    // Before parsing: copying, printing or freeing a JSON value recurses once per level.
    if (auto at = json_too_deep_at(text, kCaptureMaxJsonDepth))
        throw CaptureError(where + " nests deeper than " + std::to_string(kCaptureMaxJsonDepth) + " levels of arrays and objects (level " +
                           std::to_string(kCaptureMaxJsonDepth + 1) + " opens at byte " + std::to_string(*at) + ")");
    json j;
    try {
        j = json::parse(text);
    } catch (const json::exception& e) {  // parse_error, and out_of_range for a number like 1e999
        std::string detail = e.what();
        if (auto pos = detail.find("] "); detail.rfind("[json.exception", 0) == 0 && pos != std::string::npos) detail.erase(0, pos + 2);
        throw CaptureError(where + " is not a JSON object (" + detail + ")");
    }
    // Each key once, as in scenarios (a repeated sample_rate_hz silently took the last value).
    try {
        parse_json_bounded(text, "", kCaptureMaxJsonDepth);
    } catch (const ConfigError& e) {
        throw CaptureError(where + ": " + e.what());
    }
    if (!j.is_object()) throw CaptureError(where + " is not a JSON object (got " + j.type_name() + ")");
    return j;
}

// The metadata fields the readers use; `where` is "x.json: sidecar" or "x.fcap: header".
struct MetaFields {
    double fs_hz = 0, t0_s = 0;
    std::optional<std::uint64_t> samples;
};

MetaFields check_meta(const json& m, const std::string& where, bool rate_required) {
    MetaFields f;
    auto number = [&](const char* key, double lo, double hi, const char* unit) {
        const json& v = m[key];
        if (!v.is_number()) throw CaptureError(where + "." + key + " must be a number, got " + v.type_name());
        const double x = v.get<double>();
        if (!std::isfinite(x) || x < lo || x > hi) {
            std::ostringstream os;
            os << where << "." << key << " = " << x << " is outside [" << lo << ", " << hi << "] " << unit;
            throw CaptureError(os.str());
        }
        return x;
    };
    // a report written where the sidecar goes (fringe refuses that now; older files may exist)
    if (m.contains("schema") && m["schema"].is_string() && m["schema"].get<std::string>().rfind("fringe.", 0) == 0)
        throw CaptureError(where + " is a " + m["schema"].get<std::string>() + " report, not a capture's metadata (a report written over the sidecar?)");
    if (m.contains("sample_rate_hz")) f.fs_hz = number("sample_rate_hz", kCaptureMinRateHz, kCaptureMaxRateHz, "Hz");
    else if (rate_required) throw CaptureError(where + ".sample_rate_hz is required (a positive number)");
    if (m.contains("t0_s")) f.t0_s = number("t0_s", -kCaptureMaxAbsT0_s, kCaptureMaxAbsT0_s, "s");
    if (m.contains("samples")) {
        const json& v = m["samples"];
        if (!v.is_number_unsigned() && !(v.is_number_integer() && v.get<std::int64_t>() >= 0))
            throw CaptureError(where + ".samples must be a non-negative integer, got " + v.dump(-1, ' ', false, json::error_handler_t::replace));
        f.samples = v.get<std::uint64_t>();
    }
    if (m.contains("format") && m["format"] != "fringe-capture")
        throw CaptureError(where + ".format must be \"fringe-capture\"");
    if (m.contains("version") && m["version"] != 1)
        throw CaptureError(where + ".version " + m["version"].dump(-1, ' ', false, json::error_handler_t::replace) + " is not supported (this reader reads version 1)");
    return f;
}

std::string read_meta_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw CaptureError(path + ": cannot open: " + std::strerror(errno));
    std::string text;
    char buf[65536];
    while (in.read(buf, sizeof buf) || in.gcount() > 0) {
        text.append(buf, static_cast<std::size_t>(in.gcount()));
        if (text.size() > kMaxMetaBytes) throw CaptureError(path + ": sidecar larger than 64 MiB");
    }
    return text;
}
}  // namespace

CaptureError::CaptureError(const std::string& message) : std::runtime_error(escape_message(message)) {}

std::optional<std::size_t> first_invalid_utf8_at(const std::string& s) { return first_invalid_utf8(s); }

std::map<std::string, std::string> parse_channel_map(const std::string& text) {
    std::map<std::string, std::string> m;
    std::size_t pos = 0;
    while (pos < text.size()) {
        auto comma = text.find(',', pos);
        if (comma == std::string::npos) comma = text.size();
        const std::string item = text.substr(pos, comma - pos);
        pos = comma + 1;
        if (item.empty()) continue;
        const auto eq = item.find('=');
        if (eq == std::string::npos || eq == 0 || eq + 1 == item.size())
            throw CaptureError("channel map: expected column=channel, got " + quote(item));
        const std::string col = item.substr(0, eq);
        bool known = false;
        for (int f = kSin; f < kFieldCount; ++f) known |= col == kNames[f];
        if (!known) throw CaptureError("channel map: unknown column " + quote(col) + " (sin, cos, theta_true, omega_true, index, a, b, z)");
        if (!m.emplace(col, item.substr(eq + 1)).second) throw CaptureError("channel map: column '" + col + "' given twice");
    }
    return m;
}

CaptureReader::~CaptureReader() = default;

CaptureReader::CaptureReader(const std::string& path, const CaptureOptions& options) : path_(path), fmt_(capture_format_for(path)) {
    if (!options.channels.empty() && fmt_ != CaptureFormat::Sigrok)
        throw CaptureError(path + ": a channel map applies to sigrok session files (.sr) only; CSV and .fcap columns are named by fringe");
    if (fmt_ == CaptureFormat::Sigrok) {
        sr_ = std::make_unique<SigrokSession>(path, options.channels, options.max_expanded_bytes);
        expanded_bytes_ = sr_->data_bytes();
        for (int f : {kSin, kCos})
            if (!sr_->has(kNames[f])) {
                std::string known;
                for (const auto& c : sr_->channel_list()) known += (known.empty() ? "" : ", ") + c;
                throw CaptureError(path + ": no channel for column '" + kNames[f] + "' (channels: " + (known.empty() ? "none" : known) +
                                   "); name the channels sin and cos, or map them: sin=CH1,cos=CH2");
            }
        cols_.theta_true = sr_->has("theta_true");
        cols_.omega_true = sr_->has("omega_true");
        cols_.index = sr_->has("index");
        cols_.a = sr_->has("a");
        cols_.b = sr_->has("b");
        cols_.z = sr_->has("z");
        fs_ = sr_->sample_rate_hz();
        total_frames_ = sr_->frames();
        if (total_frames_ == 0) throw CaptureError(path + ": no samples");
        meta_["sigrok"] = {{"channels", sr_->channel_list()}, {"samplerate_hz", fs_}};
        // fringe's own metadata (encoder, t0_s) can sit beside it in a sidecar, as for CSV.
        const std::string side = sidecar_path(path);
        if (std::filesystem::exists(side)) {
            json m = parse_meta(read_meta_file(side), side + ": sidecar");
            const MetaFields f = check_meta(m, side + ": sidecar", false);
            if (f.fs_hz > 0 && std::fabs(f.fs_hz - fs_) > 1e-9 * fs_) {
                std::ostringstream os;
                os << side << ": sidecar.sample_rate_hz " << f.fs_hz << " disagrees with the session's samplerate " << fs_ << " Hz";
                throw CaptureError(os.str());
            }
            if (f.samples && *f.samples != total_frames_)
                throw CaptureError(path + (*f.samples > total_frames_ ? ": truncated payload" : ": size mismatch") + ": the sidecar's samples is " +
                                   std::to_string(*f.samples) + " but the session holds " + std::to_string(total_frames_));
            t0_ = f.t0_s;
            m["sigrok"] = meta_["sigrok"];
            meta_ = std::move(m);
        }
        if ((cols_.a != cols_.b) || (cols_.z && !cols_.a))
            throw CaptureError(path + ": digital columns: a and b come together (z is optional with them)");
        return;
    }
    in_.open(path, std::ios::binary);
    if (!in_) throw CaptureError(path + ": cannot open: " + std::strerror(errno));
    {
        std::error_code ec;
        const auto bytes = std::filesystem::file_size(path, ec);
        expanded_bytes_ = ec ? 0 : static_cast<std::uint64_t>(bytes);  // not compressed: its size is its data
    }
    if (fmt_ == CaptureFormat::Csv) {
        const std::string side = sidecar_path(path);
        if (std::filesystem::exists(side)) {
            meta_ = parse_meta(read_meta_file(side), side + ": sidecar");
            const MetaFields f = check_meta(meta_, side + ": sidecar", false);
            fs_ = f.fs_hz;
            expected_frames_ = f.samples;
        }
        std::string header;
        if (!std::getline(in_, header)) throw CaptureError(path + ":1: empty file (expected header 't,sin,cos[,theta_true]')");
        line_ = 1;
        if (!header.empty() && header.back() == '\r') header.pop_back();
        if (header.rfind("\xEF\xBB\xBF", 0) == 0) header.erase(0, 3);  // a UTF-8 byte order mark (spreadsheets)
        std::size_t pos = 0;
        bool seen[kFieldCount] = {};
        while (pos <= header.size()) {
            auto comma = header.find(',', pos);
            std::string name = header.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
            int f = -1;
            for (int k = 0; k < kFieldCount; ++k)
                if (name == kNames[k]) f = k;
            if (f < 0)
                throw CaptureError(path + ":1: unknown column " + quote(name) + " (expected t, sin, cos and optionally theta_true, omega_true, index, a, b, z)");
            if (seen[f]) throw CaptureError(path + ":1: duplicate column '" + name + "'");
            seen[f] = true;
            col_map_.push_back(f);
            if (comma == std::string::npos) break;
            pos = comma + 1;
        }
        for (int f : {kT, kSin, kCos})
            if (!seen[f]) throw CaptureError(path + ":1: missing column '" + std::string(kNames[f]) + "'");
        cols_.theta_true = seen[kTheta];
        cols_.omega_true = seen[kOmega];
        cols_.index = seen[kIndex];
        cols_.a = seen[kA];
        cols_.b = seen[kB];
        cols_.z = seen[kZ];
        if ((cols_.a != cols_.b) || (cols_.z && !cols_.a))
            throw CaptureError(path + ":1: digital columns: a and b come together (z is optional with them)");
    } else {
        char magic[8];
        std::uint32_t len = 0;
        if (!in_.read(magic, 8) || std::memcmp(magic, kMagic, 8) != 0)
            throw CaptureError(path + ": not a fringe binary capture (bad magic)");
        const auto size = std::filesystem::file_size(path);
        if (!in_.read(reinterpret_cast<char*>(&len), 4))
            throw CaptureError(path + ": truncated: the file ends inside the header length");
        if (len > kMaxMetaBytes) throw CaptureError(path + ": bad header length " + std::to_string(len) + " (at most 64 MiB)");
        if (size < 12 + static_cast<std::uintmax_t>(len))
            throw CaptureError(path + ": truncated header: length " + std::to_string(len) + " but the file has " + std::to_string(size) + " bytes");
        std::string h(len, '\0');
        if (!in_.read(h.data(), len)) throw CaptureError(path + ": truncated header");
        const std::string where = path + ": header";
        meta_ = parse_meta(h, where);
        const MetaFields mf = check_meta(meta_, where, true);
        fs_ = mf.fs_hz;
        t0_ = mf.t0_s;
        if (!meta_.contains("columns") || !meta_["columns"].is_array())
            throw CaptureError(where + ".columns missing (an array of {name, type, unit})");
        bool seen[kFieldCount] = {};
        std::size_t i = 0;
        for (const auto& c : meta_["columns"]) {
            const std::string at = where + ".columns[" + std::to_string(i++) + "]";
            if (!c.is_object()) throw CaptureError(at + " is not an object {name, type, unit}");
            if (!c.contains("name") || !c["name"].is_string()) throw CaptureError(at + ".name missing (a string)");
            if (!c.contains("type") || !c["type"].is_string()) throw CaptureError(at + ".type missing (f64 or f32)");
            const std::string name = c["name"].get<std::string>(), type = c["type"].get<std::string>();
            if (name == "t") throw CaptureError(at + ": column 't' is not stored in .fcap (frame k is at t0_s + k / sample_rate_hz)");
            int f = -1;
            for (int k = 1; k < kFieldCount; ++k)
                if (name == kNames[k]) f = k;
            if (f < 0) throw CaptureError(at + ": unknown column " + quote(name) + " (sin, cos, theta_true, omega_true, index, a, b, z)");
            // A repeated column would give that field two values per frame: refused, as in CSV.
            if (seen[f]) throw CaptureError(at + ": duplicate column '" + name + "'");
            if (type != "f64" && type != "f32" && !(digital(f) && type == "u8"))
                throw CaptureError(at + ": column '" + name + "' has unsupported type " + quote(type) + (digital(f) ? " (u8, f32, f64)" : " (f32, f64)"));
            if (c.contains("unit") && c["unit"] != kUnits[f])
                throw CaptureError(at + ": column '" + name + "' has unit " + c["unit"].dump(-1, ' ', false, json::error_handler_t::replace) +
                                   ", expected '" + kUnits[f] + "'");
            seen[f] = true;
            bin_fields_.push_back(f);
            bin_sizes_.push_back(type == "f64" ? 8 : type == "f32" ? 4 : 1);
            frame_bytes_ += static_cast<std::size_t>(bin_sizes_.back());
        }
        for (int f : {kSin, kCos})
            if (!seen[f]) throw CaptureError(where + ": missing column '" + std::string(kNames[f]) + "' (sin and cos are required)");
        cols_.theta_true = seen[kTheta];
        cols_.omega_true = seen[kOmega];
        cols_.index = seen[kIndex];
        cols_.a = seen[kA];
        cols_.b = seen[kB];
        cols_.z = seen[kZ];
        if ((cols_.a != cols_.b) || (cols_.z && !cols_.a))
            throw CaptureError(where + ": digital columns: a and b come together (z is optional with them)");
        const auto data_bytes = size - (12 + static_cast<std::uintmax_t>(len));
        if (data_bytes % frame_bytes_ != 0)
            throw CaptureError(path + ": truncated: " + std::to_string(data_bytes % frame_bytes_) +
                               " stray bytes after frame " + std::to_string(data_bytes / frame_bytes_) +
                               " (a capture cut short; the whole frames before it are intact)");
        total_frames_ = data_bytes / frame_bytes_;
        if (mf.samples && *mf.samples != total_frames_)
            throw CaptureError(path + (*mf.samples > total_frames_ ? ": truncated payload" : ": size mismatch") + ": header.samples is " +
                               std::to_string(*mf.samples) + " but the file holds " + std::to_string(total_frames_) + " frames of " +
                               std::to_string(frame_bytes_) + " bytes");
    }
}

bool CaptureReader::read(std::size_t max_frames, CaptureData& out) {
    out.clear();
    if (fmt_ == CaptureFormat::Sigrok) return read_sr(max_frames, out);
    return fmt_ == CaptureFormat::Csv ? read_csv(max_frames, out) : read_bin(max_frames, out);
}

bool CaptureReader::read_sr(std::size_t max_frames, CaptureData& out) {
    const std::uint64_t n = std::min<std::uint64_t>(max_frames, total_frames_ - frame_);
    if (n == 0) return false;
    for (auto& [c, v] : sr_cols_) v.clear();
    sr_->read(static_cast<std::size_t>(n), sr_cols_);
    for (int f = kSin; f < kFieldCount; ++f) {
        auto it = sr_cols_.find(kNames[f]);
        if (it == sr_cols_.end()) continue;
        for (std::size_t i = 0; i < it->second.size(); ++i)
            if (!std::isfinite(it->second[i]))
                throw CaptureError(path_ + ": sample " + std::to_string(frame_ + i) + ": channel of column " + kNames[f] + ": " +
                                   (std::isnan(it->second[i]) ? "NaN" : "infinite value"));
        field_vec(out, f).swap(it->second);
    }
    for (std::uint64_t i = 0; i < n; ++i) out.t_s.push_back(t0_ + static_cast<double>(frame_ + i) / fs_);
    frame_ += n;
    return true;
}

bool CaptureReader::read_csv(std::size_t max_frames, CaptureData& out) {
    std::string line;
    std::vector<std::vector<double>*> dst;
    for (int f : col_map_) dst.push_back(&field_vec(out, f));
    while (out.size() < max_frames) {
        if (!std::getline(in_, line)) {
            if (!done_ && expected_frames_ && rows_ != *expected_frames_)
                throw CaptureError(path_ + (rows_ < *expected_frames_ ? ": truncated payload" : ": size mismatch") + ": the sidecar's samples is " +
                                   std::to_string(*expected_frames_) + " but the file has " + std::to_string(rows_) + " rows");
            done_ = true;
            break;
        }
        ++line_;
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty()) continue;
        const char* p = line.data();
        const char* end = p + line.size();
        for (std::size_t c = 0; c < col_map_.size(); ++c) {
            const char* cell_end = static_cast<const char*>(std::memchr(p, ',', static_cast<std::size_t>(end - p)));
            if (!cell_end) cell_end = end;
            const bool last = c + 1 == col_map_.size();
            if (!last && cell_end == end)
                throw CaptureError(path_ + ":" + std::to_string(line_) + ": expected " + std::to_string(col_map_.size()) + " cells, got " + std::to_string(c + 1));
            if (last && cell_end != end)
                throw CaptureError(path_ + ":" + std::to_string(line_) + ": more cells than columns in the header");
            double v;
            auto r = std::from_chars(p, cell_end, v);
            const std::string col = kNames[col_map_[c]];
            if (r.ec != std::errc() || r.ptr != cell_end)
                throw CaptureError(path_ + ":" + std::to_string(line_) + ": column " + col + ": not a number: " + quote(std::string(p, cell_end)));
            if (!std::isfinite(v))
                throw CaptureError(path_ + ":" + std::to_string(line_) + ": column " + col + ": " + (std::isnan(v) ? "NaN" : "infinite value"));
            if (digital(col_map_[c]) && v != 0.0 && v != 1.0)
                throw CaptureError(path_ + ":" + std::to_string(line_) + ": column " + col + ": a logic level must be 0 or 1, got " + quote(std::string(p, cell_end)));
            if (col_map_[c] == kT) {
                if (have_last_ && !(v > last_t_))
                    throw CaptureError(path_ + ":" + std::to_string(line_) + ": column t: time does not increase (" + std::string(p, cell_end) + " after previous row)");
                if (have_last_ && fs_ == 0) {
                    fs_ = 1.0 / (v - last_t_);
                    if (!(fs_ >= kCaptureMinRateHz && fs_ <= kCaptureMaxRateHz)) {
                        std::ostringstream os;
                        os << path_ << ":" << line_ << ": column t: a time step of " << v - last_t_ << " s gives a sample rate outside ["
                           << kCaptureMinRateHz << ", " << kCaptureMaxRateHz << "] Hz (or give sample_rate_hz in the sidecar)";
                        throw CaptureError(os.str());
                    }
                    rate_from_t_ = true;
                } else if (have_last_) {
                    // Every estimator assumes uniform sampling: a step off 1/fs by more than 0.3 of
                    // a period is missing samples (a dropped block) or a sidecar rate that is not
                    // the capture's. Either would be scored as if it were not there.
                    const double steps = (v - last_t_) * fs_;
                    if (!(std::fabs(steps - 1.0) <= 0.3)) {
                        std::ostringstream os;
                        os << path_ << ":" << line_ << ": column t: a time step of " << v - last_t_ << " s is " << steps << " sample periods at "
                           << fs_ << " Hz (" << (rate_from_t_ ? "from the first two rows" : "the sidecar's sample_rate_hz")
                           << "): samples are missing here, or the rate is wrong; fringe needs uniformly sampled captures";
                        throw CaptureError(os.str());
                    }
                }
                last_t_ = v;
                have_last_ = true;
            }
            dst[c]->push_back(v);
            p = cell_end + 1;
        }
        ++rows_;
    }
    return out.size() > 0;
}

bool CaptureReader::read_bin(std::size_t max_frames, CaptureData& out) {
    const std::uint64_t n = std::min<std::uint64_t>(max_frames, total_frames_ - frame_);
    if (n == 0) return false;
    std::vector<char> raw(n * frame_bytes_);
    if (!in_.read(raw.data(), static_cast<std::streamsize>(raw.size())))
        throw CaptureError(path_ + ": read failed at frame " + std::to_string(frame_));
    const char* p = raw.data();
    for (std::uint64_t i = 0; i < n; ++i) {
        out.t_s.push_back(t0_ + static_cast<double>(frame_ + i) / fs_);
        for (std::size_t c = 0; c < bin_fields_.size(); ++c) {
            double v;
            if (bin_sizes_[c] == 8) { std::memcpy(&v, p, 8); }
            else if (bin_sizes_[c] == 4) { float f; std::memcpy(&f, p, 4); v = f; }
            else v = static_cast<unsigned char>(*p);
            p += bin_sizes_[c];
            if (!std::isfinite(v))
                throw CaptureError(path_ + ": frame " + std::to_string(frame_ + i) + ": column " + kNames[bin_fields_[c]] + ": " + (std::isnan(v) ? "NaN" : "infinite value"));
            if (digital(bin_fields_[c]) && v != 0.0 && v != 1.0)
                throw CaptureError(path_ + ": frame " + std::to_string(frame_ + i) + ": column " + kNames[bin_fields_[c]] + ": a logic level must be 0 or 1");
            field_vec(out, bin_fields_[c]).push_back(v);
        }
    }
    frame_ += n;
    return true;
}

CaptureData read_capture(const std::string& path, json* meta, double* fs, const CaptureOptions& options) {
    CaptureReader r(path, options);
    CaptureData all, chunk;
    while (r.read(1 << 16, chunk)) {
        for (int f = 0; f < kFieldCount; ++f) {
            auto& src = field_vec(chunk, f);
            auto& d = field_vec(all, f);
            d.insert(d.end(), src.begin(), src.end());
        }
    }
    if (all.size() == 0) throw CaptureError(path + ": no samples");
    if (meta) *meta = r.meta();
    if (fs) *fs = r.sample_rate_hz();
    return all;
}

}  // namespace fringe
