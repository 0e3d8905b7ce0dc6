#include "sigrok_file.hpp"

#include "capture_file.hpp"

#include <sys/stat.h>
#include <zip.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <optional>
#include <set>

namespace fringe {

namespace {

const char* const kAnalogColumns[] = {"sin", "cos", "theta_true", "omega_true", "index"};
// a, b, z: a DUT's ABZ lines; clk, data, cs: a position-word readout's (drivers/readout.cpp).
const char* const kLogicColumns[] = {"a", "b", "z", "clk", "data", "cs"};
constexpr std::uint64_t kMaxChunkNumber = 100000000;  // far beyond any real capture's chunk count
constexpr std::uint64_t kMaxChannels = 4096;
constexpr std::uint64_t kMaxUnitsize = 64;

std::string quote(const std::string& s) {
    constexpr std::size_t kMax = 40;
    return "'" + (s.size() > kMax ? s.substr(0, kMax) + "..." : s) + "'";
}

// A decimal number without sign or leading zeros, at most max; nullopt otherwise.
std::optional<std::uint64_t> parse_index(const std::string& s, std::uint64_t max) {
    if (s.empty() || s.size() > 12 || s.find_first_not_of("0123456789") != std::string::npos || s[0] == '0') return std::nullopt;
    const std::uint64_t v = std::stoull(s);
    if (v > max) return std::nullopt;
    return v;
}

std::string trim(const std::string& s) {
    const auto a = s.find_first_not_of(" \t\r");
    if (a == std::string::npos) return "";
    const auto b = s.find_last_not_of(" \t\r");
    return s.substr(a, b - a + 1);
}

// sigrok's sample rate text (sr_samplerate_string): "100 kHz", "1.5 MHz", "48 Hz"; also a bare
// number of Hz. Returns 0 if it is not one.
double parse_samplerate(const std::string& text) {
    const std::string s = trim(text);
    std::size_t i = 0;
    while (i < s.size() && s[i] >= '0' && s[i] <= '9') ++i;
    if (i == 0 || i > 15) return 0;
    const std::string whole = s.substr(0, i), frac_part = [&] {
        if (i < s.size() && s[i] == '.') {
            const std::size_t j = ++i;
            while (i < s.size() && s[i] >= '0' && s[i] <= '9') ++i;
            return s.substr(j, i - j);
        }
        return std::string();
    }();
    if (frac_part.size() > 9) return 0;
    while (i < s.size() && s[i] == ' ') ++i;
    double mult = 1;
    if (i < s.size()) {
        switch (s[i]) {
        case 'k': case 'K': mult = 1e3; ++i; break;
        case 'm': case 'M': mult = 1e6; ++i; break;
        case 'g': case 'G': mult = 1e9; ++i; break;
        default: break;
        }
    }
    const std::string unit = s.substr(i);
    if (!unit.empty() && unit != "Hz" && unit != "hz" && unit != "HZ") return 0;
    double v = std::stod(whole);
    if (!frac_part.empty()) v += std::stod("0." + frac_part);
    return v * mult;
}

constexpr std::uint64_t kSaturated = ~std::uint64_t{0};
std::uint64_t add_capped(std::uint64_t a, std::uint64_t b) { return a > kSaturated - b ? kSaturated : a + b; }

// "1024 MiB", "0.5 MiB": sizes in messages, as the options take them.
std::string mib(std::uint64_t bytes) {
    const double v = static_cast<double>(bytes) / (1 << 20);
    char buf[48];
    std::snprintf(buf, sizeof buf, v >= 10 || v == std::floor(v) ? "%.0f MiB" : "%.3g MiB", v);
    return buf;
}

// The central directory's entry count and size as the archive's end records declare them,
// read before libzip is given the file: libzip allocates for every entry when it opens an
// archive, so a file of many tiny entries costs several times its size in memory. Every
// end-of-central-directory record in the last 64 KiB counts (the largest wins: which one libzip
// settles on is its business); a ZIP64 record, when located, too. {0, 0} when none is found
// (libzip then refuses the file with its own message).
struct DirectorySize {
    std::uint64_t entries = 0, bytes = 0;
};
DirectorySize declared_directory(const std::string& path) {
    DirectorySize d;
    std::ifstream f(path, std::ios::binary);
    if (!f) return d;
    f.seekg(0, std::ios::end);
    const auto size = static_cast<std::uint64_t>(f.tellg());
    const std::uint64_t tail_len = std::min<std::uint64_t>(size, 22 + 65535 + 20);
    std::string tail(static_cast<std::size_t>(tail_len), '\0');
    f.seekg(static_cast<std::streamoff>(size - tail_len));
    if (!f.read(tail.data(), static_cast<std::streamsize>(tail_len))) return d;
    auto u16 = [](const char* p) { std::uint16_t v; std::memcpy(&v, p, 2); return std::uint64_t{v}; };
    auto u32 = [](const char* p) { std::uint32_t v; std::memcpy(&v, p, 4); return std::uint64_t{v}; };
    auto u64 = [](const char* p) { std::uint64_t v; std::memcpy(&v, p, 8); return v; };
    for (std::size_t at = 0; at + 22 <= tail.size(); ++at) {
        if (std::memcmp(tail.data() + at, "PK\x05\x06", 4) != 0) continue;
        const char* e = tail.data() + at;
        d.entries = std::max(d.entries, u16(e + 10));
        d.bytes = std::max(d.bytes, u32(e + 12));
        // ZIP64: the locator sits just before, and names where the ZIP64 record is.
        if (at >= 20 && std::memcmp(e - 20, "PK\x06\x07", 4) == 0) {
            const std::uint64_t off = u64(e - 20 + 8);
            char z[56];
            if (size >= 56 && off <= size - 56 && f.seekg(static_cast<std::streamoff>(off)) && f.read(z, 56) && std::memcmp(z, "PK\x06\x06", 4) == 0) {
                d.entries = std::max(d.entries, u64(z + 32));
                d.bytes = std::max(d.bytes, u64(z + 40));
            }
            f.clear();
        }
    }
    return d;
}

struct Entry {
    zip_uint64_t index;
    zip_uint64_t size;  // declared uncompressed size
    std::string name;
};

}  // namespace

bool sigrok_logic_column(const std::string& c) {
    return std::find_if(std::begin(kLogicColumns), std::end(kLogicColumns), [&](const char* l) { return c == l; }) != std::end(kLogicColumns);
}

struct SigrokSession::Impl {
    std::string path;
    zip_t* za = nullptr;
    // One ordered run of chunks (a channel's analog data, or the packed logic data).
    struct Stream {
        std::string what;             // for messages: "channel 'sin' (analog-1-2-*)"
        std::vector<Entry> chunks;
        std::size_t next = 0;
        zip_file_t* f = nullptr;
        zip_uint64_t left = 0;        // bytes left in the open chunk
        std::string cur;
        std::uint64_t bytes = 0;      // declared bytes of all chunks
    };
    std::map<std::string, Stream> analog;  // column -> its channel's chunks
    Stream logic;
    std::size_t unitsize = 0;
    std::map<std::string, int> logic_bit;  // column -> bit in a logic unit
    std::vector<unsigned char> buf;

