#pragma once
// Tunnel frame, cylindrical unroll and the design profile.
#include "shotcrete/config.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

/// The tunnel axis as a line with a right-handed frame: ex along the axis, ey horizontal across,
/// ez up (REP 103 style). theta = atan2(z', y'): 0 at the right springline, pi/2 at the crown.
struct TunnelAxis {
  Eigen::Vector3d origin_m{0, 0, 0};
  Eigen::Vector3d ex{1, 0, 0}, ey{0, 1, 0}, ez{0, 0, 1};

  static TunnelAxis from_direction(const Eigen::Vector3d& origin_m, const Eigen::Vector3d& direction);
  /// (r, theta, d) of a Cartesian point; theta in [-pi/2, 3pi/2): the cut lies at the invert.
  Eigen::Vector3d to_cylindrical(const Eigen::Vector3d& p) const;
  /// Cartesian point of (r, theta, d).
  Eigen::Vector3d to_cartesian(double r_m, double theta_rad, double d_m) const;
  /// Unit vector from the axis toward the wall at angle theta.
  Eigen::Vector3d radial(double theta_rad) const;
};

/// Design line: radius as a function of theta (a circle today; horseshoe profiles can follow).
struct DesignProfile {
  double radius_m = 5.6;
  double radius_at(double /*theta_rad*/) const { return radius_m; }
};

/// The axis from the config, or fitted to the cloud when profile.estimate_axis is set.
TunnelAxis axis_from_config(const ProfileConfig& config);

/// Fits the tunnel axis to a cloud with normals: the direction is the one most perpendicular to
/// all normals, the centre comes from an algebraic circle fit refined by Gauss-Newton on the
/// points projected across the axis. Throws std::invalid_argument when the cloud cannot define it.
struct AxisFit {
  TunnelAxis axis;
  double radius_m = 0.0;
  double rms_m = 0.0;  // RMS distance of the points to the fitted cylinder
};
AxisFit fit_axis(const Cloud& cloud, const Eigen::Vector3d& direction_hint);

}  // namespace shotcrete
