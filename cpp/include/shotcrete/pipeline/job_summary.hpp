#pragma once
// The one summary of a planned job: the surface, the plan for the arm and its trajectory in
// figures. report.json (Python), the ROS node's ~summary and the Python API all carry this struct,
// written as JSON by to_json.
#include <cstddef>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/surface/surface.hpp"
#include "shotcrete/timing/timing.hpp"

namespace shotcrete {

class Robot;

/// A TD over the valid grid cells [mm].
struct TdStatsMm {
  double mean = 0.0, min = 0.0, max = 0.0, rms = 0.0, abs_max = 0.0;
};

struct RoundSummary {
  int round = 0;  // from 1
  std::string kind;
  int level = 0;
  int regions = 0;
  int passes = 0;
  double spray_time_s = 0.0;
  std::string order_method;
  double link_length_m = 0.0;
  std::map<int, int> levels_before, levels_after;  // cells per level
};

/// The arm on the plan: the poses it must reach and an independent check of the trajectory (FK of
/// every check_every-th joint sample against the nozzle pose it was timed for).
struct IkSummary {
  int poses = 0;  // waypoints of all passes
  int regions = 0;
  int replans = 0;
  int learned_speed_bounds = 0;
  bool solved = true;  // false: no trajectory, `error` says why
  std::string error;
  bool checked = false;  // there is a trajectory and its samples were checked
  int samples_checked = 0;
  double worst_position_error_m = 0.0;
  double worst_angle_error_rad = 0.0;
  int untracked_regions = 0;
};

/// The scalars of a timed trajectory.
struct TrajectorySummary {
  std::size_t samples = 0;
  double duration_s = 0.0, spray_time_s = 0.0, transit_time_s = 0.0;
  CycleTimeBreakdown cycle_time;  // duration_s by what the arm does (TimedTrajectory::cycle_time)
  double max_velocity_ratio = 0.0, max_acceleration_ratio = 0.0;
  // Worst nozzle speed / limit and |acceleration| / limit over every sample (spraying or not),
  // from central finite differences of the sampled nozzle positions (independent of the timing).
  double max_nozzle_speed_ratio = 0.0, max_nozzle_accel_ratio = 0.0;
  int worst_velocity_joint = -1, worst_acceleration_joint = -1;
  double max_position_violation_rad = 0.0;  // revolute joints, outside their position limits
  double max_position_violation_m = 0.0;    // prismatic joints
  int untracked_regions = 0;
  // slow_to_joint_limits: the time it added, the sample intervals it stretched, and the worst of
  // the joint velocity and acceleration ratios before it.
  double slowed_s = 0.0, slowed_spraying_s = 0.0;
  int slowed_intervals = 0;
  double ratio_before_slowing = 0.0;
};
/// The trajectory's scalars; the nozzle ratios against nozzle_limits (timing.nozzle_max_*).
TrajectorySummary summarise_trajectory(const TimedTrajectory& trajectory, const NozzleLimits& nozzle_limits);
/// {samples, duration_s, ..., max_position_violation_rad, max_position_violation_m, untracked_regions}: every field
/// (cycle_time as cycle_time_breakdown_s).
std::string to_json(const TrajectorySummary& summary);

/// The timing swarm of a plan for the arm (timing.tune_with_pso).
struct SwarmSummary {
  bool used = false;          // the tuned trajectory replaced the config's
  std::string error;          // why the swarm failed (empty: it did not)
  double config_timing_duration_s = 0.0;
  std::optional<double> duration_s;  // of the trajectory kept
  int regions_tuned = 0, regions = 0, evaluations = 0;
  int regions_cut_by_budget = 0;     // swarms stopped early by timing.pso_time_budget_s
  std::vector<TimingParams> params;  // per region
};

/// The executed deposit in figures: volumes [m^3] and the pump's flow schedule.
struct ExecutedSummary {
  double sprayed_m3 = 0.0, rebound_m3 = 0.0, on_wall_m3 = 0.0, outside_m3 = 0.0;
  double balance_error = 0.0;  // (sprayed - rebound - on_wall - outside) / sprayed
  int switches = 0, commanded_switches = 0;  // flow on + off switches: pump, spraying flags
  double shortest_on_s = 0.0, shortest_off_s = 0.0;  // of the pump's schedule
  double flow_on_s = 0.0, commanded_on_s = 0.0;       // flow-on time: pump, flags
  double bridged_s = 0.0, bridged_volume_m3 = 0.0;    // off-gaps the flow stayed on through
  double extended_s = 0.0, extended_volume_m3 = 0.0;  // short spells extended to min_on_s
  double trimmed_s = 0.0;  // commanded flow-on time cut off spell ends to widen short gaps to min_off_s
  double dropped_s = 0.0;  // commanded flow-on time switched off (no spraying into a joint move)
  double ramp_s = 0.0;
};
ExecutedSummary summarise_executed(const ExecutedDeposit& executed);

/// Why a plan is not one the machine can execute as reported (report.json `problems`; the CLI
/// exits with code 3). code: unreachable_cells | cells_above_level_0 | arm_cannot_follow |
/// untracked_regions | joint_limits | nozzle_limits | sparse_grid | clearance | base_clearance |
/// obstructed_cells.
struct PlanProblem {
  std::string code;
  std::string message;  // one line, with the figures
};

struct JobSummary {
  std::string mode;  // planner.mode
  int cells = 0;     // valid grid cells
  int grid_n_theta = 0, grid_n_d = 0;
  double grid_cell_size_m = 0.0;                 // grid.cell_size_m (the grid spans n_theta x n_d of them)
  double spot_diameter_m = 0.0;                  // 2 x deposition.spot_radius_m (the spot at the reference standoff)
  long points_in = 0, points_used = 0;  // raw cloud, preprocessed cloud
  double design_radius_m = 0.0, axis_fit_rms_m = 0.0;  // a section's: its mean radius
  // report.json `design_profile`: circle | section (profile.section_path), the arc it spans.
  std::string design_shape = "circle", design_section_path;
  double design_theta_min_deg = -90.0, design_theta_max_deg = 270.0, design_arc_length_m = 0.0;
  // report.json `axis`: the axis the TD was measured from (the job's frame; the CLI adds
  // local_origin_m back) and, when profile.estimate_axis, how well it fitted.
  bool axis_estimated = false;
  Eigen::Vector3d axis_origin_m{0, 0, 0}, axis_direction{1, 0, 0};
  std::optional<double> axis_fit_arc_deg;  // arc the wall covers around the fitted axis
  std::optional<long> axis_fit_points;     // points the fit used
  std::optional<double> axis_fit_inlier_share;  // those / the fit's cloud (a scene's wall: under a third)
  BaySelectionResult bay;                  // report.json `bay`: the stretch of the scan gridded
  long points_not_wall = 0, points_outside_bay = 0;  // near the design line but left out of the grid
  long points_obstacle = 0;  // wall-like but in front of the wall (grid.obstacle_gap_m): left out of the grid
  std::map<int, int> levels_before;
  TdStatsMm td_before_mm;
  // Of the executed deposit (the trajectory with the pump's flow) when there is a trajectory,
  // else of the planner's estimate; deposit_source says which ("executed" | "planned").
  std::map<int, int> levels_after;
  TdStatsMm residual_mm;
  std::string deposit_source = "planned";
  std::map<int, int> planned_levels_after;  // the planner's own estimate
  TdStatsMm planned_residual_mm;
  std::optional<DepositDifferenceMm> planned_vs_executed_mm;  // executed - planned deposit per cell
  std::optional<ExecutedSummary> executed;
  int rounds = 0, regions = 0, passes = 0;
  std::string stop_reason;
  std::vector<std::string> warnings;
  int unreachable_cells = 0;
  double spray_time_s = 0.0, required_volume_m3 = 0.0, deposition_rate_m3ph = 0.0, physical_limit_s = 0.0;
  std::optional<double> spray_time_ratio;  // spray time / physical limit; none when the limit is 0
  double sprayed_volume_m3 = 0.0, link_length_m = 0.0;
  int speed_capped = 0;
  std::vector<RoundSummary> rounds_detail;
  IkSummary ik;
  std::optional<TrajectorySummary> trajectory;  // none when the timing failed (ik.error)
  // The whole executed trajectory (= its duration; breakdown in trajectory->cycle_time) and its
  // ratio to physical_limit_s: none without a trajectory (or a zero limit for the ratio).
  std::optional<double> cycle_time_s, cycle_time_ratio;
  double trajectory_rate_hz = 0.0;               // timing.trajectory_rate_hz
  double config_timing_duration_s = 0.0;         // trajectory duration with the config's timing
  std::optional<SwarmSummary> swarm;             // with a trajectory, when the swarm ran or failed
  std::optional<ClearanceReport> clearance;      // with a trajectory and clearance.enabled
  std::optional<TransitReport> transits;         // its joint moves checked and re-routed (ArmPlan::transits)
  std::optional<ObstructedCells> obstructed;     // with clearance.enabled: cells no clear pose sprays
  int obstructed_above_level_0 = 0;              // of those, left above level 0 by the deposit (deposit_source)
  std::optional<StartPosture> start;             // with clearance.enabled: where the trajectory starts (ArmPlan::start)
  std::optional<BasePlacement> base_placement;   // where the job placed the base (ArmPlan::base_placement, when checked)
  std::vector<std::string> joint_names;          // the robot's, in the order of start's postures
  double self_margin_m = 0.0;                    // clearance.self_margin_m
  // "ok", or "not_executable" when problems is not empty (plan_problems).
  std::string status = "ok";
  std::vector<PlanProblem> problems;

