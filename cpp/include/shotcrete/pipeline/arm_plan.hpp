#pragma once
// A bay planned for a given arm (docs/architecture.md §9): plan_bay with the speeds the arm can follow
// along each pass, time_plan, and re-plans where the timed passes still break a joint limit.
#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/collision/transit.hpp"
#include "shotcrete/pipeline/executed_deposit.hpp"
#include "shotcrete/planning/planner.hpp"
#include "shotcrete/timing/timing.hpp"

namespace shotcrete {

class Robot;

/// Speed bounds learned from timed trajectories: near each point (within radius_m) the nozzle
/// must not go faster than its speed.
struct SpeedCapMap {
  std::vector<Eigen::Vector3d> points_m;
  std::vector<double> speed_mps;
  double radius_m = 0.1;
  /// Lowest speed bound within radius_m of p [m/s]; +inf when there is none.
  double at(const Eigen::Vector3d& p) const;
  /// Adds a bound for every spraying sample of `tr` over a joint velocity or acceleration limit,
  /// for every lead / link sample over a velocity limit (they cruise at the speeds of the passes
  /// next to them), and, for a lead / link sample over a velocity or acceleration limit, one at
  /// the pass sample its run leaves or reaches (for a velocity, when the run moves at 90 % of that
  /// pass sample's speed or more), and for a turn-around sample over a velocity limit at about the
  /// passes' speeds, one at each pass end it joins: the speed scaled so the joints come out at
  /// limit_share of their limits (velocity ~ v, acceleration ~ v^2). Samples of regions the arm
  /// does not track (tr.untracked_region_ids) teach nothing. Returns the number of bounds added.
  int learn(const TimedTrajectory& tr, const Eigen::VectorXd& vel_limit, const Eigen::VectorXd& acc_limit,
            double limit_share);
};

/// Cells of the bay that cannot be sprayed from a clear pose: with the nozzle at the planner's
/// standoff square to the design line (the pose every pass puts it in over that cell), a nozzle
/// link rigid with the tip comes within clearance.nozzle_margin_m of a point of the scan that is
/// not gridded wall (a duct under the crown, the face at the bay's end, a rig, muck), and leaning
/// the nozzle off square (along the axis or around it, up to clearance.max_nozzle_lean_rad) does
/// not clear it either. Where a lean clears it, the passes lean there (`lean`, faded out over the
/// wall around at clearance.nozzle_lean_fade_rad_per_m so a pass's nozzle never runs back; a cell
/// the faded lean of another obstacle would not clear keeps its own). No pass can lay the
/// obstructed cells' concrete: they are reported (problem obstructed_cells), not claimed.
/// Throws std::invalid_argument for a fade rate at or above 1 / standoff (less 1 / design radius
/// for circumferential passes) when the nozzle may lean.
struct ObstructedCells {
  std::vector<int> cells;          // grid cell indices (row * n_d + col), ascending
  double margin_m = 0.0;           // the nozzle margin they were checked with
  double least_distance_m = 0.0;   // nearest obstacle point to any of their poses' nozzle links
  Eigen::Vector3d nearest_obstacle_m = Eigen::Vector3d::Zero();  // that point (tunnel frame)
  std::vector<std::string> links;  // the nozzle links checked
  int obstacle_points = 0;         // points of the scan left out of the grid (the obstacles)
  // The poses that lean to keep clear: per grid cell the lean off square (a vector tangent to the
  // wall, toward which the spray axis tips, length = angle [rad]; plan_passes), empty when none does.
  std::vector<Eigen::Vector3d> lean;
  int leaned_cells = 0;            // cells sprayed from a leaned pose (clear; not among `cells`)
  double max_lean_rad = 0.0;       // the steepest lean of those
};
/// `machine`: per scan point, 1 for the machine's own (scan_machine_points), left out of the
/// obstacles; empty: none.
ObstructedCells obstructed_cells(const Surface& surface, const Robot& robot, const Config& config,
                                 const std::vector<char>& machine = {});

/// `robot` with its carrier turned to lie along the surface's axis (its heading in the horizontal
/// plane; Robot::carrier_turned, which sets the heading: calling this twice is harmless):
/// base_link has no heading of its own (a pure translation in the tunnel frame), and the URDF puts
/// the carrier along base_link's -x. So the carrier lies along -ex, behind the arm when the axis
/// points toward the face (profile.axis_direction, an alignment's rising chainage).
Robot carrier_along_axis(const Robot& robot, const Surface& surface);

/// The scan's points that are the machine's own where `robot` stands (machine_points with
/// clearance.carrier_tolerance_m, the carrier along the axis: the rig's carrier in the scan), never
/// a gridded wall point; empty without clearance.enabled. plan_for_arm takes them with the robot as
/// given (where the rig stood for the scan) and leaves them out of every obstacle (the base's
/// place, the lean, the tracking's term, the transits and the check; ClearanceReport::carrier_points).
std::vector<char> scan_machine_points(const Surface& surface, const Config& config, const Robot& robot);

struct ArmPlan {
  Plan plan;
  std::optional<TimedTrajectory> trajectory;  // empty when the timing failed: timing_error says why
  std::string timing_error;
  // The deposit the trajectory lays (execute_deposit with the config's flow); with a trajectory.
  std::optional<ExecutedDeposit> executed;
  int replans = 0;       // plan_bay runs after the first
  SpeedCapMap learned;   // bounds added by the re-plans
  // timing.tune_with_pso: the swarm's per-region parameters (once used, feasible[r] is false
  // where region r kept the config's), the duration with the config's parameters, and whether the
  // tuned trajectory replaced it (faster, within the limits or no worse).
  std::optional<TimingTuning> tuning;
  double config_duration_s = 0.0;  // before slow_to_joint_limits
  bool tuned_timing_used = false;
  // The regions were tracked with the clearance term (clearance.enabled, null_space_gain > 0).
  bool clearance_term_used = false;
  std::string tuning_error;  // why the swarm or its timing failed (the config's timing stands)
  // With clearance.enabled and a trajectory: the space allowance of every link along it, against
  // the wall as scanned and as sprayed (check_clearance).
  std::optional<ClearanceReport> clearance;
  // With clearance.enabled and a trajectory: its joint moves checked, and those closer than the
  // margins re-routed (clear_transits, before the clearance check of the whole trajectory).
  std::optional<TransitReport> transits;
  // With clearance.enabled: the grid cells no clear pose can spray (obstructed_cells).
  std::optional<ObstructedCells> obstructed;
  // With clearance.enabled and a scan: where the trajectory starts (start_posture from the stow
  // posture against the scan); else it starts from the stow posture.
  std::optional<StartPosture> start;
  // Where the arm's base stood for all of it (place_base; unchecked without robot.place_base,
  // clearance or a scan): every posture above is that of placed_robot(robot, base_placement).
  BasePlacement base_placement;
};

/// Where the job places the arm's base: with robot.place_base, clearance.enabled and a scan, the
/// collision place_base against the scan's points along the surface's axis (up to
/// robot.max_base_shift_m); else the configured place, unchecked. The job then plans with
/// robot.placed_at(position_m) (placed_robot; plan_for_arm does both).
/// `scan_wall`: the scan's octree when the caller has one (else built here, less the machine's own
/// points); the robot's carrier is turned along the axis here (carrier_along_axis).
BasePlacement place_base(const Surface& surface, const Config& config, const Robot& robot,
                         const WallOctree* scan_wall = nullptr);

/// `robot` at placement.position_m.
Robot placed_robot(const Robot& robot, const BasePlacement& placement);

/// First the base's place (place_base: with robot.place_base, where the arm has room to slew every
/// way; ArmPlan::base_placement), then, with the arm there, plan_bay with the arm's speed caps (arm_speed_caps: the joint limits along every pass from the
/// neutral posture), then time_plan from the stow posture (with clearance.enabled, from
/// start_posture: the nearest clear posture when the stow one is in something the scan holds); while spraying samples of the trajectory still break a joint
/// limit (the arm reaches a pass in another posture than the caps assumed), their neighbourhood
/// gets the speed that would have kept them within the limits and the bay is planned and timed again,
/// at most timing.max_replans times. The deposit is always simulated at the speeds the trajectory
/// sprays. An IK or timing failure leaves the trajectory empty with the reason in timing_error.
/// With timing.tune_with_pso the final plan's regions are then tuned by tune_timing and timed
/// again; that trajectory is kept when it is shorter and each worst joint ratio stays within its
/// limit or no worse than before (regions that came out worse keep the config's parameters).
/// What is then left over a joint limit is slowed to it (slow_to_joint_limits; config_duration_s
/// and the swarm's comparison are of the trajectories before it). Last, the trajectory kept is
/// executed on the surface (execute_deposit): `executed`. With clearance.enabled its joint moves are
/// then checked against the wall as scanned and as sprayed and re-routed where they come closer
/// than the margins (arm_transits; when one was re-routed or eased, the trajectory is slowed again
/// where its joins need it and the deposit laid again), and the whole trajectory is checked
/// (arm_clearance).
ArmPlan plan_for_arm(const Surface& surface, const Config& config, const Robot& robot,
                     const ProgressFn& progress = {});

/// The wall the arm meets during the job: the scan's points (less the machine's own: `machine`,
/// scan_machine_points; empty: none) and the executed deposit's surface.
Points arm_wall(const Surface& surface, const ExecutedDeposit& executed, const std::vector<char>& machine = {});

/// clear_transits on `trajectory` against arm_wall (what plan_for_arm stores in ArmPlan::transits).
TransitReport arm_transits(const Surface& surface, TimedTrajectory& trajectory, const ExecutedDeposit& executed,
                           const Robot& robot, const ClearanceConfig& config, const TimingConfig& timing,
                           const std::vector<char>& machine = {});

/// The space allowance of `trajectory` against the wall as scanned (surface) and as sprayed
/// (executed): what plan_for_arm stores in ArmPlan::clearance with clearance.enabled.
ClearanceReport arm_clearance(const Surface& surface, const TimedTrajectory& trajectory, const ExecutedDeposit& executed,
                              const Robot& robot, const ClearanceConfig& config, const ProgressFn& progress = {},
                              const std::vector<char>& machine = {});

}  // namespace shotcrete
