#pragma once
// Motion timing (design section 7b, seed paper on AIWCPSO for shotcrete arms):
// cycloidal start/stop profiles, half-circle turn-arounds between the passes of a region,
// quintic rest-to-rest baseline, sampling at a fixed rate, joint-space timing with the robot and a
// particle swarm with adaptive inertia weight and acceleration coefficients.
//
// Region path: lead-in (straight run-up before the first pass, length start_length_m) -> pass ->
// [extension line] -> half circle (diameter = pass spacing) -> [extension line] -> pass ... ->
// lead-out (run-out after the last pass, length end_length_m). Pass speeds are set by the
// deposition, so the nozzle reaches cruise speed before a pass starts and sprays only on passes
// (and on the turns when spray_on_turns is set).
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/planning/planner.hpp"

namespace shotcrete {

class Robot;

// ------------------------------------------------------------------------------------------------
// Speed profiles
// ------------------------------------------------------------------------------------------------

/// Shape of a speed change v0 -> v1 over T: v = v0 + (v1 - v0) g(t / T).
/// Cycloid: g = tau - sin(2 pi tau) / (2 pi) (the paper's (m - sin m) / (2 pi), acceleration
/// 1 - cos: starts and ends at zero). Quintic: g = 10 tau^3 - 15 tau^4 + 6 tau^5 (acceleration and
/// jerk zero at both ends). Both cover (v0 + v1) / 2 * T.
enum class SpeedShape { Cycloid, Quintic };

struct SpeedPiece {
  double v0_mps = 0.0;
  double v1_mps = 0.0;
  double duration_s = 0.0;
  SpeedShape shape = SpeedShape::Cycloid;

  double length_m() const { return 0.5 * (v0_mps + v1_mps) * duration_s; }
  double speed_at(double t_s) const;     // t in [0, duration]
  double accel_at(double t_s) const;     // dv/dt
  double jerk_at(double t_s) const;      // d2v/dt2
  double distance_at(double t_s) const;  // distance covered since the piece start
  double peak_accel_mps2() const;        // |v1 - v0| / T * max g'
};

/// Speed along a path: pieces one after the other, starting at arc length 0.
class SpeedProfile {
 public:
  struct State {
    double s_m = 0.0, v_mps = 0.0, a_mps2 = 0.0, j_mps3 = 0.0;
  };
  void append(const SpeedPiece& piece);  // zero-duration pieces are dropped
  void append(const SpeedProfile& other);
  double duration_s() const { return t_.empty() ? 0.0 : t_.back(); }
  double length_m() const { return s_.empty() ? 0.0 : s_.back(); }
  State at(double t_s) const;  // clamped to [0, duration]
  /// Time at which arc length s is reached (bisection inside the piece).
  double time_at_distance(double s_m) const;
  const std::vector<SpeedPiece>& pieces() const { return pieces_; }

