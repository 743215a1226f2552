// Joint tracking: the 5-DOF task error and its Jacobian, exact tracking that keeps away from the
// joint limits, and the nozzle speeds the arm can follow.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <utility>
#include <vector>

#include "shotcrete/robot/joint_tracking.hpp"
#include "shotcrete/robot/robot.hpp"
#include "timing_fixtures.hpp"

using shotcrete::test::kPi;

using namespace shotcrete;

TEST(TaskError, ExactAngleAndMatchingJacobian) {
  // The one 5-DOF task error of the IK and the tracking: the exact angle between the axes, its
  // rotation vector on the nozzle x / y axes, and a task Jacobian that predicts the error change.
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd q = robot.neutral();
  const Eigen::Isometry3d T = robot.fk(q);
  const Eigen::Vector3d z = T.linear().col(2), x = T.linear().col(0);
  for (double angle : {0.0, 1e-4, 0.3, 2.0, 3.0}) {
    NozzlePose target;
    target.position_m = T.translation() + Eigen::Vector3d(0.01, -0.02, 0.03);
    target.axis = 2.5 * (Eigen::AngleAxisd(angle, x) * z);  // any length
    const TaskError te = task_error(robot, q, target);
    EXPECT_NEAR(te.position_m, std::sqrt(0.01 * 0.01 + 0.02 * 0.02 + 0.03 * 0.03), 1e-12);
    EXPECT_NEAR(te.angle_rad, angle, 1e-12);
    EXPECT_NEAR(te.e.tail<2>().norm(), angle, 1e-12);  // no small-angle approximation
    EXPECT_NEAR(te.e(3), angle, 1e-12);                 // a turn about the nozzle x axis
    // The tracking's cross-product form: sin(angle) on the same axis, pushed on past 90 deg.
    const TaskError cross = task_error(robot, q, target, nullptr, AxisError::CrossProduct);
    EXPECT_NEAR(cross.angle_rad, angle, 1e-12);
    EXPECT_NEAR(cross.e(3), std::sin(angle) + (angle > 0.5 * kPi ? 2.0 : 0.0), 1e-12);
    EXPECT_NEAR(cross.e(4), 0.0, 1e-12);
    EXPECT_EQ(cross.e.head<3>(), te.e.head<3>());
  }
  NozzlePose back;
  back.position_m = T.translation();
  back.axis = -z;
  EXPECT_NEAR(task_error(robot, q, back).angle_rad, kPi, 1e-12);
  EXPECT_NEAR(task_error(robot, q, back).e.tail<2>().norm(), kPi, 1e-12);  // antiparallel: still a full turn
  // At the target, moving the joints by h dq changes the error by -h A dq to first order.
  NozzlePose here;
  here.position_m = T.translation();
  here.axis = z;
  Eigen::MatrixXd A;
  EXPECT_NEAR(task_error(robot, q, here, &A).e.norm(), 0.0, 1e-12);
  ASSERT_EQ(A.rows(), 5);
  ASSERT_EQ(A.cols(), robot.dof());
  const Eigen::VectorXd dq = Eigen::VectorXd::LinSpaced(robot.dof(), 0.5, -0.3);
  for (double h : {1e-3, 1e-4}) {
    for (AxisError form : {AxisError::RotationVector, AxisError::CrossProduct}) {
      const Eigen::Matrix<double, 5, 1> de = task_error(robot, q + h * dq, here, nullptr, form).e;
      EXPECT_LT((de + h * A * dq).norm(), 20.0 * h * h) << h;
    }
  }
}

TEST(Joint, TrackingPullsAJointBackFromItsLimit) {
  // From the ready posture, push the nozzle 3 m along its own axis (or 2 m straight up): the arm
  // telescope runs out to its limit unless the null-space drift hands the extension over to the
  // other joints in time. A fixed drift cap of 0.05 range/m overran it by 45 mm / 15 mm.
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd q0 = robot.neutral();
  const Eigen::Isometry3d T0 = robot.fk(q0);
  for (const auto& [dir, length] : {std::pair<Eigen::Vector3d, double>{T0.linear().col(2), 3.0},
                                    std::pair<Eigen::Vector3d, double>{Eigen::Vector3d::UnitZ(), 2.0}}) {
    std::vector<NozzlePose> poses;
    for (double s = 0.0; s <= length + 1e-9; s += 0.005) {
      NozzlePose p;
      p.position_m = T0.translation() + s * dir;
      p.axis = T0.linear().col(2);
      poses.push_back(p);
    }
    double em = 0.0, ea = 0.0;
    const auto q = track_joint_path(robot, poses, q0, 0.02, &em, &ea);
    EXPECT_LT(em, 1e-9);
    EXPECT_LT(ea, 1e-9);
    for (std::size_t k = 0; k < q.size(); ++k) ASSERT_TRUE(robot.within_limits(q[k])) << "step " << k << " of " << length;
    // Still a smooth function of the path: no joint jumps between 5 mm steps.
    for (std::size_t k = 1; k < q.size(); ++k) ASSERT_LT((q[k] - q[k - 1]).cwiseAbs().maxCoeff(), 0.02) << k;
  }
}

