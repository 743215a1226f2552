// The tracking's clearance term (clearance.null_space_gain): the spare degrees of freedom keep the
// links from the wall while spraying, without breaking the exact tracking, the joint limits or the
// timing. Measured by check_clearance (exact distances to the wall's points) on the spraying samples.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>

#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/robot/joint_tracking.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/trajectory.hpp"
#include "shotcrete/timing/tuning.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

namespace {

constexpr double kR = 4.5;  // the narrow bay's wall radius

// Half cylinder of radius R (the narrow bay's by default) about the x axis over x in [x0, x1],
// points every ~4 cm.
Points narrow_wall(double x0, double x1, double R = kR) {
  const int n_theta = static_cast<int>(M_PI * R / 0.04), n_d = static_cast<int>((x1 - x0) / 0.04);
  Points p(n_theta * n_d, 3);
  for (int i = 0; i < n_theta; ++i)
    for (int j = 0; j < n_d; ++j) {
      const double th = M_PI * (i + 0.5) / n_theta, x = x0 + (x1 - x0) * (j + 0.5) / n_d;
      p.row(i * n_d + j) << x, R * std::cos(th), R * std::sin(th);
    }
  return p;
}

// Least exact distance over the links but the nozzle* ones (their place is the task's) while spraying.
double least_link_clearance(const Robot& robot, const TimedTrajectory& tr, const WallOctree& wall, std::string* which = nullptr) {
  const ClearanceReport rep = check_clearance(robot, spraying_samples(tr), wall, ClearanceConfig{});
  double least = std::numeric_limits<double>::infinity();
  for (const auto& l : rep.links)
    if (l.link.rfind("nozzle", 0) != 0 && l.min_m < least) {
      least = l.min_m;
      if (which) *which = l.link;
    }
  return least;
}

}  // namespace

// A region low on the narrow wall (theta 2.6 rad, the nozzle at 1 m standoff): the arm works
// 1.3 m from the wall without the term. With the config's term (gain 1, influence 1.5 m) the least
// clearance of the links while spraying rises by more than 10 cm (measured: 1.290 -> 1.442 m), and
// every sample still tracks its nozzle pose within the IK's tolerances, within the joint limits,
// the joint velocities and accelerations of the timed trajectory within theirs. Gain 0 (the
// term off) fails the first expectation.
TEST(ClearanceTerm, KeepsTheLinksFartherFromTheWallWhileSpraying) {
  const Robot robot = Robot::load(RobotConfig{});
  const WallOctree wall(narrow_wall(-1.5, 3.5), 0.05);
  const TimingConfig timing;
  const RobotConfig rc;
  const std::vector<std::vector<Pass>> regions{test::axial_region(6, 1.2, 0.2, 0.2, 2.6, {0.4}, kR - 1.0, kR)};
  const ClearanceConfig cc;  // the defaults
  const NullSpaceObjective term = clearance_objective(robot, wall, cc);
  ASSERT_TRUE(term.active());
  const TimedTrajectory off = time_plan(robot, regions, robot.stow(), timing, rc);
  const TimedTrajectory on = time_plan(robot, regions, robot.stow(), timing, rc, {}, term);
  std::string link_off, link_on;
  const double c_off = least_link_clearance(robot, off, wall, &link_off);
  const double c_on = least_link_clearance(robot, on, wall, &link_on);
  EXPECT_GT(c_on, c_off + 0.1) << link_off << " -> " << link_on;
  EXPECT_EQ(on.untracked_regions, 0);
  std::size_t spraying = 0;
  for (std::size_t k = 0; k < on.size(); ++k) {
    EXPECT_TRUE(robot.within_limits(on.q[k])) << k;
    if (!on.spraying[k]) continue;
    ++spraying;
    const TaskError te = task_error(robot, on.q[k], on.nozzle[k]);
    EXPECT_LE(te.position_m, rc.ik_position_tolerance_m) << k;
    EXPECT_LE(te.angle_rad, rc.ik_angle_tolerance_rad) << k;
  }
  EXPECT_EQ(spraying, 900u);  // 6 passes of 1.2 m at 0.4 m/s, 50 Hz
  EXPECT_LE(on.max_velocity_ratio, 1.0 + 1e-9);
  EXPECT_LE(on.max_acceleration_ratio, 1.0 + 1e-9);
  // The same region, the same sprayed time: the term changes the joints only.
  EXPECT_NEAR(on.spray_time_s, off.spray_time_s, 1e-9);
}