 private:
  std::vector<SpeedPiece> pieces_;
  std::vector<double> t_{0.0}, s_{0.0};  // cumulative start time / arc length of each piece + end
};

/// Paper start profile over s_start: cycloidal acceleration 0 -> v over t1 = k1 Ts, then cruise
/// until Ts = 2 s_start / (v (2 - k1)).
SpeedProfile cycloid_start(double s_start_m, double v_mps, double k1);
/// Paper end profile over s_end: cruise until t2 = k2 Te, then cycloidal deceleration v -> 0 until
/// Te = 2 s_end / (v (1 + k2)).
SpeedProfile cycloid_end(double s_end_m, double v_mps, double k2);
/// Rest-to-rest move over length_m: accelerate 0 -> v over accel_time_s, cruise, decelerate over
/// accel_time_s (quintic: the baseline). When the move is too short to reach v the peak speed
/// drops to length / accel_time.
SpeedProfile rest_to_rest(double length_m, double v_mps, double accel_time_s, SpeedShape shape);

// ------------------------------------------------------------------------------------------------
// Cartesian path of a region
// ------------------------------------------------------------------------------------------------

enum class SegmentKind : char { Pass = 0, Turn = 1, Lead = 2, Link = 3, Transit = 4 };

/// One geometric piece of a nozzle path: a polyline of poses or a half circle.
struct PathPiece {
  SegmentKind kind = SegmentKind::Pass;
  int pass_index = -1;    // global pass number for kind == Pass, else -1
  bool spraying = false;
  double speed_mps = 0.0; // planned cruise speed (pass, lead, link); turn: speed at its start
  double speed_out_mps = 0.0;  // turn and spray-off gap: speed at its end (next pass); others = speed_mps
  // How the speed profile treats the piece: 0 by kind (cruise, turn), 1 stop at its end (cycloid
  // end, k2), 2 rest to rest (cycloid, cruise at speed_mps), 3 start from rest (cycloid start, k1),
  // 4 spray-off gap on a pass line (cycloidal change from speed_mps to speed_out_mps).
  char motion = 0;
  // polyline
  std::vector<NozzlePose> poses;
  std::vector<double> cum_m;  // arc length at each pose, from 0
  // arc: p(phi) = center + r (-cos(phi) u + sin(phi) d), phi in [0, pi]; the axis blends from
  // axis0 to axis1 with weight (1 - cos phi) / 2
  bool is_arc = false;
  double accel_scale = 1.0;  // turn arc: share of the profile's turn acceleration that caps its
                             // speed (region_path's gap scale: time_plan eases awkward joins)
  Eigen::Vector3d center{0, 0, 0}, u{1, 0, 0}, d{0, 1, 0};
  double radius_m = 0.0;
  Eigen::Vector3d axis0{0, 0, 1}, axis1{0, 0, 1};
  // pass with a per-waypoint speed profile (Pass::speed_profile_mps): its constant-speed runs
  std::vector<double> run_len_m, run_speed_mps;

  double length_m() const;
  NozzlePose pose_at(double s_m) const;
  Eigen::Vector3d tangent_at(double s_m) const;
  double curvature_at(double s_m) const;  // 1/r on arcs, turning angle / step on polylines
};

class CartesianPath {
 public:
  void append(PathPiece piece);
  const std::vector<PathPiece>& pieces() const { return pieces_; }
  double length_m() const { return cum_.back(); }
  double piece_start_m(std::size_t i) const { return cum_[i]; }
  /// Piece containing arc length s and the local arc length inside it.
  std::size_t locate(double s_m, double& local_m) const;
  NozzlePose pose_at(double s_m) const;
  Eigen::Vector3d tangent_at(double s_m) const;
  double curvature_at(double s_m) const;

