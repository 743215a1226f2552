#pragma once
// Pass geometry of the planner (docs/architecture.md §5): slicing planes over a set of grid cells, the
// crossing points offset by the standoff, and the clamped cubic spline the nozzle follows.
#include <cstddef>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

/// One nozzle pass: waypoints (position + spray axis, tunnel frame) along a clamped cubic spline.
/// Graded mode: one constant speed, slower where the machine's cap binds, and in the level-1
/// rounds a speed of its own at each bay end it runs on past (speed_profile_mps; speed_mps is the
/// pass's own). Optimal mode: the speed may change per segment (speed_profile_mps, one value per
/// waypoint, piecewise constant); speed_mps is then the mean.
struct Pass {
  std::vector<NozzlePose> waypoints;      // spline samples, about sample_step_m apart
  double speed_mps = 0.0;
  double length_m = 0.0;
  std::vector<double> speed_profile_mps;  // empty: constant speed_mps
  int line = -1;                          // index of the slicing plane the pass lies in (plan_passes); -1: none
  // The nozzle leans at this end to keep clear of something past it (a face) and the lean keeps
  // room for the pass's run-on only (obstructed_cells): the joins there go no further than the
  // nozzle needs to stop (timing: region_path's tight joins).
  bool tight_start = false, tight_end = false;

  double speed_at(std::size_t waypoint) const {
    return speed_profile_mps.empty() ? speed_mps : speed_profile_mps[waypoint];
  }
  /// Nozzle time of the pass [s].
  double duration_s() const;
  /// Dwell per waypoint (half of each neighbouring interval / speed), for accumulate_dwells.
  std::vector<double> dwell_s() const;
};

/// Length of the polyline through the poses' positions [m].
double polyline_length(const std::vector<NozzlePose>& poses);

/// The pass run the other way (waypoints and speed profile reversed).
void reverse_pass(Pass& pass);

/// The longest run-on past the bay's ends that the rounds of config.mode give their lines [m]:
/// edge_overrun_m, or the late levelling rounds' (optimal mode) or the level-1 rounds' (graded
/// mode) where longer. The clearance check keeps room for it (obstructed_cells).
double longest_edge_overrun_m(const PlannerConfig& config);

/// The run-on of lines that run on overrun_m at an end where the nozzle leans (a face past it):
/// at most leaned_edge_overrun_m [m].
double leaned_edge_overrun_m(const PlannerConfig& config, double overrun_m);

/// Pass lines over a set of grid cells (docs/architecture.md §5): envelope box in (d, s), slicing planes
/// `spacing_m` apart (through the axis for axial passes, across it for circumferential ones),
/// crossing points from pairs of neighbouring cells on either side of each plane, offset by the
/// standoff toward the axis (along -r, or along the normal), clamped cubic spline sampled every
/// sample_step_m. Passes alternate direction (serpentine) and step up the wall from the springline.
/// lean (optional, one entry per grid cell): the nozzle's lean off square over that cell, a vector
/// tangent to the wall whose direction the spray axis tips toward and whose length is the lean
/// angle [rad]; the nozzle then stands at the standoff back along the leaned axis (the pose that
/// keeps it off a face or a duct: nozzle_lean). Interpolated between cells like the crossing points.
/// split_gap_m > 0: a line is cut into several passes where more than that length of wall [m]
/// along it holds none of `cells` (0: one pass from the line's first cell to its last), and the
/// cells are parted where more than that (and more than a spacing) of wall across the lines holds
/// none of them, each part with slicing planes centred on its own extent (0: one set of planes
/// centred on all the cells).
std::vector<Pass> plan_passes(const Grid& grid, const std::vector<int>& cells, double spacing_m,
                              const PlannerConfig& config, const std::vector<Eigen::Vector3d>* lean = nullptr,
                              double split_gap_m = 0.0);

/// The unit direction square to the design line at wall point p, outward: the section's normal,
/// radial on a circle (and off a section's ends, where it has no normal). A square nozzle stands
/// the standoff back along it (the passes' poses, and the levelling's lean_slowdown).
Eigen::Vector3d square_axis(const TunnelAxis& axis, const DesignProfile& profile, const Eigen::Vector3d& p);

/// The spray axis `square_axis` (unit) tipped by `lean` (its component tangent to the axis gives
/// the direction, its length the angle [rad]); `square_axis` itself when that is zero. The one
/// formula of the passes' poses and of the clearance check of them (obstructed_cells).
Eigen::Vector3d leaned_axis(const Eigen::Vector3d& square_axis, const Eigen::Vector3d& lean);

/// Clamped cubic spline through `points` (chord-length parameter; end slopes of the parabola
/// through the three end knots), sampled about `step_m` apart including both ends.
std::vector<Eigen::Vector3d> clamped_cubic_spline(const std::vector<Eigen::Vector3d>& points, double step_m);

}  // namespace shotcrete