// The timing swarm's model of a region (RegionJointModel, tune_timing) tracks with the term as
// time_plan does: on the same region its end posture keeps the links as far from the wall as
// time_plan's with the term (within 2 cm), farther than without it; an inactive objective
// changes nothing.
TEST(ClearanceTerm, TheSwarmsRegionModelTracksWithTheTerm) {
  const Robot robot = Robot::load(RobotConfig{});
  const WallOctree wall(narrow_wall(-1.5, 3.5), 0.05);
  const TimingConfig timing;
  const RobotConfig rc;
  const std::vector<Pass> region = test::axial_region(6, 1.2, 0.2, 0.2, 2.6, {0.4}, kR - 1.0, kR);
  const NullSpaceObjective term = clearance_objective(robot, wall, ClearanceConfig{});
  ASSERT_TRUE(term.active());
  const auto links_clearance = [&](const Eigen::VectorXd& q) {
    const auto frames = robot.link_frames(q);
    double least = std::numeric_limits<double>::infinity();
    for (const auto& s : robot.collision_shapes())
      if (s.link.rfind("nozzle", 0) != 0) least = std::min(least, wall.exact_distance(s, frames[s.frame]));
    return least;
  };
  const TimingParams params = TimingParams::from_config(timing);
  const NozzleLimits limits{timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2};
  const double lead = timing.max_lead_length_m;
  const auto off = RegionJointModel(robot, region, lead, timing, robot.stow(), rc).evaluate(params, limits);
  const auto on = RegionJointModel(robot, region, lead, timing, robot.stow(), rc, 0.005, term).evaluate(params, limits);
  const auto inactive = RegionJointModel(robot, region, lead, timing, robot.stow(), rc, 0.005, NullSpaceObjective{}).evaluate(params, limits);
  EXPECT_EQ(inactive.q_last, off.q_last);
  const TimedTrajectory planned = time_plan(robot, {region}, robot.stow(), timing, rc, {}, term);
  std::size_t last = 0;
  for (std::size_t k = 0; k < planned.size(); ++k)
    if (planned.spraying[k]) last = k;
  const double c_off = links_clearance(off.q_last), c_on = links_clearance(on.q_last), c_plan = links_clearance(planned.q[last]);
  std::printf("region end: links' clearance model without %.4f, with %.4f, time_plan with %.4f m\n", c_off, c_on, c_plan);
  EXPECT_GT(c_on, c_off + 0.05);
  EXPECT_NEAR(c_on, c_plan, 0.02);
}

