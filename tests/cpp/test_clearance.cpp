// Clearance: point-shape distances in closed form, the FCL octree query and the exact read-outs
// (exact_distance, distance_below) against a brute-force minimum over the wall's points, the
// self-check pairs, and check_clearance's bounded skipping against a check of every sample.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>

#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/trajectory.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

namespace {

CollisionShape cylinder(double r, double len, const Eigen::Isometry3d& origin = Eigen::Isometry3d::Identity()) {
  CollisionShape s;
  s.kind = CollisionShape::Kind::cylinder;
  s.radius_m = r;
  s.length_m = len;
  s.origin = origin;
  return s;
}

// Points on a half cylinder of radius R about the x axis (theta in [0, pi]), d in [0, L].
Points half_cylinder(double R, double L, int n_theta, int n_d) {
  Points p(n_theta * n_d, 3);
  for (int i = 0; i < n_theta; ++i)
    for (int j = 0; j < n_d; ++j) {
      const double th = M_PI * (i + 0.5) / n_theta;
      p.row(i * n_d + j) << L * (j + 0.5) / n_d, R * std::cos(th), R * std::sin(th);
    }
  return p;
}

double brute_force(const Points& wall, const CollisionShape& s, const Eigen::Isometry3d& pose) {
  double best = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < wall.rows(); ++i)
    best = std::min(best, point_shape_distance(wall.row(i).transpose(), s, pose));
  return best;
}

}  // namespace

TEST(Clearance, PointShapeDistanceClosedForms) {
  const CollisionShape c = cylinder(0.2, 2.0);  // along z, |z| <= 1
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  EXPECT_NEAR(point_shape_distance({1.0, 0, 0}, c, I), 0.8, 1e-12);        // beside the mantle
  EXPECT_NEAR(point_shape_distance({0, 0, 3.0}, c, I), 2.0, 1e-12);        // beyond the cap
  EXPECT_NEAR(point_shape_distance({0.5, 0, 1.4}, c, I), 0.5, 1e-12);      // off the rim: hypot(0.3, 0.4)
  EXPECT_EQ(point_shape_distance({0.1, 0, 0.5}, c, I), 0.0);               // inside
  // The same cylinder laid along x by its origin, the link moved by 5 m along y.
  const CollisionShape cx = cylinder(0.2, 2.0, Eigen::Isometry3d(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY())));
  const Eigen::Isometry3d moved(Eigen::Translation3d(0, 5, 0));
  EXPECT_NEAR(point_shape_distance({0.9, 5.0, 1.2}, cx, moved), 1.0, 1e-12);
  CollisionShape b;
  b.kind = CollisionShape::Kind::box;
  b.size_m = {2, 2, 2};
  EXPECT_NEAR(point_shape_distance({2, 2, 1}, b, I), std::sqrt(2.0), 1e-12);
  // FCL's shape-shape distance agrees with the closed form of two parallel cylinders.
  const Eigen::Isometry3d beside(Eigen::Translation3d(1.0, 0, 0));
  EXPECT_NEAR(shape_distance(c, I, c, beside), 0.6, 1e-6);
  EXPECT_EQ(shape_distance(c, I, c, Eigen::Isometry3d(Eigen::Translation3d(0.3, 0, 0))), 0.0);
}

