// The estimates CSV of `fringe estimate` (t,theta_rad,omega_rad_s,valid): the estimator's
// output as it left it, written block by block, complete up to a failure.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

namespace fringe {

// Numbers in their shortest round-trip form.
class EstimatesWriter {
public:
    explicit EstimatesWriter(const std::string& path);
    ~EstimatesWriter() { if (f_) std::fclose(f_); }  // on an error path: what was written stays
    EstimatesWriter(const EstimatesWriter&) = delete;
    EstimatesWriter& operator=(const EstimatesWriter&) = delete;
    void write(std::size_t n, const double* t, const double* theta, const double* omega, const std::uint8_t* valid);
    void close();

private:
    std::string path_;
    std::FILE* f_ = nullptr;
    std::string buf_;
};

}  // namespace fringe
