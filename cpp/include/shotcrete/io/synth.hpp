#pragma once
// Synthetic tunnel bay: a half-cylinder wall outside the design line by a base over-break plus
// random dig pits dT = Tmax (1 - d^2/D^2)^alpha, sampled with radial scanner noise. Seeded.
#include <utility>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/grid.hpp"
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
  DesignProfile profile;  // the circle of synth.design_radius_m, or the section of synth.section_path

  /// The wall's theta range: synth.theta_min_rad..theta_max_rad within the design line's span.
  std::pair<double, double> wall_theta_span() const;
  /// Noise-free TD (m) of the wall at (d, theta): over-break, pits, less the protrusion.
  double td_at(double d_m, double theta_rad) const;
  /// Points on the wall with radial noise; about points_per_cell per cell of `cell_size_m`. On a
  /// section the wall lies td_at along the section's normal, over the part of theta_min..max it spans.
  Cloud sample(double cell_size_m = 0.05) const;
  /// The unsprayed surroundings (context_*), `points_per_cell` per cell area, noise along each
  /// surface's normal: the lined previous bay (d in [-context_previous_bay_m, 0), on the design
  /// line), the invert (plane z = -context_invert_depth_m, |y| <= r_design, under both bays) and the
  /// face (plane d = length_m inside the design circle, above the invert), and when set the
  /// ventilation duct (a cylinder along the axis under the crown, its whole round, over both bays)
  /// and the rig's carrier (a box on the invert, its top and four sides), and the muck pile
  /// (muck_height_at; the invert and the face under it are left out). Every surface is sampled
  /// whole here: the scanner's shadow is sample_scan's (context_scanner_shadow). Empty when
  /// disabled. Circle only (std::invalid_argument on a section).
  Cloud sample_context(double cell_size_m, double points_per_cell, double noise_m, std::uint64_t seed) const;
  /// What a scanner sees before spraying: sample() plus sample_context() when context_enabled, less
  /// the points in the scanner's shadow (drop_shadowed) when context_scanner_shadow.
  Cloud sample_scan(double cell_size_m = 0.05) const;
  /// Height (m) of the muck pile above the invert at (d along the axis, y across); 0 off it or
  /// when there is none (context_muck_height_m = 0 or no invert).
  double muck_height_at(double d_m, double y_m) const;
  /// Whether the scanner at context_scanner_position_m sees p (world frame): false when the straight
  /// line to it meets the duct, the rig's box or the muck more than 3 cm short of p. Always true
  /// without context_scanner_shadow. The wall, the invert and the face hide nothing from inside.
  bool scanner_sees(const Eigen::Vector3d& p) const;
  /// The points of `cloud` the scanner sees (the cloud itself without context_scanner_shadow).
  Cloud drop_shadowed(const Cloud& cloud) const;
};

SyntheticBay make_synthetic_bay(const SynthConfig& config);

/// A synthetic scan after spraying, with its ground truth.
struct AfterScan {
  Cloud cloud;                   // in the after-scan's own frame (p_before = pose * p_after)
  Eigen::Matrix4d pose = Eigen::Matrix4d::Identity();  // true after -> before transform
  Eigen::VectorXd true_thickness_m;  // per cell of the lattice: mean radial layer over the cell (NaN: invalid cell)
  double layer_scale = 1.0;      // after_flow_scale * (1 - after_rebound) / (1 - deposition.rebound_fraction)
};

/// The rigid transform of synth.after_pose_*: rotation R = Rz(yaw) Ry(pitch) Rx(roll), then t.
Eigen::Matrix4d after_pose(const SynthConfig& config);

/// The bay of `bay` after spraying: the wall moves toward the axis by the layer
/// L(d, theta) = layer_scale * D(d, theta) * (1 + after_thickness_noise * F(d, s)), clamped at 0, where D
/// interpolates `deposit_m` (per cell of `lattice`, the job's executed deposit; invalid or NaN cells
/// count 0) bilinearly between cell centres and F is a unit-variance Gaussian random field of
/// correlation length after_noise_length_m (64 random Fourier modes). Sampled with
/// after_points_per_cell and after_noise_m, the context added unchanged (when enabled), and every
/// point expressed in the after-scan's frame (inverse of after_pose). Throws std::invalid_argument
/// for a deposit of the wrong size or a lattice with another design radius.
AfterScan make_after_scan(const SyntheticBay& bay, const Grid& lattice, const Eigen::VectorXd& deposit_m,
                          const Config& config);

}  // namespace shotcrete
