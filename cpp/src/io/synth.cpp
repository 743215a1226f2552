#include "shotcrete/io/synth.hpp"

#include <cmath>
#include <random>
#include <stdexcept>

namespace shotcrete {

SyntheticBay make_synthetic_bay(const SynthConfig& c) {
  if (!(c.design_radius_m > 0)) throw std::invalid_argument("synth: design_radius_m must be > 0");
  if (!(c.length_m > 0)) throw std::invalid_argument("synth: length_m must be > 0");
  if (!(c.theta_max_rad > c.theta_min_rad)) throw std::invalid_argument("synth: theta_max_rad must exceed theta_min_rad");
  SyntheticBay bay;
  bay.config = c;
  std::mt19937_64 rng(c.seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double s0 = c.theta_min_rad * c.design_radius_m, s1 = c.theta_max_rad * c.design_radius_m;
  for (int i = 0; i < c.pit_count; ++i) {
    DigPit p;
    p.d_m = u(rng) * c.length_m;
    p.s_m = s0 + u(rng) * (s1 - s0);
    p.depth_m = c.pit_depth_min_m + u(rng) * (c.pit_depth_max_m - c.pit_depth_min_m);
    p.radius_m = c.pit_radius_min_m + u(rng) * (c.pit_radius_max_m - c.pit_radius_min_m);
    bay.pits.push_back(p);
  }
  return bay;
}

double SyntheticBay::td_at(double d_m, double theta_rad) const {
  const double s = theta_rad * config.design_radius_m;
  double td = config.base_overbreak_m;
  for (const auto& p : pits) {
    const double q = ((d_m - p.d_m) * (d_m - p.d_m) + (s - p.s_m) * (s - p.s_m)) / (p.radius_m * p.radius_m);
    if (q < 1.0) td += p.depth_m * std::pow(1.0 - q, config.pit_shape_alpha);
  }
  if (config.protrusion_height_m > 0.0) {
    const double ds = s - config.protrusion_theta_rad * config.design_radius_m, dd = d_m - config.protrusion_d_m;
    const double q = (dd * dd + ds * ds) / (config.protrusion_radius_m * config.protrusion_radius_m);
    if (q < 1.0) td -= config.protrusion_height_m * std::pow(1.0 - q, config.pit_shape_alpha);
  }
  return td;
}

Cloud SyntheticBay::sample(double cell_size_m) const {
  const auto& c = config;
  const double arc = (c.theta_max_rad - c.theta_min_rad) * c.design_radius_m;
  const auto n = static_cast<Eigen::Index>(std::llround(arc * c.length_m / (cell_size_m * cell_size_m) * c.points_per_cell));
  if (n < 1) throw std::invalid_argument("synth: the bay would have no points");
  // A second stream, so the pits do not change when only the sampling density does.
  std::mt19937_64 rng(c.seed * 0x9E3779B97F4A7C15ULL + 17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, c.noise_m > 0 ? c.noise_m : 1.0);
  Cloud cloud;
  cloud.xyz.resize(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double d = u(rng) * c.length_m;
    const double theta = c.theta_min_rad + u(rng) * (c.theta_max_rad - c.theta_min_rad);
    const double r = c.design_radius_m + td_at(d, theta) + (c.noise_m > 0 ? noise(rng) : 0.0);
    cloud.xyz.row(i) = axis.to_cartesian(r, theta, d).transpose();
  }
  return cloud;
}

}  // namespace shotcrete
