#pragma once

// SI units inside, other units at one edge only (ARCHITECTURE.md). The constants every folder
// needs to convert at that edge, defined once:
//
//   const double angle = angle_deg * common::kDeg;       // degrees -> radians
//   const double angle_deg = common::ToDegrees(angle);   // radians -> degrees (for printing)
//   out << x * common::kMmPerM << " mm";                // metres -> millimetres

namespace kinevis::common {

inline constexpr double kPi = 3.14159265358979323846;
// One degree, in radians.
inline constexpr double kDeg = kPi / 180.0;
// Output units per SI unit, for files and printing that use degrees and millimetres.
inline constexpr double kDegPerRad = 180.0 / kPi;
inline constexpr double kMmPerM = 1e3;

constexpr double ToDegrees(double radians) { return radians * kDegPerRad; }
constexpr double ToRadians(double degrees) { return degrees * kDeg; }

}  // namespace kinevis::common
