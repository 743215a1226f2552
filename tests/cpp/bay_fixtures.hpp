#pragma once
// Test bays shared by the stage tests: a slice of the wall whose TD is a given function of the
// position, sampled per_cell x per_cell points per grid cell, without voxel or outlier filtering.
#include <cmath>
#include <functional>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/surface.hpp"

namespace shotcrete::test {

/// TD [m] at (d [m] along the axis, theta [rad]); NaN leaves a hole in the scan.
using TdFunction = std::function<double(double d_m, double theta_rad)>;

/// The slice theta in [t0, t1], d in [0, L] of `cfg`'s design circle; cfg's preprocess filters are
/// switched off (the caller's config then plans the same surface).
inline Surface analytic_bay(const TdFunction& td, Config& cfg, double t0 = 0.9, double t1 = 1.6, double L = 0.8,
                            int per_cell = 3) {
  const double R = cfg.profile.design_radius_m, cs = cfg.grid.cell_size_m;
  const int rows = static_cast<int>(std::round((t1 - t0) * R / cs)), cols = static_cast<int>(std::round(L / cs));
  Cloud c;
  c.xyz.resize(static_cast<Eigen::Index>(rows) * cols * per_cell * per_cell, 3);
  Eigen::Index k = 0;
  for (int i = 0; i < rows; ++i)
    for (int j = 0; j < cols; ++j)
      for (int a = 0; a < per_cell; ++a)
        for (int b = 0; b < per_cell; ++b) {
          const double theta = t0 + (i + (a + 0.5) / per_cell) * cs / R, d = (j + (b + 0.5) / per_cell) * cs;
          const double t = td(d, theta);
          if (std::isnan(t)) continue;  // a hole in the scan
          const double r = R + t;
          c.xyz.row(k++) << d, r * std::cos(theta), r * std::sin(theta);
        }
  c.xyz.conservativeResize(k, 3);
  cfg.preprocess.voxel_size_m = 0;
  cfg.preprocess.outlier_neighbors = 0;
  return build_surface(c, cfg);
}

}  // namespace shotcrete::test
