// Inverse kinematics of the 5-DOF spraying task: the task error, damped least squares with joint
// limits and seeded restarts, the plain-KDL baseline and continuous joint paths along passes.
#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>

#include <kdl/chainiksolverpos_nr_jl.hpp>
#include <kdl/chainiksolvervel_pinv.hpp>

#include "detail.hpp"
#include "shotcrete/robot/robot.hpp"

namespace shotcrete {

using namespace robot_detail;

// ---------------------------------------------------------------------------------------------
// Task error

TaskError task_error(const Eigen::Vector3d& p, const Eigen::Matrix3d& R, const Eigen::Vector3d& target_position_m,
                     const Eigen::Vector3d& target_axis, AxisError form) {
  TaskError out;
  const Eigen::Vector3d z = R.col(2);
  out.e.head<3>() = target_position_m - p;
  out.position_m = out.e.head<3>().norm();
  Eigen::Vector3d c = z.cross(target_axis);
  const double s = c.norm();
  out.angle_rad = std::atan2(s, z.dot(target_axis));
  Eigen::Vector3d w;
  if (form == AxisError::CrossProduct) {
    w = c;
  } else if (s > 1e-12) {
    w = c / s * out.angle_rad;
  } else if (z.dot(target_axis) < 0) {
    w = R.col(0) * out.angle_rad;  // antiparallel: any perpendicular turns it round
  } else {
    w.setZero();
  }
  out.e(3) = R.col(0).dot(w);
  out.e(4) = R.col(1).dot(w);
  if (form == AxisError::CrossProduct && z.dot(target_axis) < 0.0) out.e(3) += 2.0;  // far side
  return out;
}

Eigen::Matrix<double, 5, Eigen::Dynamic> task_jacobian(const Eigen::Matrix3d& R,
                                                       const Eigen::Matrix<double, 6, Eigen::Dynamic>& J) {
  Eigen::Matrix<double, 5, Eigen::Dynamic> A(5, J.cols());
  A.topRows<3>() = J.topRows<3>();
  A.row(3) = R.col(0).transpose() * J.bottomRows<3>();
  A.row(4) = R.col(1).transpose() * J.bottomRows<3>();
  return A;
}

TaskError task_error(const Robot& robot, const Eigen::VectorXd& q, const NozzlePose& target,
                     Eigen::MatrixXd* jacobian, AxisError form) {
  check_q(robot, q, "q");
  // Pose and Jacobian in one pass over the chain, then into the robot's base frame (a rotation
  // and a translation), as Robot::fk and Robot::jacobian give them.
  Kin kin(robot.impl());
  Eigen::Vector3d p;
  Eigen::Matrix3d R;
  kin.compose(q, p, R, jacobian != nullptr);
  const Eigen::Isometry3d& base = robot.impl().base;
  R = base.linear() * R;
  const TaskError out = task_error(base * p, R, target.position_m, target.axis.normalized(), form);
  if (jacobian) {
    Eigen::Matrix<double, 6, Eigen::Dynamic> J(6, kin.J.cols());
    J.topRows<3>() = base.linear() * kin.J.topRows<3>();
    J.bottomRows<3>() = base.linear() * kin.J.bottomRows<3>();
    *jacobian = task_jacobian(R, J);
  }
  return out;
}

namespace {

std::string fmt_vec(const Eigen::Vector3d& v, int precision = 3) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return os.str();
}

struct Target {
  Eigen::Vector3d p;  // base frame
  Eigen::Vector3d z;  // unit, base frame
};

constexpr double kAngleWeight = 1.0;  // metres per radian in the damped least-squares cost
constexpr double kLimitGain = 0.02;   // null-space step towards mid-range per iteration
constexpr double kAnchorGain = 0.05;  // null-space pull towards the seed (minimal motion)
constexpr double kNullClip = 0.02;    // largest null-space step per joint and iteration (continuity)

double cost(const TaskError& te) {
  return te.position_m * te.position_m + kAngleWeight * kAngleWeight * te.angle_rad * te.angle_rad;
}

struct Attempt {
  Eigen::VectorXd q;
  double pos = 1e9, ang = 1e9;
  int iterations = 0;
};

// Secondary objective gradient (descent direction) at q: away from the limits, towards the anchor.
// Limit term: descent of H = sum 1 / (4 s (1 - s)), s = normalised joint position, which is
// flat mid-range and grows without bound at a limit (clipped per joint).
Eigen::VectorXd secondary_gradient(const Robot::Impl& r, const Eigen::VectorXd& q, const Eigen::VectorXd& anchor,
                                   const Eigen::VectorXd& range) {
  const int n = static_cast<int>(q.size());
  Eigen::VectorXd g(n);
  for (int i = 0; i < n; ++i) {
    const double s = std::clamp((q(i) - r.lower(i)) / range(i), 1e-3, 1.0 - 1e-3);
    const double dH = (1.0 - 2.0 * s) / (4.0 * s * s * (1.0 - s) * (1.0 - s)) / range(i);
    g(i) = std::clamp(kLimitGain * dH, -kNullClip, kNullClip) - kAnchorGain * (q(i) - anchor(i));
  }
  return g;
}

// Damped least-squares step towards task error e (Jacobian A, damping lambda) plus the null-space
// projection of g, restricted to the joints free to move: a joint this step would push through a
// limit it already touches is locked and the step solved again without it.
Eigen::VectorXd dls_step(const Robot::Impl& r, const Eigen::Matrix<double, 5, Eigen::Dynamic>& A,
                         const Eigen::Matrix<double, 5, 1>& e, const Eigen::VectorXd& g, double lambda,
                         const Eigen::VectorXd& q) {
  const int n = static_cast<int>(q.size());
  Eigen::VectorXd active = Eigen::VectorXd::Ones(n);  // 0 = locked at a limit
  Eigen::VectorXd dq(n);
  for (int pass = 0; pass < 3; ++pass) {
    Eigen::Matrix<double, 5, Eigen::Dynamic> Aa = A * active.asDiagonal();
    Eigen::Matrix<double, 5, 5> M = Aa * Aa.transpose();
    M.diagonal().array() += lambda;
    Eigen::LDLT<Eigen::Matrix<double, 5, 5>> ldlt(M);
    dq = Aa.transpose() * ldlt.solve(e);
    // Null-space projection of the secondary gradient (restricted to free joints).
    Eigen::VectorXd gn = active.asDiagonal() * g;
    gn -= Aa.transpose() * ldlt.solve(Aa * gn);
    dq += gn;
    // Lock joints that this step would push through a limit, then re-solve without them.
    bool changed = false;
    for (int i = 0; i < n; ++i) {
      if (active(i) == 0) continue;
      if ((q(i) + dq(i) > r.upper(i) && q(i) >= r.upper(i) - 1e-9) ||
          (q(i) + dq(i) < r.lower(i) && q(i) <= r.lower(i) + 1e-9)) {
        active(i) = 0;
        changed = true;
      }
    }
    if (!changed) break;
  }
  // Trust region: no joint moves more than 0.4 rad / 0.4 m per iteration.
  const double big = dq.cwiseAbs().maxCoeff();
  if (big > 0.4) dq *= 0.4 / big;
  return dq;
}

// One damped least-squares descent (Levenberg-Marquardt damping) from q0 with clamping to the
// limits, an active set of joints pressed against a limit, and a null-space pull towards
// mid-range and towards `anchor` (minimal motion).
// posture_iterations > 0 keeps iterating after convergence, moving only in the null space while
// the task stays within the goal (settles the configuration away from limits).
Attempt dls_attempt(Kin& kin, const Target& target, const Eigen::VectorXd& q0, const Eigen::VectorXd& anchor,
                    const RobotConfig& config, int posture_iterations = 0) {
  const auto& r = kin.r;
  const Eigen::VectorXd range = (r.upper - r.lower).cwiseMax(1e-9);
  const double pos_goal = 0.1 * config.ik_position_tolerance_m;
  const double ang_goal = 0.1 * config.ik_angle_tolerance_rad;

  Attempt a;
  a.q = q0.cwiseMax(r.lower).cwiseMin(r.upper);
  Eigen::Vector3d p;
  Eigen::Matrix3d R;
  kin.pose(a.q, p, R);
  TaskError te = task_error(p, R, target.p, target.z);
  double lambda = 1e-3;
  int settled = 0;
  for (int it = 0; it < config.ik_max_iterations + posture_iterations; ++it) {
    a.iterations = it + 1;
    const bool converged = te.position_m < pos_goal && te.angle_rad < ang_goal;
    if (converged && settled++ >= posture_iterations) break;
    Eigen::Matrix<double, 5, Eigen::Dynamic> A = task_jacobian(R, kin.jacobian(a.q));
    A.bottomRows<2>() *= kAngleWeight;
    Eigen::Matrix<double, 5, 1> e = te.e;
    e.tail<2>() *= kAngleWeight;
    const Eigen::VectorXd g = secondary_gradient(r, a.q, anchor, range);

    bool improved = false;
    for (int tries = 0; tries < 6 && !improved; ++tries) {
      const Eigen::VectorXd dq = dls_step(r, A, e, g, lambda, a.q);
      Eigen::VectorXd qn = (a.q + dq).cwiseMax(r.lower).cwiseMin(r.upper);
      Eigen::Vector3d pn;
      Eigen::Matrix3d Rn;
      kin.pose(qn, pn, Rn);
      TaskError ten = task_error(pn, Rn, target.p, target.z);
      // While settling the posture, a null-space step may cost a little task accuracy (second
      // order); the following iterations restore it.
      const bool posture_ok = converged && ten.position_m < 0.5 * config.ik_position_tolerance_m &&
                              ten.angle_rad < 0.5 * config.ik_angle_tolerance_rad;
      if (cost(ten) < cost(te) || posture_ok) {
        a.q = qn;
        p = pn;
        R = Rn;
        te = ten;
        lambda = std::max(lambda * 0.3, 1e-6);
        improved = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved) break;  // stuck in a local minimum (or at limits): let a restart try
  }
  a.pos = te.position_m;
  a.ang = te.angle_rad;
  return a;
}

Target to_base(const Robot::Impl& r, const NozzlePose& pose) {
  if (!pose.position_m.allFinite() || !pose.axis.allFinite())
    throw std::invalid_argument("nozzle pose contains NaN or inf");
  const double norm = pose.axis.norm();
  if (!(norm > 1e-9)) throw std::invalid_argument("nozzle axis must be non-zero");
  Target t;
  t.p = r.base.inverse() * pose.position_m;
  t.z = r.base.linear().transpose() * (pose.axis / norm);
  return t;
}

std::string describe_pose(const NozzlePose& pose) {
  return "position " + fmt_vec(pose.position_m) + " m, axis " + fmt_vec(pose.axis.normalized());
}

// Why the best attempt failed: out of reach (distance bound) or stuck against joint limits.
std::string failure_reason(const Robot& robot, const NozzlePose& pose, const Attempt& best) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  const double dist = (pose.position_m - robot.shoulder_position()).norm();
  if (dist > robot.max_reach_m()) {
    os.precision(2);
    os << "out of reach: the target is " << dist << " m from the slew centre, the arm reaches at most "
       << robot.max_reach_m() << " m";
    return os.str();
  }
  const auto& r = robot.impl();
  std::vector<std::string> at_limit;
  for (int i = 0; i < robot.dof(); ++i) {
    const double tol = 1e-6 * std::max(1.0, r.upper(i) - r.lower(i));
    if (best.q(i) <= r.lower(i) + tol) at_limit.push_back(r.names[i] + " (lower)");
    if (best.q(i) >= r.upper(i) - tol) at_limit.push_back(r.names[i] + " (upper)");
  }
  os.precision(1);
  os << (at_limit.empty() ? "out of reach" : "joint limits") << ": best attempt is " << best.pos * 1000.0
     << " mm and " << best.ang * 180.0 / M_PI << " deg from the target";
  if (!at_limit.empty()) {
    os << " with ";
    for (size_t i = 0; i < at_limit.size(); ++i) os << (i ? ", " : "") << at_limit[i];
    os << " at the limit";
  }
  return os.str();
}

bool within_tol(const Attempt& a, const RobotConfig& c) {
  return a.pos <= c.ik_position_tolerance_m && a.ang <= c.ik_angle_tolerance_rad;
}

double joint_step(const Eigen::VectorXd& a, const Eigen::VectorXd& b, int* which = nullptr) {
  Eigen::Index i = 0;
  const double s = (a - b).cwiseAbs().maxCoeff(&i);
  if (which) *which = static_cast<int>(i);
  return s;
}

// Walks from pose `from` (joints q_prev) to `to` through interpolated poses (4, 16 or 64 steps,
// the first count where no joint jumps more than ik_max_joint_step): continuation without flips.
struct Walk {
  bool ok = false;
  IkResult last;      // the solution at `to`
  int substeps = 0;   // interpolated poses inserted
  std::string why;    // why no count worked
};
Walk walk_to(const Robot& robot, const NozzlePose& from, const NozzlePose& to, const Eigen::VectorXd& q_prev,
             const RobotConfig& config, std::string why) {
  RobotConfig local = config;
  local.ik_max_restarts = 0;  // continuation: stay in the current branch
  Walk walk;
  const Eigen::Vector3d a0 = from.axis.normalized(), a1 = to.axis.normalized();
  for (int n : {4, 16, 64}) {
    Eigen::VectorXd q = q_prev;
    bool good = true;
    for (int s = 1; s <= n && good; ++s) {
      const double t = static_cast<double>(s) / n;
      NozzlePose mid;
      mid.position_m = (1 - t) * from.position_m + t * to.position_m;
      // Slerp of the axis (falls back to lerp for nearly equal axes).
      const double om = axis_angle(a0, a1);
      mid.axis = om < 1e-9 ? a1 : Eigen::Vector3d((std::sin((1 - t) * om) * a0 + std::sin(t * om) * a1) / std::sin(om));
      if (om > M_PI - 1e-6) mid.axis = a1;  // antiparallel: no unique slerp, go straight
      IkResult sub = solve_ik_5dof(robot, mid, q, local);
      int w = 0;
      if (!sub.success) {
        good = false;
        why = sub.reason;
      } else if (joint_step(sub.q, q, &w) > config.ik_max_joint_step) {
        good = false;
        why = "joint " + robot.joint_names()[w] + " would jump " + std::to_string(joint_step(sub.q, q)) +
              " (rad or m) > ik_max_joint_step " + std::to_string(config.ik_max_joint_step);
      } else {
        q = sub.q;
        walk.last = sub;
      }
    }
    if (good) {
      walk.ok = true;
      walk.substeps = n - 1;
      return walk;
    }
  }
  walk.why = why;
  return walk;
}

// The first waypoint of a pass: IK from `seed` (with restarts), then the posture settled away from
// the limits so the pass does not run into one.
IkResult first_waypoint(const Robot& robot, const NozzlePose& wp, const Eigen::VectorXd& seed,
                        const RobotConfig& config) {
  IkResult res = solve_ik_5dof(robot, wp, seed, config);
  if (!res.success) return res;
  Kin kin(robot.impl());
  const Attempt settled = dls_attempt(kin, to_base(robot.impl(), wp), res.q, res.q, config, 60);
  if (within_tol(settled, config) && robot.within_limits(settled.q)) {
    res.q = settled.q;
    res.position_error_m = settled.pos;
    res.angle_error_rad = settled.ang;
  }
  return res;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// IK

IkResult solve_ik_5dof(const Robot& robot, const NozzlePose& pose, const Eigen::VectorXd& seed,
                       const RobotConfig& config) {
  check_q(robot, seed, "IK seed");
  const auto& r = robot.impl();
  const Target target = to_base(r, pose);
  Kin kin(r);
  IkResult out;
  const Eigen::VectorXd start = seed.cwiseMax(r.lower).cwiseMin(r.upper);
  Attempt best = dls_attempt(kin, target, start, start, config);
  int iterations = best.iterations;
  int restarts = 0;
  // Seeded restarts: the same target and seed always give the same answer.
  std::mt19937 rng(0x5eedu);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double dist = (pose.position_m - robot.shoulder_position()).norm();
  const bool hopeless = dist > robot.max_reach_m();
  while (!within_tol(best, config) && restarts < config.ik_max_restarts && !hopeless) {
    ++restarts;
    Eigen::VectorXd q0(robot.dof());
    for (int i = 0; i < robot.dof(); ++i) q0(i) = r.lower(i) + u(rng) * (r.upper(i) - r.lower(i));
    Attempt a = dls_attempt(kin, target, q0, start, config);
    iterations += a.iterations;
    if (cost(TaskError{{}, a.pos, a.ang}) < cost(TaskError{{}, best.pos, best.ang})) best = a;
  }
  out.q = best.q;
  out.position_error_m = best.pos;
  out.angle_error_rad = best.ang;
  out.iterations = iterations;
  out.restarts = restarts;
  out.success = within_tol(best, config) && robot.within_limits(best.q);
  if (!out.success) out.reason = failure_reason(robot, pose, best);
  return out;
}

IkResult solve_ik_kdl_nr_jl(const Robot& robot, const Eigen::Isometry3d& target, const Eigen::VectorXd& seed,
                            const RobotConfig& config, int max_iterations) {
  check_q(robot, seed, "IK seed");
  const auto& r = robot.impl();
  KDL::ChainFkSolverPos_recursive fk(r.chain);
  KDL::ChainIkSolverVel_pinv vel(r.chain);
  KDL::JntArray qmin = to_kdl(r.lower), qmax = to_kdl(r.upper);
  KDL::ChainIkSolverPos_NR_JL ik(r.chain, qmin, qmax, fk, vel, static_cast<unsigned>(max_iterations), 1e-6);
  KDL::JntArray q_out(r.chain.getNrOfJoints());
  const KDL::Frame goal = to_kdl(r.base.inverse() * target);
  const int rc = ik.CartToJnt(to_kdl(seed.cwiseMax(r.lower).cwiseMin(r.upper)), goal, q_out);
  IkResult out;
  out.q = q_out.data;
  const Eigen::Isometry3d got = robot.fk(out.q);
  out.position_error_m = (got.translation() - target.translation()).norm();
  out.angle_error_rad = axis_angle(got.linear().col(2), target.linear().col(2));
  out.iterations = max_iterations;
  out.success = rc >= 0 && out.position_error_m <= config.ik_position_tolerance_m &&
                out.angle_error_rad <= config.ik_angle_tolerance_rad && robot.within_limits(out.q);
  if (!out.success) out.reason = std::string("KDL NR_JL: ") + ik.strError(rc);
  return out;
}

namespace {

// One pass tracked from the first waypoint's solution nearest to `seed`.
JointPath solve_path_once(const Robot& robot, const std::vector<NozzlePose>& waypoints, const Eigen::VectorXd& seed,
                          const RobotConfig& config) {
  JointPath path;
  if (waypoints.empty()) return path;
  RobotConfig local = config;
  local.ik_max_restarts = 0;  // continuation: stay in the current branch
  auto fail = [&](size_t k, const std::string& why) {
    throw std::runtime_error("IK: waypoint " + std::to_string(k) + " of " + std::to_string(waypoints.size()) + " (" +
                             describe_pose(waypoints[k]) + ") unreachable: " + why);
  };
  Eigen::VectorXd q_prev = seed;
  for (size_t k = 0; k < waypoints.size(); ++k) {
    const NozzlePose& wp = waypoints[k];
    IkResult res;
    if (k == 0) {
      res = first_waypoint(robot, wp, q_prev, config);  // the first waypoint may use restarts
      if (!res.success) fail(k, res.reason);
    } else {
      res = solve_ik_5dof(robot, wp, q_prev, local);
      if (!res.success) {
        // Is the pose reachable at all? If not, say why (out of reach / limits) right away.
        const IkResult any = solve_ik_5dof(robot, wp, q_prev, config);
        if (!any.success) fail(k, any.reason);
      }
      if (!res.success || joint_step(res.q, q_prev) > config.ik_max_joint_step) {
        const Walk walk = walk_to(robot, waypoints[k - 1], wp, q_prev, config, res.success ? "" : res.reason);
        if (!walk.ok) fail(k, "reachable only through a configuration flip (" + walk.why + ")");
        res = walk.last;
        path.inserted_substeps += walk.substeps;
      }
      path.max_joint_step = std::max(path.max_joint_step, joint_step(res.q, q_prev));
    }
    path.q.push_back(res.q);
    path.position_error_m.push_back(res.position_error_m);
    path.angle_error_rad.push_back(res.angle_error_rad);
    path.max_position_error_m = std::max(path.max_position_error_m, res.position_error_m);
    path.max_angle_error_rad = std::max(path.max_angle_error_rad, res.angle_error_rad);
    q_prev = res.q;
  }
  return path;
}

}  // namespace

JointPath solve_path(const Robot& robot, const std::vector<NozzlePose>& waypoints, const Eigen::VectorXd& seed,
                     const RobotConfig& config) {
  check_q(robot, seed, "path seed");
  for (const auto& wp : waypoints) to_base(robot.impl(), wp);  // validates every pose up front
  // A branch chosen at the first waypoint can run into a limit later in the pass; then the pass is
  // tracked again from other start configurations (neutral, then seeded random ones) and the
  // smoothest complete path wins. The first error is reported if none completes.
  std::mt19937 rng(0x9a7bu);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const int tries = 2 + std::min(config.ik_max_restarts, 6);
  std::string first_error;
  JointPath best;
  bool have = false;
  for (int t = 0; t < tries; ++t) {
    Eigen::VectorXd start = seed;
    if (t == 1) start = robot.neutral();
    if (t >= 2)
      for (int i = 0; i < robot.dof(); ++i)
        start(i) = robot.lower_limits()(i) + u(rng) * (robot.upper_limits()(i) - robot.lower_limits()(i));
    try {
      JointPath p = solve_path_once(robot, waypoints, start, config);
      if (!have || p.inserted_substeps < best.inserted_substeps ||
          (p.inserted_substeps == best.inserted_substeps && p.max_joint_step < best.max_joint_step)) {
        best = std::move(p);
        have = true;
      }
      if (best.inserted_substeps == 0) break;  // smooth without interpolated poses: good enough
    } catch (const std::runtime_error& e) {
      if (first_error.empty()) first_error = e.what();
      // The first waypoint itself unreachable or out of reach: no start configuration helps.
      if (!have && (std::string(e.what()).find("waypoint 0 ") != std::string::npos ||
                    std::string(e.what()).find("out of reach: the target is") != std::string::npos))
        break;
    }
  }
  if (!have) throw std::runtime_error(first_error);
  return best;
}

}  // namespace shotcrete