// The octree query reads at most the leaf's diagonal short of the true distance to the points,
// never long, on random cylinders around a half-cylinder wall.
TEST(Clearance, OctreeDistanceAgainstBruteForce) {
  const Points wall = half_cylinder(5.6, 1.2, 400, 24);
  for (double res : {0.05, 0.02}) {
    const WallOctree tree(wall, res);
    EXPECT_GT(tree.occupied_leaves(), 1000u);
    EXPECT_NEAR(tree.leaf_diagonal_m(), std::sqrt(3.0) * res, 1e-15);  // the bound the readings keep below
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> U(0.0, 1.0);
    double worst_short = 0.0;
    int touching = 0;
    for (int k = 0; k < 200; ++k) {
      const CollisionShape s = cylinder(0.05 + 0.2 * U(rng), 0.2 + 2.0 * U(rng));
      const Eigen::Vector3d axis = Eigen::Vector3d(U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5).normalized();
      const double r = 3.0 + 3.0 * U(rng), th = M_PI * U(rng);
      Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
      pose.linear() = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis).toRotationMatrix();
      pose.translation() = Eigen::Vector3d(0.6, r * std::cos(th), r * std::sin(th));
      const double exact = brute_force(wall, s, pose);
      Eigen::Vector3d closest;
      const double d = tree.distance(s, pose, &closest);
      EXPECT_LE(d, exact + 1e-6) << "octree read long at pose " << k;
      // Refined over the points near the shape (KD-tree): the brute force's minimum, at a wall point.
      Eigen::Vector3d point;
      EXPECT_NEAR(tree.exact_distance(s, pose, &point), exact, 1e-9) << "pose " << k;
      EXPECT_NEAR(point_shape_distance(point, s, pose), exact, 1e-9);
      EXPECT_NEAR(std::hypot(point.y(), point.z()), 5.6, 1e-9);
      if (exact > std::sqrt(3.0) * res) {
        EXPECT_GE(d, exact - std::sqrt(3.0) * res - 1e-6) << "pose " << k;
        worst_short = std::max(worst_short, exact - d);
        // The closest point lies on the wall's leaves: within a leaf diagonal of radius 5.6.
        EXPECT_NEAR(std::hypot(closest.y(), closest.z()), 5.6, std::sqrt(3.0) * res + 1e-6);
      } else {
        ++touching;
      }
    }
    EXPECT_LT(touching, 200);
    RecordProperty("worst_short_mm_at_" + std::to_string(res), std::to_string(worst_short * 1e3));
  }
  EXPECT_THROW(WallOctree(Points(0, 3), 0.05), std::invalid_argument);
  EXPECT_THROW(WallOctree(wall, 0.0), std::invalid_argument);
  Points bad = wall;
  bad(3, 1) = std::nan("");
  EXPECT_THROW(WallOctree(bad, 0.05), std::invalid_argument);
}

// exact_distance against the brute force over every point, on every shape kind, on two walls (a
// half cylinder and a random cloud with a dense clump, whose blocks and cells hold very different
// counts), for poses inside, around and far from them: the same value to the last bit, the first
// row at it (shapes inside the wall hold many points at 0), and `at_most_m`: a distance of at
// least it comes back as it, with the closest point left alone.
TEST(Clearance, ExactDistanceEqualsBruteForceOnEveryShapeKind) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  Points cloud(6000, 3);
  for (Eigen::Index i = 0; i < cloud.rows(); ++i) {
    const bool clump = i % 3 == 0;
    cloud.row(i) << (clump ? 0.3 : 3.0) * U(rng) - (clump ? -0.5 : 1.0), (clump ? 0.3 : 6.0) * U(rng) - 3.0,
        (clump ? 0.3 : 4.0) * U(rng);
  }
  int inside = 0, capped = 0;
  for (const Points& wall : {half_cylinder(5.6, 1.2, 400, 24), cloud}) {
    const WallOctree tree(wall, 0.05);
    for (int k = 0; k < 300; ++k) {
      CollisionShape s;
      const int kind = k % 3;
      if (kind == 0) s = cylinder(0.05 + 0.3 * U(rng), 0.1 + 2.5 * U(rng));
      else if (kind == 1) s.kind = CollisionShape::Kind::sphere, s.radius_m = 0.05 + 0.6 * U(rng);
      else s.kind = CollisionShape::Kind::box, s.size_m = Eigen::Vector3d(0.1 + U(rng), 0.1 + U(rng), 0.1 + 2.0 * U(rng));
      s.origin.translation() = Eigen::Vector3d(0.2 * U(rng), 0.0, 0.3 * U(rng));
      Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
      pose.linear() = Eigen::Quaterniond::FromTwoVectors(
                          Eigen::Vector3d::UnitZ(), Eigen::Vector3d(U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5).normalized())
                          .toRotationMatrix();
      pose.translation() = Eigen::Vector3d(-3.0 + 7.0 * U(rng), -8.0 + 16.0 * U(rng), -2.0 + 9.0 * U(rng));
      double exact = std::numeric_limits<double>::infinity();
      Eigen::Index first = -1;
      for (Eigen::Index i = 0; i < wall.rows(); ++i) {
        const double d = point_shape_distance(wall.row(i).transpose(), s, pose);
        if (d < exact) exact = d, first = i;
      }
      inside += exact == 0.0 ? 1 : 0;
      Eigen::Vector3d point;
      EXPECT_EQ(tree.exact_distance(s, pose, &point), exact) << "pose " << k;
      EXPECT_EQ(point, wall.row(first).transpose()) << "pose " << k;
      // Asked up to a bound below, at or above the distance.
      for (const double at_most : {0.5 * exact, exact, exact + 0.01, exact + 1.0}) {
        Eigen::Vector3d p2 = Eigen::Vector3d::Constant(-99.0);
        const double d = tree.exact_distance(s, pose, &p2, at_most);
        if (exact >= at_most) {
          ++capped;
          EXPECT_EQ(d, at_most) << "pose " << k;
          EXPECT_EQ(p2, Eigen::Vector3d::Constant(-99.0)) << "pose " << k;
        } else {
          EXPECT_EQ(d, exact) << "pose " << k;
          EXPECT_EQ(p2, wall.row(first).transpose()) << "pose " << k;
        }
      }
    }
  }
  EXPECT_GT(inside, 10);  // ties at 0 exercised
  EXPECT_GT(capped, 300);
}

