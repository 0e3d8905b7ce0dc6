// Text from outside (requests, files, device messages) on its way into JSON, XML and logs:
// UTF-8 validation, replacement of what is not UTF-8, and escaping of control characters.
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

// One log line per event: CR, LF, other control characters and bytes that are not UTF-8
// are written as \r, \n, \t, \xNN, so a request cannot forge or split log lines.
inline std::string log_escape(std::string_view s) {
    std::string o;
    o.reserve(s.size());
    char hex[5];
    for (std::size_t i = 0; i < s.size();) {
        const auto c = static_cast<unsigned char>(s[i]);
        const std::size_t n = utf8_sequence(s, i);
        if (c == '\n') o += "\\n";
        else if (c == '\r') o += "\\r";
        else if (c == '\t') o += "\\t";
        else if (c == '\\') o += "\\\\";
        else if (n == 0 || c < 0x20 || c == 0x7f) {
            std::snprintf(hex, sizeof hex, "\\x%02x", c);
            o += hex;
        } else {
            o.append(s.substr(i, n));
            i += n;
            continue;
        }
        ++i;
    }
    return o;
}

}  // namespace fringe
