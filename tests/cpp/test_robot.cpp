// Robot model and IK: FK against an independent FK built from the URDF text, IK on random
// reachable poses, continuous paths, clear errors, reachability of the design tunnels.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <random>
#include <regex>
#include <sstream>

#include "shotcrete/robot/robot.hpp"

using namespace shotcrete;

namespace {

const std::string kUrdf = std::string(SHOTCRETE_DATA_DIR) + "/shotcrete_manipulator.urdf";

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

Eigen::Vector3d parse3(const std::string& s) {
  std::istringstream is(s);
  Eigen::Vector3d v;
  is >> v.x() >> v.y() >> v.z();
  return v;
}

std::string attr(const std::string& body, const std::string& name) {
  std::smatch m;
  if (std::regex_search(body, m, std::regex("\\b" + name + "\\s*=\\s*\"([^\"]*)\""))) return m[1];
  return "";
}

// Independent FK: the URDF's joints read with regexes, composed with Eigen (no KDL, no urdfdom).
struct RefJoint {
  std::string name, type, parent, child;
  Eigen::Isometry3d origin = Eigen::Isometry3d::Identity();
  Eigen::Vector3d axis{1, 0, 0};
  double lower = 0, upper = 0;
};

std::vector<RefJoint> reference_chain(const std::string& text) {
  std::vector<RefJoint> all;
  const std::string xml = std::regex_replace(text, std::regex(R"(<!--[\s\S]*?-->)"), "");
  const std::regex jre(R"(<joint\s+([^>]*)>([\s\S]*?)</joint>)");
  for (auto it = std::sregex_iterator(xml.begin(), xml.end(), jre); it != std::sregex_iterator(); ++it) {
    RefJoint j;
    const std::string head = (*it)[1], body = (*it)[2];
    j.name = attr(head, "name");
    j.type = attr(head, "type");
    std::smatch m;
    std::regex_search(body, m, std::regex(R"re(<parent\s+link="([^"]*)")re"));
    j.parent = m[1];
    std::regex_search(body, m, std::regex(R"re(<child\s+link="([^"]*)")re"));
    j.child = m[1];
    if (std::regex_search(body, m, std::regex(R"re(<origin\s+([^>]*)/>)re"))) {
      const std::string o = m[1];
      const Eigen::Vector3d xyz = parse3(attr(o, "xyz"));
      const std::string rpy_s = attr(o, "rpy");
      const Eigen::Vector3d rpy = rpy_s.empty() ? Eigen::Vector3d::Zero() : parse3(rpy_s);
      j.origin.translation() = xyz;
      // URDF rpy: R = Rz(yaw) Ry(pitch) Rx(roll).
      j.origin.linear() = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                           Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                           Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                              .toRotationMatrix();
    }
    if (std::regex_search(body, m, std::regex(R"re(<axis\s+xyz="([^"]*)")re"))) j.axis = parse3(m[1]).normalized();
    if (std::regex_search(body, m, std::regex(R"re(<limit\s+([^>]*)/>)re"))) {
      j.lower = std::stod(attr(m[1], "lower"));
      j.upper = std::stod(attr(m[1], "upper"));
    }
    all.push_back(j);
  }
  // Walk from nozzle_tip back to base_link.
  std::vector<RefJoint> chain;
  std::string link = "nozzle_tip";
  while (link != "base_link") {
    auto it = std::find_if(all.begin(), all.end(), [&](const RefJoint& j) { return j.child == link; });
    if (it == all.end()) throw std::runtime_error("no joint with child " + link);
    chain.insert(chain.begin(), *it);
    link = it->parent;
  }
  return chain;
}

Eigen::Isometry3d reference_fk(const std::vector<RefJoint>& chain, const Eigen::VectorXd& q, const Eigen::Vector3d& base) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.translation() = base;
  int k = 0;
  for (const auto& j : chain) {
    t = t * j.origin;
    if (j.type == "revolute") {
      t.rotate(Eigen::AngleAxisd(q(k++), j.axis));
    } else if (j.type == "prismatic") {
      t.translate(j.axis * q(k++));
    }
  }
  return t;
}

RobotConfig cfg() { return RobotConfig{}; }

Eigen::VectorXd random_q(const Robot& r, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  Eigen::VectorXd q(r.dof());
  for (int i = 0; i < r.dof(); ++i) q(i) = r.lower_limits()(i) + u(rng) * (r.upper_limits()(i) - r.lower_limits()(i));
  return q;
}

double angle(const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return std::atan2(a.cross(b).norm(), a.dot(b)); }

NozzlePose pose_of(const Eigen::Isometry3d& f) {
  NozzlePose p;
  p.position_m = f.translation();
  p.axis = f.linear().col(2);
  return p;
}

}  // namespace

TEST(Robot, LoadsBundledUrdfWithLimits) {
  const Robot r = Robot::load(cfg());
  ASSERT_EQ(r.dof(), 8);
  const std::vector<std::string> expected = {"slew",     "boom_lift",     "boom_telescope", "boom_roll",
                                             "arm_lift", "arm_telescope", "nozzle_rotate",  "nozzle_tilt"};
  EXPECT_EQ(r.joint_names(), expected);
  int prismatic = 0;
  for (bool p : r.joint_is_prismatic()) prismatic += p;
  EXPECT_EQ(prismatic, 2);
  const auto chain = reference_chain(slurp(kUrdf));
  int k = 0;
  for (const auto& j : chain) {
    if (j.type == "fixed") continue;
    EXPECT_DOUBLE_EQ(r.lower_limits()(k), j.lower) << j.name;
    EXPECT_DOUBLE_EQ(r.upper_limits()(k), j.upper) << j.name;
    ++k;
  }
  EXPECT_TRUE((r.velocity_limits().array() > 0).all());
  EXPECT_TRUE((r.acceleration_limits().array() > 0).all());
  EXPECT_EQ(r.urdf_path(), bundled_urdf_path());
  EXPECT_TRUE(r.within_limits(r.neutral()));
}

TEST(Robot, ForwardKinematicsMatchesIndependentUrdfFk) {
  RobotConfig c = cfg();
  c.base_position_m = Eigen::Vector3d(0.6, 0.1, -1.3);
  const Robot r = Robot::load(c);
  const auto chain = reference_chain(slurp(kUrdf));
  std::mt19937 rng(3);
  for (int s = 0; s < 200; ++s) {
    const Eigen::VectorXd q = random_q(r, rng);
    const Eigen::Isometry3d a = r.fk(q);
    const Eigen::Isometry3d b = reference_fk(chain, q, c.base_position_m);
    EXPECT_LT((a.translation() - b.translation()).norm(), 1e-9);
    EXPECT_LT((a.linear() - b.linear()).norm(), 1e-9);
  }
  // At q = 0 every link points along +x: the tip is straight ahead at the summed offsets, spraying +x.
  const Eigen::Isometry3d zero = r.fk(Eigen::VectorXd::Zero(8));
  EXPECT_NEAR(zero.linear().col(2).x(), 1.0, 1e-12);
}

TEST(Robot, JacobianMatchesFiniteDifferences) {
  RobotConfig c = cfg();
  c.base_position_m = Eigen::Vector3d(0.6, 0.1, -1.3);
  const Robot r = Robot::load(c);
  std::mt19937 rng(5);
  for (int s = 0; s < 20; ++s) {
    const Eigen::VectorXd q = random_q(r, rng);
    const Eigen::MatrixXd J = r.jacobian(q);
    const Eigen::Matrix3d R = r.fk(q).linear();
    const double h = 1e-6;
    for (int i = 0; i < r.dof(); ++i) {
      Eigen::VectorXd qp = q, qm = q;
      qp(i) += h;
      qm(i) -= h;
      const Eigen::Vector3d dp = (r.fk(qp).translation() - r.fk(qm).translation()) / (2 * h);
      EXPECT_LT((dp - J.col(i).head<3>()).norm(), 1e-6) << r.joint_names()[i];
      // Angular rows: dR/dq R^T is the skew matrix of the joint's angular velocity per unit rate.
      const Eigen::Matrix3d W = (r.fk(qp).linear() - r.fk(qm).linear()) / (2 * h) * R.transpose();
      const Eigen::Vector3d w(0.5 * (W(2, 1) - W(1, 2)), 0.5 * (W(0, 2) - W(2, 0)), 0.5 * (W(1, 0) - W(0, 1)));
      EXPECT_LT((w - J.col(i).tail<3>()).norm(), 1e-6) << r.joint_names()[i];
    }
  }
}

// The joint axes link_frames gives beside the frames (what the clearance term's gradient uses):
// the velocity of a point fixed on any link, per unit joint rate, equals the central difference
// of its position through link_frames, and the frames are those of the plain call.
TEST(Robot, JointAxesGiveEveryLinkPointsVelocity) {
  RobotConfig c = cfg();
  c.base_position_m = Eigen::Vector3d(0.6, 0.1, -1.3);
  const Robot r = Robot::load(c);
  std::mt19937 rng(7);
  const Eigen::Vector3d local(0.13, -0.07, 0.21);  // a point off every link's origin
  for (int s = 0; s < 20; ++s) {
    const Eigen::VectorXd q = random_q(r, rng);
    std::vector<JointAxis> joints;
    const auto frames = r.link_frames(q, joints);
    ASSERT_EQ(joints.size(), static_cast<std::size_t>(r.dof()));
    const auto plain = r.link_frames(q);
    ASSERT_EQ(frames.size(), plain.size());
    for (std::size_t f = 0; f < frames.size(); ++f) EXPECT_EQ(frames[f].matrix(), plain[f].matrix());
    const double h = 1e-6;
    for (int j = 0; j < r.dof(); ++j) {
      Eigen::VectorXd qp = q, qm = q;
      qp(j) += h;
      qm(j) -= h;
      const auto fp = r.link_frames(qp), fm = r.link_frames(qm);
      const JointAxis& ja = joints[static_cast<std::size_t>(j)];
      EXPECT_EQ(ja.rotational, !r.joint_is_prismatic()[static_cast<std::size_t>(j)]);
      for (std::size_t f = 0; f < frames.size(); ++f) {
        const Eigen::Vector3d x = frames[f] * local;
        const Eigen::Vector3d fd = (fp[f] * local - fm[f] * local) / (2 * h);
        const Eigen::Vector3d v = static_cast<int>(f) < ja.first_frame ? Eigen::Vector3d::Zero()
                                  : ja.rotational ? Eigen::Vector3d(ja.axis.cross(x - ja.point_m))
                                                  : ja.axis;
        EXPECT_LT((fd - v).norm(), 1e-6) << r.joint_names()[static_cast<std::size_t>(j)] << " frame " << f;
      }
    }
  }
}

TEST(Robot, KinematicsFromSeveralThreadsEqualsOneThread) {
  // fk, jacobian and link_frames are called from parallel loops (clearance checks, the deposit's
  // stages): the same answers, bit for bit, as one after another.
  const Robot r = Robot::load(cfg());
  std::mt19937 rng(11);
  std::vector<Eigen::VectorXd> qs;
  for (int s = 0; s < 400; ++s) qs.push_back(random_q(r, rng));
  std::vector<Eigen::Matrix4d> fk(qs.size()), frames(qs.size());
  std::vector<Eigen::MatrixXd> jac(qs.size());
#pragma omp parallel for num_threads(4) schedule(dynamic, 1)
  for (long s = 0; s < static_cast<long>(qs.size()); ++s) {
    const auto k = static_cast<std::size_t>(s);
    fk[k] = r.fk(qs[k]).matrix();
    jac[k] = r.jacobian(qs[k]);
    frames[k] = r.link_frames(qs[k]).back().matrix();
  }
  for (std::size_t k = 0; k < qs.size(); ++k) {
    EXPECT_EQ(fk[k], r.fk(qs[k]).matrix()) << k;
    EXPECT_EQ(jac[k], r.jacobian(qs[k])) << k;
    EXPECT_EQ(frames[k], r.link_frames(qs[k]).back().matrix()) << k;
  }
}

TEST(Robot, BadInputIsRejected) {
  RobotConfig c = cfg();
  c.urdf_path = "/nonexistent/robot.urdf";
  EXPECT_THROW(Robot::load(c), std::invalid_argument);
  const std::string xml = slurp(kUrdf);
  // Missing acceleration limit for one joint.
  std::string no_acc = std::regex_replace(xml, std::regex(R"(<shotcrete:limits joint="slew"[^>]*/>)"), "");
  try {
    Robot::from_string(no_acc, Eigen::Vector3d::Zero());
    FAIL() << "expected invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("slew"), std::string::npos) << e.what();
  }
  EXPECT_THROW(Robot::from_string("<robot", Eigen::Vector3d::Zero()), std::invalid_argument);
  const Robot r = Robot::load(cfg());
  EXPECT_THROW(r.fk(Eigen::VectorXd::Zero(3)), std::invalid_argument);
  NozzlePose bad;
  bad.axis = Eigen::Vector3d::Zero();
  EXPECT_THROW(solve_ik_5dof(r, bad, r.neutral(), cfg()), std::invalid_argument);
}

TEST(Ik, RandomReachablePosesFromNeutralAndRandomSeeds) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  std::mt19937 rng(11);
  const int n = 300;
  int solved_neutral = 0, solved_random = 0;
  for (int s = 0; s < n; ++s) {
    const Eigen::VectorXd q_true = random_q(r, rng);
    const Eigen::VectorXd seed = random_q(r, rng);
    const NozzlePose target = pose_of(r.fk(q_true));
    for (int which = 0; which < 2; ++which) {
      const IkResult res = solve_ik_5dof(r, target, which == 0 ? r.neutral() : seed, c);
      if (!res.success) {
        EXPECT_FALSE(res.reason.empty());
        continue;
      }
      (which == 0 ? solved_neutral : solved_random)++;
      // Never outside limits, never off target: checked with FK, not with the solver's own numbers.
      ASSERT_TRUE(r.within_limits(res.q)) << res.q.transpose();
      const Eigen::Isometry3d f = r.fk(res.q);
      EXPECT_LE((f.translation() - target.position_m).norm(), c.ik_position_tolerance_m);
      EXPECT_LE(angle(f.linear().col(2), target.axis), c.ik_angle_tolerance_rad);
      EXPECT_NEAR((f.translation() - target.position_m).norm(), res.position_error_m, 1e-9);
    }
  }
  EXPECT_GE(solved_neutral, static_cast<int>(0.99 * n));
  EXPECT_GE(solved_random, static_cast<int>(0.99 * n));
}

TEST(Ik, IsDeterministic) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  std::mt19937 rng(2);
  const NozzlePose target = pose_of(r.fk(random_q(r, rng)));
  const IkResult a = solve_ik_5dof(r, target, r.neutral(), c);
  const IkResult b = solve_ik_5dof(r, target, r.neutral(), c);
  EXPECT_EQ(a.q, b.q);
}

TEST(Ik, KdlBaselineSolvesSomeFullPoses) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  std::mt19937 rng(7);
  int solved = 0;
  for (int s = 0; s < 50; ++s) {
    const Eigen::Isometry3d goal = r.fk(random_q(r, rng));
    const IkResult res = solve_ik_kdl_nr_jl(r, goal, r.neutral(), c);
    if (!res.success) continue;
    ++solved;
    EXPECT_TRUE(r.within_limits(res.q));
    EXPECT_LE((r.fk(res.q).translation() - goal.translation()).norm(), c.ik_position_tolerance_m);
  }
  EXPECT_GT(solved, 0);
}

namespace {
// A horizontal pass along the arc of the wall: nozzle at standoff, perpendicular to the wall.
std::vector<NozzlePose> arc_pass(double radius_m, double standoff_m, double d_m, double th0, double th1, int n) {
  std::vector<NozzlePose> out;
  for (int k = 0; k < n; ++k) {
    const double th = th0 + (th1 - th0) * k / (n - 1);
    const Eigen::Vector3d normal(0, std::cos(th), std::sin(th));
    NozzlePose p;
    p.position_m = Eigen::Vector3d(d_m, 0, 0) + (radius_m - standoff_m) * normal;
    p.axis = normal;
    out.push_back(p);
  }
  return out;
}
}  // namespace

TEST(Path, ArcPassIsContinuousAndOnTarget) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  // From the right springline over the crown to the left springline, 5 cm steps at 4.6 m.
  const auto pass = arc_pass(5.6, 1.0, 0.3, 0.05, M_PI - 0.05, 290);
  const JointPath path = solve_path(r, pass, r.neutral(), c);
  ASSERT_EQ(path.q.size(), pass.size());
  double worst_step = 0;
  for (size_t k = 0; k < pass.size(); ++k) {
    ASSERT_TRUE(r.within_limits(path.q[k]));
    const Eigen::Isometry3d f = r.fk(path.q[k]);
    EXPECT_LE((f.translation() - pass[k].position_m).norm(), c.ik_position_tolerance_m) << k;
    EXPECT_LE(angle(f.linear().col(2), pass[k].axis), c.ik_angle_tolerance_rad) << k;
    if (k) worst_step = std::max(worst_step, (path.q[k] - path.q[k - 1]).cwiseAbs().maxCoeff());
  }
  EXPECT_LE(worst_step, c.ik_max_joint_step);
  EXPECT_NEAR(worst_step, path.max_joint_step, 1e-12);
  // 5 cm of nozzle travel should never need more than a few degrees of any joint (no flips).
  EXPECT_LT(worst_step, 0.1);
}

TEST(Path, AlongTheAxisPassIsContinuous) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  std::vector<NozzlePose> pass;
  for (int k = 0; k <= 24; ++k) {
    NozzlePose p;
    p.axis = Eigen::Vector3d(0, std::cos(1.0), std::sin(1.0));
    p.position_m = Eigen::Vector3d(0.05 * k, 0, 0) + 4.6 * p.axis;
    pass.push_back(p);
  }
  const JointPath path = solve_path(r, pass, r.neutral(), c);
  EXPECT_LE(path.max_position_error_m, c.ik_position_tolerance_m);
  EXPECT_LE(path.max_angle_error_rad, c.ik_angle_tolerance_rad);
  EXPECT_LT(path.max_joint_step, 0.1);
}

TEST(Path, UnreachableWaypointNamesIndexPoseAndReason) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  auto pass = arc_pass(5.6, 1.0, 0.3, 1.0, 1.2, 5);
  pass[3].position_m = Eigen::Vector3d(0.3, 0.0, 25.0);  // far above any reach
  try {
    solve_path(r, pass, r.neutral(), c);
    FAIL() << "expected runtime_error";
  } catch (const std::runtime_error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("waypoint 3"), std::string::npos) << msg;
    EXPECT_NE(msg.find("25.000"), std::string::npos) << msg;
    EXPECT_NE(msg.find("out of reach"), std::string::npos) << msg;
  }
  // Within the reach bound but needing the nozzle to point back at the pedestal from below the
  // floor: joint limits / unreachable, still reported.
  NozzlePose under;
  under.position_m = r.shoulder_position() + Eigen::Vector3d(0, 0, -3.0);
  under.axis = Eigen::Vector3d(0, 0, 1);
  const IkResult res = solve_ik_5dof(r, under, r.neutral(), c);
  EXPECT_FALSE(res.success);
  EXPECT_FALSE(res.reason.empty());
  EXPECT_TRUE(r.within_limits(res.q));
}

TEST(Reach, DesignTunnelsAreFullyReachable) {
  RobotConfig c = cfg();
  for (double radius : {5.0, 5.6, 8.0}) {
    const ReachMap m = reachability_map(Robot::load(c), c, radius, 1.0, 1.2, 19, 4);
    EXPECT_EQ(m.n_reached, m.n_total) << "radius " << radius;
  }
}

TEST(Path, PassesOverWholeBayAreSmoothForSmallAndLargeTunnels) {
  const RobotConfig c = cfg();
  const Robot r = Robot::load(c);
  for (double radius : {5.0, 8.0}) {
    // Arc passes (springline over the crown to springline) at both ends of the bay, both directions.
    for (double d : {0.0, 1.2}) {
      for (int dir : {1, -1}) {
        auto pass = arc_pass(radius, 1.0, d, dir > 0 ? 0.0 : M_PI, dir > 0 ? M_PI : 0.0,
                             static_cast<int>(M_PI * (radius - 1.0) / 0.05) + 1);
        const JointPath p = solve_path(r, pass, r.neutral(), c);
        EXPECT_LE(p.max_joint_step, c.ik_max_joint_step) << radius << " " << d;
        EXPECT_LE(p.max_position_error_m, c.ik_position_tolerance_m);
      }
    }
    // Passes along the axis every 20 degrees up the wall.
    for (int t = 0; t <= 9; ++t) {
      const double th = M_PI * t / 9;
      const Eigen::Vector3d n(0, std::cos(th), std::sin(th));
      std::vector<NozzlePose> pass;
      for (int k = 0; k <= 24; ++k) pass.push_back({Eigen::Vector3d(0.05 * k, 0, 0) + (radius - 1.0) * n, n});
      const JointPath p = solve_path(r, pass, r.neutral(), c);
      EXPECT_LE(p.max_joint_step, c.ik_max_joint_step) << radius << " theta " << th;
      EXPECT_LE(p.max_angle_error_rad, c.ik_angle_tolerance_rad);
    }
  }
}
