#pragma once
// Helpers shared by the timing sources (not part of the public headers).
#include <Eigen/Core>
#include <string>
#include <utility>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/planning/planner.hpp"  // Pass
#include "shotcrete/timing/cartesian_path.hpp"
#include "shotcrete/timing/region_path.hpp"
#include "shotcrete/timing/sampling.hpp"
#include "shotcrete/timing/speed_profile.hpp"

namespace shotcrete::timing_detail {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;

/// A number for an error message (6 significant digits).
std::string num(double v);

// speed_profile.cpp: shape function g(tau) of a speed change, its derivatives, and max g'.
double shape_g(SpeedShape s, double t);
double shape_dg(SpeedShape s, double t);
double shape_ddg(SpeedShape s, double t);
double shape_peak_dg(SpeedShape s);

// cartesian_path.cpp
Eigen::Vector3d normalized_or(const Eigen::Vector3d& v, const Eigen::Vector3d& fallback);
/// Polyline piece through the poses (repeated points dropped), one speed, not an arc.
PathPiece polyline_piece(SegmentKind kind, std::vector<NozzlePose> poses, double speed, bool spraying, int pass_index);
/// Rotation of the spray axis per metre of path at a pass's end (at_end) or start, along the
/// travel, as a rotation vector, read over its last or first 2 cm (zero for fewer than two
/// waypoints).
Eigen::Vector3d axis_turn_rate(const std::vector<NozzlePose>& waypoints, bool at_end);
/// A straight run from a to b as poses about 5 mm apart, the axis a's (leaving: the run leaves a
/// pass at a, whose axis turns at `rate` there) or b's (entering: it enters a pass at b) turned on
/// at a rate that falls linearly from `rate` at the pass to 0 over min(run, 0.1 m), then held.
/// Runs that held the axis stopped a leaning nozzle's turn at once: a step in the joints'
/// velocities. Rates up to 0.1 rad/m are left held ({a, b} as before).
std::vector<NozzlePose> run_carrying_axis_turn(const NozzlePose& a, const NozzlePose& b, const Eigen::Vector3d& rate,
                                               bool leaving);
/// The same on given poses (positions in order along the run, e.g. a curve): their axes set from
/// the pass end's axis (poses.front() leaving, poses.back() entering). False: left as they were.
bool carry_axis_turn(std::vector<NozzlePose>& poses, const Eigen::Vector3d& rate, bool leaving);
/// Cubic Bezier from a (leaving along unit ta) to b (arriving along unit tb), control points a third
/// of the chord out, as a dense polyline; the axis blends linearly. Joins two pieces whose
/// directions differ without a corner.
std::vector<NozzlePose> tangent_curve(const NozzlePose& a, const Eigen::Vector3d& ta, const NozzlePose& b,
                                      const Eigen::Vector3d& tb);

// region_profile.cpp
/// Speed on a turn arc of radius r between the pass speeds v_in and v_out: the turn speed (or the
/// pass speeds when it is 0), capped so that the centripetal acceleration v^2 / r stays at accel;
/// 0 = no own turn speed (the arc changes from one pass speed to the next).
double turn_arc_speed(double radius_m, double v_in, double v_out, double turn_speed_mps, double accel_mps2);
/// The highest arc speed in [lo, hi] at which a turn lasts min_s, by bisection (duration(u) falls
/// as u grows; duration(lo) >= min_s > duration(hi)): region_path sizes the turn runs for it,
/// region_profile slows the arc to it (timing.min_turn_s).
template <class Duration>
double speed_lasting(const Duration& duration, double lo, double hi, double min_s) {
  const double tol = 1e-9 * hi;
  for (int it = 0; it < 60 && hi - lo > tol; ++it) {
    const double mid = 0.5 * (lo + hi);
    (duration(mid) >= min_s ? lo : hi) = mid;
  }
  return lo;
}
/// Piece data needed by the speed profile: kind, length and the planned speeds.
struct PieceSpec {
  SegmentKind kind;
  double length_m, v_in, v_out;
  std::vector<double> run_len_m, run_speed_mps;  // pass with a speed profile: constant-speed runs
  PieceMotion motion;
  double accel_scale;  // turn arc, tight turn's creep: share of the params' turn acceleration
};
std::vector<PieceSpec> specs_of(const CartesianPath& path);
/// region_profile on piece specs (RegionJointModel changes the lead lengths of a fixed path).
SpeedProfile profile_from_specs(const std::vector<PieceSpec>& specs, const TimingParams& params);

// sampling.cpp
/// Uniform times over [0, T] with steps <= 1 / rate (no tiny last step).
std::vector<double> time_grid(double duration_s, double rate_hz);
/// Samples of the profile's time window [t0_s, t1_s] (uniform steps <= 1 / rate, both ends).
CartesianSamples sample_window(const CartesianPath& path, const SpeedProfile& profile, double rate_hz, double t0_s,
                               double t1_s);

// trajectory.cpp
/// Arc-length spans [start, end] of a region path tracked in Cartesian space: everything but its
/// rest-to-rest pieces (stop-and-go middles), where the arm moves in joint space. Shared by
/// time_region and RegionJointModel so both track the same stretches.
std::vector<std::pair<double, double>> cartesian_stretches(const CartesianPath& path);

// tuning.cpp
/// Longest lead the swarm considers for a region (and the lead time_plan tracks the region's first
/// stretch from, so both see the same joint path).
double swarm_max_lead(const std::vector<Pass>& passes, const TimingConfig& timing);

}  // namespace shotcrete::timing_detail