// The distance field's bounds against the brute force: for random balls (in, around and far
// outside the wall's bounding box) no point of the ball is nearer to a wall point than `lower`,
// some wall point is within `upper` of the centre; for random cylinders the shape's lower bound
// is never above the exact distance, and within the bound's worst gap of it (each wall point's
// offset in its cell, the centre's from its cell's centre, the cover's slack). Two walls: a half
// cylinder (regular) and a random cloud with a dense clump (irregular cells).
TEST(Clearance, FieldBoundNeverAboveExactDistance) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  Points cloud(4000, 3);
  for (Eigen::Index i = 0; i < cloud.rows(); ++i) {
    const bool clump = i % 4 == 0;
    cloud.row(i) << (clump ? 0.4 : 3.0) * U(rng) - (clump ? -0.5 : 1.0), (clump ? 0.4 : 6.0) * U(rng) - 3.0,
        (clump ? 0.4 : 4.0) * U(rng);
  }
  for (const Points& wall : {half_cylinder(5.6, 1.2, 400, 24), cloud}) {
    for (double res : {0.05, 0.02}) {
      const WallOctree tree(wall, res);
      const double h = tree.field_voxel_m();
      EXPECT_GE(h, res / 2 - 1e-12);  // coarser only where the box would need more than 64 M cells
      double least_gap = std::numeric_limits<double>::infinity(), worst_gap = 0.0;
      for (int k = 0; k < 300; ++k) {
        // A ball: the brute-force distance of its centre; the least over the ball is that less r.
        const Eigen::Vector3d c(-3.0 + 7.0 * U(rng), -8.0 + 16.0 * U(rng), -2.0 + 9.0 * U(rng));
        const double r = 0.3 * U(rng);
        double nearest = std::numeric_limits<double>::infinity();
        for (Eigen::Index i = 0; i < wall.rows(); ++i) nearest = std::min(nearest, (wall.row(i).transpose() - c).norm());
        const auto b = tree.field_bounds(c, r);
        EXPECT_LE(b.lower_m, nearest - r + 1e-9) << "ball " << k;
        EXPECT_GE(b.upper_m, nearest - 1e-9) << "ball " << k;
        const Eigen::Vector3d lo = wall.colwise().minCoeff().transpose(), hi = wall.colwise().maxCoeff().transpose();
        if ((c.array() >= lo.array()).all() && (c.array() <= hi.array()).all()) {  // inside the field's grid
          EXPECT_LE(b.upper_m - b.lower_m, r + 2 * std::sqrt(3.0) * h + 1e-4) << "ball " << k;
        }
        // A cylinder: lower bound against the brute force.
        const CollisionShape s = cylinder(0.05 + 0.2 * U(rng), 0.2 + 2.0 * U(rng));
        Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
        const Eigen::Vector3d axis = Eigen::Vector3d(U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5).normalized();
        pose.linear() = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis).toRotationMatrix();
        pose.translation() = c;
        const double exact = brute_force(wall, s, pose);
        const double lower = tree.field_lower_bound(s, pose);
        EXPECT_LE(lower, exact + 1e-9) << "cylinder " << k;
        if (exact > 0) {
          least_gap = std::min(least_gap, exact - lower);
          worst_gap = std::max(worst_gap, exact - lower);
        }
      }
      // Tight somewhere (a bound too high by half a cell would show): the gap's floor is set by
      // the cells, its worst by the cover's balls past a cylinder's caps.
      EXPECT_LT(least_gap, 0.5 * std::sqrt(3.0) * h);
      RecordProperty("field_worst_gap_mm_at_" + std::to_string(res), std::to_string(worst_gap * 1e3));
    }
  }
}

