// Text from outside (requests, files, device messages) on its way into JSON, XML, logs and
// terminals: UTF-8 validation, replacement of what is not UTF-8, and escaping of control characters.
#pragma once

#include <cstddef>
#include <cstdio>
#include <string>
#include <string_view>

namespace fringe {

// Length of the well-formed UTF-8 sequence at s[i] (RFC 3629: no overlongs, no surrogates,
// nothing past U+10FFFF), or 0 if the bytes there are not one.
inline std::size_t utf8_sequence(std::string_view s, std::size_t i) {
    const auto b = [&](std::size_t k) { return static_cast<unsigned char>(s[k]); };
    const unsigned char c = b(i);
    if (c < 0x80) return 1;
    std::size_t n = 0;
    unsigned char lo = 0x80, hi = 0xbf;  // range of the second byte
    if (c >= 0xc2 && c <= 0xdf) n = 2;
    else if (c == 0xe0) n = 3, lo = 0xa0;
    else if (c >= 0xe1 && c <= 0xec) n = 3;
    else if (c == 0xed) n = 3, hi = 0x9f;
    else if (c >= 0xee && c <= 0xef) n = 3;
    else if (c == 0xf0) n = 4, lo = 0x90;
    else if (c >= 0xf1 && c <= 0xf3) n = 4;
    else if (c == 0xf4) n = 4, hi = 0x8f;
    else return 0;
    if (i + n > s.size()) return 0;
    if (b(i + 1) < lo || b(i + 1) > hi) return 0;
    for (std::size_t k = 2; k < n; ++k)
        if (b(i + k) < 0x80 || b(i + k) > 0xbf) return 0;
    return n;
}

// Offset of the first byte that is not well-formed UTF-8, or npos.
inline std::size_t invalid_utf8_at(std::string_view s) {
    for (std::size_t i = 0; i < s.size();) {
        const std::size_t n = utf8_sequence(s, i);
        if (n == 0) return i;
        i += n;
    }
    return std::string_view::npos;
}

inline bool valid_utf8(std::string_view s) { return invalid_utf8_at(s) == std::string_view::npos; }

// Every byte that is not part of well-formed UTF-8 becomes U+FFFD.
inline std::string sanitize_utf8(std::string_view s) {
    std::string o;
    o.reserve(s.size());
    for (std::size_t i = 0; i < s.size();) {
        const std::size_t n = utf8_sequence(s, i);
        if (n == 0) {
            o += "\xef\xbf\xbd";
            ++i;
        } else {
            o.append(s.substr(i, n));
            i += n;
        }
    }
    return o;
}

namespace text_detail {
// Shared by log_escape and term_escape: C0 controls, DEL, bytes that are not UTF-8, the C1
// controls (U+0080..U+009F: some terminals act on them even UTF-8 encoded) and the
// bidirectional overrides (U+202A..U+202E, U+2066..U+2069: they reorder what follows) are
// written visibly; everything else is copied.
inline std::string escape(std::string_view s, bool backslash, bool keep_newlines) {
    std::string o;
    o.reserve(s.size());
    char hex[8];
    for (std::size_t i = 0; i < s.size();) {
        const auto c = static_cast<unsigned char>(s[i]);
        const std::size_t n = utf8_sequence(s, i);
        if (c == '\n' && keep_newlines) o += '\n';
        else if (c == '\n') o += "\\n";
        else if (c == '\r') o += "\\r";
        else if (c == '\t') o += "\\t";
        else if (c == '\\' && backslash) o += "\\\\";
        else if (n == 0 || c < 0x20 || c == 0x7f) {
            std::snprintf(hex, sizeof hex, "\\x%02x", c);
            o += hex;
        } else if (n == 1) {
            o += static_cast<char>(c);
        } else {
            // Code point of a 2- or 3-byte sequence (the only lengths the ranges above use).
            unsigned cp = 0;
            if (n == 2) cp = ((c & 0x1fu) << 6) | (static_cast<unsigned char>(s[i + 1]) & 0x3fu);
            else if (n == 3) cp = ((c & 0x0fu) << 12) | ((static_cast<unsigned char>(s[i + 1]) & 0x3fu) << 6) | (static_cast<unsigned char>(s[i + 2]) & 0x3fu);
            if ((cp >= 0x80 && cp <= 0x9f) || (cp >= 0x202a && cp <= 0x202e) || (cp >= 0x2066 && cp <= 0x2069)) {
                std::snprintf(hex, sizeof hex, "\\u%04x", cp);
                o += hex;
            } else {
                o.append(s.substr(i, n));
            }
            i += n;
            continue;
        }
        ++i;
    }
    return o;
}
}  // namespace text_detail

// One log line per event: CR, LF, other control characters and bytes that are not UTF-8
// are written as \r, \n, \t, \xNN (C1 controls and bidi overrides as \uNNNN), so a request
// cannot forge or split log lines.
inline std::string log_escape(std::string_view s) { return text_detail::escape(s, true, false); }

// Text from a device, a file or a client on its way to an operator's terminal (run summaries,
// the run history, warnings, errors): ESC and every other control character (NUL included),
// DEL, C1 controls and bidi overrides are shown visibly (\x1b, \x00, \u009b), bytes that are
// not UTF-8 as \xNN; nothing the terminal would act on gets through, nothing is cut at a NUL.
// keep_newlines: for multi-line blocks (a table) whose lines come from fringe itself.
inline std::string term_escape(std::string_view s, bool keep_newlines = false) { return text_detail::escape(s, false, keep_newlines); }

}  // namespace fringe
