#pragma once
// Synthetic tunnel bay: a half-cylinder wall outside the design line by a base over-break plus
// random dig pits dT = Tmax (1 - d^2/D^2)^alpha, sampled with radial scanner noise. Seeded.
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/profile.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

struct DigPit {
  double d_m = 0;      // centre along the axis
  double s_m = 0;      // centre along the wall arc (s = theta * r_design)
  double depth_m = 0;  // Tmax
  double radius_m = 0; // D
};

struct SyntheticBay {
  SynthConfig config;
  std::vector<DigPit> pits;
  TunnelAxis axis;  // x axis through the origin

  /// Noise-free TD (m) of the wall at (d, theta): over-break, pits, less the protrusion.
  double td_at(double d_m, double theta_rad) const;
  /// Points on the wall with radial noise; about points_per_cell per cell of `cell_size_m`.
  Cloud sample(double cell_size_m = 0.05) const;
};

SyntheticBay make_synthetic_bay(const SynthConfig& config);

}  // namespace shotcrete