  /// The JSON object report.json starts with (same keys, same order); total_time_s and cycle_time_s
  /// are the trajectory's duration, cycle_time_breakdown_s its parts (null without one). Compact, one line.
  std::string to_json() const;
};

/// Limits the status check allows: a joint or nozzle ratio up to 1 + limit_ratio_tolerance (the
/// nozzle's come from finite differences of samples), and grids with at least
/// min_grid_coverage of their cells holding points.
constexpr double kLimitRatioTolerance = 1e-3;
constexpr double kMinGridCoverage = 0.5;

/// The problems of a summary (empty: the plan is right): cells it leaves above level 0 or cannot
/// reach, an arm that cannot follow it, limits broken, a grid mostly made of holes.
std::vector<PlanProblem> plan_problems(const JobSummary& summary);

struct JobSummaryOptions {
  long points_in = 0;    // points of the raw cloud the surface was built from
  int check_every = 10;  // FK check of every n-th trajectory sample
};

/// Summary of a bay planned for the arm (plan_for_arm) on `surface`; `robot` as given to plan_for_arm
/// (or already placed): it is placed where arm_plan.base_placement says.
JobSummary summarise_job(const Surface& surface, const ArmPlan& arm_plan, const Robot& robot, const Config& config,
                         const JobSummaryOptions& options = {});

}  // namespace shotcrete