 private:
  std::vector<PathPiece> pieces_;
  std::vector<double> cum_{0.0};
};

/// Half circle from the end of pass a (position pa, unit direction da) to the start of pass b:
/// the pass ends are first aligned along da by a straight extension (the "line" of line + arc),
/// then joined by a half circle whose diameter is their distance across (the pass spacing).
/// Returns 1 to 3 pieces (extension of a, arc, extension before b), kinds Link / Turn.
/// run_m > 0 adds a straight run of that length before the arc, run_in_m (< 0: run_m) one after it
/// (the speed change to and from the turn speed happens there, so the arc is entered at the turn
/// speed). dir_b (zero: -dir_a) is the next pass's start direction: when it is not exactly -dir_a the
/// run-in is a cubic Bezier tangent to the arc and to the pass, so the path has no corner.
std::vector<PathPiece> turn_around(const NozzlePose& end_a, const Eigen::Vector3d& dir_a, const NozzlePose& start_b,
                                   double speed_a_mps, double speed_b_mps, bool spraying, double run_m = 0.0,
                                   double run_in_m = -1.0, const Eigen::Vector3d& dir_b = Eigen::Vector3d::Zero());

/// Region path: lead-in, passes joined by turn-arounds (serpentine as given), lead-out. Two
/// consecutive passes that are not serpentine neighbours (not running opposite ways side by side,
/// e.g. pieces of one line in optimal mode) are joined by stop-and-go instead: run-out along the
/// pass with a cycloidal stop, a straight rest-to-rest move, run-in with a cycloidal start (runs of
/// turn_run_m, 0.1 m if that is 0). A pass with
/// a speed profile (optimal mode) keeps it: constant-speed runs with the planner's dwell semantics
/// (waypoint i owns half of each neighbouring interval at speed_at(i)), joined by cycloidal
/// changes centred on the run boundaries (peak speed_change_accel_mps2).
/// first_pass_index numbers the passes globally. Throws std::invalid_argument for an empty region,
/// a pass with fewer than 2 waypoints or a non-positive speed.
/// stop_accel_mps2 > 0: the run-out / run-in of a stop-and-go link are lengthened so that their
/// plain cycloidal stop and start (region_profile: no cruise, peak v^2 / length) stay within that
/// acceleration at the pass end speeds.
/// turn_accel_mps2 > 0 (with turn_run_m > 0): the runs before and after a turn arc are lengthened so
/// that the change between the pass speed and the arc speed (region_profile's, from turn_speed_mps
/// and the centripetal cap at turn_accel_mps2) peaks at turn_accel_mps2.
/// gap_accel_scale (empty, or one value in (0, 1] per gap between consecutive passes) scales
/// stop_accel_mps2 and turn_accel_mps2 for that gap alone, and the turn arc's accel_scale (the
/// profile's arc speed): time_plan eases only the joins where the arm needs it.
CartesianPath region_path(const std::vector<Pass>& passes, double lead_in_m, double lead_out_m, bool spray_on_turns,
                          int first_pass_index = 0, double turn_run_m = 0.0, double stop_accel_mps2 = 0.0,
                          double turn_speed_mps = 0.0, double turn_accel_mps2 = 0.0,
                          const std::vector<double>& gap_accel_scale = {});

/// The region path time_plan times (and the swarm's RegionJointModel models): region_path with the
/// config's turn runs, stop-and-go runs sized for timing.nozzle_max_accel_mps2 and turn runs sized
/// for the config's turn speed at timing.speed_change_accel_mps2. The geometry depends on the
/// config only, never on the tuned TimingParams (they shape the speed profile along it), so one
/// joint path serves every particle of the swarm.
CartesianPath timing_region_path(const std::vector<Pass>& passes, double lead_in_m, double lead_out_m,
                                 const TimingConfig& timing, int first_pass_index = 0,
                                 const std::vector<double>& gap_accel_scale = {});

/// Tunable timing parameters (the swarm's particle).
struct TimingParams {
  double k1 = 0.5;                // start: share of Ts spent accelerating
  double k2 = 0.5;                // end: share of Te spent cruising
  double start_length_m = 0.1;    // lead-in length
  double end_length_m = 0.1;      // lead-out length
  double turn_speed_mps = 0.0;    // speed in the middle of a turn-around; 0 = pass speeds
  double speed_change_accel_mps2 = 0.5;  // peak of speed changes inside a pass and of the
                                         // centripetal acceleration on turn arcs (not tuned)
  double turn_accel_mps2 = 0.0;  // centripetal acceleration capping the turn arc speed when > 0
                                 // (tuned); 0 = speed_change_accel_mps2
  static TimingParams from_config(const TimingConfig& config);
};

/// Speed profile of a region path built by region_path (same lead lengths): cycloid start, pass
/// speeds on passes and links, cycloidal speed changes on turns (pass speed -> turn speed -> next
/// pass speed, or pass speed -> next pass speed when turn_speed_mps == 0; with turn runs the
/// changes happen on the runs and the arc runs at the turn speed), cycloid end (k1, k2 on the lead-in
/// and lead-out; stop-and-go runs stop and start without a cruise).
SpeedProfile region_profile(const CartesianPath& path, const TimingParams& params);

/// Quintic baseline: every pass extended by its acceleration / deceleration run, straight
/// step-overs, full stop at every corner. The step-over cruises at stepover_speed_mps.
struct BaselinePath {
  CartesianPath path;
  SpeedProfile profile;
};
BaselinePath quintic_baseline(const std::vector<Pass>& passes, double accel_time_s, double stepover_speed_mps,
                              int first_pass_index = 0);

// ------------------------------------------------------------------------------------------------
// Sampling
// ------------------------------------------------------------------------------------------------

struct CartesianSamples {
  std::vector<double> t_s;
  std::vector<double> s_m;
  std::vector<NozzlePose> nozzle;
  std::vector<double> speed_mps, tangential_accel_mps2, normal_accel_mps2;
  std::vector<char> spraying;
  std::vector<int> pass_index;
  std::vector<char> kind;  // SegmentKind
};

/// Samples at t = 0, 1/rate, ... and always the end time.
CartesianSamples sample_path(const CartesianPath& path, const SpeedProfile& profile, double rate_hz);

/// Dwell per sample for accumulate_dwells: each spraying sample stands for the time from the
/// midpoint with its previous sample to the midpoint with its next one (so the dwells of a pass add
/// up to its duration); non-spraying samples dwell 0.
std::vector<double> spray_dwells(const std::vector<double>& t_s, const std::vector<char>& spraying);

struct NozzleLimits {
  double max_speed_mps = 1.0;
  double max_accel_mps2 = 2.0;
};
/// Largest speed / limit and |acceleration| / limit (tangential and centripetal) on a dense sampling.
struct NozzleCheck {
  double max_speed_mps = 0.0, max_accel_mps2 = 0.0;
  double speed_ratio = 0.0, accel_ratio = 0.0;
  bool ok() const { return speed_ratio <= 1.0 + 1e-9 && accel_ratio <= 1.0 + 1e-9; }
};
NozzleCheck check_nozzle(const CartesianPath& path, const SpeedProfile& profile, const NozzleLimits& limits,
                         double rate_hz = 500.0);

// ------------------------------------------------------------------------------------------------
// Joint space
// ------------------------------------------------------------------------------------------------

/// Rest-to-rest quintic q0 -> q1 (q = q0 + dq (10 tau^3 - 15 tau^4 + 6 tau^5)): the shortest
/// duration meeting every joint's velocity (peak 1.875 |dq| / T) and acceleration
/// (peak 10 / sqrt(3) |dq| / T^2) limit.
double quintic_min_duration(const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, const Eigen::VectorXd& vel_limit,
                            const Eigen::VectorXd& acc_limit);
/// Position, velocity, acceleration of that quintic at t in [0, T].
void quintic_joint(const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, double duration_s, double t_s,
                   Eigen::VectorXd& q, Eigen::VectorXd& qd, Eigen::VectorXd& qdd);

/// Joint path through closely spaced poses: from q0, the start configuration is first settled in
/// the null space away from the joint limits (at rest), then minimal-norm Gauss-Newton steps reach
/// every pose (position and spray axis to ~1e-10) plus a null-space drift away from the limits
/// proportional to the path step (limit_gain * dH/dx, at most 0.05 normalised joint range per metre,
/// rising quadratically to 0.5 at a limit once a joint is within 10 % of its range of it),
/// so q is a smooth function of the path and finite differences are meaningful. Reports the worst
/// errors.
std::vector<Eigen::VectorXd> track_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                              const Eigen::VectorXd& q0, double limit_gain = 0.02,
                                              double* max_error_m = nullptr, double* max_error_rad = nullptr);

