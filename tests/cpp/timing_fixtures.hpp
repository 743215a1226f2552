#pragma once
// Shared by the timing tests: a serpentine region of axial passes on a tunnel wall.
#include <Eigen/Core>
#include <cmath>
#include <vector>

#include "shotcrete/planning/planner.hpp"

namespace shotcrete::test {

constexpr double kPi = 3.14159265358979323846;

// Axial passes on a nozzle cylinder of radius rn (wall 5.6 m at 1 m standoff), serpentine.
inline std::vector<Pass> axial_region(int n, double length, double wall_spacing, double x0, double theta0,
                                      const std::vector<double>& speeds, double rn = 4.6, double R = 5.6) {
  std::vector<Pass> passes;
  for (int i = 0; i < n; ++i) {
    const double th = theta0 + i * wall_spacing / R;
    Pass p;
    const int m = static_cast<int>(std::round(length / 0.01));
    for (int k = 0; k <= m; ++k) {
      const double f = static_cast<double>(k) / m;
      const double x = x0 + (i % 2 == 0 ? f : 1.0 - f) * length;
      NozzlePose w;
      w.position_m = Eigen::Vector3d(x, rn * std::cos(th), rn * std::sin(th));
      w.axis = Eigen::Vector3d(0, std::cos(th), std::sin(th));
      p.waypoints.push_back(w);
    }
    p.speed_mps = speeds[static_cast<std::size_t>(i) % speeds.size()];
    p.length_m = length;
    passes.push_back(p);
  }
  return passes;
}

}  // namespace shotcrete::test
