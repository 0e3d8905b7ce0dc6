#include "server/engine/evaluate.hpp"

#include "drivers/capture_file.hpp"

#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>

namespace fringe {

EstimatesWriter::EstimatesWriter(const std::string& path) : path_(path) {
    f_ = std::fopen(path.c_str(), "w");
    if (!f_) throw CaptureError(path + ": cannot write: " + std::strerror(errno));
    std::fputs("t,theta_rad,omega_rad_s,valid\n", f_);
}

void EstimatesWriter::write(std::size_t n, const double* t, const double* th, const double* om, const std::uint8_t* v) {
    buf_.resize(n * 80);
    char* p = buf_.data();
    for (std::size_t i = 0; i < n; ++i) {
        p = std::to_chars(p, p + 32, t[i]).ptr; *p++ = ',';
        p = std::to_chars(p, p + 32, th[i]).ptr; *p++ = ',';
        p = std::to_chars(p, p + 32, om[i]).ptr; *p++ = ',';
        *p++ = v[i] ? '1' : '0'; *p++ = '\n';
    }
    const std::size_t len = static_cast<std::size_t>(p - buf_.data());
    if (std::fwrite(buf_.data(), 1, len, f_) != len) throw CaptureError(path_ + ": write failed: " + std::strerror(errno));
}

void EstimatesWriter::close() {
    if (f_) {
        const bool bad = std::fclose(f_) != 0;
        f_ = nullptr;
        if (bad) throw CaptureError(path_ + ": close failed");
    }
}

}  // namespace fringe
