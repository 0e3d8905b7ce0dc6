// Mathematical constants, defined once for every layer.
#pragma once

namespace fringe {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 6.28318530717958647692;

}  // namespace fringe