// The term's gradient: dU/dq_j = sum over the key points within the influence d0 of
// -(d0 - d) / d0 g . dx/dq_j (d the field distance less the key's radius, g the field's gradient
// as field_distance gives it). Against the same sum with the point velocities dx/dq_j taken as
// central differences through link_frames (the term takes them from the joints' axes), at
// postures of a region low on the narrow wall, where the links come within the influence.
TEST(ClearanceTerm, GradientMatchesCentralDifferencesOfTheLinks) {
  const Robot robot = Robot::load(RobotConfig{});
  const WallOctree wall(narrow_wall(-1.5, 3.5), 0.05);
  ClearanceConfig cc;
  const NullSpaceObjective term = clearance_objective(robot, wall, cc);
  ASSERT_TRUE(term.active());
  const double d0 = cc.null_space_influence_m;
  const std::vector<ClearanceKeyPoint> keys = clearance_key_points(robot);
  ASSERT_GT(keys.size(), 8u);
  const std::vector<Pass> region = test::axial_region(2, 1.2, 0.2, 0.2, 2.6, {0.4}, kR - 1.0, kR);
  const TimedTrajectory tr = time_plan(robot, {region}, robot.stow(), TimingConfig{}, RobotConfig{});
  int checked = 0;
  for (std::size_t i = 0; i < tr.size(); i += tr.size() / 12) {
    const Eigen::VectorXd& q = tr.q[i];
    Eigen::VectorXd grad;
    term.gradient(q, grad);
    ASSERT_EQ(grad.size(), q.size());
    const auto frames = robot.link_frames(q);
    Eigen::VectorXd ref = Eigen::VectorXd::Zero(q.size());
    const double h = 1e-6;
    for (Eigen::Index j = 0; j < q.size(); ++j) {
      Eigen::VectorXd qp = q, qm = q;
      qp[j] += h;
      qm[j] -= h;
      const auto fp = robot.link_frames(qp), fm = robot.link_frames(qm);
      for (const ClearanceKeyPoint& k : keys) {
        const auto f = static_cast<std::size_t>(k.frame);
        Eigen::Vector3d g;
        const double d = wall.field_distance(frames[f] * k.point_m, &g) - k.radius_m;
        if (d < d0) ref[j] += -(d0 - d) / d0 * g.dot((fp[f] * k.point_m - fm[f] * k.point_m) / (2.0 * h));
      }
    }
    if (ref.norm() > 0.0) ++checked;
    EXPECT_LT((grad - ref).norm(), 1e-6 * (1.0 + ref.norm())) << "sample " << i << "\n" << grad.transpose() << "\n" << ref.transpose();
  }
  EXPECT_GE(checked, 6);
}

// The wall's points with a face across the axis at x_face (a disc of radius R down to z = -1.5,
// points every 4 cm) appended.
static Points with_face(const Points& wall_pts, double x_face, double R) {
  std::vector<Eigen::Vector3d> face;
  for (double y = -R; y <= R; y += 0.04)
    for (double z = -1.5; z <= R; z += 0.04)
      if (y * y + z * z < R * R) face.emplace_back(x_face, y, z);
  Points all(wall_pts.rows() + static_cast<Eigen::Index>(face.size()), 3);
  all.topRows(wall_pts.rows()) = wall_pts;
  for (std::size_t k = 0; k < face.size(); ++k) all.row(wall_pts.rows() + static_cast<Eigen::Index>(k)) = face[k].transpose();
  return all;
}