TEST(Clearance, RobotShapesFramesAndSelfPairs) {
  const Robot robot = Robot::load(RobotConfig{});
  const auto& shapes = robot.collision_shapes();
  // base_link, turret, boom, boom_extension, boom_head, arm, arm_extension, nozzle_head, nozzle on
  // the chain, then the carrier (a link fixed to base_link off the chain, on base_link's frame).
  ASSERT_EQ(shapes.size(), 10u);
  EXPECT_EQ(shapes.front().link, "base_link");
  EXPECT_EQ(shapes[8].link, "nozzle");
  EXPECT_EQ(shapes.back().link, "carrier");
  EXPECT_EQ(shapes.back().frame, 0);
  EXPECT_TRUE(shapes.back().carrier);
  for (std::size_t k = 0; k + 1 < shapes.size(); ++k) EXPECT_FALSE(shapes[k].carrier) << shapes[k].link;
  const Eigen::VectorXd q = robot.neutral();
  const auto frames = robot.link_frames(q);
  ASSERT_EQ(frames.size(), robot.link_names().size());
  EXPECT_EQ(robot.link_names().back(), "nozzle_tip");
  EXPECT_TRUE(frames.back().isApprox(robot.fk(q), 1e-12));  // the last frame is the tool
  // The nozzle cylinder ends at the tip: the tip point is on its cap (distance 0), a point 1 m
  // beyond the tip along the spray axis is 1 m away.
  const CollisionShape& nozzle = shapes[8];
  const Eigen::Isometry3d& nozzle_frame = frames[nozzle.frame];
  EXPECT_NEAR(point_shape_distance(frames.back().translation(), nozzle, nozzle_frame), 0.0, 1e-9);
  const Eigen::Vector3d ahead = frames.back().translation() + frames.back().linear().col(2);
  EXPECT_NEAR(point_shape_distance(ahead, nozzle, nozzle_frame), 1.0, 1e-9);
  // Self pairs: no neighbours, none that touch at neutral (the telescopes inside their booms).
  const auto pairs = self_check_pairs(robot);
  EXPECT_FALSE(pairs.empty());
  for (const auto& [a, b] : pairs) {
    EXPECT_GT(std::abs(shapes[a].frame - shapes[b].frame), 1);
    EXPECT_GT(shape_distance(shapes[a], frames[shapes[a].frame], shapes[b], frames[shapes[b].frame]), 0.0);
  }
}

