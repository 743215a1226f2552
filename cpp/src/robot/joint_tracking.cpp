// Exact joint tracking of closely spaced nozzle poses, finite differences along it, and the nozzle
// speeds the arm can follow within its joint limits.
#include "shotcrete/robot/joint_tracking.hpp"

#include <algorithm>
#include <cmath>
#include <future>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

#include "shotcrete/robot/robot.hpp"

#ifdef _OPENMP
#include <omp.h>
#endif

namespace shotcrete {

void finite_differences(const std::vector<double>& t, const std::vector<Eigen::VectorXd>& q,
                        std::vector<Eigen::VectorXd>& qd, std::vector<Eigen::VectorXd>& qdd,
                        bool one_sided_ends) {
  const std::size_t n = q.size();
  const Eigen::Index dof = n ? q[0].size() : 0;
  qd.assign(n, Eigen::VectorXd::Zero(dof));
  qdd.assign(n, Eigen::VectorXd::Zero(dof));
  for (std::size_t i = 1; i + 1 < n; ++i) {
    const double h1 = t[i] - t[i - 1], h2 = t[i + 1] - t[i];
    if (h1 < 1e-9 || h2 < 1e-9) {
      const std::size_t a = h1 < 1e-9 ? i : i - 1, b = h1 < 1e-9 ? i + 1 : i;
      if (t[b] - t[a] > 1e-9) qd[i] = (q[b] - q[a]) / (t[b] - t[a]);
      qdd[i] = qdd[i - 1];
      continue;
    }
    qd[i] = (-h2 / (h1 * (h1 + h2))) * q[i - 1] + ((h2 - h1) / (h1 * h2)) * q[i] + (h1 / (h2 * (h1 + h2))) * q[i + 1];
    qdd[i] = 2.0 * (q[i - 1] / (h1 * (h1 + h2)) - q[i] / (h1 * h2) + q[i + 1] / (h2 * (h1 + h2)));
  }
  if (one_sided_ends && n >= 2) {
    if (t[1] - t[0] > 1e-9) qd[0] = (q[1] - q[0]) / (t[1] - t[0]);
    if (t[n - 1] - t[n - 2] > 1e-9) qd[n - 1] = (q[n - 1] - q[n - 2]) / (t[n - 1] - t[n - 2]);
  }
  if (n >= 3) {
    qdd[0] = qdd[1];
    qdd[n - 1] = qdd[n - 2];
  }
}

namespace {

// Joint limits and ranges.
struct JointRange {
  Eigen::VectorXd lo, hi, range;
  explicit JointRange(const Robot& robot)
      : lo(robot.lower_limits()), hi(robot.upper_limits()), range((hi - lo).cwiseMax(1e-9)) {}
};

// Null-space step of q away from the limits for a path step ds at pose `at`: the projection of
// -grad H (H = sum 1 / (4 x (1 - x)), x = normalised joint position) onto the null space of the
// task, a descent direction of H, times limit_gain * ds (plus objective.gain times the objective's
// descent, projected alike), scaled down as a whole (direction kept) so
// no joint drifts faster than kMaxDrift of its range per metre of path. Returns the largest step
// as a share of the joint range.
double null_step(const Robot& robot, const JointRange& jr, const NozzlePose& at, double ds, double limit_gain,
                 Eigen::VectorXd& q, const NullSpaceObjective& objective) {
  constexpr double kMaxDrift = 0.05, kNearDrift = 0.5, kNearBand = 0.1;
  const int n = robot.dof();
  Eigen::MatrixXd A;
  task_error(robot, q, at, &A, AxisError::CrossProduct);
  Eigen::VectorXd g(n);
  for (int i = 0; i < n; ++i) {
    const double x = std::clamp((q(i) - jr.lo(i)) / jr.range(i), 1e-4, 1.0 - 1e-4);
    g(i) = (1.0 - 2.0 * x) / (4.0 * x * x * (1.0 - x) * (1.0 - x)) / jr.range(i);
  }
  double scale = limit_gain;
  if (objective.active()) {
    // The second potential's descent, weighed by its gain against the limits' (same units: per
    // joint unit, per metre of path). Without it the arithmetic is the limits' alone, as before.
    Eigen::VectorXd grad = Eigen::VectorXd::Zero(n);
    objective.gradient(q, grad);
    g = limit_gain * g - objective.gain * grad;
    scale = 1.0;
  }
  const Eigen::Matrix<double, 5, 5> M = A * A.transpose() + 1e-12 * Eigen::Matrix<double, 5, 5>::Identity();
  Eigen::VectorXd dq = scale * ds * (g - A.transpose() * M.ldlt().solve(A * g));
  // Near a limit the task itself may push the joint outwards faster than kMaxDrift can pull it
  // back (e.g. the arm telescope at the edge of the reach): the allowed drift grows smoothly up
  // to kNearDrift as the closest joint comes within kNearBand of its range.
  double margin = 1.0;
  for (int i = 0; i < n; ++i)
    margin = std::min({margin, (q(i) - jr.lo(i)) / jr.range(i), (jr.hi(i) - q(i)) / jr.range(i)});
  const double near = std::clamp(1.0 - margin / kNearBand, 0.0, 1.0);
  const double cap = kMaxDrift + (kNearDrift - kMaxDrift) * near * near;
  const double worst = dq.cwiseQuotient(jr.range).cwiseAbs().maxCoeff() / (cap * ds);
  if (worst > 1.0) dq /= worst;
  q += dq;
  return dq.cwiseQuotient(jr.range).cwiseAbs().maxCoeff();
}

// Minimal-norm Gauss-Newton steps of q onto the exact target.
void correct(const Robot& robot, const NozzlePose& target, Eigen::VectorXd& q) {
  Eigen::MatrixXd A;
  for (int it = 0; it < 30; ++it) {
    const TaskError te = task_error(robot, q, target, &A, AxisError::CrossProduct);
    if (te.e.head<3>().norm() < 1e-10 && te.e.tail<2>().norm() < 1e-10) break;
    const Eigen::Matrix<double, 5, 5> M = A * A.transpose() + 1e-10 * Eigen::Matrix<double, 5, 5>::Identity();
    Eigen::VectorXd dq = A.transpose() * M.ldlt().solve(te.e);
    const double big = dq.cwiseAbs().maxCoeff();
    if (big > 0.2) dq *= 0.2 / big;
    q += dq;
  }
}

}  // namespace

std::vector<Eigen::VectorXd> track_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                              const Eigen::VectorXd& q0, double limit_gain, double* max_error_m,
                                              double* max_error_rad, const NullSpaceObjective& objective) {
  if (q0.size() != robot.dof()) throw std::invalid_argument("track_joint_path: q0 does not match the robot");
  const JointRange jr(robot);
  std::vector<Eigen::VectorXd> out;
  out.reserve(poses.size());
  Eigen::VectorXd q = q0;
  double emax = 0.0, amax = 0.0;
  // Settle the start configuration at rest (free: the transit brings the arm there anyway), so the
  // drift along the path stays small.
  if (!poses.empty() && limit_gain > 0.0) {
    correct(robot, poses.front(), q);
    for (int it = 0; it < 2000; ++it) {
      const double step = null_step(robot, jr, poses.front(), 0.05, limit_gain, q, objective);
      correct(robot, poses.front(), q);
      if (step < 1e-6) break;
    }
  }
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const double ds = k == 0 ? 0.0 : (poses[k].position_m - poses[k - 1].position_m).norm();
    // Drift proportional to the path step: q(s) depends on the path only, as smooth as the path.
    if (ds > 0.0 && limit_gain > 0.0) null_step(robot, jr, poses[k - 1], ds, limit_gain, q, objective);
    correct(robot, poses[k], q);  // minimal-norm Gauss-Newton onto the exact target
    const TaskError te = task_error(robot, q, poses[k], nullptr, AxisError::CrossProduct);
    emax = std::max(emax, te.position_m);
    amax = std::max(amax, std::asin(std::min(1.0, te.e.tail<2>().norm())));
    out.push_back(q);
  }
  if (max_error_m) *max_error_m = emax;
  if (max_error_rad) *max_error_rad = amax;
  return out;
}

