#pragma once
// Tunnel frame, cylindrical unroll and the design profile.
#include "shotcrete/config.hpp"
#include "shotcrete/types.hpp"

#include <string>
#include <vector>

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

/// A vertex of a design cross-section in the section plane: y along the axis frame's ey
/// (horizontal, to the left looking along the advance), z up, metres from the tunnel axis. bulge
/// (DXF LWPOLYLINE convention) shapes the edge to the next vertex: 0 a line, else an arc whose
/// included angle is 4 atan(bulge), counter-clockwise when positive.
struct SectionVertex {
  double y_m = 0.0, z_m = 0.0, bulge = 0.0;
};

/// Design line of the cross-section: a circle of radius_m about the axis, or the sprayed part of a
/// section made of lines and arcs (horseshoe, multi-centre), from one foot over the crown to the
/// other, that every ray from the axis within its span meets once. TD is measured along the
/// profile's normal, positive outside (concrete missing).
struct DesignProfile {
  /// Circle: its radius. Section: the mean radius (arc length / angle spanned), which sets the
  /// grid's theta step so a cell spans cell_size_m of arc on average.
  double radius_m = 5.6;
  /// Section only: the edges flattened to chords (arcs within 0.2 mm), vertices in increasing
  /// theta, and each vertex's theta. Empty: the circle.
  std::vector<Eigen::Vector2d> polyline_m;
  std::vector<double> vertex_theta_rad;

  static DesignProfile circle(double radius_m);
  /// Throws std::invalid_argument (one line naming the problem) for fewer than two vertices,
  /// non-finite values, a profile some ray from the axis meets twice or tangentially (not
  /// star-shaped about the axis), or one crossing the invert's cut (straight down from the axis).
  static DesignProfile from_section(const std::vector<SectionVertex>& vertices);

  bool is_circle() const { return polyline_m.empty(); }
  double theta_min_rad() const;
  double theta_max_rad() const;
  bool covers(double theta_rad) const;
  /// Distance from the axis to the design line along theta. Off a section's span its end chords
  /// run on straight (the grid's end rows reach up to half a cell past the span); NaN where the
  /// extended chord no longer meets the ray.
  double radius_at(double theta_rad) const;
  /// Cosine of the angle between the design line's outward normal and the radial direction at
  /// theta (1 on a circle).
  double normal_cos_at(double theta_rad) const;
  /// Outward unit normal of the design line at theta in the section plane (y, z).
  Eigen::Vector2d normal_at(double theta_rad) const;
  /// TD [m] of a point at radius r_m and angle theta: its distance from the design line along the
  /// line's normal, positive outside: (r - R(theta)) cos(phi), exact on a circle and a line. NaN
  /// off a section's span (such a point is not wall).
  double td_m(double r_m, double theta_rad) const;
  /// Radial distance [m] from the design line at theta of a point at TD td_m: td / cos(phi).
  double radial_offset_m(double td_m, double theta_rad) const;

 private:
  int segment_at(double theta_rad) const;
};

/// Outward unit normal of the design line at theta in the tunnel frame (the radial direction on a circle).
Eigen::Vector3d design_normal(const TunnelAxis& axis, const DesignProfile& profile, double theta_rad);

/// Reads a design cross-section from a CSV file: one vertex per line, `y_m,z_m[,bulge]`, blank
/// lines and lines starting with '#' ignored, a header line `y_m,z_m[,bulge]` allowed. Throws
/// std::invalid_argument naming the file and line on a malformed value.
std::vector<SectionVertex> read_section_csv(const std::string& path);

/// The design profile of a config: the circle of profile.design_radius_m, or the section of
/// profile.section_path (CSV).
DesignProfile design_profile_from_config(const ProfileConfig& config);

/// The axis from the config, or fitted to the cloud when profile.estimate_axis is set.
TunnelAxis axis_from_config(const ProfileConfig& config);

/// A point of the tunnel's alignment (its axis as designed) at a chainage, in the scan's frame.
struct AlignmentPoint {
  double chainage_m = 0.0;
  Eigen::Vector3d xyz_m{0, 0, 0};
};

/// Reads an alignment CSV: one point per line, `chainage_m,x_m,y_m,z_m`, chainage strictly
/// increasing, '#' comments and a header allowed; a curve is given by its points (e.g. every metre).
/// Throws std::invalid_argument naming the file and line.
std::vector<AlignmentPoint> read_alignment_csv(const std::string& path);