namespace {

// The arm swept by the slew and the boom: 400 samples at 50 Hz, repeated `repeats` times.
TimedTrajectory sweep(const Robot& robot, int period, int repeats) {
  TimedTrajectory traj;
  const Eigen::VectorXd q0 = robot.neutral();
  for (int k = 0; k < period * repeats; ++k) {
    const int i = k % period;
    Eigen::VectorXd q = q0;
    q[0] += 1.2 * std::sin(i * 0.02);
    q[1] = std::clamp(q0[1] + 0.6 * std::sin(i * 0.013), robot.lower_limits()[1], robot.upper_limits()[1]);
    q[2] = std::clamp(1.5 + 1.5 * std::sin(i * 0.03), robot.lower_limits()[2], robot.upper_limits()[2]);
    traj.t_s.push_back(k * 0.02);
    traj.q.push_back(q);
  }
  return traj;
}

// Brute force for a cylinder, all points at once (the closed form of point_shape_distance).
double brute_force_cylinder(const Points& wall, const CollisionShape& s, const Eigen::Isometry3d& pose) {
  if (s.kind != CollisionShape::Kind::cylinder) return brute_force(wall, s, pose);
  const Eigen::Isometry3d T = pose * s.origin;
  const Eigen::MatrixXd local = (wall.rowwise() - T.translation().transpose()) * T.linear();  // rows: R^T (p - t)
  const Eigen::ArrayXd radial = (local.col(0).array().square() + local.col(1).array().square()).sqrt() - s.radius_m;
  const Eigen::ArrayXd axial = local.col(2).array().abs() - 0.5 * s.length_m;
  return (radial.max(0.0).square() + axial.max(0.0).square()).sqrt().minCoeff();
}

// Every sample, every shape, by brute force over every wall point: per link the least distance
// and the samples below its margin.
struct EverySample {
  std::map<std::string, double> min_m;
  std::map<std::string, int> below;
  std::vector<std::map<std::string, double>> at;  // per sample, per link
};
EverySample every_sample(const Robot& robot, const TimedTrajectory& traj, std::size_t samples, const Points& wall,
                         const ClearanceConfig& cfg) {
  EverySample out;
  for (std::size_t k = 0; k < samples; ++k) {
    const auto frames = robot.link_frames(traj.q[k]);
    std::map<std::string, double> d;
    for (const auto& s : robot.collision_shapes()) {
      const double e = brute_force_cylinder(wall, s, frames[s.frame]);
      d[s.link] = d.count(s.link) ? std::min(d[s.link], e) : e;
    }
    std::map<std::string, bool> b;
    for (const auto& s : robot.collision_shapes()) {
      out.min_m[s.link] = out.min_m.count(s.link) ? std::min(out.min_m[s.link], d[s.link]) : d[s.link];
      b[s.link] = b[s.link] || d[s.link] < shape_margin_m(s, cfg);
    }
    for (const auto& [link, v] : b) out.below[link] += v ? 1 : 0;
    out.at.push_back(d);
  }
  return out;
}

}  // namespace

