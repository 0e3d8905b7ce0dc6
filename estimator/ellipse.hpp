// The Heydemann least-squares ellipse fit (MODEL.md 4.1) that atan2-ellipse runs, for whoever
// else identifies a Lissajous calibration from signals (fringe calibrate).
#pragma once

#include "common.hpp"

#include <Eigen/Dense>

#include <string>

namespace fringe::est {

// Least squares on A c^2 + B cs + C s^2 + D c + E s = 1 (the origin lies inside the ellipse
// whenever the offsets are below the amplitudes).
struct ConicAccumulator {
    Eigen::Matrix<double, 5, 5> M = Eigen::Matrix<double, 5, 5>::Zero();
    Eigen::Matrix<double, 5, 1> v = Eigen::Matrix<double, 5, 1>::Zero();
    double points = 0;  // effective number of points
    void add(double s, double c, double keep = 1.0) {
        Eigen::Matrix<double, 5, 1> m;
        m << c * c, c * s, s * s, c, s;
        M = keep * M + m * m.transpose();
        v = keep * v + m;
        points = keep * points + 1.0;
    }
};

// The centre, the normalised quadratic form and sin(delta) = b'/(2 sqrt(a'c')),
// A_c = 1/(cos(delta) sqrt(a')), A_s = 1/(cos(delta) sqrt(c')). Returns an empty string on
// success (out set), else why the fit is rejected (out untouched).
std::string fit_ellipse(const ConicAccumulator& acc, Calibration& out);

}  // namespace fringe::est