/// The job's axis taken from the alignment where the scan lies (docs/architecture.md §3, "Alignment").
struct AxisOnAlignment {
  TunnelAxis axis;            // a straight axis through the alignment over the scan's stretch
  double chainage_m = 0.0;    // chainage of the axis origin (the job frame's d = 0)
  double start_m = 0.0, end_m = 0.0;  // chainage span the straight axis stands for
  double deviation_m = 0.0;   // largest distance of the alignment from the straight axis over it
  double scan_offset_m = 0.0; // distance of the scan's centre from the alignment
};

/// The straight axis that stands for the alignment over the scan: the scan's centre (`centre_m`,
/// e.g. the mean of its points) is projected onto the alignment (chainage c: the section through it); the axis runs along
/// the chord from c - half_span_m to c + half_span_m (clamped to the alignment), through the mean
/// of the alignment over it, origin at chainage c. Throws std::invalid_argument for fewer than two
/// points, a scan centre more than max_offset_m from the alignment or off its ends, or a non-finite input.
AxisOnAlignment axis_on_alignment(const std::vector<AlignmentPoint>& alignment, const Eigen::Vector3d& centre_m,
                                  double half_span_m, double max_offset_m = 20.0);

/// The config a scan is planned with when profile.alignment_path is set: the axis from the
/// alignment where the scan's points (xyz_m, metres in the config's frame; non-finite rows
/// ignored) lie, the half span half their extent along it, and grid.bay_start_m/bay_end_m, given
/// as chainages of the alignment, turned into distances from the axis origin. Without an
/// alignment, the config unchanged (`where` untouched). Throws std::invalid_argument as
/// read_alignment_csv and axis_on_alignment, or for a scan without finite points.
Config with_alignment_axis(const Config& config, const Points& xyz_m, AxisOnAlignment* where = nullptr);

/// The axis fitted to a cloud with normals (docs/architecture.md §3, "Axis estimation").
struct AxisFit {
  TunnelAxis axis;          // origin: on the axis where the scan starts (0.5 % quantile), or the given one
  double radius_m = 0.0;    // mean distance of the points to the fitted axis
  double rms_m = 0.0;       // RMS distance of the points to the coaxial cylinder of radius_m
  double arc_rad = 0.0;     // arc the points cover around the axis (2 pi minus the largest gap)
  long points = 0;          // points used (the wall)
  double inlier_share = 1.0;  // points / the cloud's points (the rest: face, floor, duct, rig, stray)
  bool origin_fitted = true;  // false: the centre line goes through the given profile.axis_origin_m
};

/// Points needed for an axis fit.
constexpr long kMinAxisFitPoints = 100;
/// Largest fit RMS accepted, as a fraction of the fitted radius.
constexpr double kMaxAxisFitRmsFraction = 0.05;
/// Quantile of the radial distances the cylinder is fitted to: the intact contour (least
/// over-break) of the wall, not its mean, which dig pits pull outward.
constexpr double kAxisFitQuantile = 0.005;
/// Length of the slabs along the axis that first get their own radius in the fit of a wall (a lined
/// bay and an over-broken one are concentric at other radii; one radius let the envelope tilt 2 deg).
constexpr double kAxisFitSlab_m = 0.3;
/// Neighbouring slabs whose radii differ by less than this then share one radius (one surface).
constexpr double kAxisFitStep_m = 0.03;
/// The same, refitted on the means of 7.5 cm patches (less noise, so a looser quantile).
constexpr double kAxisFitPatchQuantile = 0.01;

/// Rounds of "take the wall around the axis, fit it" after the seed (the last ones move it < 0.1 mm).
constexpr int kAxisFitRounds = 4;

/// Fits the tunnel axis to the wall in a cloud with normals, which may hold a whole scene (face,
/// floor, lined bay, duct, rig): a RANSAC seed on pairs of oriented points, then the points
/// build_grid (with `grid`) takes as wall around it (less points obstacle_gap_m inside their bin's
/// median), fitted with a radius per run of the wall along the axis, taken again around the fit
/// until it settles; when that is refused the whole cloud is fitted with one radius, as without a
/// seed. Each fit: the direction starts as the one most perpendicular to the normals (with
/// the most tilted normals dropped) and is refined with the centre by a quantile (lower envelope)
/// cylinder fit of the points; profile.axis_direction orients it, profile.axis_origin_m is kept
/// when profile.estimate_axis_origin is false. Throws
/// std::invalid_argument, one line, when the cloud is not a tunnel wall: too few points, no
/// curvature (a plane), a radius more than profile.max_deviation_m from the design radius, an arc
/// below profile.min_fit_arc_rad, or an RMS above kMaxAxisFitRmsFraction of the radius.
AxisFit fit_axis(const Cloud& cloud, const ProfileConfig& profile, const GridConfig& grid = GridConfig{});

}  // namespace shotcrete
