#include "optics.hpp"

#include "fastmath.hpp"

#include <cmath>
#include <complex>
#include <limits>

namespace fringe::optics {

double sine_integral(double x) {
    const double ax = std::fabs(x);
    double si;
    if (ax == 0.0) return 0.0;
    if (ax <= 2.0) {
        // Si(x) = sum_n (-1)^n x^(2n+1) / ((2n+1) (2n+1)!)
        double term = ax;  // x^(2n+1)/(2n+1)!
        double sum = ax;
        const double x2 = ax * ax;
        for (int n = 1; n < 40; ++n) {
            term *= -x2 / ((2.0 * n) * (2.0 * n + 1.0));
            double add = term / (2.0 * n + 1.0);
            sum += add;
            if (std::fabs(add) < 1e-18 * std::fabs(sum)) break;
        }
        si = sum;
    } else {
        // E1(i x) = e^{-ix} / (ix + 1 - 1^2/(ix + 3 - 2^2/(ix + 5 - ...))), modified Lentz.
        // Si(x) = pi/2 + Im(E1(ix)) for x > 0.
        using cd = std::complex<double>;
        const double tiny = 1e-300;
        cd b(1.0, ax);
        cd c = 1.0 / tiny;
        cd d = 1.0 / b;
        cd h = d;
        for (int i = 1; i < 1000; ++i) {
            double a = -static_cast<double>(i) * i;
            b += 2.0;
            d = 1.0 / (a * d + b);
            c = b + a / c;
            cd del = c * d;
            h *= del;
            if (std::abs(del - 1.0) < 1e-16) break;
        }
        h *= cd(std::cos(ax), -std::sin(ax));
        si = kPi / 2 + h.imag();
    }
    return x < 0 ? -si : si;
}

double slit_intensity(double u) {
    if (std::fabs(u) < 1e-4) return 1.0 - u * u / 3.0;
    double s = std::sin(u) / u;
    return s * s;
}

double slit_integral(double u) {
    if (std::fabs(u) < 1e-3) {
        // integral of 1 - u^2/3 + 2u^4/45 - u^6/315
        double u2 = u * u;
        return u * (1.0 - u2 / 9.0 + 2.0 * u2 * u2 / 225.0 - u2 * u2 * u2 / 2205.0);
    }
    double s = std::sin(u);
    return sine_integral(2.0 * u) - s * s / u;
}

int harmonic_count(double kappa) {
    return std::max(0, static_cast<int>(std::ceil(2.0 * kappa)) - 1);
}

double fourier_weight(int m, double kappa) { return std::max(0.0, 1.0 - m / (2.0 * kappa)); }

double aperture_coefficient(int m, double kappa, double w_rad) {
    return (2.0 / m) * fourier_weight(m, kappa) * std::sin(m * w_rad / 2.0);
}

double aperture_coefficient_dkappa(int m, double kappa, double w_rad) {
    return (m < 2.0 * kappa) ? std::sin(m * w_rad / 2.0) / (kappa * kappa) : 0.0;
}

double aperture_fourier(double centre_rad, double kappa, double w_rad) {
    double v = w_rad / 2.0;
    for (int m = 1, M = harmonic_count(kappa); m <= M; ++m)
        v += aperture_coefficient(m, kappa, w_rad) * std::cos(m * centre_rad);
    return v;
}

namespace {
// Digamma for large x (x > 100): asymptotic series, error < 1e-20.
double digamma_large(double x) {
    double x2 = 1.0 / (x * x);
    return std::log(x) - 0.5 / x - x2 * (1.0 / 12 - x2 * (1.0 / 120 - x2 * (1.0 / 252 - x2 * (1.0 / 240))));
}
}  // namespace

double aperture_slit_sum(double centre_rad, double kappa, double w_rad, int k_exact, int k_osc) {
    const double theta0 = centre_rad - w_rad / 2.0;
    double sum = 0.0;
    for (int k = -k_exact; k <= k_exact; ++k) {
        double a = kappa * (theta0 + kTwoPi * k);
        sum += slit_integral(a + kappa * w_rad) - slit_integral(a);
    }
    // Smooth tail: sum over |k| > k_exact of 1/(2a) - 1/(2b), in closed form.
    const double p0 = theta0 / kTwoPi;
    const double p1 = (theta0 + w_rad) / kTwoPi;
    const double n0 = k_exact + 1.0;
    double smooth = (digamma_large(n0 + p1) - digamma_large(n0 + p0)) +
                    (digamma_large(n0 - p0) - digamma_large(n0 - p1));
    sum += smooth / (4.0 * kPi * kappa);
    // Oscillating tail: -[sin(2b)/(4b^2) - sin(2a)/(4a^2)].
    double osc = 0.0;
    for (int j = k_osc; j > k_exact; --j) {  // smallest terms first
        for (int sgn = -1; sgn <= 1; sgn += 2) {
            double a = kappa * (theta0 + kTwoPi * sgn * j);
            double b = a + kappa * w_rad;
            osc -= std::sin(2 * b) / (4 * b * b) - std::sin(2 * a) / (4 * a * a);
        }
    }
    return sum + osc;
}

double fundamental_amplitude(double kappa, double w_rad) {
    return 2.0 * fourier_weight(1, kappa) * std::sin(w_rad / 2.0);
}

}  // namespace fringe::optics