// check_clearance against a check of every sample by exact distances (brute force over every wall
// point): the same samples below the margins, each link's least distance the exact distance at its
// reported time, at a wall point at that distance, and the every-sample least; link pairs against FCL's shape distance at every sample (least within
// 10 mm above). In stretches over two threads, the same result on every run.
TEST(Clearance, CheckEqualsExactDistancesAtEverySample) {
  const Robot robot = Robot::load(RobotConfig{});
  constexpr int kPeriod = 400, kRepeats = 11;  // 4400 samples: two stretches, split inside a repeat
  const TimedTrajectory traj = sweep(robot, kPeriod, kRepeats);
  // A wall close enough that some samples fall below the margins: half cylinder of 4.5 m about
  // an axis at the base's height.
  Points wall = half_cylinder(4.5, 6.0, 300, 60);
  wall.col(0).array() -= 3.0;
  const WallOctree tree(wall, 0.05);
  ClearanceConfig cfg;
  cfg.link_margin_m = 1.0;
  const ClearanceReport rep = check_clearance(robot, traj, tree, cfg);
  const EverySample ref = every_sample(robot, traj, kPeriod, wall, cfg);
  int total_below = 0;
  for (const auto& lc : rep.links) {
    EXPECT_EQ(lc.samples_below_margin, kRepeats * ref.below.at(lc.link)) << lc.link;
    total_below += lc.samples_below_margin;
    // The value is the exact distance at the reported sample, and the closest point is at it.
    const auto k = static_cast<std::size_t>(std::llround(lc.at_time_s / 0.02)) % kPeriod;
    EXPECT_NEAR(lc.min_m, ref.at[k].at(lc.link), 1e-12) << lc.link;
    const auto frames = robot.link_frames(traj.q[k]);
    double brute = std::numeric_limits<double>::infinity();
    for (const auto& s : robot.collision_shapes())
      if (s.link == lc.link) brute = std::min(brute, brute_force(wall, s, frames[s.frame]));
    EXPECT_NEAR(lc.min_m, brute, 1e-12) << lc.link;
    double at_closest = std::numeric_limits<double>::infinity();
    for (const auto& s : robot.collision_shapes())
      if (s.link == lc.link) at_closest = std::min(at_closest, point_shape_distance(lc.closest_m, s, frames[s.frame]));
    EXPECT_NEAR(at_closest, lc.min_m, 1e-12) << lc.link;
    EXPECT_NEAR(ref.min_m.at(lc.link), lc.min_m, 1e-12) << lc.link;  // the every-sample least
  }
  EXPECT_GT(total_below, 0);                                                   // the test exercises the count
  EXPECT_EQ(rep.wall_queries, 0);                                              // no octree readings:
  EXPECT_GT(rep.field_queries, 0);                                             // field bounds, skipped by the motion
  EXPECT_LT(rep.field_queries, static_cast<long long>(traj.size() * robot.collision_shapes().size()));
  EXPECT_GT(rep.exact_queries, static_cast<long long>(rep.links.size()));     // and the exact decisions
  // Link pairs: FCL at every sample.
  const auto& shapes = robot.collision_shapes();
  const auto pairs = self_check_pairs(robot);
  double self_min = std::numeric_limits<double>::infinity();
  int self_below = 0;
  for (int k = 0; k < kPeriod; ++k) {
    const auto frames = robot.link_frames(traj.q[static_cast<std::size_t>(k)]);
    bool sb = false;
    for (const auto& [a, c] : pairs) {
      const double d = shape_distance(shapes[a], frames[shapes[a].frame], shapes[c], frames[shapes[c].frame]);
      self_min = std::min(self_min, d);
      sb = sb || d < cfg.self_margin_m;
    }
    self_below += sb ? 1 : 0;
  }
  EXPECT_GE(rep.self.min_m, self_min - 1e-12);
  EXPECT_LE(rep.self.min_m, self_min + 0.01);
  EXPECT_EQ(rep.self.samples_below_margin, kRepeats * self_below);
  EXPECT_LT(rep.self_queries, static_cast<long long>(traj.size() * pairs.size()) / 4);  // b's motion relative to a
  EXPECT_EQ(rep.samples, kPeriod * kRepeats);
  // Deterministic: the stretches do not depend on the threads' timing.
  const ClearanceReport again = check_clearance(robot, traj, tree, cfg);
  ASSERT_EQ(again.links.size(), rep.links.size());
  for (std::size_t l = 0; l < rep.links.size(); ++l) {
    EXPECT_EQ(again.links[l].min_m, rep.links[l].min_m);
    EXPECT_EQ(again.links[l].at_time_s, rep.links[l].at_time_s);
    EXPECT_EQ(again.links[l].samples_below_margin, rep.links[l].samples_below_margin);
  }
  EXPECT_EQ(again.self.min_m, rep.self.min_m);
  EXPECT_EQ(again.wall_queries, rep.wall_queries);
  EXPECT_EQ(again.exact_queries, rep.exact_queries);
  EXPECT_EQ(again.field_queries, rep.field_queries);
  EXPECT_EQ(again.self_queries, rep.self_queries);
}

// Farther from the wall (every link but the nozzle clear of it, the default margins), every joint
// wandering: each link's least distance against the brute force's least over every sample (every
// wall point, every sample), the value and the sample (the earliest where the brute force reaches
// it). Many samples lie within the field's gap of the least, so a check that measures only the
// samples of the lowest bounds misses it (the earlier check's 32 per link read 5 of the 9 links
// 4 um to 1.4 mm long here, at other samples).
TEST(Clearance, LeastDistancesExactOverEverySample) {
  const Robot robot = Robot::load(RobotConfig{});
  Points wall = half_cylinder(8.0, 8.0, 420, 80);
  wall.col(0).array() -= 4.0;
  const WallOctree tree(wall, 0.05);
  const ClearanceConfig cfg;
  constexpr int kSamples = 1500;
  TimedTrajectory traj;
  const Eigen::VectorXd q0 = robot.neutral();
  for (int k = 0; k < kSamples; ++k) {
    Eigen::VectorXd q = q0;
    for (int j = 0; j < robot.dof(); ++j)
      q[j] = std::clamp(q0[j] + 0.3 * std::sin(2 * M_PI * (j + 1) * k / kSamples + j), robot.lower_limits()[j],
                        robot.upper_limits()[j]);
    traj.t_s.push_back(k * 0.02);
    traj.q.push_back(q);
  }
  const ClearanceReport rep = check_clearance(robot, traj, tree, cfg);
  const EverySample ref = every_sample(robot, traj, kSamples, wall, cfg);
  int clear = 0;
  for (const auto& lc : rep.links) {
    const double least = ref.min_m.at(lc.link);
    clear += least > 0.0 ? 1 : 0;
    EXPECT_NEAR(lc.min_m, least, 1e-12) << lc.link;
    int first = -1;  // the first sample at the least (within rounding)
    for (int k = 0; k < kSamples && first < 0; ++k)
      if (ref.at[static_cast<std::size_t>(k)].at(lc.link) <= least + 1e-12) first = k;
    EXPECT_EQ(std::llround(lc.at_time_s / 0.02), first) << lc.link;
    EXPECT_EQ(lc.samples_below_margin, ref.below.at(lc.link)) << lc.link;
  }
  EXPECT_GE(clear, 8);
}

