#include "shotcrete/robot/robot.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <random>
#include <regex>
#include <sstream>
#include <stdexcept>

#include <kdl/chain.hpp>
#include <kdl/chainfksolverpos_recursive.hpp>
#include <kdl/chainiksolverpos_nr_jl.hpp>
#include <kdl/chainiksolvervel_pinv.hpp>
#include <kdl/chainjnttojacsolver.hpp>
#include <kdl/tree.hpp>
#include <kdl_parser/kdl_parser.hpp>
#include <urdf/model.h>

namespace shotcrete {

struct Robot::Impl {
  KDL::Chain chain;
  std::vector<std::string> names;
  std::vector<bool> prismatic;
  Eigen::VectorXd lower, upper, velocity, acceleration, neutral;
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
  std::string path;
  Eigen::Vector3d shoulder_in_base{0, 0, 0};
  double max_reach_m = 0.0;
};

namespace {

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("cannot open URDF file '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string fmt_vec(const Eigen::Vector3d& v, int precision = 3) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(precision);
  os << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return os.str();
}

// Acceleration limits live in <shotcrete:limits joint=".." acceleration=".."/> elements, which URDF
// parsers ignore; a regex over the flat, attribute-only element is all that is needed.
struct ExtraLimits {
  double acceleration = 0.0;
  double neutral = NAN;  // optional ready posture; NaN = mid-range
};

double parse_number(const std::string& joint, const char* what, const std::string& text) {
  try {
    size_t used = 0;
    const double v = std::stod(text, &used);
    if (used != text.size() || !std::isfinite(v)) throw std::invalid_argument("bad");
    return v;
  } catch (const std::exception&) {
    throw std::invalid_argument("URDF: " + std::string(what) + " of joint '" + joint + "' is not a number: '" + text + "'");
  }
}

std::map<std::string, ExtraLimits> parse_extra_limits(const std::string& text) {
  std::map<std::string, ExtraLimits> out;
  static const std::regex comment(R"(<!--[\s\S]*?-->)");
  const std::string xml = std::regex_replace(text, comment, "");
  static const std::regex elem(R"(<shotcrete:limits\b([^>]*)/?>)");
  static const std::regex attr(R"re((\w+)\s*=\s*"([^"]*)")re");
  for (auto it = std::sregex_iterator(xml.begin(), xml.end(), elem); it != std::sregex_iterator(); ++it) {
    const std::string body = (*it)[1].str();
    std::string joint, acc, neutral;
    for (auto a = std::sregex_iterator(body.begin(), body.end(), attr); a != std::sregex_iterator(); ++a) {
      if ((*a)[1] == "joint") joint = (*a)[2];
      if ((*a)[1] == "acceleration") acc = (*a)[2];
      if ((*a)[1] == "neutral") neutral = (*a)[2];
    }
    if (joint.empty() || acc.empty())
      throw std::invalid_argument("URDF: <shotcrete:limits> needs joint=\"..\" and acceleration=\"..\"");
    ExtraLimits e;
    e.acceleration = parse_number(joint, "acceleration limit", acc);
    if (!(e.acceleration > 0.0)) throw std::invalid_argument("URDF: acceleration limit of joint '" + joint + "' must be > 0");
    if (!neutral.empty()) e.neutral = parse_number(joint, "neutral position", neutral);
    out[joint] = e;
  }
  return out;
}

KDL::JntArray to_kdl(const Eigen::VectorXd& q) {
  KDL::JntArray a(static_cast<unsigned>(q.size()));
  a.data = q;
  return a;
}

Eigen::Isometry3d to_eigen(const KDL::Frame& f) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) t.linear()(r, c) = f.M(r, c);
    t.translation()(r) = f.p(r);
  }
  return t;
}

KDL::Frame to_kdl(const Eigen::Isometry3d& t) {
  KDL::Frame f;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) f.M(r, c) = t.linear()(r, c);
    f.p(r) = t.translation()(r);
  }
  return f;
}

void check_q(const Robot& robot, const Eigen::VectorXd& q, const char* what) {
  if (q.size() != robot.dof())
    throw std::invalid_argument(std::string(what) + " has " + std::to_string(q.size()) + " entries, the robot has " +
                                std::to_string(robot.dof()) + " joints");
  if (!q.allFinite()) throw std::invalid_argument(std::string(what) + " contains NaN or inf");
}