/// Highest constant nozzle speed at each pose at which the arm follows `poses` within limit_share
/// of its joint velocity and acceleration limits while leaving room for speed changes of up to
/// tangential_accel_mps2: with q' = dq/ds and q'' = d2q/ds2 of the tracked joint path
/// (track_joint_path from seed), qd = q' v and qdd = q'' v^2 + q' a, so per joint
/// v <= share vmax / |q'| and v^2 <= (share amax - |q'| a) / |q''|. +inf where nothing binds, 0 where
/// the speed changes alone would break an acceleration limit.
std::vector<double> joint_speed_limits(const Robot& robot, const std::vector<NozzlePose>& poses,
                                       const Eigen::VectorXd& seed, double tangential_accel_mps2,
                                       double limit_share = 1.0);

/// plan_bay's speed cap for this arm: joint_speed_limits from the neutral posture with
/// timing.speed_change_accel_mps2 and share 1 - timing.joint_limit_margin. The robot must outlive it.
SpeedCapFn arm_speed_caps(const Robot& robot, const Config& config);

struct TimedTrajectory {
  std::vector<double> t_s;
  std::vector<Eigen::VectorXd> q, qd, qdd;
  std::vector<NozzlePose> nozzle;
  std::vector<char> spraying;
  std::vector<int> pass_index;   // -1 off a pass (turns, leads, transits)
  std::vector<int> region_index; // -1 on transits between regions (stop-and-go moves inside one: its index)
  std::vector<char> kind;        // SegmentKind
  double duration_s = 0.0;
  double spray_time_s = 0.0;     // time with spraying on (exact, from the profiles)
  double transit_time_s = 0.0;   // joint-space moves: between regions and stop-and-go inside them
  // Limit check of the finite-difference velocities / accelerations (worst |value| / limit).
  double max_velocity_ratio = 0.0;
  double max_acceleration_ratio = 0.0;
  int worst_velocity_joint = -1, worst_acceleration_joint = -1;
  double max_position_violation_rad = 0.0;  // largest excursion outside the position limits
  int untracked_regions = 0;  // regions where exact tracking failed and solve_path's result is used

