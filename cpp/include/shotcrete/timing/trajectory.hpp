#pragma once
// Joint-space timing (docs/architecture.md §8): joint quintics between rest configurations and the timed
// joint trajectory of regions sprayed in order.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"  // NozzlePose
#include "shotcrete/planning/planner.hpp"  // Pass
#include "shotcrete/robot/joint_tracking.hpp"  // NullSpaceObjective
#include "shotcrete/timing/cartesian_path.hpp"
#include "shotcrete/timing/region_path.hpp"  // TimingParams
#include "shotcrete/timing/speed_profile.hpp"

namespace shotcrete {

class Robot;

/// Rest-to-rest quintic q0 -> q1 (q = q0 + dq (10 tau^3 - 15 tau^4 + 6 tau^5)): the shortest
/// duration meeting every joint's velocity (peak 1.875 |dq| / T) and acceleration
/// (peak 10 / sqrt(3) |dq| / T^2) limit.
double quintic_min_duration(const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, const Eigen::VectorXd& vel_limit,
                            const Eigen::VectorXd& acc_limit);
/// Position, velocity, acceleration of that quintic at t in [0, T].
void quintic_joint(const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, double duration_s, double t_s,
                   Eigen::VectorXd& q, Eigen::VectorXd& qd, Eigen::VectorXd& qdd);

/// The same quintic stretched until the nozzle (tool tip, FK) also stays within max_speed_mps and
/// max_accel_mps2. The nozzle's geometric path does not depend on the duration, so its speed scales
/// as 1 / T and its acceleration as 1 / T^2: the peaks at T = 1 s, by finite differences of FK
/// positions on kQuinticNozzleSteps steps of the quintic, give the shortest T directly (times
/// kQuinticNozzleMargin, for the finite-difference error). Never shorter than quintic_min_duration.
double quintic_nozzle_duration(const Robot& robot, const Eigen::VectorXd& q0, const Eigen::VectorXd& q1,
                               double max_speed_mps, double max_accel_mps2);
constexpr int kQuinticNozzleSteps = 200;
constexpr double kQuinticNozzleMargin = 1.01;

/// Where the time of a trajectory goes, from the path pieces and joint moves it was built from
/// (exact, not from the samples: a Link piece can be part of a turn-around or of a stop-and-go
/// move, which the per-sample kind does not tell). The parts add up to the duration.
struct CycleTimeBreakdown {
  double spraying_s = 0.0;      // pieces with the nozzle on, whatever their kind
  double turn_arounds_s = 0.0;  // nozzle off on a turn-around between serpentine neighbours (its arc,
                                // straight runs and joining curves; a tight turn's stop, creep and
                                // start) or a spray-off gap along a pass line
  double leads_s = 0.0;         // nozzle off on the lead-in / lead-out runs of a region or pass (Lead)
  double transits_s = 0.0;      // joint quintics between regions (and from the start configuration)
  double stop_and_go_s = 0.0;   // inside a region between passes that are no serpentine neighbours:
                                // the run-out to rest, the joint quintic, the run-in from rest
  double other_s = 0.0;         // anything else (a Pass or Transit piece with the nozzle off)
  double total_s() const {
    return spraying_s + turn_arounds_s + leads_s + transits_s + stop_and_go_s + other_s;
  }
  CycleTimeBreakdown& operator+=(const CycleTimeBreakdown& o);
};

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
  CycleTimeBreakdown cycle_time;  // duration_s by what the arm does
  // Limit check of the finite-difference velocities / accelerations (worst |value| / limit).
  double max_velocity_ratio = 0.0;
  double max_acceleration_ratio = 0.0;
  int worst_velocity_joint = -1, worst_acceleration_joint = -1;
  // Largest excursion outside the position limits: of the revolute joints, of the prismatic ones.
  double max_position_violation_rad = 0.0;
  double max_position_violation_m = 0.0;
  int untracked_regions = 0;  // regions where exact tracking failed and solve_path's result is used
  std::vector<int> untracked_region_ids;  // their region indices (time_plan)
  // slow_to_joint_limits, over every call: the time it added (in duration_s and its buckets), the
  // sample intervals it stretched, and the worst of the velocity and acceleration ratios before it.
  // Gross over the calls: time a later re-route replaced stays counted, an interval stretched twice
  // is counted twice.
  double slowed_s = 0.0;
  double slowed_spraying_s = 0.0;  // of it, with the nozzle spraying (more concrete laid there)
  int slowed_intervals = 0;
  double ratio_before_slowing = 0.0;

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
/// joint quintics too (kind Transit with the region's index; counted in transit_time_s). Every joint
/// quintic also keeps the nozzle within timing.nozzle_max_speed_mps / nozzle_max_accel_mps2
/// (quintic_nozzle_duration). Where the
/// turns, runs or leads of a region break a joint acceleration limit, the region is re-timed (up to
/// 5 more times) with the accelerations of the offending lead or gap scaled down by its own excess
/// (the others keep theirs); the passes keep their planned speeds. params: empty = the config's
/// for every region, one = for every region, or one per region (tune_timing's). Whatever stays
/// over a limit (on the passes, or where longer runs would leave the reach)
/// is reported in max_acceleration_ratio, not hidden. `objective`: a second null-space objective
/// of the regions' joint tracking (timing_joint_path; plan_for_arm passes the clearance term).
TimedTrajectory time_plan(const Robot& robot, const std::vector<std::vector<Pass>>& regions_in_order,
                          const Eigen::VectorXd& q_start, const TimingConfig& timing, const RobotConfig& robot_config,
                          const std::vector<TimingParams>& params = {}, const NullSpaceObjective& objective = {});

/// The samples of `tr` with the nozzle spraying, in order (times, joints, poses and flags; no
/// derivatives or totals): what check_clearance reads for the clearance while spraying.
TimedTrajectory spraying_samples(const TimedTrajectory& tr);

/// A rest-to-rest joint move of a trajectory (a transit between regions, the move from the start
/// posture, or a stop-and-go move inside a region): it starts at rest at sample `start` and its
/// samples are (start, end], all of kind Transit; it ends at rest at sample `end`.
struct JointMove {
  std::size_t start = 0, end = 0;
  int region_index = -1;  // -1 between regions (and from the start posture), else the region's stop-and-go
  double duration_s(const TimedTrajectory& tr) const { return tr.t_s[end] - tr.t_s[start]; }
};
/// The trajectory's joint moves in time order: every run of Transit samples.
std::vector<JointMove> joint_moves(const TimedTrajectory& tr);

/// Per sample, 1 on a joint move (kind Transit: between regions, from the start posture, or a
/// stop-and-go inside a region), where the arm swings the nozzle from rest to rest: the pump's flow
/// must be off there, ramps included (flow_schedule's `blocked`). The planner deposits each region
/// as if joint moves came before and after it (region_spray), so both see the same spells. (Leaving
/// the transits between regions to the minimum off spell let a ramp reach into a transit and kept a
/// short first spell the region's own schedule had dropped: 25 mm over the plan on a cell.)
std::vector<char> joint_move_samples(const TimedTrajectory& tr);

/// Rest-to-rest joint quintics through `postures` in turn (at least two), each leg as time_plan
/// times its joint moves (quintic_nozzle_duration: joint and nozzle limits), sampled at
/// timing.trajectory_rate_hz. Times start at 0 at postures.front(), which is not included; samples
/// are of kind Transit with region index `region_index`.
TimedTrajectory joint_move_through(const Robot& robot, const std::vector<Eigen::VectorXd>& postures,
                                   const TimingConfig& timing, int region_index);

/// Replaces the samples (move.start, move.end] of `tr` by `piece` (times from move.start, as
/// joint_move_through gives them), shifts the later samples by the change of duration (added to
/// duration_s, transit_time_s and the cycle-time bucket of the move: transits or stop_and_go), and
/// redoes the finite differences and limit checks. The piece must end where the move ended.
void replace_joint_move(const Robot& robot, TimedTrajectory& tr, const JointMove& move, const TimedTrajectory& piece);

/// Slows `tr` where its finite-difference joint velocities or accelerations break a limit (what the
/// re-plans' speed bounds and the regions' easing left: a tracking's null-space motion, a tight
/// turn): the same samples and joint path, the time between them stretched by a smooth factor.
/// At sample i the need is max(velocity ratio, sqrt(acceleration ratio)) (velocities scale as
/// 1 / f, accelerations as 1 / f^2); each interval takes the largest need within +-window_s of it,
/// averaged over +-window_s again so that the factor changes gently (its own rate of change adds
/// q' d(1/f)/dt to the accelerations), and the check is redone, up to 12 times. A trajectory within
/// its limits is left as it is, to the bit. The added time goes to duration_s and to the bucket of
/// each stretched interval's later sample (spraying: spray_time_s too; a joint move:
/// transit_time_s too; a Link run that holds a joint move of its region: stop-and-go, else a
/// turn-around), and to slowed_s. Returns whether the trajectory ends within its limits. Throws
/// std::invalid_argument for times that are not finite and non-decreasing, or postures that are
/// not the robot's dof finite values.
bool slow_to_joint_limits(const Robot& robot, TimedTrajectory& tr, double window_s = 1.0);

/// One timed Cartesian path (e.g. a region, or the quintic baseline) in joint space from rest to
/// rest: sampled at rate_hz, joints tracked from the solve_path start found from `seed`,
/// velocities / accelerations by finite differences and the limit check; no transits.
TimedTrajectory time_path(const Robot& robot, const CartesianPath& path, const SpeedProfile& profile,
                          const Eigen::VectorXd& seed, double rate_hz, const RobotConfig& robot_config);

}  // namespace shotcrete