    ~Impl() {
        for (auto& [c, s] : analog) close(s);
        close(logic);
        if (za) zip_discard(za);
    }
    [[noreturn]] void fail(const std::string& what) const { throw CaptureError(path + ": " + what); }
    void close(Stream& s) {
        if (s.f) zip_fclose(s.f);
        s.f = nullptr;
    }
    std::string zip_message() { return zip_error_strerror(zip_get_error(za)); }

    std::string read_small(const Entry& e, std::uint64_t max, const char* what) {
        if (e.size > max) fail(std::string(what) + " entry is " + std::to_string(e.size) + " bytes (at most " + std::to_string(max) + ")");
        zip_file_t* f = zip_fopen_index(za, e.index, 0);
        if (!f) fail(std::string("cannot read the ") + what + " entry: " + zip_message());
        std::string s(static_cast<std::size_t>(e.size) + 1, '\0');
        const zip_int64_t r = zip_fread(f, s.data(), s.size());
        const std::string err = r < 0 ? zip_file_strerror(f) : "";
        zip_fclose(f);
        if (r < 0) fail(std::string("cannot read the ") + what + " entry: " + err);
        if (static_cast<zip_uint64_t>(r) != e.size)
            fail(std::string("the ") + what + " entry decompresses to " + (static_cast<zip_uint64_t>(r) > e.size ? "more" : "fewer") +
                 " bytes than its declared " + std::to_string(e.size));
        s.resize(static_cast<std::size_t>(r));
        return s;
    }