// A face across a bay of the default radius (5.7 m) 0.6 m ahead of the base (x = 1.2) and a
// pass right of the crown (y < 0) near it. Tracked from the posture a face scene's plan had
// reached there (the slew pointing the boom ahead and to the right, measured on the default bay
// with the face), the boom goes through the face: the path breaks a margin, by posture_allowance
// (the room the tracking judges) and by the links' exact distances to the points. With the term's
// room, timing_joint_path starts from the roomiest solution of the slew turns instead: a path whose
// links keep their margins, every pose tracked exactly within the joint limits. With the face 8 m
// off the room changes nothing (the same path to the bit). Gain 0 gives neither drift nor room.
TEST(ClearanceTerm, APathThroughTheFaceStartsFromARoomierPosture) {
  const Robot robot = Robot::load(RobotConfig{});
  const double x_face = 1.2, R = 5.7;
  const Points wall_pts = narrow_wall(-1.5, x_face, R);
  const Points all = with_face(wall_pts, x_face, R);
  const WallOctree wall(all, 0.05);
  const RobotConfig rc;
  const ClearanceConfig cc;
  const NullSpaceObjective term = clearance_objective(robot, wall, cc);
  ASSERT_TRUE(term.active());
  ASSERT_TRUE(static_cast<bool>(term.room));
  NullSpaceObjective no_room = term;
  no_room.room = nullptr;
  // One pass, x 0.1 -> 0.6 at theta 2.27 rad (y < 0, right of the crown), 1 m off the wall.
  const std::vector<Pass> pass = test::axial_region(1, 0.5, 0.2, 0.1, 2.27, {0.3}, R - 1.0, R);
  const std::vector<NozzlePose>& poses = pass.front().waypoints;
  Eigen::VectorXd seed(8);
  seed << -0.86, 0.77, 1.57, 1.05, 2.01, 1.46, -0.03, -1.73;
  bool tracked = false;
  const auto before = timing_joint_path(robot, poses, seed, rc, &tracked, no_room);
  ASSERT_TRUE(tracked);
  const auto after = timing_joint_path(robot, poses, seed, rc, &tracked, term);
  ASSERT_TRUE(tracked);
  const auto least_room = [&](const std::vector<Eigen::VectorXd>& path) {
    double least = std::numeric_limits<double>::infinity();
    for (const auto& q : path) least = std::min(least, term.room(q));
    return least;
  };
  // Independently: the exact distances of the links the spare degrees of freedom move (not the
  // base, not the nozzle links) to the wall's points, against clearance.link_margin_m.
  const std::vector<char> fixed = fixed_shapes(robot);
  const auto least_exact = [&](const std::vector<Eigen::VectorXd>& path) {
    double least = std::numeric_limits<double>::infinity();
    for (const auto& q : path) {
      const auto frames = robot.link_frames(q);
      const auto& shapes = robot.collision_shapes();
      for (std::size_t k = 0; k < shapes.size(); ++k)
        if (!fixed[k] && shapes[k].link.rfind("nozzle", 0) != 0)
          least = std::min(least, wall.exact_distance(shapes[k], frames[shapes[k].frame]));
    }
    return least;
  };
  const double r_before = least_room(before), r_after = least_room(after);
  std::printf("room before %.3f (slew %.2f), after %.3f (slew %.2f) m\n", r_before, before.front()[0], r_after, after.front()[0]);
  EXPECT_LT(r_before, 0.0);
  EXPECT_GE(r_after, 0.0);
  EXPECT_LT(least_exact(before), cc.link_margin_m);
  EXPECT_GE(least_exact(after), cc.link_margin_m);
  // With the face far off (x = 8 m) no path breaks a margin: the room changes nothing.
  Points far = all;
  for (Eigen::Index k = wall_pts.rows(); k < far.rows(); ++k) far(k, 0) = 8.0;
  const WallOctree far_wall(far, 0.05);
  const NullSpaceObjective far_term = clearance_objective(robot, far_wall, cc);
  NullSpaceObjective far_no_room = far_term;
  far_no_room.room = nullptr;
  const auto far_with = timing_joint_path(robot, poses, seed, rc, &tracked, far_term);
  const auto far_without = timing_joint_path(robot, poses, seed, rc, &tracked, far_no_room);
  ASSERT_EQ(far_with.size(), far_without.size());
  for (std::size_t k = 0; k < far_with.size(); ++k) EXPECT_EQ(far_with[k], far_without[k]) << k;
  // Gain 0: no drift and no room (without the drift the settling takes a roomier start back).
  ClearanceConfig no_drift = cc;
  no_drift.null_space_gain = 0.0;
  const NullSpaceObjective off = clearance_objective(robot, wall, no_drift);
  EXPECT_FALSE(off.active());
  EXPECT_FALSE(static_cast<bool>(off.room));
  for (std::size_t k = 0; k < poses.size(); ++k) {
    EXPECT_TRUE(robot.within_limits(after[k])) << k;
    const TaskError te = task_error(robot, after[k], poses[k]);
    EXPECT_LE(te.position_m, rc.ik_position_tolerance_m) << k;
    EXPECT_LE(te.angle_rad, rc.ik_angle_tolerance_rad) << k;
  }
}