TEST(Joint, SpeedLimitsPutTheBindingJointAtItsLimit) {
  // The nozzle pose of the ready posture swung 0.6 rad about the slew axis. Reference: the tracked
  // joint path timed at each waypoint's cap, with velocities and accelerations differenced in time
  // (t = s / v): the worst joint is then exactly at its limit there, and the slew does most of the
  // turning (at most 1 / rho rad per metre; the redundant joints take a little of it).
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd q0 = robot.neutral();
  const Eigen::Isometry3d T0 = robot.fk(q0);
  const Eigen::Vector3d c = RobotConfig{}.base_position_m;  // the slew axis is vertical through it
  const double rho = Eigen::Vector2d(T0.translation().x() - c.x(), T0.translation().y() - c.y()).norm();
  ASSERT_GT(rho, 1.0);
  std::vector<NozzlePose> poses;
  for (int k = -150; k <= 150; ++k) {
    const Eigen::AngleAxisd R(0.002 * k, Eigen::Vector3d::UnitZ());
    NozzlePose p;
    p.position_m = c + R * (T0.translation() - c);
    p.axis = R * T0.linear().col(2);
    poses.push_back(p);
  }
  const Eigen::VectorXd vl = robot.velocity_limits(), al = robot.acceleration_limits();
  const auto cap = joint_speed_limits(robot, poses, q0, 0.0, 1.0);
  ASSERT_EQ(cap.size(), poses.size());
  const auto q = track_joint_path(robot, poses, q0);
  for (std::size_t k = 1; k + 1 < poses.size(); ++k) {
    const double v = cap[k];
    ASSERT_GT(v, 0.9 * vl[0] * rho) << k;
    ASSERT_LT(v, 1.2 * vl[0] * rho) << k;
    const double t0 = -(poses[k].position_m - poses[k - 1].position_m).norm() / v,
                 t2 = (poses[k + 1].position_m - poses[k].position_m).norm() / v;
    const Eigen::VectorXd qd = (q[k + 1] - q[k - 1]) / (t2 - t0);
    const Eigen::VectorXd qdd = ((q[k + 1] - q[k]) / t2 - (q[k] - q[k - 1]) / -t0) / (0.5 * (t2 - t0));
    const double ratio = std::max(qd.cwiseAbs().cwiseQuotient(vl).maxCoeff(), qdd.cwiseAbs().cwiseQuotient(al).maxCoeff());
    ASSERT_NEAR(ratio, 1.0, 1e-6) << k;
  }
  // A limit share scales the velocity bound (the speed changes below cost the slew about half its
  // acceleration); a tangential acceleration beyond what the slew can give allows no speed.
  const auto shared = joint_speed_limits(robot, poses, q0, 0.5 * al[0] * rho, 0.8);
  for (std::size_t k = 0; k < cap.size(); ++k) ASSERT_LE(shared[k], 0.8 * cap[k] * (1 + 1e-9)) << k;
  const auto none = joint_speed_limits(robot, poses, q0, 1.3 * al[0] * rho, 1.0);
  for (std::size_t k = 0; k < none.size(); ++k) ASSERT_EQ(none[k], 0.0) << k;
  EXPECT_THROW(joint_speed_limits(robot, poses, q0, 0.0, 0.0), std::invalid_argument);
  EXPECT_THROW(joint_speed_limits(robot, poses, q0, -1.0, 1.0), std::invalid_argument);
}

// timing_joint_path solves the whole path on a second thread while it tracks from the first pose's
// own solution, and tracks again from the path's start when that differs. The result must be the
// one of solving first and tracking after: compared, bit for bit, with the same call made inside a
// parallel loop (where it runs one after the other), over a pass across the crown from random
// seeds, some of which start the path on a branch the whole path does not keep.
TEST(Joint, TimingPathTrackedWhileThePathIsSolvedEqualsOneAfterTheOther) {
  const Robot robot = Robot::load(RobotConfig{});
  std::vector<NozzlePose> poses;
  for (int k = 0; k <= 400; ++k) {  // 2 m along the axis, then around the crown from 1.2 to 1.9 rad
    const double th = k <= 200 ? 1.2 : 1.2 + 0.7 * (k - 200) / 200.0, x = k <= 200 ? 0.01 * k : 2.0;
    NozzlePose p;
    p.position_m = Eigen::Vector3d(x, 4.6 * std::cos(th), 4.6 * std::sin(th));
    p.axis = Eigen::Vector3d(0, std::cos(th), std::sin(th));
    poses.push_back(p);
  }
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  int other_start = 0, compared = 0;
  for (int s = 0; s < 24; ++s) {
    Eigen::VectorXd seed = robot.neutral();
    if (s > 0)
      for (int i = 0; i < robot.dof(); ++i)
        seed(i) = robot.lower_limits()(i) + u(rng) * (robot.upper_limits()(i) - robot.lower_limits()(i));
    std::vector<Eigen::VectorXd> alone, serial;
    bool ok_alone = false, ok_serial = false;
    try {
      alone = timing_joint_path(robot, poses, seed, RobotConfig{}, &ok_alone);
    } catch (const std::exception&) {
      continue;  // no start from this seed: nothing to compare
    }
#pragma omp parallel num_threads(2)
    {
#pragma omp single
      serial = timing_joint_path(robot, poses, seed, RobotConfig{}, &ok_serial);
    }
    ++compared;
    EXPECT_EQ(ok_alone, ok_serial) << s;
    ASSERT_EQ(alone.size(), serial.size()) << s;
    for (std::size_t k = 0; k < alone.size(); ++k) ASSERT_EQ(alone[k], serial[k]) << "seed " << s << " sample " << k;
    const Eigen::VectorXd first = solve_path(robot, {poses.front()}, seed, RobotConfig{}).q.front();
    if (first != solve_path(robot, poses, seed, RobotConfig{}).q.front()) ++other_start;
  }
  std::printf("%d seeds compared, %d with the path starting off the first pose's own solution\n", compared, other_start);
  EXPECT_GE(compared, 12);
  EXPECT_GE(other_start, 1);
}