    // Exactly `bytes` bytes of the stream into dst, chunk after chunk; each chunk must hold
    // exactly its declared size (a chunk that inflates further is refused, never read on).
    void read_bytes(Stream& s, unsigned char* dst, std::uint64_t bytes) {
        while (bytes > 0) {
            if (!s.f) {
                if (s.next >= s.chunks.size()) fail(s.what + ": data ends early");
                const Entry& e = s.chunks[s.next++];
                s.f = zip_fopen_index(za, e.index, 0);
                if (!s.f) fail("cannot read entry " + quote(e.name) + ": " + zip_message());
                s.left = e.size;
                s.cur = e.name;
            }
            const zip_uint64_t want = std::min<zip_uint64_t>(bytes, s.left);
            if (want > 0) {
                const zip_int64_t r = zip_fread(s.f, dst, want);
                if (r < 0) fail("entry " + quote(s.cur) + " is corrupt: " + zip_file_strerror(s.f));
                if (r == 0) fail("entry " + quote(s.cur) + " ends " + std::to_string(s.left) + " bytes before its declared size");
                dst += r;
                bytes -= static_cast<std::uint64_t>(r);
                s.left -= static_cast<zip_uint64_t>(r);
            }
            if (s.left == 0) {
                // End of the chunk: libzip checks the CRC here, and nothing may follow.
                unsigned char extra;
                const zip_int64_t r = zip_fread(s.f, &extra, 1);
                if (r < 0) fail("entry " + quote(s.cur) + " is corrupt: " + zip_file_strerror(s.f));
                if (r > 0) fail("entry " + quote(s.cur) + " decompresses to more than its declared size");
                close(s);
            }
        }
    }
};

SigrokSession::SigrokSession(const std::string& path, const std::map<std::string, std::string>& channel_for, std::uint64_t max_data_bytes)
    : impl_(std::make_unique<Impl>()) {
    Impl& m = *impl_;
    m.path = path;
    for (const auto& kv : channel_for) {  // (not a structured binding: clang 14 cannot capture one)
        const std::string& col = kv.first;
        const std::string& ch = kv.second;
        const bool known = sigrok_logic_column(col) || std::find_if(std::begin(kAnalogColumns), std::end(kAnalogColumns),
                                                                    [&](const char* c) { return col == c; }) != std::end(kAnalogColumns);
        if (!known) throw CaptureError(path + ": channel map: unknown column " + quote(col) + " (sin, cos, theta_true, omega_true, index, a, b, z, clk, data, cs)");
        if (ch.empty()) throw CaptureError(path + ": channel map: empty channel name for column '" + col + "'");
    }
    // A session is a ZIP read by seeking: a FIFO or a device would block its open (a FIFO with
    // no writer, forever) and cannot be seeked.
    if (struct stat st; ::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode))
        throw CaptureError(path + ": not a regular file (" + (S_ISDIR(st.st_mode) ? "a directory" : S_ISFIFO(st.st_mode) ? "a FIFO" : "a device or socket") +
                           "): a sigrok session is read from a file");
    if (const DirectorySize dir = declared_directory(path); dir.entries > kSigrokMaxEntries || dir.bytes > kSigrokMaxDirectoryBytes)
        m.fail("the archive declares " + std::to_string(dir.entries) + " entries in a central directory of " + std::to_string(dir.bytes) +
               " bytes (at most " + std::to_string(kSigrokMaxEntries) + " entries and " + mib(kSigrokMaxDirectoryBytes) + ")");
    int zerr = 0;
    m.za = zip_open(path.c_str(), ZIP_RDONLY | ZIP_CHECKCONS, &zerr);
    if (!m.za) {
        zip_error_t e;
        zip_error_init_with_code(&e, zerr);
        const std::string msg = zip_error_strerror(&e);
        zip_error_fini(&e);
        m.fail("not a sigrok session file (a ZIP archive): " + msg);
    }
    const zip_int64_t count = zip_get_num_entries(m.za, 0);
    if (count < 0) m.fail("cannot list the archive: " + m.zip_message());
    if (static_cast<std::uint64_t>(count) > kSigrokMaxEntries)
        m.fail("the archive has " + std::to_string(count) + " entries (at most " + std::to_string(kSigrokMaxEntries) + ")");