// The same face, and a path from the crown down the right wall (a circumferential line at x 0.6,
// theta pi/2 -> pi/2 + 1.2, 1 m off the wall), tracked from the posture the face scene's region over
// the crown started in: the left wall's family (slew 2.82 rad, the boom back and to the left, where
// the region before it ended). From there the boom luffs over the top and the slew turns it toward
// the face as the path goes down. The right wall's family (slew near -2.8 rad) is 5.6 rad away: a
// slew turned by a clamped eighth of a turn stops at the joint's limit (3.05) and never reaches it;
// turned around the range, the roomiest of the tracked starts keeps every margin.
TEST(ClearanceTerm, APathOverTheCrownStartsInTheFamilyOfTheWallItGoesDown) {
  const Robot robot = Robot::load(RobotConfig{});
  const double x_face = 1.2, R = 5.7;
  const Points wall_pts = narrow_wall(-1.5, x_face, R);
  const Points all = with_face(wall_pts, x_face, R);
  const WallOctree wall(all, 0.05);
  const RobotConfig rc;
  const ClearanceConfig cc;
  const NullSpaceObjective term = clearance_objective(robot, wall, cc);
  ASSERT_TRUE(static_cast<bool>(term.room));
  NullSpaceObjective no_room = term;
  no_room.room = nullptr;
  std::vector<NozzlePose> poses;
  const double rn = R - 1.0;
  for (double th = 0.5 * test::kPi; th <= 0.5 * test::kPi + 1.2 + 1e-9; th += 0.01 / rn) {
    NozzlePose w;
    w.position_m = Eigen::Vector3d(0.6, rn * std::cos(th), rn * std::sin(th));
    w.axis = Eigen::Vector3d(0, std::cos(th), std::sin(th));
    poses.push_back(w);
  }
  Eigen::VectorXd seed(8);
  seed << 2.819, 0.974, 1.439, -0.028, 1.852, 1.264, -0.312, -0.714;
  bool tracked = false;
  const auto before = timing_joint_path(robot, poses, seed, rc, &tracked, no_room);
  ASSERT_TRUE(tracked);
  const auto after = timing_joint_path(robot, poses, seed, rc, &tracked, term);
  ASSERT_TRUE(tracked);
  const std::vector<char> fixed = fixed_shapes(robot);
  // The exact distances of the links the spare degrees of freedom move to the points, at every
  // posture.
  const auto least_exact = [&](const std::vector<Eigen::VectorXd>& path) {
    double least = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < path.size(); ++i) {
      const auto frames = robot.link_frames(path[i]);
      const auto& shapes = robot.collision_shapes();
      for (std::size_t k = 0; k < shapes.size(); ++k)
        if (!fixed[k] && shapes[k].link.rfind("nozzle", 0) != 0)
          least = std::min(least, wall.exact_distance(shapes[k], frames[shapes[k].frame]));
    }
    return least;
  };
  std::printf("slew at start / end: before %.2f / %.2f, after %.2f / %.2f; least link distance %.3f -> %.3f m\n",
              before.front()[0], before.back()[0], after.front()[0], after.back()[0], least_exact(before), least_exact(after));
  EXPECT_LT(least_exact(before), cc.link_margin_m);
  EXPECT_GE(least_exact(after), cc.link_margin_m);
  EXPECT_LT(after.front()[0], 0.0);  // the right wall's family
  for (std::size_t k = 0; k < poses.size(); ++k) {
    EXPECT_TRUE(robot.within_limits(after[k])) << k;
    const TaskError te = task_error(robot, after[k], poses[k]);
    EXPECT_LE(te.position_m, rc.ik_position_tolerance_m) << k;
    EXPECT_LE(te.angle_rad, rc.ik_angle_tolerance_rad) << k;
  }
}

