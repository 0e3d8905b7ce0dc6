// Photodetector optics of MODEL.md section 2 (paper eqs 1-4): Fraunhofer single-slit
// intensity F(u) = (sin u/u)^2, its integral Phi(u), the incoherent sum over all slits
// integrated over the detector aperture, and its finite Fourier series.
//
// Units: u is the diffraction argument (dimensionless); theta and w are electrical radians;
// voltages here are normalised to Vmax = 1.
#pragma once

#include <vector>

namespace fringe::optics {

// Sine integral Si(x) = integral_0^x sin(t)/t dt. Power series for |x| <= 2, continued
// fraction of E1(ix) beyond; ~1e-15 absolute.
double sine_integral(double x);

// F(u) = (sin u/u)^2 with F(0) = 1 (eq. 3).
double slit_intensity(double u);

// Phi(u) = integral_0^u F = Si(2u) - sin(u)^2/u (MODEL.md 2).
double slit_integral(double u);

// Highest harmonic with non-zero weight: M = ceil(2*kappa) - 1.
int harmonic_count(double kappa);

// c_m(kappa) = max(0, 1 - m/(2*kappa)): Fourier weights of the periodised intensity.
double fourier_weight(int m, double kappa);

// B_m = (2/m)*c_m(kappa)*sin(m*w/2): weight of cos(m*theta_c) in the aperture integral,
// theta_c being the aperture centre (MODEL.md 2.2).
double aperture_coefficient(int m, double kappa, double w_rad);

// dB_m/dkappa = sin(m*w/2)/kappa^2 for m < 2*kappa, else 0.
double aperture_coefficient_dkappa(int m, double kappa, double w_rad);

// Normalised detector output from the closed form: w/2 + sum_m B_m cos(m*centre_rad).
double aperture_fourier(double centre_rad, double kappa, double w_rad);

// The same quantity from the slit sum in its direct form,
//   sum_k [Phi(kappa*(theta0 + 2*pi*k) + kappa*w) - Phi(kappa*(theta0 + 2*pi*k))],
// theta0 = centre - w/2: exact Phi terms for |k| <= k_exact, then the asymptotic
// expansion Phi(u) = sign(u)*pi/2 - 1/(2u) - sin(2u)/(4u^2) + O(u^-3), whose smooth part is
// summed in closed form (digamma) and whose oscillating part explicitly to k_osc. Slow; an
// independent check of the closed form for tests (accuracy ~1e-11 when 2*kappa is not
// an integer).
double aperture_slit_sum(double centre_rad, double kappa, double w_rad, int k_exact = 3000,
                         int k_osc = 200000);

// Fundamental amplitude, 2*(1 - 1/(2*kappa))*sin(w/2) (normalised; = B_1).
double fundamental_amplitude(double kappa, double w_rad);

}  // namespace fringe::optics
