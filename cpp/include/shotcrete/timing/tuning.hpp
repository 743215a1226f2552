#pragma once
// Tuning of the timing parameters by the swarm (docs/architecture.md §8): a joint-space model of a
// region's timing that needs no IK per candidate, and the per-region AIWCPSO over TimingParams.
#include <Eigen/Core>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/planning/planner.hpp"  // Pass
#include "shotcrete/robot/joint_tracking.hpp"  // NullSpaceObjective
#include "shotcrete/timing/cartesian_path.hpp"
#include "shotcrete/timing/pso.hpp"
#include "shotcrete/timing/region_path.hpp"  // TimingParams
#include "shotcrete/timing/sampling.hpp"     // NozzleLimits, NozzleCheck

namespace shotcrete {

class Robot;

/// Joint-space feasibility of a region timing without re-solving IK for every candidate: the joint
/// path q(s) is solved once on timing_region_path with the longest lead lengths at a fine
/// arc-length step, then q' = dq/ds and q'' = d2q/ds2 give qd = q' v and qdd = q'' v^2 + q' a.
/// As in time_plan, the stop-and-go moves are joint quintics between the rest configurations at
/// their ends (their minimal duration counts, their samples are not checked) and each stretch after
/// one is tracked anew from where the move ends.
class RegionJointModel {
 public:
  /// `objective`: the tracking's second null-space objective (plan_for_arm's clearance term), as
  /// time_plan tracks the region with it.
  RegionJointModel(const Robot& robot, const std::vector<Pass>& passes, double max_lead_m, const TimingConfig& timing,
                   const Eigen::VectorXd& seed, const RobotConfig& robot_config, double step_m = 0.005,
                   const NullSpaceObjective& objective = {});
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
  std::vector<double> move_s_;      // quintic_nozzle_duration of each joint move
  Eigen::VectorXd vel_limit_, acc_limit_;
  // Stretch containing s, -1 inside a joint move.
  int stretch_at(double s) const;
  void interpolate(const Stretch& st, double s, Eigen::VectorXd& q, Eigen::VectorXd& dq, Eigen::VectorXd& ddq) const;
  // The pieces the parameters shape at arc length s: the leads, the turn arcs with their runs, and
  // the tight turns' creeps (timed at the turn acceleration).
  bool tuned_at(double s) const;
  // Joint velocity / acceleration ratios and nozzle figures on samples of the profile at rate_hz
  // (the joint path starting at arc length offset_m).
  void check_samples(const SpeedProfile& prof, double offset_m, double rate_hz, Evaluation& ev) const;
};

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
  int regions_cut_by_budget = 0;     // swarms stopped early by timing.pso_time_budget_s
};
/// The budget timing.pso_time_budget_s is shared out over the regions in order; progress gets
/// stage "tuning timing" with the share of regions done. `objective`: the regions' models track
/// with it (RegionJointModel), as time_plan does with the same objective.
TimingTuning tune_timing(const Robot* robot, const std::vector<std::vector<Pass>>& regions_in_order,
                         const Eigen::VectorXd& q_start, const TimingConfig& timing, const RobotConfig& robot_config,
                         const ProgressFn& progress = {}, const NullSpaceObjective& objective = {});

}  // namespace shotcrete