  std::size_t size() const { return t_s.size(); }
  /// Dense matrix (samples x (1 + 3 dof)): t, q..., qd..., qdd... ; for CSV / numpy.
  Eigen::MatrixXd joint_table() const;
  /// Header of joint_table: t_s,q0,...,qd0,...,qdd0,...
  std::vector<std::string> joint_table_header() const;
  /// CSV with the joint table plus nozzle position/axis, spraying, pass and region index.
  std::string to_csv() const;
};

/// Timed trajectory of regions sprayed in order (each a serpentine of passes), starting at rest at
/// q_start: transit (joint quintic, minimum duration) -> region (IK per sample, warm-started)
/// -> transit -> ... Velocities / accelerations by finite differences of the sampled joint path.
/// Inside a region the stop-and-go moves (between passes that are no serpentine neighbours) are
/// joint quintics too (kind Transit with the region's index; counted in transit_time_s). Where the
/// turns, runs or leads of a region break a joint acceleration limit, the region is re-timed (up to
/// 5 more times) with the accelerations of the offending lead or gap scaled down by its own excess
/// (the others keep theirs); the passes keep their planned speeds. params: empty = the config's
/// for every region, one = for every region, or one per region (tune_timing's). Whatever stays
/// over a limit (on the passes, or where longer runs would leave the reach)
/// is reported in max_acceleration_ratio, not hidden.
TimedTrajectory time_plan(const Robot& robot, const std::vector<std::vector<Pass>>& regions_in_order,
                          const Eigen::VectorXd& q_start, const TimingConfig& timing, const RobotConfig& robot_config,
                          const std::vector<TimingParams>& params = {});

/// One timed Cartesian path (e.g. a region, or the quintic baseline) in joint space from rest to
/// rest: sampled at rate_hz, joints tracked from the solve_path start found from `seed`,
/// velocities / accelerations by finite differences and the limit check; no transits.
TimedTrajectory time_path(const Robot& robot, const CartesianPath& path, const SpeedProfile& profile,
                          const Eigen::VectorXd& seed, double rate_hz, const RobotConfig& robot_config);

/// Joint-space feasibility of a region timing without re-solving IK for every candidate: the joint
/// path q(s) is solved once on timing_region_path with the longest lead lengths at a fine
/// arc-length step, then q' = dq/ds and q'' = d2q/ds2 give qd = q' v and qdd = q'' v^2 + q' a.
/// As in time_plan, the stop-and-go moves are joint quintics between the rest configurations at
/// their ends (their minimal duration counts, their samples are not checked) and each stretch after
/// one is tracked anew from where the move ends.
class RegionJointModel {
 public:
  RegionJointModel(const Robot& robot, const std::vector<Pass>& passes, double max_lead_m, const TimingConfig& timing,
                   const Eigen::VectorXd& seed, const RobotConfig& robot_config, double step_m = 0.005);
  struct Evaluation {
    double duration_s = 0.0;
    double velocity_ratio = 0.0, acceleration_ratio = 0.0;  // worst |qd| / limit, |qdd| / limit
    NozzleCheck nozzle;
    // The same on the leads and the turns (arcs and their runs) alone: what the parameters shape.
    // The passes keep their planned speeds, and the stop-and-go runs and spray-off gaps are sized
    // by the config (time_plan eases them where the arm needs it), whatever the parameters.
    double tuned_velocity_ratio = 0.0, tuned_acceleration_ratio = 0.0;
    NozzleCheck tuned_nozzle;
    Eigen::VectorXd q_first, q_last;  // joints at the start / end of the timed path
  };
  Evaluation evaluate(const TimingParams& params, const NozzleLimits& limits, double rate_hz = 100.0) const;
  double max_lead_m() const { return max_lead_m_; }
  bool tracked() const { return tracked_; }  // false: solve_path's (coarser) joint path is used