    // Entries by role; names are raw bytes (refused unless UTF-8).
    std::optional<Entry> version, metadata, logic_single;
    std::map<std::uint64_t, Entry> logic_chunks;
    std::map<std::uint64_t, std::map<std::uint64_t, Entry>> analog_chunks;  // channel -> chunk -> entry
    std::set<std::string> names;
    for (zip_int64_t i = 0; i < count; ++i) {
        const auto idx = static_cast<zip_uint64_t>(i);
        const char* raw = zip_get_name(m.za, idx, ZIP_FL_ENC_RAW);
        if (!raw) m.fail("cannot read the name of entry " + std::to_string(i) + ": " + m.zip_message());
        const std::string name = raw;
        if (auto bad = first_invalid_utf8_at(name)) m.fail("entry " + std::to_string(i) + " has a name that is not UTF-8 (byte " + std::to_string(*bad) + "): " + quote(name));
        if (!names.insert(name).second) m.fail("duplicate entry " + quote(name));
        zip_stat_t st;
        zip_stat_init(&st);
        if (zip_stat_index(m.za, idx, 0, &st) != 0) m.fail("cannot stat entry " + quote(name) + ": " + m.zip_message());
        if ((st.valid & ZIP_STAT_SIZE) == 0) m.fail("entry " + quote(name) + " has no declared size");
        if ((st.valid & ZIP_STAT_ENCRYPTION_METHOD) && st.encryption_method != ZIP_EM_NONE) m.fail("entry " + quote(name) + " is encrypted");
        if ((st.valid & ZIP_STAT_COMP_METHOD) && !zip_compression_method_supported(st.comp_method, 0))
            m.fail("entry " + quote(name) + " uses compression method " + std::to_string(st.comp_method) + ", which libzip cannot read");
        const Entry e{idx, st.size, name};
        if (name == "version") version = e;
        else if (name == "metadata") metadata = e;
        else if (name == "logic-1") logic_single = e;
        else if (name.rfind("logic-1-", 0) == 0) {
            const auto n = parse_index(name.substr(8), kMaxChunkNumber);
            if (!n) m.fail("malformed entry name " + quote(name) + " (expected logic-1-N, N = 1, 2, ...)");
            logic_chunks[*n] = e;
        } else if (name.rfind("analog-1-", 0) == 0) {
            const std::string rest = name.substr(9);
            const auto dash = rest.find('-');
            const auto k = dash == std::string::npos ? std::nullopt : parse_index(rest.substr(0, dash), kMaxChannels * 2);
            const auto n = dash == std::string::npos ? std::nullopt : parse_index(rest.substr(dash + 1), kMaxChunkNumber);
            if (!k || !n) m.fail("malformed entry name " + quote(name) + " (expected analog-1-K-N)");
            analog_chunks[*k][*n] = e;
        } else if (name.rfind("logic-", 0) == 0 || name.rfind("analog-", 0) == 0) {
            m.fail("entry " + quote(name) + ": only one device (logic-1, analog-1-*) is supported");
        }
        // Other entries (none in sigrok's own files) are ignored.
    }
    if (!version) m.fail("not a sigrok session file: no 'version' entry");
    const std::string ver = trim(m.read_small(*version, 16, "version"));
    if (ver != "1" && ver != "2") m.fail("sigrok session version " + quote(ver) + " is not supported (1 or 2)");
    if (!metadata) m.fail("not a sigrok session file: no 'metadata' entry");
    const std::string meta = m.read_small(*metadata, kSigrokMaxMetadataBytes, "metadata");
    if (auto bad = first_invalid_utf8_at(meta)) m.fail("metadata is not valid UTF-8 (byte " + std::to_string(*bad) + ")");