// The transit router's screen: the octree's reading at every sample gives its counts, and its
// minima within 10 mm above.
TEST(Clearance, OctreeScreenEqualsEverySampleReading) {
  const Robot robot = Robot::load(RobotConfig{});
  constexpr int kPeriod = 400, kRepeats = 11;
  const TimedTrajectory traj = sweep(robot, kPeriod, kRepeats);
  Points wall = half_cylinder(4.5, 6.0, 300, 60);
  wall.col(0).array() -= 3.0;
  const WallOctree tree(wall, 0.05);
  ClearanceConfig cfg;
  cfg.link_margin_m = 1.0;
  const ClearanceReport rep = check_clearance_octree(robot, traj, tree, cfg);
  std::map<std::string, double> min_m;
  std::map<std::string, int> below;
  for (int k = 0; k < kPeriod; ++k) {
    const auto frames = robot.link_frames(traj.q[static_cast<std::size_t>(k)]);
    std::map<std::string, bool> b;
    for (const auto& s : robot.collision_shapes()) {
      const double d = tree.distance(s, frames[s.frame]);
      min_m[s.link] = min_m.count(s.link) ? std::min(min_m[s.link], d) : d;
      b[s.link] = b[s.link] || d < shape_margin_m(s, cfg);
    }
    for (const auto& [l, v] : b) below[l] += v ? 1 : 0;
  }
  int total_below = 0;
  for (const auto& lc : rep.links) {
    EXPECT_GE(lc.min_m, min_m.at(lc.link) - 1e-12) << lc.link;
    EXPECT_LE(lc.min_m, min_m.at(lc.link) + 0.01) << lc.link;
    EXPECT_EQ(lc.samples_below_margin, kRepeats * below.at(lc.link)) << lc.link;
    total_below += lc.samples_below_margin;
  }
  EXPECT_GT(total_below, 0);
  EXPECT_EQ(rep.exact_queries, 0);
}

// One sample dipping below the margin between two samples far from the wall (the arm jumps to a
// posture near the wall and back): the motion bound does not skip it; it is the only one counted
// and the nozzle's least distance is read there.
TEST(Clearance, OneSampleDipBetweenFarSamplesIsFound) {
  const Robot robot = Robot::load(RobotConfig{});
  TimedTrajectory traj;
  const Eigen::VectorXd far = robot.stow();
  Eigen::VectorXd near = far;
  near[2] = robot.upper_limits()[2];  // the boom's telescope out
  const auto frames_near = robot.link_frames(near);
  const auto& shapes = robot.collision_shapes();
  const auto nozzle = std::find_if(shapes.begin(), shapes.end(), [](const CollisionShape& s) { return s.link == "nozzle"; });
  ASSERT_NE(nozzle, shapes.end());
  // A small plane of points 0.2 m from the nozzle's centre at the dip, across its axis.
  const Eigen::Isometry3d T = frames_near[nozzle->frame] * nozzle->origin;
  Points plane(21 * 21, 3);
  for (int i = 0; i < 21; ++i)
    for (int j = 0; j < 21; ++j)
      plane.row(i * 21 + j) = (T * Eigen::Vector3d(nozzle->radius_m + 0.2, 0.05 * (i - 10), 0.05 * (j - 10))).transpose();
  for (int k = 0; k < 2001; ++k) {
    traj.t_s.push_back(k * 0.02);
    traj.q.push_back(k == 1000 ? near : far);
  }
  const WallOctree tree(plane, 0.05);
  ClearanceConfig cfg;
  const ClearanceReport rep = check_clearance(robot, traj, tree, cfg);
  const auto it = std::find_if(rep.links.begin(), rep.links.end(), [](const LinkClearance& l) { return l.link == "nozzle"; });
  ASSERT_NE(it, rep.links.end());
  const double exact = brute_force(plane, *nozzle, frames_near[nozzle->frame]);
  ASSERT_LT(exact, cfg.nozzle_margin_m);  // the dip is below the margin
  const double far_d = brute_force(plane, *nozzle, robot.link_frames(far)[nozzle->frame]);
  ASSERT_GT(far_d, cfg.nozzle_margin_m + 0.5);  // and the samples around it far above
  EXPECT_EQ(it->samples_below_margin, 1);
  EXPECT_NEAR(it->min_m, exact, 1e-12);
  EXPECT_DOUBLE_EQ(it->at_time_s, 1000 * 0.02);
  EXPECT_GE(rep.samples_below_margin(), 1);
}