 private:
  // A stretch tracked in Cartesian space, on a uniform arc-length grid [s.front(), s.back()].
  struct Stretch {
    std::vector<double> s;
    std::vector<Eigen::VectorXd> q, dq, ddq;
  };
  CartesianPath path_;
  double max_lead_m_;
  bool tracked_ = true;
  std::vector<Stretch> stretches_;  // stretch k + 1 follows the joint move k
  std::vector<double> move_s_;      // minimal quintic duration of each joint move
  Eigen::VectorXd vel_limit_, acc_limit_;
  // Stretch containing s, -1 inside a joint move.
  int stretch_at(double s) const;
  void interpolate(const Stretch& st, double s, Eigen::VectorXd& q, Eigen::VectorXd& dq, Eigen::VectorXd& ddq) const;
};

// ------------------------------------------------------------------------------------------------
// Particle swarm with adaptive inertia weight and acceleration coefficients (AIWCPSO)
// ------------------------------------------------------------------------------------------------

struct PsoOptions {
  int particles = 15;
  int iterations = 30;
  std::uint64_t seed = 1;
  double a = 2.05, b = 0.5;          // c1 = a Bs + b, c2 = a (1 - Bs) + b
  double w_min = 0.0, w_max = 1.0;   // w = (w_max - w_min) Bs + w_min
  static PsoOptions from_config(const TimingConfig& config);
};
struct PsoResult {
  Eigen::VectorXd best_x;
  double best_f = 0.0;
  std::vector<double> best_history;  // global best after each iteration (first = initial swarm)
  std::vector<double> success_history;  // Bs per iteration
  int evaluations = 0;
};
/// Minimises f over the box [lower, upper]; `initial` particles (clamped) replace the first random
/// ones. Deterministic for a given seed. Infeasible points should return +inf or a penalty.
PsoResult pso_minimize(const std::function<double(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& lower,
                       const Eigen::VectorXd& upper, const PsoOptions& options,
                       const std::vector<Eigen::VectorXd>& initial = {});

/// Tuning of TimingParams (k1, k2, start_length_m, end_length_m, turn_speed_mps, turn_accel_mps2)
/// region by region, in spraying order: fitness = execution time of the region plus the transit to
/// it, infeasible when a joint velocity or acceleration limit (reduced by
/// timing.joint_limit_margin) or a nozzle limit breaks on the leads or turns (what the parameters
/// shape, RegionJointModel::Evaluation's tuned_* figures). Without a robot
/// (robot == nullptr) only the nozzle limits apply and transits are not counted.
struct TimingTuning {
  std::vector<TimingParams> params;  // one per region: time_plan's params (the config's where the
                                     // swarm found no timing within the limits)
  std::vector<char> feasible;        // per region: the swarm found a timing within the limits
  double duration_s = 0.0;           // of the regions (and transits) with the tuned params; a
                                     // region without a feasible timing adds the config's cost
                                     // (its duration, or 1e6 x its worst ratio)
  double initial_duration_s = 0.0;   // with the config's params, each region from where the tuned
                                     // previous one ends (+inf when they break a limit)
  bool initial_feasible = false;
  std::vector<PsoResult> pso;        // per region
};
TimingTuning tune_timing(const Robot* robot, const std::vector<std::vector<Pass>>& regions_in_order,
                         const Eigen::VectorXd& q_start, const TimingConfig& timing, const RobotConfig& robot_config);

}  // namespace shotcrete