    // INI: [section], key=value, # comments. Only [device 1] matters.
    std::map<std::string, std::string> dev;
    {
        std::string section;
        std::size_t line_no = 0, pos = 0;
        while (pos < meta.size()) {
            auto nl = meta.find('\n', pos);
            if (nl == std::string::npos) nl = meta.size();
            const std::string line = trim(meta.substr(pos, nl - pos));
            pos = nl + 1;
            ++line_no;
            if (line.empty() || line[0] == '#') continue;
            const std::string at = "metadata:" + std::to_string(line_no) + ": ";
            if (line[0] == '[') {
                if (line.back() != ']') m.fail(at + "malformed section header " + quote(line));
                section = line.substr(1, line.size() - 2);
                if (section.rfind("device ", 0) == 0 && section != "device 1")
                    m.fail(at + "section " + quote(section) + ": only one device ([device 1]) is supported");
                continue;
            }
            const auto eq = line.find('=');
            if (eq == std::string::npos) m.fail(at + "expected key=value, got " + quote(line));
            if (section.empty()) m.fail(at + "key outside a section");
            if (section != "device 1") continue;
            const std::string key = trim(line.substr(0, eq));
            if (!dev.emplace(key, trim(line.substr(eq + 1))).second) m.fail(at + "duplicate key " + quote(key));
        }
    }
    auto integer = [&](const std::string& key, std::uint64_t lo, std::uint64_t hi) -> std::optional<std::uint64_t> {
        auto it = dev.find(key);
        if (it == dev.end()) return std::nullopt;
        const auto v = it->second == "0" ? std::optional<std::uint64_t>(0) : parse_index(it->second, hi);
        if (!v || *v < lo) m.fail("metadata: " + key + " = " + quote(it->second) + " is not an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        return v;
    };
    if (!dev.count("samplerate")) m.fail("metadata: [device 1] has no samplerate");
    fs_hz_ = parse_samplerate(dev["samplerate"]);
    if (!(fs_hz_ >= kCaptureMinRateHz && fs_hz_ <= kCaptureMaxRateHz))
        m.fail("metadata: samplerate " + quote(dev["samplerate"]) + " is not a rate in [1 Hz, 10 GHz] (sigrok's form: '100 kHz')");
    const std::uint64_t total_probes = integer("total probes", 0, kMaxChannels).value_or(0);
    const std::uint64_t total_analog = integer("total analog", 0, kMaxChannels).value_or(0);
    const auto unitsize = integer("unitsize", 1, kMaxUnitsize);
    if (dev.count("capturefile") && dev["capturefile"] != "logic-1")
        m.fail("metadata: capturefile " + quote(dev["capturefile"]) + " is not supported (logic-1)");

    // Channels: name -> (logic probe N | analog K).
    struct Channel { bool logic; std::uint64_t n; };
    std::map<std::string, std::vector<Channel>> by_name;
    std::uint64_t analog_seen = 0;
    for (const auto& [key, val] : dev) {
        std::optional<std::uint64_t> n;
        bool logic = false;
        if (key.rfind("probe", 0) == 0) { n = parse_index(key.substr(5), kMaxChannels); logic = true; }
        else if (key.rfind("analog", 0) == 0) n = parse_index(key.substr(6), kMaxChannels * 2);
        else continue;
        if (!n) m.fail("metadata: malformed channel key " + quote(key));
        if (logic && *n > total_probes) m.fail("metadata: " + key + " is beyond total probes = " + std::to_string(total_probes));
        if (!logic) ++analog_seen;
        if (val.empty()) m.fail("metadata: " + key + " has an empty channel name");
        by_name[val].push_back({logic, *n});
        channel_list_.push_back(val + " (" + key + ")");
    }
    if (analog_seen > total_analog) m.fail("metadata: " + std::to_string(analog_seen) + " analog channels named but total analog = " + std::to_string(total_analog));

    auto chunks_in_order = [&](const std::map<std::uint64_t, Entry>& chunks, const std::string& pattern) {
        std::vector<Entry> v;
        std::uint64_t expect = 1;
        for (const auto& [n, e] : chunks) {
            if (n != expect) m.fail("missing chunk " + pattern + std::to_string(expect) + " (the next present is " + pattern + std::to_string(n) + ")");
            v.push_back(e);
            ++expect;
        }
        return v;
    };
    std::uint64_t declared = 0;
    std::optional<std::uint64_t> frames;
    std::string frames_from;
    auto agree = [&](std::uint64_t n, const std::string& who) {
        if (!frames) { frames = n; frames_from = who; return; }
        if (*frames != n)
            m.fail("length mismatch: " + frames_from + " has " + std::to_string(*frames) + " samples but " + who + " has " + std::to_string(n));
    };
    auto find_channel = [&](const std::string& col, bool logic) -> std::optional<Channel> {
        const auto it = channel_for.find(col);
        const std::string name = it == channel_for.end() ? col : it->second;
        const auto f = by_name.find(name);
        if (f == by_name.end()) {
            if (it == channel_for.end()) return std::nullopt;
            std::string known;
            for (const auto& c : channel_list_) known += (known.empty() ? "" : ", ") + c;
            m.fail("column '" + col + "' is mapped to channel " + quote(name) + ", which the session does not have (channels: " + (known.empty() ? "none" : known) + ")");
        }
        if (f->second.size() > 1) m.fail("two channels are named " + quote(name) + ": map the column to one by another name");
        const Channel c = f->second.front();
        if (c.logic != logic)
            m.fail("column '" + col + "' needs a" + (logic ? " logic" : "n analog") + " channel, but " + quote(name) + " is " + (c.logic ? "a logic" : "an analog") + " channel");
        return c;
    };
    std::set<std::string> used_channels;
    auto claim = [&](const std::string& col) {
        const auto it = channel_for.find(col);
        const std::string name = it == channel_for.end() ? col : it->second;
        if (!used_channels.insert(name).second) m.fail("channel " + quote(name) + " is mapped to two columns");
    };
    for (const char* col : kAnalogColumns) {
        const auto c = find_channel(col, false);
        if (!c) continue;
        claim(col);
        const std::string pattern = "analog-1-" + std::to_string(c->n) + "-";
        auto it = analog_chunks.find(c->n);
        if (it == analog_chunks.end()) m.fail("channel " + quote(col) + " (analog" + std::to_string(c->n) + ") has no data: no " + pattern + "N entries");
        Impl::Stream s;
        s.what = "channel '" + std::string(col) + "' (" + pattern + "*)";
        s.chunks = chunks_in_order(it->second, pattern);
        for (const Entry& e : s.chunks) {
            if (e.size % 4 != 0) m.fail("entry " + quote(e.name) + " is " + std::to_string(e.size) + " bytes, not whole float32 samples");
            s.bytes = add_capped(s.bytes, e.size);
        }
        declared = add_capped(declared, s.bytes);
        agree(s.bytes / 4, "channel '" + std::string(col) + "'");
        m.analog.emplace(col, std::move(s));
    }
    for (const char* col : kLogicColumns) {
        // A readout's lines are read only when asked for by name (a capture's a/b/z are found
        // by their own names too): a capture's channels named clk or data stay unread.
        const bool word_line = std::string_view(col) == "clk" || std::string_view(col) == "data" || std::string_view(col) == "cs";
        if (word_line && !channel_for.count(col)) continue;
        const auto c = find_channel(col, true);
        if (!c) continue;
        claim(col);
        if (!unitsize) m.fail("metadata: logic channels need unitsize (bytes per logic sample)");
        if (c->n > *unitsize * 8) m.fail("metadata: probe" + std::to_string(c->n) + " does not fit in unitsize " + std::to_string(*unitsize) + " bytes");
        m.logic_bit[col] = static_cast<int>(c->n - 1);
    }
    if (!m.logic_bit.empty()) {
        if (logic_single && !logic_chunks.empty()) m.fail("both 'logic-1' and 'logic-1-N' entries: the logic data is ambiguous");
        if (logic_single) m.logic.chunks = {*logic_single};
        else if (logic_chunks.empty()) m.fail("logic channels are named but there is no logic data (no logic-1-N entries)");
        else m.logic.chunks = chunks_in_order(logic_chunks, "logic-1-");
        m.unitsize = static_cast<std::size_t>(*unitsize);
        m.logic.what = "the logic data (logic-1-*)";
        for (const Entry& e : m.logic.chunks) {
            if (e.size % m.unitsize != 0) m.fail("entry " + quote(e.name) + " is " + std::to_string(e.size) + " bytes, not whole samples of unitsize " + std::to_string(m.unitsize));
            m.logic.bytes = add_capped(m.logic.bytes, e.size);
        }
        declared = add_capped(declared, m.logic.bytes);
        agree(m.logic.bytes / m.unitsize, "the logic data");
    }
    // Before a sample is inflated: the declared sizes are what the data expands to at most
    // (read_bytes refuses a member that inflates further), so this bounds time and disk-equivalent
    // size whatever the archive holds.
    if (declared > max_data_bytes)
        throw CaptureTooLarge(path + ": the sample data declares " + (declared == kSaturated ? "more than 2^64" : std::to_string(declared)) +
                                  " bytes uncompressed (" + mib(declared) + "), more than the " + mib(max_data_bytes) +
                                  " allowed (a limit against ZIP bombs)",
                              declared, max_data_bytes);
    data_bytes_ = declared;
    frames_ = frames.value_or(0);
}

SigrokSession::~SigrokSession() = default;

bool SigrokSession::has(const std::string& column) const {
    return impl_->analog.count(column) > 0 || impl_->logic_bit.count(column) > 0;
}

void SigrokSession::read(std::size_t n, std::map<std::string, std::vector<double>>& out) {
    Impl& m = *impl_;
    static_assert(std::endian::native == std::endian::little, "float32 chunks are little-endian");
    for (auto& [col, s] : m.analog) {
        m.buf.resize(n * 4);
        m.read_bytes(s, m.buf.data(), n * 4);
        auto& v = out[col];
        for (std::size_t i = 0; i < n; ++i) {
            float f;
            std::memcpy(&f, m.buf.data() + 4 * i, 4);
            v.push_back(f);
        }
    }
    if (!m.logic_bit.empty()) {
        m.buf.resize(n * m.unitsize);
        m.read_bytes(m.logic, m.buf.data(), n * m.unitsize);
        for (const auto& [col, bit] : m.logic_bit) {
            auto& v = out[col];
            const std::size_t byte = static_cast<std::size_t>(bit / 8);
            const int shift = bit % 8;
            for (std::size_t i = 0; i < n; ++i) v.push_back((m.buf[i * m.unitsize + byte] >> shift) & 1 ? 1.0 : 0.0);
        }
    }
}

}  // namespace fringe