// The config's tolerances (1 mm) are coarse next to the motion between two samples, and a
// warm-started solver that stops inside them returns a staircase whose finite differences are
// meaningless: so the samples are tracked exactly (minimal-norm steps + smooth null-space limit
// avoidance) from solve_path's first solution.
// Start postures tracked for a path that breaks a margin (each a whole tracking of the path).
constexpr std::size_t kMostStartsTried = 3;

std::vector<Eigen::VectorXd> timing_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                               const Eigen::VectorXd& seed, const RobotConfig& rc, bool* tracked,
                                               const NullSpaceObjective& objective) {
  // The default limit avoidance is gentle, so q(s) stays close to the minimal-norm path; where it
  // lets a joint run past its limit (the telescope at the edge of the reach, late in a long
  // region: 0.4 mm over on the default bay's graded springline), stronger avoidance is tried before
  // falling back to solve_path's staircase, whose finite differences break the acceleration limits.
  // With a second objective (the clearance term) every limit gain is tried with it first, then
  // with a quarter of its gain (over a long region its drift can take a joint past a limit the
  // full gain's does not come back from: a 93 k-sample region of the narrow bay), then without
  // it: the term never costs a region its exact tracking.
  const auto track_from = [&](const Eigen::VectorXd& q0, std::vector<Eigen::VectorXd>& q) {
    for (const double share : {1.0, 0.25, 0.0}) {
      NullSpaceObjective used = objective;
      used.gain *= share;
      if (share > 0.0 && !used.active()) continue;
      for (const double limit_gain : {0.02, 0.1, 0.3}) {
        double em = 0.0, ea = 0.0;
        q = track_joint_path(robot, poses, q0, limit_gain, &em, &ea, share > 0.0 ? used : NullSpaceObjective{});
        bool ok = em <= rc.ik_position_tolerance_m && ea <= rc.ik_angle_tolerance_rad;
        for (const auto& x : q) ok = ok && robot.within_limits(x);
        if (ok) return true;
      }
    }
    return false;
  };
  // Only solve_path's start is tracked from (its whole path is the fallback), and that start is
  // nearly always the first pose's own solution from the seed (the path's first try, kept when it
  // runs smoothly). So, outside a parallel loop, the path is solved on a second thread while the
  // tracking runs from that solution, and tracked again should the path start elsewhere: the same
  // result as one after the other, in about the tracking's time.
  bool speculate = poses.size() > 1;
#ifdef _OPENMP
  speculate = speculate && !omp_in_parallel();
#endif
  std::vector<Eigen::VectorXd> q;
  bool ok = false;
  JointPath jp;
  if (speculate) {
    std::future<JointPath> whole = std::async(std::launch::async, [&] { return solve_path(robot, poses, seed, rc); });
    Eigen::VectorXd guess;
    try {
      guess = solve_path(robot, {poses.front()}, seed, rc).q.front();
    } catch (const std::exception&) {
      // The first pose alone fails: the whole path's error says why (it fails there too).
    }
    if (guess.size() > 0) ok = track_from(guess, q);
    jp = whole.get();
    if (guess.size() == 0 || guess != jp.q.front()) ok = track_from(jp.q.front(), q);
  } else {
    jp = solve_path(robot, poses, seed, rc);
    ok = track_from(jp.q.front(), q);
  }
  // The seed carries the last region's posture family: the boom may then stand in what lies
  // beyond the wall (a face: a link wholly past it reads far from the scan's points, so the
  // clearance term cannot pull it back). A path that breaks a margin gives way to the roomiest of
  // the paths tracked from the first pose's solutions from the seed's slew turned by eighths of a
  // turn (the least room at five postures along each). The turns wrap modulo 2 pi (then clamped to
  // the slew's limits, +-3.05 rad, just inside +-pi): a region from the crown down the right wall
  // that starts in the left wall's family (slew 2.8 rad, the boom back and left) luffs over the
  // top and slews the boom toward the face as it goes down (the face scene); the right wall's own
  // family (-2.8 rad) is 5.6 rad away, past the limit a clamped turn stops at. Candidates whose first posture has less room than the path's own first
  // are left out, and at most kMostStartsTried of the roomiest are tracked.
  if (ok && objective.room) {
    const auto path_room = [&](const std::vector<Eigen::VectorXd>& path) {
      double least = std::numeric_limits<double>::infinity();
      for (int k = 0; k <= 4; ++k) least = std::min(least, objective.room(path[(path.size() - 1) * k / 4]));
      return least;
    };
    double have = path_room(q);
    if (have < 0.0) {
      const double own_room = objective.room(q.front());
      std::vector<std::pair<double, Eigen::VectorXd>> starts;  // (-room, first posture)
      for (const double turn : {0.25, -0.25, 0.5, -0.5, 0.75, -0.75, 1.0}) {
        Eigen::VectorXd s = seed;
        s[0] = std::clamp(std::remainder(s[0] + turn * M_PI, 2.0 * M_PI), robot.lower_limits()[0], robot.upper_limits()[0]);
        Eigen::VectorXd cand;
        try {
          cand = solve_path(robot, {poses.front()}, s, rc).q.front();
        } catch (const std::exception&) {
          continue;  // no solution from this turn
        }
        const bool seen = (cand - q.front()).norm() < 1e-3 ||
                          std::any_of(starts.begin(), starts.end(), [&](const auto& c) { return (c.second - cand).norm() < 1e-3; });
        const double room = objective.room(cand);
        if (!seen && room >= own_room - 1e-3) starts.emplace_back(-room, std::move(cand));
      }
      std::sort(starts.begin(), starts.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
      if (starts.size() > kMostStartsTried) starts.resize(kMostStartsTried);
      for (const auto& start : starts) {
        std::vector<Eigen::VectorXd> alt;
        if (!track_from(start.second, alt)) continue;
        const double room = path_room(alt);
        if (room > have + 1e-3) have = room, q = std::move(alt);
      }
    }
  }
  if (tracked) *tracked = ok;
  return ok ? q : jp.q;
}

namespace {
void require(bool ok, const char* what, double value, const char* rule) {
  if (ok) return;
  std::ostringstream m;
  m << std::setprecision(6) << "joint_speed_limits: " << what << " " << value << " must be " << rule;
  throw std::invalid_argument(m.str());
}
}  // namespace

std::vector<double> joint_speed_limits(const Robot& robot, const std::vector<NozzlePose>& poses,
                                       const Eigen::VectorXd& seed, double tangential_accel_mps2, double limit_share) {
  require(limit_share > 0.0 && limit_share <= 1.0, "limit_share", limit_share, "in (0, 1]");
  require(tangential_accel_mps2 >= 0.0, "tangential_accel_mps2", tangential_accel_mps2, ">= 0");
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> cap(poses.size(), inf);
  if (poses.size() < 2) return cap;
  const auto q = track_joint_path(robot, poses, seed);
  std::vector<double> s(poses.size(), 0.0);
  for (std::size_t k = 1; k < poses.size(); ++k)
    s[k] = s[k - 1] + (poses[k].position_m - poses[k - 1].position_m).norm();
  std::vector<Eigen::VectorXd> dq, ddq;
  finite_differences(s, q, dq, ddq, true);
  const Eigen::VectorXd vmax = limit_share * robot.velocity_limits(), amax = limit_share * robot.acceleration_limits();
  for (std::size_t k = 0; k < poses.size(); ++k)
    for (int i = 0; i < robot.dof(); ++i) {
      const double d1 = std::abs(dq[k][i]), d2 = std::abs(ddq[k][i]);
      if (d1 > 0.0) cap[k] = std::min(cap[k], vmax[i] / d1);
      const double budget = amax[i] - d1 * tangential_accel_mps2;
      if (budget <= 0.0) cap[k] = 0.0;
      else if (d2 > 0.0) cap[k] = std::min(cap[k], std::sqrt(budget / d2));
    }
  return cap;
}

SpeedCapFn arm_speed_caps(const Robot& robot, const Config& config) {
  const double accel = config.timing.speed_change_accel_mps2, share = 1.0 - config.timing.joint_limit_margin;
  return [&robot, accel, share](const std::vector<NozzlePose>& poses) {
    return joint_speed_limits(robot, poses, robot.neutral(), accel, share);
  };
}

}  // namespace shotcrete
