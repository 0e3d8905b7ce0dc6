#include "analysis.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace fringe {

HarmonicFit fit_harmonics(const double* v, const double* theta, std::size_t n, int K) {
    const int p = 2 * K + 1;
    if (n < static_cast<std::size_t>(p)) throw std::invalid_argument("fit_harmonics: too few samples");
    Eigen::MatrixXd ata = Eigen::MatrixXd::Zero(p, p);
    Eigen::VectorXd atb = Eigen::VectorXd::Zero(p);
    Eigen::VectorXd row(p);
    for (std::size_t i = 0; i < n; ++i) {
        row(0) = 1.0;
        for (int k = 1; k <= K; ++k) {
            row(2 * k - 1) = std::cos(k * theta[i]);
            row(2 * k) = std::sin(k * theta[i]);
        }
        ata.selfadjointView<Eigen::Lower>().rankUpdate(row);
        atb += row * v[i];
    }
    ata = ata.selfadjointView<Eigen::Lower>();
    Eigen::LDLT<Eigen::MatrixXd> ldlt(ata);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive())
        throw std::runtime_error("fit_harmonics: singular normal equations (theta does not cover a cycle?)");
    Eigen::VectorXd x = ldlt.solve(atb);
    HarmonicFit f;
    f.dc = x(0);
    for (int k = 1; k <= K; ++k) {
        f.cos_coef.push_back(x(2 * k - 1));
        f.sin_coef.push_back(x(2 * k));
        f.amplitude.push_back(std::hypot(x(2 * k - 1), x(2 * k)));
    }
    return f;
}

double duty_cycle(const double* v, std::size_t n) {
    if (n == 0) return 0.0;
    auto [lo, hi] = std::minmax_element(v, v + n);
    const double mid = 0.5 * (*lo + *hi);
    std::size_t above = 0;
    for (std::size_t i = 0; i < n; ++i) above += v[i] > mid;
    return static_cast<double>(above) / static_cast<double>(n);
}

}  // namespace fringe