// A pose that puts the boom through the wall reads 0 for the boom and counts below the margin.
TEST(Clearance, CollidingPoseIsFound) {
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd q = robot.neutral();
  const auto frames = robot.link_frames(q);
  const auto& shapes = robot.collision_shapes();
  const auto boom = std::find_if(shapes.begin(), shapes.end(), [](const CollisionShape& s) { return s.link == "boom"; });
  ASSERT_NE(boom, shapes.end());
  // A small plane of points through the middle of the boom's cylinder.
  const Eigen::Vector3d mid = frames[boom->frame] * boom->origin * Eigen::Vector3d::Zero();
  Points plane(21 * 21, 3);
  for (int i = 0; i < 21; ++i)
    for (int j = 0; j < 21; ++j) plane.row(i * 21 + j) = (mid + Eigen::Vector3d(0, 0.05 * (i - 10), 0.05 * (j - 10))).transpose();
  const WallOctree tree(plane, 0.05);
  TimedTrajectory traj;
  traj.t_s = {0.0};
  traj.q = {q};
  const ClearanceReport rep = check_clearance(robot, traj, tree, ClearanceConfig{});
  const auto it = std::find_if(rep.links.begin(), rep.links.end(), [](const LinkClearance& l) { return l.link == "boom"; });
  ASSERT_NE(it, rep.links.end());
  EXPECT_EQ(it->min_m, 0.0);
  EXPECT_EQ(it->samples_below_margin, 1);
  EXPECT_GE(rep.samples_below_margin(), 1);
}

// The posture a job starts from: the URDF's stow, within the limits; on the default wall (a 5.6 m
// design circle with 0.15 m over-break) the ready posture reaches into the crown, stow is clear of
// it by every margin, and time_plan's first sample is stow.
TEST(Clearance, StowPostureIsClearWhereTheNeutralIsNot) {
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd stow = robot.stow();
  EXPECT_TRUE(robot.within_limits(stow));
  EXPECT_FALSE(stow.isApprox(robot.neutral()));
  const Points wall = half_cylinder(5.75, 1.2, 600, 24);
  const WallOctree tree(wall, 0.05);
  auto least = [&](const Eigen::VectorXd& q) {
    const auto frames = robot.link_frames(q);
    double d = std::numeric_limits<double>::infinity();
    for (const auto& s : robot.collision_shapes()) d = std::min(d, tree.distance(s, frames[s.frame]));
    return d;
  };
  EXPECT_LT(least(robot.neutral()), 0.3);  // the ready posture is no place to start a job from
  EXPECT_GT(least(stow), 0.5);
  const auto passes = shotcrete::test::axial_region(4, 0.8, 0.2, 0.2, 1.3, {0.3});
  const TimedTrajectory tr = time_plan(robot, {passes}, robot.stow(), TimingConfig{}, RobotConfig{});
  ASSERT_GT(tr.size(), 1u);
  EXPECT_TRUE(tr.q.front().isApprox(stow, 1e-12));
}