double axis_angle(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

// Per-call KDL solver state (KDL solvers are not thread-safe; construction is cheap).
struct Kin {
  const Robot::Impl& r;
  KDL::ChainFkSolverPos_recursive fk;
  KDL::ChainJntToJacSolver jac;
  KDL::JntArray qk;
  KDL::Frame frame;
  KDL::Jacobian J;
  explicit Kin(const Robot::Impl& impl)
      : r(impl), fk(impl.chain), jac(impl.chain), qk(impl.chain.getNrOfJoints()), J(impl.chain.getNrOfJoints()) {}
  // Pose of nozzle_tip in the base frame.
  void pose(const Eigen::VectorXd& q, Eigen::Vector3d& p, Eigen::Matrix3d& R) {
    qk.data = q;
    fk.JntToCart(qk, frame);
    for (int i = 0; i < 3; ++i) {
      p(i) = frame.p(i);
      for (int j = 0; j < 3; ++j) R(i, j) = frame.M(i, j);
    }
  }
  const Eigen::Matrix<double, 6, Eigen::Dynamic>& jacobian(const Eigen::VectorXd& q) {
    qk.data = q;
    jac.JntToJac(qk, J);
    return J.data;
  }
};

struct Target {
  Eigen::Vector3d p;  // base frame
  Eigen::Vector3d z;  // unit, base frame
};

// Task error: position (3) and the spray-axis rotation vector expressed on the tool x/y axes (2).
struct TaskError {
  Eigen::Matrix<double, 5, 1> e;
  double pos = 0.0, ang = 0.0;
};

TaskError task_error(const Eigen::Vector3d& p, const Eigen::Matrix3d& R, const Target& t) {
  TaskError out;
  const Eigen::Vector3d z = R.col(2);
  out.e.head<3>() = t.p - p;
  out.pos = out.e.head<3>().norm();
  Eigen::Vector3d c = z.cross(t.z);
  const double s = c.norm();
  out.ang = std::atan2(s, z.dot(t.z));
  Eigen::Vector3d w;
  if (s > 1e-12) {
    w = c / s * out.ang;
  } else if (z.dot(t.z) < 0) {
    w = R.col(0) * out.ang;  // antiparallel: any perpendicular turns it round
  } else {
    w.setZero();
  }
  out.e(3) = R.col(0).dot(w);
  out.e(4) = R.col(1).dot(w);
  return out;
}

constexpr double kAngleWeight = 1.0;  // metres per radian in the damped least-squares cost
constexpr double kLimitGain = 0.02;   // null-space step towards mid-range per iteration
constexpr double kAnchorGain = 0.05;  // null-space pull towards the seed (minimal motion)
constexpr double kNullClip = 0.02;    // largest null-space step per joint and iteration (continuity)

double cost(const TaskError& te) { return te.pos * te.pos + kAngleWeight * kAngleWeight * te.ang * te.ang; }

struct Attempt {
  Eigen::VectorXd q;
  double pos = 1e9, ang = 1e9;
  int iterations = 0;
};

// One damped least-squares descent (Levenberg-Marquardt damping) from q0 with clamping to the
// limits, an active set of joints pressed against a limit, and a null-space pull towards
// mid-range and towards `anchor` (minimal motion).
// posture_iterations > 0 keeps iterating after convergence, moving only in the null space while
// the task stays within the goal (settles the configuration away from limits).
Attempt dls_attempt(Kin& kin, const Target& target, const Eigen::VectorXd& q0, const Eigen::VectorXd& anchor,
                    const RobotConfig& config, int posture_iterations = 0) {
  const auto& r = kin.r;
  const int n = static_cast<int>(q0.size());
  const Eigen::VectorXd range = (r.upper - r.lower).cwiseMax(1e-9);
  const double pos_goal = 0.1 * config.ik_position_tolerance_m;
  const double ang_goal = 0.1 * config.ik_angle_tolerance_rad;

  Attempt a;
  a.q = q0.cwiseMax(r.lower).cwiseMin(r.upper);
  Eigen::Vector3d p;
  Eigen::Matrix3d R;
  kin.pose(a.q, p, R);
  TaskError te = task_error(p, R, target);
  double lambda = 1e-3;
  Eigen::Matrix<double, 5, Eigen::Dynamic> A(5, n);
  int settled = 0;
  for (int it = 0; it < config.ik_max_iterations + posture_iterations; ++it) {
    a.iterations = it + 1;
    const bool converged = te.pos < pos_goal && te.ang < ang_goal;
    if (converged && settled++ >= posture_iterations) break;
    const auto& J = kin.jacobian(a.q);
    A.topRows<3>() = J.topRows<3>();
    A.row(3) = kAngleWeight * R.col(0).transpose() * J.bottomRows<3>();
    A.row(4) = kAngleWeight * R.col(1).transpose() * J.bottomRows<3>();
    Eigen::Matrix<double, 5, 1> e = te.e;
    e.tail<2>() *= kAngleWeight;

    // Secondary objective gradient (descent direction): away from limits, towards the anchor.
    // Limit term: descent of H = sum 1 / (4 s (1 - s)), s = normalised joint position, which is
    // flat mid-range and grows without bound at a limit (clipped per joint).
    Eigen::VectorXd g(n);
    for (int i = 0; i < n; ++i) {
      const double s = std::clamp((a.q(i) - r.lower(i)) / range(i), 1e-3, 1.0 - 1e-3);
      const double dH = (1.0 - 2.0 * s) / (4.0 * s * s * (1.0 - s) * (1.0 - s)) / range(i);
      g(i) = std::clamp(kLimitGain * dH, -kNullClip, kNullClip) - kAnchorGain * (a.q(i) - anchor(i));
    }

    bool improved = false;
    for (int tries = 0; tries < 6 && !improved; ++tries) {
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
          if ((a.q(i) + dq(i) > r.upper(i) && a.q(i) >= r.upper(i) - 1e-9) ||
              (a.q(i) + dq(i) < r.lower(i) && a.q(i) <= r.lower(i) + 1e-9)) {
            active(i) = 0;
            changed = true;
          }
        }
        if (!changed) break;
      }
      // Trust region: no joint moves more than 0.4 rad / 0.4 m per iteration.
      const double big = dq.cwiseAbs().maxCoeff();
      if (big > 0.4) dq *= 0.4 / big;
      Eigen::VectorXd qn = (a.q + dq).cwiseMax(r.lower).cwiseMin(r.upper);
      Eigen::Vector3d pn;
      Eigen::Matrix3d Rn;
      kin.pose(qn, pn, Rn);
      TaskError ten = task_error(pn, Rn, target);
      // While settling the posture, a null-space step may cost a little task accuracy (second
      // order); the following iterations restore it.
      const bool posture_ok = converged && ten.pos < 0.5 * config.ik_position_tolerance_m &&
                              ten.ang < 0.5 * config.ik_angle_tolerance_rad;
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
  a.pos = te.pos;
  a.ang = te.ang;
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

}  // namespace

// ---------------------------------------------------------------------------------------------
// Robot

std::string bundled_urdf_path() { return std::string(SHOTCRETE_SOURCE_DIR) + "/data/shotcrete_manipulator.urdf"; }

Robot::Robot() : impl_(std::make_unique<Impl>()) {}
Robot::Robot(const Robot& o) : impl_(std::make_unique<Impl>(*o.impl_)) {}
Robot& Robot::operator=(const Robot& o) {
  if (this != &o) impl_ = std::make_unique<Impl>(*o.impl_);
  return *this;
}
Robot::Robot(Robot&&) noexcept = default;
Robot& Robot::operator=(Robot&&) noexcept = default;
Robot::~Robot() = default;

Robot Robot::load(const RobotConfig& config) {
  return load_file(config.urdf_path.empty() ? bundled_urdf_path() : config.urdf_path, config.base_position_m);
}

Robot Robot::load_file(const std::string& urdf_path, const Eigen::Vector3d& base_position_m) {
  Robot r = from_string(read_text(urdf_path), base_position_m);
  r.impl_->path = urdf_path;
  return r;
}

Robot Robot::from_string(const std::string& xml, const Eigen::Vector3d& base_position_m) {
  if (!base_position_m.allFinite()) throw std::invalid_argument("robot.base_position_m contains NaN or inf");
  urdf::Model model;
  if (!model.initString(xml)) throw std::invalid_argument("URDF: cannot parse the robot description");
  KDL::Tree tree;
  if (!kdl_parser::treeFromUrdfModel(model, tree)) throw std::invalid_argument("URDF: kdl_parser cannot build a tree");
  Robot robot;
  Impl& im = *robot.impl_;
  if (!tree.getChain("base_link", "nozzle_tip", im.chain))
    throw std::invalid_argument("URDF: no kinematic chain from base_link to nozzle_tip");
  const auto acc = parse_extra_limits(xml);
  const int n = static_cast<int>(im.chain.getNrOfJoints());
  if (n < 5) throw std::invalid_argument("URDF: the chain has " + std::to_string(n) + " joints; a 5-DOF task needs >= 5");
  im.lower.resize(n);
  im.upper.resize(n);
  im.velocity.resize(n);
  im.acceleration.resize(n);
  im.neutral.resize(n);
  int j = 0;
  bool past_first = false;
  for (const auto& seg : im.chain.segments) {
    const KDL::Joint& kj = seg.getJoint();
    if (kj.getType() == KDL::Joint::None) {
      if (past_first) im.max_reach_m += seg.getFrameToTip().p.Norm();
      continue;
    }
    const std::string name = kj.getName();
    const auto uj = model.getJoint(name);
    if (!uj || !uj->limits || uj->type == urdf::Joint::CONTINUOUS)
      throw std::invalid_argument("URDF: joint '" + name + "' needs <limit lower upper velocity> (no continuous joints)");
    const auto it = acc.find(name);
    if (it == acc.end())
      throw std::invalid_argument("URDF: joint '" + name + "' has no <shotcrete:limits acceleration=..> element");
    if (!(uj->limits->upper > uj->limits->lower))
      throw std::invalid_argument("URDF: joint '" + name + "' has upper limit <= lower limit");
    if (!(uj->limits->velocity > 0)) throw std::invalid_argument("URDF: joint '" + name + "' needs a velocity limit > 0");
    im.names.push_back(name);
    im.prismatic.push_back(uj->type == urdf::Joint::PRISMATIC);
    im.lower(j) = uj->limits->lower;
    im.upper(j) = uj->limits->upper;
    im.velocity(j) = uj->limits->velocity;
    im.acceleration(j) = it->second.acceleration;
    im.neutral(j) = std::isnan(it->second.neutral) ? 0.5 * (im.lower(j) + im.upper(j)) : it->second.neutral;
    if (im.neutral(j) < im.lower(j) || im.neutral(j) > im.upper(j))
      throw std::invalid_argument("URDF: neutral position of joint '" + name + "' is outside its limits");
    // Reach bound measured from the first joint's origin: every later offset plus full strokes.
    // Each segment's tip is the next joint origin, so the offsets after the first joint bound
    // the distance from that joint's origin (triangle inequality).
    if (past_first) im.max_reach_m += seg.getFrameToTip().p.Norm();
    past_first = true;
    if (im.prismatic.back()) im.max_reach_m += std::max(std::abs(im.lower(j)), std::abs(im.upper(j)));
    ++j;
  }
  // First joint origin in base_link: the tip frame of its segment at q = 0 (joint origins coincide
  // with segment tips in kdl_parser's trees, up to the joint's own motion).
  {
    KDL::Frame f = KDL::Frame::Identity();
    for (const auto& seg : im.chain.segments) {
      f = f * seg.pose(0.0);
      if (seg.getJoint().getType() != KDL::Joint::None) break;
    }
    im.shoulder_in_base = Eigen::Vector3d(f.p.x(), f.p.y(), f.p.z());
  }
  for (const auto& [name, value] : acc) {
    (void)value;
    if (std::find(im.names.begin(), im.names.end(), name) == im.names.end())
      throw std::invalid_argument("URDF: <shotcrete:limits> names unknown joint '" + name + "'");
  }
  im.base = Eigen::Isometry3d::Identity();
  im.base.translation() = base_position_m;
  return robot;
}

int Robot::dof() const { return static_cast<int>(impl_->names.size()); }
const std::vector<std::string>& Robot::joint_names() const { return impl_->names; }
const std::vector<bool>& Robot::joint_is_prismatic() const { return impl_->prismatic; }
const Eigen::VectorXd& Robot::lower_limits() const { return impl_->lower; }
const Eigen::VectorXd& Robot::upper_limits() const { return impl_->upper; }
const Eigen::VectorXd& Robot::velocity_limits() const { return impl_->velocity; }
const Eigen::VectorXd& Robot::acceleration_limits() const { return impl_->acceleration; }
const Eigen::Isometry3d& Robot::base_pose() const { return impl_->base; }
const std::string& Robot::urdf_path() const { return impl_->path; }
Eigen::Vector3d Robot::shoulder_position() const { return impl_->base * impl_->shoulder_in_base; }
double Robot::max_reach_m() const { return impl_->max_reach_m; }

Eigen::Isometry3d Robot::fk(const Eigen::VectorXd& q) const {
  check_q(*this, q, "q");
  KDL::ChainFkSolverPos_recursive solver(impl_->chain);
  KDL::Frame f;
  if (solver.JntToCart(to_kdl(q), f) < 0) throw std::runtime_error("KDL forward kinematics failed");
  return impl_->base * to_eigen(f);
}

Eigen::MatrixXd Robot::jacobian(const Eigen::VectorXd& q) const {
  check_q(*this, q, "q");
  Kin kin(*impl_);
  Eigen::MatrixXd J = kin.jacobian(q);
  // Base is a pure translation here, but rotate anyway in case the frame ever gains a rotation.
  J.topRows(3) = impl_->base.linear() * J.topRows(3);
  J.bottomRows(3) = impl_->base.linear() * J.bottomRows(3);
  return J;
}

Eigen::VectorXd Robot::neutral() const { return impl_->neutral; }

bool Robot::within_limits(const Eigen::VectorXd& q, double slack) const {
  if (q.size() != dof() || !q.allFinite()) return false;
  return ((q - impl_->lower).array() >= -slack).all() && ((impl_->upper - q).array() >= -slack).all();
}

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
      res = solve_ik_5dof(robot, wp, q_prev, config);  // the first waypoint may use restarts
      if (!res.success) fail(k, res.reason);
      // Settle the start posture away from the limits so the pass does not run into one.
      Kin kin(robot.impl());
      const Attempt settled = dls_attempt(kin, to_base(robot.impl(), wp), res.q, res.q, config, 60);
      if (within_tol(settled, config) && robot.within_limits(settled.q)) {
        res.q = settled.q;
        res.position_error_m = settled.pos;
        res.angle_error_rad = settled.ang;
      }
    } else {
      res = solve_ik_5dof(robot, wp, q_prev, local);
      int which = 0;
      if (!res.success) {
        // Is the pose reachable at all? If not, say why (out of reach / limits) right away.
        const IkResult any = solve_ik_5dof(robot, wp, q_prev, config);
        if (!any.success) fail(k, any.reason);
      }
      if (!res.success || joint_step(res.q, q_prev, &which) > config.ik_max_joint_step) {
        // Walk there through interpolated poses from the previous waypoint (continuation).
        const NozzlePose& from = waypoints[k - 1];
        bool ok = false;
        std::string why = res.success ? "" : res.reason;
        for (int n : {4, 16, 64}) {
          Eigen::VectorXd q = q_prev;
          bool good = true;
          const Eigen::Vector3d a0 = from.axis.normalized(), a1 = wp.axis.normalized();
          for (int s = 1; s <= n && good; ++s) {
            const double t = static_cast<double>(s) / n;
            NozzlePose mid;
            mid.position_m = (1 - t) * from.position_m + t * wp.position_m;
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
              res = sub;
            }
          }
          if (good) {
            ok = true;
            path.inserted_substeps += n - 1;
            break;
          }
        }
        if (!ok) {
          why = "reachable only through a configuration flip (" + why + ")";
          if (why.empty())
            why = "joint " + robot.joint_names()[which] + " would jump " + std::to_string(joint_step(res.q, q_prev)) +
                  " (rad or m) > ik_max_joint_step";
          fail(k, why);
        }
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

// ---------------------------------------------------------------------------------------------
// Reachability and benchmark

ReachMap reachability_map(const Robot& robot, const RobotConfig& config, double radius_m, double standoff_m,
                          double bay_length_m, int n_theta, int n_d) {
  if (!(radius_m > 0) || !(standoff_m >= 0) || !(standoff_m < radius_m))
    throw std::invalid_argument("reachability_map: need radius_m > standoff_m >= 0");
  if (!(bay_length_m >= 0) || n_theta < 2 || n_d < 1)
    throw std::invalid_argument("reachability_map: need bay_length_m >= 0, n_theta >= 2, n_d >= 1");
  ReachMap m;
  m.radius_m = radius_m;
  m.standoff_m = standoff_m;
  for (int i = 0; i < n_theta; ++i) m.theta_rad.push_back(M_PI * i / (n_theta - 1));
  for (int j = 0; j < n_d; ++j) m.d_m.push_back(n_d == 1 ? 0.0 : bay_length_m * j / (n_d - 1));
  const size_t cells = static_cast<size_t>(n_theta) * n_d;
  m.reached.assign(cells, 0);
  m.position_error_m.assign(cells, NAN);
  m.angle_error_rad.assign(cells, NAN);
  m.min_limit_margin.assign(cells, NAN);
  const auto& lo = robot.lower_limits();
  const auto& hi = robot.upper_limits();
  Eigen::VectorXd q_row = robot.neutral();
  for (int i = 0; i < n_theta; ++i) {
    Eigen::VectorXd q = q_row;
    for (int j = 0; j < n_d; ++j) {
      const double th = m.theta_rad[i];
      const Eigen::Vector3d normal(0.0, std::cos(th), std::sin(th));  // outward wall normal
      NozzlePose pose;
      pose.position_m = Eigen::Vector3d(m.d_m[j], 0, 0) + (radius_m - standoff_m) * normal;
      pose.axis = normal;
      IkResult r = solve_ik_5dof(robot, pose, q, config);
      if (!r.success) r = solve_ik_5dof(robot, pose, robot.neutral(), config);
      const size_t c = static_cast<size_t>(i) * n_d + j;
      m.position_error_m[c] = r.position_error_m;
      m.angle_error_rad[c] = r.angle_error_rad;
      m.min_limit_margin[c] = ((r.q - lo).cwiseMin(hi - r.q)).cwiseQuotient(hi - lo).minCoeff();
      if (r.success) {
        m.reached[c] = 1;
        ++m.n_reached;
        q = r.q;
        if (j == 0) q_row = r.q;
      }
      ++m.n_total;
    }
  }
  return m;
}

IkBenchmark ik_benchmark(const Robot& robot, const RobotConfig& config, int samples, unsigned seed) {
  if (samples < 1) throw std::invalid_argument("ik_benchmark: samples must be >= 1");
  IkBenchmark b;
  b.samples = samples;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const auto& lo = robot.lower_limits();
  const auto& hi = robot.upper_limits();
  auto random_q = [&] {
    Eigen::VectorXd q(robot.dof());
    for (int i = 0; i < robot.dof(); ++i) q(i) = lo(i) + u(rng) * (hi(i) - lo(i));
    return q;
  };
  RobotConfig no_restart = config;
  no_restart.ik_max_restarts = 0;
  using clock = std::chrono::steady_clock;
  auto seconds = [](clock::time_point a, clock::time_point b) { return std::chrono::duration<double>(b - a).count(); };
  auto check = [&](const IkResult& r, const NozzlePose& pose) {
    if (!r.success) return;
    const Eigen::Isometry3d f = robot.fk(r.q);
    const double pe = (f.translation() - pose.position_m).norm();
    const double ae = axis_angle(f.linear().col(2), pose.axis);
    if (!robot.within_limits(r.q)) ++b.limit_violations;
    if (pe > config.ik_position_tolerance_m || ae > config.ik_angle_tolerance_rad) ++b.tolerance_misses;
    b.max_position_error_m = std::max(b.max_position_error_m, pe);
    b.max_angle_error_rad = std::max(b.max_angle_error_rad, ae);
  };
  const Eigen::VectorXd neutral = robot.neutral();
  for (int s = 0; s < samples; ++s) {
    const Eigen::VectorXd q_true = random_q();
    const Eigen::VectorXd q_seed = random_q();
    const Eigen::Isometry3d goal = robot.fk(q_true);
    NozzlePose pose;
    pose.position_m = goal.translation();
    pose.axis = goal.linear().col(2);

    auto t0 = clock::now();
    IkResult r1 = solve_ik_5dof(robot, pose, neutral, config);
    auto t1 = clock::now();
    IkResult r2 = solve_ik_5dof(robot, pose, q_seed, config);
    auto t2 = clock::now();
    IkResult r3 = solve_ik_kdl_nr_jl(robot, goal, neutral, config);
    auto t3 = clock::now();
    IkResult r4 = solve_ik_5dof(robot, pose, neutral, no_restart);
    auto t4 = clock::now();
    b.time_5dof_neutral_s.push_back(seconds(t0, t1));
    b.time_5dof_random_seed_s.push_back(seconds(t1, t2));
    b.time_kdl_6dof_s.push_back(seconds(t2, t3));
    b.time_5dof_no_restart_s.push_back(seconds(t3, t4));
    b.solved_5dof_neutral += r1.success;
    b.solved_5dof_random_seed += r2.success;
    b.solved_kdl_6dof += r3.success;
    b.solved_5dof_no_restart += r4.success;
    check(r1, pose);
    check(r2, pose);
    check(r4, pose);
  }
  return b;
}

}  // namespace shotcrete
