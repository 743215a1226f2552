#pragma once
// Joint paths that follow closely spaced nozzle poses exactly (docs/architecture.md §7): smooth enough in
// the path for finite differences, so they give the joint velocities and accelerations of a timed
// path, and the nozzle speeds at which the arm stays within its joint limits.
#include <Eigen/Core>
#include <functional>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"  // NozzlePose
#include "shotcrete/planning/planner.hpp"       // SpeedCapFn

namespace shotcrete {

class Robot;

/// First and second derivatives of q sampled at t (time, or arc length): three-point differences on
/// an uneven grid, exact for quadratics; qdd at the ends copies its neighbour's. qd at the ends is 0
/// (a trajectory from rest to rest) or, with one_sided_ends, the one-sided difference (a path). At a
/// repeated point (step under 1e-9) qd is the one-sided difference and qdd the previous value.
void finite_differences(const std::vector<double>& t, const std::vector<Eigen::VectorXd>& q,
                        std::vector<Eigen::VectorXd>& qd, std::vector<Eigen::VectorXd>& qdd,
                        bool one_sided_ends = false);

/// A second objective of the tracking's null-space drift (besides the joint limits): `gradient`
/// writes the joint-space gradient of a potential at q (dof entries) that the drift descends,
/// scaled by `gain` (0 or no gradient: off). The clearance module gives one that keeps the links
/// away from the wall (clearance_objective); the robot module knows nothing of the wall.
struct NullSpaceObjective {
  std::function<void(const Eigen::VectorXd& q, Eigen::VectorXd& gradient)> gradient;
  double gain = 0.0;
  // Optional: the room of posture q (least distance less margin over the links the spare degrees
  // of freedom move; < 0: a margin broken). timing_joint_path picks the start posture by it.
  std::function<double(const Eigen::VectorXd& q)> room;
  bool active() const { return gain > 0.0 && static_cast<bool>(gradient); }
};

/// Joint path through closely spaced poses: from q0, the start configuration is first settled in
/// the null space away from the joint limits (at rest), then minimal-norm Gauss-Newton steps on the
/// task error (task_error) reach every pose (position and spray axis to ~1e-10) plus a null-space
/// drift away from the limits proportional to the path step (limit_gain * dH/dx, at most 0.05
/// normalised joint range per metre, rising quadratically to 0.5 at a limit once a joint is within
/// 10 % of its range of it), so q is a smooth function of the path and finite differences are
/// meaningful. With `objective` the drift descends limit_gain * H + objective.gain * its potential
/// (the same projection and the same cap per metre). Reports the worst errors.
std::vector<Eigen::VectorXd> track_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                              const Eigen::VectorXd& q0, double limit_gain = 0.02,
                                              double* max_error_m = nullptr, double* max_error_rad = nullptr,
                                              const NullSpaceObjective& objective = {});

/// Joint path for timing: solve_path (limits, restarts, no flips) gives the branch and the start
/// configuration, then track_joint_path follows the poses exactly from there. If that leaves the
/// limits or misses a target by more than the config's tolerances, solve_path's result is used and
/// *tracked (optional) is false. With an active `objective` (the clearance term) the tracking
/// tries it at each limit gain, then at a quarter of its gain, then without it. With
/// `objective.room`, a tracked path that breaks a margin (the least room at five postures along
/// it) is replaced by the one tracked from the roomiest of the first pose's solutions from the
/// seed turned about the first joint (the slew) by +-45, +-90, +-135 and 180 deg, when that path
/// has more room.
std::vector<Eigen::VectorXd> timing_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                               const Eigen::VectorXd& seed, const RobotConfig& robot_config,
                                               bool* tracked = nullptr, const NullSpaceObjective& objective = {});

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

}  // namespace shotcrete