// The robot's carrier (the URDF's carrier link) pushes the arm by its own signed distance
// (box_signed_distance: outside, the exact point-to-box distance; inside, minus the depth to the
// nearest face; its gradient the central differences; as the URDF puts it and turned about the
// vertical), within link_margin_m: at postures whose
// links stay farther than that from it the gradient is that of the robot without a carrier, to
// the bit; at postures a face scene's plan reached (the boom folded back over the top and down
// into the carrier, at two boom lifts) it is the central differences of the potential (the wall's
// field and the box, written here), and steps down it take every link off the carrier.
TEST(ClearanceTerm, TheCarrierPushesTheArmOffItAndLeavesPosturesClearOfIt) {
  const Robot robot = Robot::load(RobotConfig{});
  // The same arm without the carrier: the bundled URDF less its carrier link and joint.
  std::ifstream in(bundled_urdf_path());
  std::string xml((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::size_t l0 = xml.find("<link name=\"carrier\">"), l1 = xml.find("</joint>", xml.find("name=\"carrier_mount\""));
  ASSERT_NE(l0, std::string::npos);
  ASSERT_NE(l1, std::string::npos);
  xml.erase(l0, l1 + 8 - l0);
  const Robot bare = Robot::from_string(xml, robot.base_pose().translation());
  ASSERT_EQ(bare.collision_shapes().size() + 1, robot.collision_shapes().size());
  const auto& shapes = robot.collision_shapes();
  const CollisionShape& box = shapes.back();
  ASSERT_TRUE(box.carrier);

  // The signed distance against the exact point-to-shape distance outside and the depth inside,
  // the box as the URDF puts it and turned (its gradient in the tunnel frame).
  const Eigen::Isometry3d base = robot.base_pose();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int inside = 0;
  const CollisionShape turned_box = robot.carrier_turned(0.5).collision_shapes().back();
  ASSERT_TRUE(turned_box.carrier);
  EXPECT_TRUE(robot.carrier_turned(0.5).carrier_turned(0.5).collision_shapes().back().origin.isApprox(turned_box.origin, 1e-12))
      << "a heading, not a turn";
  EXPECT_FALSE(turned_box.origin.isApprox(box.origin, 1e-3));
  for (int k = 0; k < 4000; ++k) {
    const CollisionShape& box = k % 2 ? turned_box : shapes.back();
    const Eigen::Vector3d local(u(rng) * 0.5 * box.size_m.x() * 1.4, u(rng) * 0.5 * box.size_m.y() * 1.4, u(rng) * 0.5 * box.size_m.z() * 1.4);
    const Eigen::Vector3d p = base * box.origin * local;
    Eigen::Vector3d g;
    const double d = box_signed_distance(box, base, p, &g);
    const Eigen::Vector3d depth = 0.5 * box.size_m - local.cwiseAbs();
    if (depth.minCoeff() > 0.0) {
      ++inside;
      ASSERT_NEAR(d, -depth.minCoeff(), 1e-12);
    } else {
      ASSERT_NEAR(d, point_shape_distance(p, box, base), 1e-9);
    }
    const double h = 1e-7;
    Eigen::Vector3d fd;
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3d e = Eigen::Vector3d::Zero();
      e[a] = h;
      fd[a] = (box_signed_distance(box, base, p + e) - box_signed_distance(box, base, p - e)) / (2 * h);
    }
    ASSERT_LT((g - fd).norm(), 1e-5) << local.transpose();
  }
  EXPECT_GT(inside, 200);

  const WallOctree wall(narrow_wall(-1.5, 3.5), 0.05);
  ClearanceConfig cc;
  const NullSpaceObjective without = clearance_objective(bare, wall, cc);
  const NullSpaceObjective with = clearance_objective(robot, wall, cc);
  const std::vector<ClearanceKeyPoint> keys = clearance_key_points(robot);
  // Clear of the carrier: a region's postures.
  const std::vector<Pass> region = test::axial_region(2, 1.2, 0.2, 0.2, 2.6, {0.4}, kR - 1.0, kR);
  const TimedTrajectory tr = time_plan(robot, {region}, robot.stow(), TimingConfig{}, RobotConfig{});
  ASSERT_GE(tr.size(), 12u);
  for (std::size_t i = 0; i < tr.size(); i += tr.size() / 12) {
    Eigen::VectorXd a, b;
    without.gradient(tr.q[i], a);
    with.gradient(tr.q[i], b);
    EXPECT_EQ(a, b) << "sample " << i;
  }
  // The potential, written here: the wall's field, and the box's depth inside or the exact
  // point-to-box distance outside (`box_only`: the box's part alone).
  auto potential = [&](const Eigen::VectorXd& qq, bool box_only = false) {
    const auto f = robot.link_frames(qq);
    double sum = 0.0;
    for (const ClearanceKeyPoint& k : keys) {
      if (k.frame == 0) continue;
      const Eigen::Vector3d x = f[static_cast<std::size_t>(k.frame)] * k.point_m;
      const double dw = wall.field_distance(x) - k.radius_m, d0 = cc.null_space_influence_m;
      if (dw < d0 && !box_only) sum += 0.5 * (d0 - dw) * (d0 - dw) / d0;
      const Eigen::Vector3d local = (f[0] * box.origin).inverse() * x;
      const Eigen::Vector3d depth = 0.5 * box.size_m - local.cwiseAbs();
      const double db = (depth.minCoeff() > 0.0 ? -depth.minCoeff() : point_shape_distance(x, box, f[0])) - k.radius_m;
      const double dc = cc.link_margin_m;
      if (db < dc) sum += 0.5 * (dc - db) * (dc - db) / dc;
    }
    return sum;
  };
  auto least_to_carrier = [&](const Eigen::VectorXd& qq) {
    const auto f = robot.link_frames(qq);
    double least = std::numeric_limits<double>::infinity();
    for (std::size_t s = 0; s + 1 < shapes.size(); ++s)
      if (shapes[s].frame > 1) least = std::min(least, shape_distance(shapes[s], f[shapes[s].frame], box, f[0]));
    return least;
  };
  for (const double lift : {3.315, 3.45}) {
    Eigen::VectorXd q(8);
    q << 0.967, lift, 1.786, -1.305, -1.834, 1.004, 0.012, 1.209;  // folded back over the top, into the carrier
    ASSERT_TRUE(robot.within_limits(q, 0.0));
    ASSERT_LE(least_to_carrier(q), 0.0);
    Eigen::VectorXd grad, plain;
    with.gradient(q, grad);
    without.gradient(q, plain);
    // The box's part by central differences of its potential; the wall's as the term reads it (its
    // field's smoothed gradient at each key point times the point's motion, as the gradient test).
    Eigen::VectorXd ref = plain;
    const double h = 1e-6;
    for (Eigen::Index j = 0; j < q.size(); ++j) {
      Eigen::VectorXd qp = q, qm = q;
      qp[j] += h;
      qm[j] -= h;
      ref[j] += (potential(qp, true) - potential(qm, true)) / (2.0 * h);
    }
    EXPECT_LT((grad - ref).norm(), 1e-4 * (1.0 + ref.norm())) << grad.transpose() << "\n" << ref.transpose();
    EXPECT_GT((grad - plain).norm(), 0.1 * grad.norm());
    Eigen::VectorXd qq = q;
    const double u0 = potential(q);
    int steps = 0;
    for (; steps < 200 && least_to_carrier(qq) <= 0.0; ++steps) {
      Eigen::VectorXd g;
      with.gradient(qq, g);
      qq -= 0.02 * g / g.norm();
      if (steps == 0) EXPECT_LT(potential(qq), u0);
    }
    EXPECT_GT(least_to_carrier(qq), 0.0);
    std::printf("[carrier term] boom lift %.3f rad: the arm into the carrier (potential %.3f), every link off it after "
                "%d steps of 0.02 down the gradient (%.3f m)\n", lift, u0, steps, least_to_carrier(qq));
  }
}
