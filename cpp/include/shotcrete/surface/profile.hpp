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

/// The axis fitted to a cloud with normals (docs/architecture.md §3, "Axis estimation").
struct AxisFit {
  TunnelAxis axis;          // origin: on the axis where the scan starts (0.5 % quantile), or the given one
  double radius_m = 0.0;    // mean distance of the points to the fitted axis
  double rms_m = 0.0;       // RMS distance of the points to the coaxial cylinder of radius_m
  double arc_rad = 0.0;     // arc the points cover around the axis (2 pi minus the largest gap)
  long points = 0;          // points used
  bool origin_fitted = true;  // false: the centre line goes through the given profile.axis_origin_m
};

/// Points needed for an axis fit.
constexpr long kMinAxisFitPoints = 100;
/// Largest fit RMS accepted, as a fraction of the fitted radius.
constexpr double kMaxAxisFitRmsFraction = 0.05;
/// Quantile of the radial distances the cylinder is fitted to: the intact contour (least
/// over-break) of the wall, not its mean, which dig pits pull outward.
constexpr double kAxisFitQuantile = 0.005;
/// The same, refitted on the means of 7.5 cm patches (less noise, so a looser quantile).
constexpr double kAxisFitPatchQuantile = 0.01;

/// Fits the tunnel axis: the direction starts as the one most perpendicular to the normals (with
/// the most tilted normals dropped) and is refined with the centre by a quantile (lower envelope)
/// cylinder fit of the points; profile.axis_direction orients it, profile.axis_origin_m is kept
/// when profile.estimate_axis_origin is false. Throws std::invalid_argument, one line, when the
/// cloud is not a tunnel wall: too few points, no curvature (a plane), a radius more than
/// profile.max_deviation_m from the design radius, an arc below profile.min_fit_arc_rad, or an RMS
/// above kMaxAxisFitRmsFraction of the radius.
AxisFit fit_axis(const Cloud& cloud, const ProfileConfig& profile);

}  // namespace shotcrete
