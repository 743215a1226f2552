// Transits by the seed method: the joint moves of a trajectory, their replacement, and a transit
// that a rock protrusion makes collide re-routed through a via posture, checked against a
// brute-force distance to the wall's points (not the octree).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/collision/transit.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/trajectory.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

namespace {

constexpr double kR = 4.5;  // the narrow bay's wall radius

// A dome of the synthetic pits' shape (alpha 1.5) standing `height` toward the axis at (x_c,
// theta_c), radius `radius` on the unrolled wall.
struct Dome {
  double x_c, theta_c, height, radius;
};

// Half cylinder of radius kR about the x axis over x in [x0, x1] with domes on it (their heights
// add where they overlap). Points every ~4 cm.
Points wall_with_domes(double x0, double x1, const std::vector<Dome>& domes) {
  const int n_theta = static_cast<int>(M_PI * kR / 0.04), n_d = static_cast<int>((x1 - x0) / 0.04);
  Points p(n_theta * n_d, 3);
  for (int i = 0; i < n_theta; ++i)
    for (int j = 0; j < n_d; ++j) {
      const double th = M_PI * (i + 0.5) / n_theta, x = x0 + (x1 - x0) * (j + 0.5) / n_d;
      double r = kR;
      for (const Dome& d : domes) {
        const double ds = (th - d.theta_c) * kR, dd = x - d.x_c;
        const double q = (ds * ds + dd * dd) / (d.radius * d.radius);
        if (q < 1.0) r -= d.height * std::pow(1.0 - q, 1.5);
      }
      p.row(i * n_d + j) << x, r * std::cos(th), r * std::sin(th);
    }
  return p;
}

Points wall_with_protrusion(double x0, double x1, double x_c, double theta_c, double height, double radius) {
  return wall_with_domes(x0, x1, {{x_c, theta_c, height, radius}});
}

// Least distance less margin over every shape (exact distance to every wall point) and every
// checked pair (FCL shape-shape) at posture q: the brute-force reference of posture_allowance.
double brute_allowance(const Robot& robot, const Eigen::VectorXd& q, const Points& wall, const ClearanceConfig& cfg,
                       const std::vector<std::pair<int, int>>& pairs) {
  const auto& shapes = robot.collision_shapes();
  const auto frames = robot.link_frames(q);
  double least = std::numeric_limits<double>::infinity();
  for (const auto& s : shapes) {
    // Every point, exactly; a point whose distance to the shape's bounding sphere is already no
    // less than the least so far is skipped (it cannot be nearer).
    const Eigen::Vector3d c = frames[s.frame] * s.origin.translation();
    const double rb = s.kind == CollisionShape::Kind::box ? 0.5 * s.size_m.norm()
                      : s.kind == CollisionShape::Kind::sphere ? s.radius_m
                                                               : std::hypot(s.radius_m, 0.5 * s.length_m);
    double d = std::numeric_limits<double>::infinity();
    for (Eigen::Index i = 0; i < wall.rows(); ++i) {
      const Eigen::Vector3d p = wall.row(i).transpose();
      if ((p - c).norm() - rb >= d) continue;
      d = std::min(d, point_shape_distance(p, s, frames[s.frame]));
    }
    least = std::min(least, d - shape_margin_m(s, cfg));
  }
  for (const auto& [a, b] : pairs)
    least = std::min(least, shape_distance(shapes[a], frames[shapes[a].frame], shapes[b], frames[shapes[b].frame]) -
                                cfg.self_margin_m);
  return least;
}

// Two regions on the narrow wall far apart around the arch (nozzle at 1 m standoff): the transit
// between them swings the arm over the crown.
std::vector<std::vector<Pass>> two_regions() {
  return {shotcrete::test::axial_region(2, 0.6, 0.2, 0.3, 0.55, {0.3}, kR - 1.0, kR),
          shotcrete::test::axial_region(2, 0.6, 0.2, 0.3, 2.45, {0.3}, kR - 1.0, kR)};
}

// The first transit between two regions (no region's index), after the move from the start
// posture; moves.end() when there is none.
std::vector<JointMove>::const_iterator first_transit(const std::vector<JointMove>& moves) {
  return std::find_if(moves.begin() + 1, moves.end(), [](const JointMove& m) { return m.region_index < 0; });
}

// Where the nozzle of the move [start, end] comes nearest the plain wall: its room to the wall [m]
// and the place (x, theta) on the wall.
struct NearestWall {
  double room_m = std::numeric_limits<double>::infinity(), x_m = 0.0, theta_rad = 0.0;
};
NearestWall nearest_wall(const TimedTrajectory& tr, const JointMove& m) {
  NearestWall n;
  for (std::size_t k = m.start; k <= m.end; ++k) {
    const Eigen::Vector3d p = tr.nozzle[k].position_m;
    const double room = kR - std::hypot(p.y(), p.z());
    if (room < n.room_m) n = {room, p.x(), std::atan2(p.z(), p.y())};
  }
  return n;
}

// The narrow wall with a rock over the crown where the trajectory's first transit between regions
// swings its nozzle nearest (0.6 m past the nozzle's room above its margin, radius 0.8 m); no
// points when it has no such transit.
Points rock_over_the_crown(const TimedTrajectory& tr, const ClearanceConfig& cfg) {
  const auto moves = joint_moves(tr);
  const auto it = first_transit(moves);
  if (it == moves.end()) return Points(0, 3);
  const NearestWall near = nearest_wall(tr, *it);
  return wall_with_protrusion(-0.6, 2.0, near.x_m, near.theta_rad, near.room_m - cfg.nozzle_margin_m + 0.6, 0.8);
}

}  // namespace

TEST(Transit, JointMovesAndTheirReplacement) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const auto moves = joint_moves(tr);
  ASSERT_GE(moves.size(), 2u);
  EXPECT_EQ(moves.front().start, 0u);  // from the start posture
  EXPECT_EQ(moves.front().region_index, -1);
  double moves_s = 0.0;
  for (const auto& m : moves) {
    moves_s += m.duration_s(tr);
    for (std::size_t k = m.start + 1; k <= m.end; ++k) EXPECT_EQ(tr.kind[k], static_cast<char>(SegmentKind::Transit));
    if (m.start > 0) EXPECT_NE(tr.kind[m.start], static_cast<char>(SegmentKind::Transit));  // a region's last sample
    if (m.end + 1 < tr.size()) EXPECT_NE(tr.kind[m.end + 1], static_cast<char>(SegmentKind::Transit));
  }
  EXPECT_NEAR(moves_s, tr.transit_time_s, 1e-9);  // every joint move counted once
  // The transit between the regions through a via posture: later samples shift by the added time.
  const auto it = first_transit(moves);
  ASSERT_NE(it, moves.end());
  const JointMove m = *it;
  const Eigen::VectorXd qa = tr.q[m.start], qb = tr.q[m.end];
  Eigen::VectorXd via = 0.5 * (qa + qb);
  via[0] += 0.3;  // a slew detour
  const TimedTrajectory piece = joint_move_through(robot, {qa, via, qb}, timing, -1);
  const TimedTrajectory before = tr;
  replace_joint_move(robot, tr, m, piece);
  const double delta = piece.duration_s - m.duration_s(before);
  EXPECT_NE(delta, 0.0);  // (a via can also shorten it: the nozzle's path, which bounds its speed, changes)
  EXPECT_NEAR(tr.duration_s, before.duration_s + delta, 1e-9);
  EXPECT_NEAR(tr.transit_time_s, before.transit_time_s + delta, 1e-9);
  EXPECT_NEAR(tr.cycle_time.transits_s, before.cycle_time.transits_s + delta, 1e-9);
  EXPECT_NEAR(tr.cycle_time.total_s(), tr.duration_s, 1e-6);
  EXPECT_EQ(tr.size(), before.size() - (m.end - m.start) + piece.size());
  const std::size_t after = m.start + 1 + piece.size();
  EXPECT_TRUE(tr.q[after - 1].isApprox(qb, 1e-9));
  for (std::size_t k = after, k0 = m.end + 1; k < tr.size(); ++k, ++k0) {
    ASSERT_NEAR(tr.t_s[k], before.t_s[k0] + delta, 1e-9);
    ASSERT_TRUE(tr.q[k].isApprox(before.q[k0], 0.0));
  }
  for (std::size_t k = 1; k < tr.size(); ++k) ASSERT_GT(tr.t_s[k], tr.t_s[k - 1]);
  // Rest-to-rest quintics within the joint limits: on the new move's samples and at the via.
  for (std::size_t k = m.start + 1; k < after; ++k) {
    EXPECT_LE(tr.qd[k].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff(), 1.0 + 1e-6);
    EXPECT_LE(tr.qdd[k].cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff(), 1.0 + 1e-2);
  }
  const auto via_at = std::min_element(tr.q.begin() + static_cast<std::ptrdiff_t>(m.start + 1),
                                       tr.q.begin() + static_cast<std::ptrdiff_t>(after),
                                       [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
                                         return (a - via).norm() < (b - via).norm();
                                       });
  EXPECT_LT((*via_at - via).norm(), 1e-9);  // it stops at the via
  EXPECT_THROW(replace_joint_move(robot, tr, JointMove{5, 3, -1}, piece), std::invalid_argument);
}

// The seed method's test bay: a narrow wall (radius 4.5 m) with a rock protrusion where the
// straight joint interpolation of the transit between two regions passes; the transit is
// re-routed through a via posture, every sample of the new move keeps the margins by a
// brute-force distance to the wall's points, and the time it costs is reported.
TEST(Transit, ProtrusionInTheTransitIsRerouted) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  const ClearanceConfig cfg;
  TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const auto moves = joint_moves(tr);
  const auto it = first_transit(moves);
  ASSERT_NE(it, moves.end());
  const JointMove transit = *it;
  // Where the straight transit's nozzle comes nearest the plain wall: the protrusion goes there,
  // standing 0.3 m further in than the nozzle's room above its margin.
  const NearestWall near = nearest_wall(tr, transit);
  const double least = near.room_m, x_c = near.x_m, th_c = near.theta_rad;
  const double height = least - cfg.nozzle_margin_m + 0.3;
  const Points wall = wall_with_protrusion(-0.6, 2.0, x_c, th_c, height, 0.8);
  const WallOctree octree(wall, cfg.octree_resolution_m);
  const auto pairs = self_check_pairs(robot);
  // The straight interpolation collides; its end postures do not.
  double straight = std::numeric_limits<double>::infinity();
  for (std::size_t k = transit.start; k <= transit.end; k += 5)
    straight = std::min(straight, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
  ASSERT_LT(straight, 0.0);
  ASSERT_GE(brute_allowance(robot, tr.q[transit.start], wall, cfg, pairs), 0.0);
  ASSERT_GE(brute_allowance(robot, tr.q[transit.end], wall, cfg, pairs), 0.0);

  const double duration_before = tr.duration_s;
  const TransitReport rep = clear_transits(robot, tr, octree, cfg, timing);
  EXPECT_EQ(rep.moves_checked, static_cast<int>(moves.size()));
  // The rock stands over the crown: the move from the stow posture may cross it too. Every move
  // it blocks is re-routed, the transit between the regions among them.
  EXPECT_EQ(rep.failed, 0);
  ASSERT_GE(rep.rerouted, 1);
  ASSERT_EQ(rep.detours.size(), static_cast<std::size_t>(rep.rerouted));
  const int transit_index = static_cast<int>(it - moves.begin());
  EXPECT_TRUE(std::any_of(rep.detours.begin(), rep.detours.end(), [&](const TransitDetour& d) { return d.move == transit_index; }));
  const auto after = joint_moves(tr);
  ASSERT_EQ(after.size(), moves.size());
  double detour_s = 0.0;
  for (const TransitDetour& d : rep.detours) {
    EXPECT_TRUE(d.rerouted);
    EXPECT_GT(d.straight_samples_below, 0);
    EXPECT_LT(d.straight_min_allowance_m, 0.0);
    ASSERT_FALSE(d.vias.empty());
    EXPECT_GE(d.min_allowance_m, 0.0);
    detour_s += d.duration_s - d.straight_duration_s;
    const JointMove m = after[static_cast<std::size_t>(d.move)];
    EXPECT_NEAR(m.duration_s(tr), d.duration_s, 1e-9);
    EXPECT_NEAR(tr.t_s[m.start], d.start_time_s, 1e-9);
    // Independent check of every sample of the new move: exact distances to the wall's points.
    double worst = std::numeric_limits<double>::infinity();
    for (std::size_t k = m.start; k <= m.end; ++k) worst = std::min(worst, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
    EXPECT_GE(worst, 0.0) << "move " << d.move;
    RecordProperty("move_" + std::to_string(d.move) + "_allowance_m", std::to_string(worst));
    // Within the joint limits along it.
    for (std::size_t k = m.start + 1; k <= m.end; ++k) {
      ASSERT_TRUE(robot.within_limits(tr.q[k], 1e-9));
      EXPECT_LE(tr.qd[k].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff(), 1.0 + 1e-6);
    }
    // posture_allowance reads short of the brute force by at most half a leaf diagonal, never long.
    for (const auto& v : d.vias) {
      const double exact = brute_allowance(robot, v, wall, cfg, pairs);
      const double read = posture_allowance(robot, v, octree, cfg, pairs, 10.0);
      EXPECT_LE(read, exact + 1e-6);
      EXPECT_GE(read, exact - std::sqrt(3.0) * cfg.octree_resolution_m - 1e-6);
    }
  }
  // The time cost: reported, and what the trajectory grew by.
  EXPECT_NEAR(rep.detour_time_s, detour_s, 1e-9);
  EXPECT_NEAR(tr.duration_s, duration_before + rep.detour_time_s, 1e-9);
  RecordProperty("straight_allowance_m", std::to_string(straight));
  RecordProperty("detour_s", std::to_string(rep.detour_time_s));
  // With re-routing off the move stays and is reported as not re-routed.
  TimedTrajectory plain = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  ClearanceConfig off = cfg;
  off.reroute_transits = false;
  const TransitReport kept = clear_transits(robot, plain, octree, off, timing);
  EXPECT_EQ(kept.rerouted, 0);
  EXPECT_EQ(kept.failed, rep.rerouted);
  EXPECT_EQ(kept.detour_time_s, 0.0);
}

// clear_transits screens a move by the exact check first and reads the octree only where that
// leaves less than a leaf diagonal to spare: the moves it reports are exactly those the octree's
// readings put below a margin (check_clearance_octree on each move, as before the screen), with a
// rock whose height puts the transit's allowance below, within and beyond a diagonal.
TEST(Transit, TheExactScreenReportsTheMovesTheOctreeReadingsFlag) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  ClearanceConfig cfg;
  cfg.reroute_transits = false;  // every flagged move is reported as it is
  const TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const auto moves = joint_moves(tr);
  const auto it = first_transit(moves);
  ASSERT_NE(it, moves.end());
  double least = std::numeric_limits<double>::infinity(), x_c = 0.0, th_c = 0.0;
  for (std::size_t k = it->start; k <= it->end; ++k) {
    const Eigen::Vector3d p = tr.nozzle[k].position_m;
    const double room = kR - std::hypot(p.y(), p.z());
    if (room < least) least = room, x_c = p.x(), th_c = std::atan2(p.z(), p.y());
  }
  const double diagonal = std::sqrt(3.0) * cfg.octree_resolution_m;
  int flagged_total = 0, spared_by_octree = 0;
  for (const double spare : {-0.1, 0.02, 0.05, 0.08, 0.3}) {
    const Points wall = wall_with_protrusion(-0.6, 2.0, x_c, th_c, least - cfg.nozzle_margin_m - spare, 0.8);
    const WallOctree octree(wall, cfg.octree_resolution_m);
    std::vector<int> flagged;
    for (std::size_t i = 0; i < moves.size(); ++i) {
      TimedTrajectory piece;
      for (std::size_t k = moves[i].start; k <= moves[i].end; ++k) piece.t_s.push_back(tr.t_s[k]), piece.q.push_back(tr.q[k]);
      const ClearanceReport oct = check_clearance_octree(robot, piece, octree, cfg);
      if (oct.samples_below_margin() > 0) flagged.push_back(static_cast<int>(i));
      const ClearanceReport exact = check_clearance(robot, piece, octree, cfg);
      if (oct.samples_below_margin() > 0 && exact.samples_below_margin() == 0) ++spared_by_octree;
      // The octree never reads long: where it flags nothing the exact check flags nothing either.
      if (oct.samples_below_margin() == 0) EXPECT_EQ(exact.samples_below_margin(), 0) << "spare " << spare << ", move " << i;
    }
    TimedTrajectory copy = tr;
    const TransitReport rep = clear_transits(robot, copy, octree, cfg, timing);
    std::vector<int> reported;
    for (const auto& d : rep.detours) reported.push_back(d.move);
    EXPECT_EQ(reported, flagged) << "spare " << spare << " m (leaf diagonal " << diagonal << " m)";
    EXPECT_EQ(rep.rerouted, 0);
    flagged_total += static_cast<int>(flagged.size());
  }
  EXPECT_GT(flagged_total, 0);     // the low rocks block the transit
  EXPECT_GT(spared_by_octree, 0);  // and some rock is within a diagonal: flagged by the octree alone
}

// A rock at the goal of the transit (where the next region starts spraying) 0.8 m high: the goal
// itself is short of the margins (0.245 m), so no route keeps them. The straight move comes no
// closer than its goal, so nothing is searched: the move stays, reported with the reason and
// counted as failed.
TEST(Transit, GoalPostureInsideTheMarginIsReportedNotRerouted) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  const ClearanceConfig cfg;
  TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const auto moves = joint_moves(tr);
  const auto it = first_transit(moves);
  ASSERT_NE(it, moves.end());
  const Eigen::Vector3d goal = tr.nozzle[it->end].position_m;  // 1 m from the wall, facing it
  const Points wall = wall_with_protrusion(-0.6, 2.0, goal.x(), std::atan2(goal.z(), goal.y()), 0.8, 0.8);
  const WallOctree octree(wall, cfg.octree_resolution_m);
  const auto pairs = self_check_pairs(robot);
  ASSERT_LT(brute_allowance(robot, tr.q[it->end], wall, cfg, pairs), 0.0);
  const TimedTrajectory before = tr;
  const TransitReport rep = clear_transits(robot, tr, octree, cfg, timing);
  const int index = static_cast<int>(it - moves.begin());
  const auto d = std::find_if(rep.detours.begin(), rep.detours.end(), [&](const TransitDetour& x) { return x.move == index; });
  ASSERT_NE(d, rep.detours.end());
  EXPECT_FALSE(d->rerouted);
  EXPECT_EQ(d->reason.rfind("its start or goal posture is itself ", 0), 0u) << d->reason;
  EXPECT_GE(rep.failed, 1);
  EXPECT_FALSE(d->eased);
  EXPECT_EQ(d->optimisations, 0);
  EXPECT_EQ(d->duration_s, d->straight_duration_s);
  if (rep.rerouted == 0 && std::none_of(rep.detours.begin(), rep.detours.end(), [](const TransitDetour& x) { return x.eased; }))
    EXPECT_EQ(tr.duration_s, before.duration_s);  // nothing changed
}

// The seed method's test bay with the rock over the crown where the transit between its regions
// passes nearest (the move from the stow posture swings through it too, a link wholly in it, 0.4 m
// short of a margin), and a second rock where that move ends
// (the first region's first posture), its nozzle 0.1 m short of its margin: no route can keep
// every margin to a goal that does not. Before, such a move stayed as it was, through the rock
// (the face scene's start swung through the face: 2,000 link-samples at 0 m). It is routed with
// the margins lowered by the goal's shortfall (and a leaf diagonal): every fifth sample of the new
// move and its last one, by brute-force distances to the wall's points, keeps the lowered margins
// to within the octree's two readings (the goal's and the route's: each never more than a leaf
// diagonal short), less short than the straight swing, with fewer link-samples below the margins
// proper. Still failed; within the joint limits; the time it costs reported. (With the sampled
// planner off; with it on, its route replaces the move when it breaks the margins proper at fewer
// link-samples: never more than the via route's, checked at the end.)
TEST(Transit, AMoveToAPostureShortOfTheMarginsSweepsNoCloserThanItsEnd) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  ClearanceConfig cfg;
  cfg.sampled_route_nodes = 0;
  TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const auto moves = joint_moves(tr);
  const auto it = first_transit(moves);
  ASSERT_NE(it, moves.end());
  const JointMove first = moves.front();
  const NearestWall swing = nearest_wall(tr, *it);
  // The goal's nozzle room to the plain wall, and the rock under it that takes 0.1 m more than
  // the room above its margin.
  JointMove at_goal = first;
  at_goal.start = first.end;
  const NearestWall goal = nearest_wall(tr, at_goal);
  const Points wall = wall_with_domes(-0.6, 2.0, {{swing.x_m, swing.theta_rad, swing.room_m - cfg.nozzle_margin_m + 0.6, 0.8},
                                                   {goal.x_m, goal.theta_rad, goal.room_m - cfg.nozzle_margin_m + 0.1, 0.6}});
  const WallOctree octree(wall, cfg.octree_resolution_m);
  const auto pairs = self_check_pairs(robot);
  const double goal_allowance = brute_allowance(robot, tr.q[first.end], wall, cfg, pairs);
  ASSERT_LT(goal_allowance, -0.05);
  ASSERT_GT(goal_allowance, -0.15);
  ASSERT_GE(brute_allowance(robot, tr.q[first.start], wall, cfg, pairs), 0.0);
  double straight = std::numeric_limits<double>::infinity();
  for (std::size_t k = first.start; k <= first.end; k += 5) straight = std::min(straight, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
  ASSERT_LT(straight, goal_allowance - 0.2);  // the swing goes far deeper than its end

  const double duration_before = tr.duration_s;
  const Eigen::VectorXd goal_q = tr.q[first.end];
  const TransitReport rep = clear_transits(robot, tr, octree, cfg, timing);
  const auto d = std::find_if(rep.detours.begin(), rep.detours.end(), [](const TransitDetour& x) { return x.move == 0; });
  ASSERT_NE(d, rep.detours.end());
  EXPECT_FALSE(d->rerouted);
  ASSERT_TRUE(d->eased) << d->reason;
  EXPECT_NE(d->reason.find("routed with the margins lowered by"), std::string::npos) << d->reason;
  EXPECT_FALSE(d->vias.empty());
  EXPECT_GE(rep.failed, 1);
  const JointMove m = joint_moves(tr).front();
  EXPECT_NEAR(m.duration_s(tr), d->duration_s, 1e-9);
  double worst = std::numeric_limits<double>::infinity();
  for (std::size_t k = m.start; k <= m.end; k += 5) worst = std::min(worst, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
  worst = std::min(worst, brute_allowance(robot, tr.q[m.end], wall, cfg, pairs));
  const double diagonal = std::sqrt(3.0) * cfg.octree_resolution_m;
  std::printf("goal %.3f m, straight %.3f m, routed %.3f m (reported %.3f) short of the margins\n", -goal_allowance, -straight,
              -worst, -d->min_allowance_m);
  EXPECT_GE(worst, goal_allowance - 2.0 * diagonal - 1e-6);
  EXPECT_GT(worst, straight + 0.1);
  EXPECT_GE(worst, d->min_allowance_m - 1e-6);  // the octree reads short, never long
  TimedTrajectory new_move;
  for (std::size_t k = m.start; k <= m.end; ++k) new_move.t_s.push_back(tr.t_s[k]), new_move.q.push_back(tr.q[k]);
  const int via_below = check_clearance_octree(robot, new_move, octree, cfg).moving_samples_below_margin();
  EXPECT_LT(via_below, d->straight_samples_below);
  for (std::size_t k = m.start + 1; k <= m.end; ++k) {
    ASSERT_TRUE(robot.within_limits(tr.q[k], 1e-9));
    EXPECT_LE(tr.qd[k].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff(), 1.0 + 1e-6);
  }
  EXPECT_NEAR(tr.duration_s, duration_before + rep.detour_time_s, 1e-9);
  // The goal's posture is the region's own: unchanged.
  EXPECT_LT((tr.q[m.end] - goal_q).norm(), 1e-12);
  // The sampled planner on (the default): the move is eased by whichever route breaks the margins
  // proper at fewer link-samples, so never more than the via route's; by brute-force distances
  // it keeps within the goal's shortfall and the octree's two readings, like the via route.
  {
    TimedTrajectory sampled = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
    const ClearanceConfig on;
    ASSERT_GT(on.sampled_route_nodes, 0);
    const TransitReport rs = clear_transits(robot, sampled, octree, on, timing);
    const auto ds = std::find_if(rs.detours.begin(), rs.detours.end(), [](const TransitDetour& x) { return x.move == 0; });
    ASSERT_NE(ds, rs.detours.end());
    ASSERT_TRUE(ds->eased) << ds->reason;
    EXPECT_FALSE(ds->rerouted);
    EXPECT_GT(ds->sampled_nodes, 0);
    const JointMove ms = joint_moves(sampled).front();
    TimedTrajectory move_s;
    double worst_s = std::numeric_limits<double>::infinity();
    for (std::size_t k = ms.start; k <= ms.end; ++k) {
      move_s.t_s.push_back(sampled.t_s[k]), move_s.q.push_back(sampled.q[k]);
      if ((k - ms.start) % 5 == 0 || k == ms.end) worst_s = std::min(worst_s, brute_allowance(robot, sampled.q[k], wall, cfg, pairs));
    }
    const int sampled_below = check_clearance_octree(robot, move_s, octree, cfg).moving_samples_below_margin();
    std::printf("with the sampled planner: %d link-samples below (the via route %d), %.3f m short; %s\n", sampled_below,
                via_below, -worst_s, ds->reason.c_str());
    EXPECT_LE(sampled_below, via_below);
    EXPECT_GE(worst_s, goal_allowance - 2.0 * diagonal - 1e-6);
    EXPECT_LT((sampled.q[ms.end] - goal_q).norm(), 1e-12);
  }
  // With re-routing off the move stays as it was, and the reason says so.
  TimedTrajectory plain = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  ClearanceConfig off = cfg;
  off.reroute_transits = false;
  const TransitReport kept = clear_transits(robot, plain, octree, off, timing);
  const auto k = std::find_if(kept.detours.begin(), kept.detours.end(), [](const TransitDetour& x) { return x.move == 0; });
  ASSERT_NE(k, kept.detours.end());
  EXPECT_FALSE(k->eased || k->rerouted);
  EXPECT_EQ(k->duration_s, k->straight_duration_s);
  EXPECT_NE(k->reason.find("clearance.reroute_transits is off"), std::string::npos) << k->reason;
}

// The wall of the narrow bay with a face across the axis at x = x_face (points every ~4 cm).
Points wall_and_face(double x_face) {
  const Points wall = wall_with_protrusion(-0.6, x_face, 0.0, 0.0, 0.0, 0.8);
  std::vector<Eigen::Vector3d> face;
  for (double y = -kR; y <= kR; y += 0.04)
    for (double z = 0.0; z <= kR; z += 0.04)
      if (std::hypot(y, z) < kR) face.emplace_back(x_face, y, z);
  Points p(wall.rows() + static_cast<Eigen::Index>(face.size()), 3);
  p.topRows(wall.rows()) = wall;
  for (std::size_t k = 0; k < face.size(); ++k) p.row(wall.rows() + static_cast<Eigen::Index>(k)) = face[k].transpose();
  return p;
}

TEST(Transit, StartPostureKeepsAClearStowAndLeavesOneInTheFace) {
  const Robot robot = Robot::load(RobotConfig{});
  const ClearanceConfig cfg;
  const auto pairs = self_check_pairs(robot);
  // Without the face the stow posture keeps its margins: it is the start, nothing searched.
  const Points open = wall_and_face(6.0);
  ASSERT_GE(brute_allowance(robot, robot.stow(), open, cfg, pairs), 0.0);
  const StartPosture same = start_posture(robot, robot.stow(), WallOctree(open, cfg.octree_resolution_m), cfg);
  EXPECT_FALSE(same.moved);
  EXPECT_EQ(same.q, robot.stow());
  EXPECT_EQ(same.optimisations, 0);
  EXPECT_GE(same.allowance_m, 0.0);
  // A face 1.4 m ahead of the base: the stow posture's boom points into it.
  const Points closed = wall_and_face(2.0);
  ASSERT_LT(brute_allowance(robot, robot.stow(), closed, cfg, pairs), 0.0);
  const StartPosture sp = start_posture(robot, robot.stow(), WallOctree(closed, cfg.octree_resolution_m), cfg);
  ASSERT_TRUE(sp.moved);
  EXPECT_LT(sp.preferred_allowance_m, 0.0);
  EXPECT_GE(sp.allowance_m, 0.0);
  EXPECT_TRUE(robot.within_limits(sp.q));
  // The brute-force distances agree: clear, and the octree's reading is never more than that.
  const double exact = brute_allowance(robot, sp.q, closed, cfg, pairs);
  EXPECT_GE(exact, 0.0);
  EXPECT_LE(sp.allowance_m, exact + 1e-6);
  EXPECT_EQ(sp.preferred, robot.stow());
}

// A rock over the crown where the move from the stow posture swings (0.6 m past the nozzle's room
// above its margin, radius 0.8 m): no via keeps every margin, so no via route clears that move
// (the sampled planner, which may, is off here: AMoveNoViaRouteClearsIsSampledClear).
// The straight swing comes 0.4 m short of a margin (a link wholly in the rock); the route through
// the via with the fewest link-samples below a margin replaces it all the same ("eased", still counted as
// failed; fewer link-samples below a margin). Independently, every fifth sample of the new move by
// the brute-force distances to the wall's points: never nearer than the route's reported
// allowance (the octree reads short, never long), and less short than the straight move; the
// move within the joint limits, and the time it costs reported.
TEST(Transit, AMoveNoRouteClearsIsEasedThroughItsBestRoute) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  ClearanceConfig cfg;
  cfg.sampled_route_nodes = 0;
  TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const auto moves = joint_moves(tr);
  const Points wall = rock_over_the_crown(tr, cfg);
  ASSERT_GT(wall.rows(), 0);
  const WallOctree octree(wall, cfg.octree_resolution_m);
  const auto pairs = self_check_pairs(robot);
  const JointMove first = moves.front();
  double straight = std::numeric_limits<double>::infinity();
  for (std::size_t k = first.start; k <= first.end; k += 5) straight = std::min(straight, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
  const double duration_before = tr.duration_s;
  const TransitReport rep = clear_transits(robot, tr, octree, cfg, timing);
  const auto d = std::find_if(rep.detours.begin(), rep.detours.end(), [](const TransitDetour& x) { return x.move == 0; });
  ASSERT_NE(d, rep.detours.end());
  EXPECT_FALSE(d->rerouted);
  ASSERT_TRUE(d->eased) << d->reason;
  EXPECT_EQ(rep.rerouted, 0);
  EXPECT_EQ(rep.failed, static_cast<int>(rep.detours.size()));
  EXPECT_LT(d->min_allowance_m, 0.0);
  EXPECT_GT(d->min_allowance_m, d->straight_min_allowance_m);  // here also less short (not the rule's)
  EXPECT_FALSE(d->vias.empty());
  EXPECT_NE(d->reason.find("replaced the move"), std::string::npos);
  const JointMove m = joint_moves(tr).front();
  EXPECT_NEAR(m.duration_s(tr), d->duration_s, 1e-9);
  double worst = std::numeric_limits<double>::infinity();
  for (std::size_t k = m.start; k <= m.end; k += 5) worst = std::min(worst, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
  worst = std::min(worst, brute_allowance(robot, tr.q[m.end], wall, cfg, pairs));
  std::printf("straight %.3f m, eased route %.3f m (reported %.3f) short of the margins\n", -straight, -worst, -d->min_allowance_m);
  EXPECT_GE(worst, d->min_allowance_m - 1e-6);
  EXPECT_GT(worst, straight);
  // Fewer link-samples below a margin than the straight move, by the octree's readings as the
  // router counted them.
  TimedTrajectory new_move;
  for (std::size_t k = m.start; k <= m.end; ++k) new_move.t_s.push_back(tr.t_s[k]), new_move.q.push_back(tr.q[k]);
  EXPECT_LT(check_clearance_octree(robot, new_move, octree, cfg).moving_samples_below_margin(), d->straight_samples_below);
  for (std::size_t k = m.start + 1; k <= m.end; ++k) {
    ASSERT_TRUE(robot.within_limits(tr.q[k], 1e-9));
    EXPECT_LE(tr.qd[k].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff(), 1.0 + 1e-6);
  }
  EXPECT_NEAR(tr.duration_s, duration_before + rep.detour_time_s, 1e-9);
}

// The same rock with the sampled planner on (the default): where no via route clears the move
// from the stow posture, the joint-space RRT-Connect finds one that does. Independently, every
// sample of the new move by the brute-force distances to the wall's points keeps every margin
// (the octree reads short, never long); within the joint limits; its vias are the route's
// postures; the trajectory grew by the time reported. With a budget too small, not re-routed.
TEST(Transit, AMoveNoViaRouteClearsIsSampledClear) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig timing;
  const ClearanceConfig cfg;
  ASSERT_GT(cfg.sampled_route_nodes, 0);
  TimedTrajectory tr = time_plan(robot, two_regions(), robot.stow(), timing, RobotConfig{});
  const TimedTrajectory untouched = tr;
  const auto moves = joint_moves(tr);
  const Points wall = rock_over_the_crown(tr, cfg);
  ASSERT_GT(wall.rows(), 0);
  const WallOctree octree(wall, cfg.octree_resolution_m);
  const auto pairs = self_check_pairs(robot);
  const double duration_before = tr.duration_s;
  const TransitReport rep = clear_transits(robot, tr, octree, cfg, timing);
  const auto d = std::find_if(rep.detours.begin(), rep.detours.end(), [](const TransitDetour& x) { return x.move == 0; });
  ASSERT_NE(d, rep.detours.end());
  ASSERT_TRUE(d->rerouted) << d->reason;
  EXPECT_GT(d->sampled_nodes, 0);  // the via routes failed first
  EXPECT_GE(d->min_allowance_m, 0.0);
  ASSERT_FALSE(d->vias.empty());
  const JointMove m = joint_moves(tr).front();
  EXPECT_NEAR(m.duration_s(tr), d->duration_s, 1e-9);
  double worst = std::numeric_limits<double>::infinity();
  for (std::size_t k = m.start; k <= m.end; ++k) {
    worst = std::min(worst, brute_allowance(robot, tr.q[k], wall, cfg, pairs));
    if (k > m.start) {
      ASSERT_TRUE(robot.within_limits(tr.q[k], 1e-9));
      EXPECT_LE(tr.qd[k].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff(), 1.0 + 1e-6);
    }
  }
  std::printf("sampled route: %zu vias, %d nodes, %.1f s (straight %.1f s), least allowance %.3f m (reported %.3f)\n",
              d->vias.size(), d->sampled_nodes, d->duration_s, d->straight_duration_s, worst, d->min_allowance_m);
  EXPECT_GE(worst, d->min_allowance_m - 1e-6);
  EXPECT_GE(worst, 0.0);
  // Every via is passed through, in order.
  std::size_t next = 0;
  for (std::size_t k = m.start; k <= m.end && next < d->vias.size(); ++k)
    if ((tr.q[k] - d->vias[next]).norm() < 1e-9) ++next;
  EXPECT_EQ(next, d->vias.size());
  EXPECT_NEAR(tr.duration_s, duration_before + rep.detour_time_s, 1e-9);
  // A budget too small to find it: not re-routed; the trees stop near it (a connect step may
  // overshoot by the postures on its way, at most the arm's reach in 0.1 m steps).
  ClearanceConfig small = cfg;
  small.sampled_route_nodes = 20;
  TimedTrajectory poor = untouched;
  const TransitReport rep3 = clear_transits(robot, poor, octree, small, timing);
  const auto d3 = std::find_if(rep3.detours.begin(), rep3.detours.end(), [](const TransitDetour& x) { return x.move == 0; });
  ASSERT_NE(d3, rep3.detours.end());
  EXPECT_FALSE(d3->rerouted);
  EXPECT_GE(d3->sampled_nodes, 1);
  EXPECT_LT(d3->sampled_nodes, 20 + 200);
}

// The base 0.6 m from a face (the default base, face at x = 1.2): at slew 0 the boom's root, its
// lift pivot 0.3 m ahead of the slew axis, lies on the boom's shape, so no posture keeps the boom
// more than F - x_base - 0.3 from the face: the arm cannot turn through the face with
// via_allowance_m of room unless x_base <= F - 0.3 - link_margin_m - via_allowance_m (closed form,
// up to the slack). place_base moves the base back along the axis to a place with that room at
// every slew direction; the roomiest posture of its worst direction keeps it by brute-force
// distances to the points. Without the face the base stays; with no shift allowed it stays, not
// found; boxed in between the face and a wall behind, it stays, not carried through either.
TEST(Transit, TheBaseStandsBackFromAFaceUntilTheArmCanSlewEveryWay) {
  const Robot robot = Robot::load(RobotConfig{});
  const ClearanceConfig cfg;
  const double need = cfg.via_allowance_m - kSwingRoomSlack_m;
  const double x_face = 1.2;
  const Points closed = wall_and_face(x_face);
  const WallOctree wall(closed, cfg.octree_resolution_m);
  const Eigen::Vector3d along(1.0, 0.0, 0.0);
  ASSERT_GT(robot.base_pose().translation().x(), x_face - 0.3 - cfg.link_margin_m - need);
  const BasePlacement b = place_base(robot, wall, along, cfg, 1.5);
  EXPECT_TRUE(b.found);
  ASSERT_TRUE(b.moved);
  EXPECT_LT(b.configured_room_m, need);
  EXPECT_GT(std::cos(b.configured_short_slew_rad), 0.5) << "on the face's side";
  EXPECT_LT(b.shift_m, 0.0);
  EXPECT_NEAR(std::fmod(std::abs(b.shift_m) + 1e-9, kBaseShiftStep_m), 0.0, 1e-6);
  EXPECT_EQ(b.configured_m, robot.base_pose().translation());
  EXPECT_NEAR((b.position_m - b.configured_m - b.shift_m * along).norm(), 0.0, 1e-12);
  EXPECT_LE(b.position_m.x(), x_face - 0.3 - cfg.link_margin_m - need + 1e-9);
  EXPECT_GE(b.room_m, need);
  EXPECT_GE(b.base_room_m, 0.0);
  const Robot placed = robot.placed_at(b.position_m);
  EXPECT_EQ(placed.base_pose().translation(), b.position_m);
  EXPECT_LT((placed.fk(robot.stow()).translation() - robot.fk(robot.stow()).translation() - (b.position_m - b.configured_m)).norm(), 1e-12);
  const SwingRoom room = swing_room(placed, wall, cfg);
  ASSERT_EQ(room.worst_q.size(), robot.dof());
  EXPECT_DOUBLE_EQ(room.worst_q[0], room.worst_slew_rad);
  EXPECT_GE(room.directions, 25);  // every 15 deg over the slew's 2 x 3.05 rad and its two limits
  const double exact = brute_allowance(placed, room.worst_q, closed, cfg, self_check_pairs(placed));
  EXPECT_GE(exact, room.least_m - 1e-6);  // the octree reads short, never long
  EXPECT_GE(exact, need);
  // The place one step nearer the face is short of room (the nearest place was taken).
  const Robot nearer = robot.placed_at(b.position_m - kBaseShiftStep_m * b.shift_m / std::abs(b.shift_m) * along);
  EXPECT_LT(swing_room(nearer, wall, cfg).least_m, need);

  // No face within reach: the configured place has room every way.
  const BasePlacement open = place_base(robot, WallOctree(wall_and_face(6.0), cfg.octree_resolution_m), along, cfg, 1.5);
  EXPECT_TRUE(open.found);
  EXPECT_FALSE(open.moved) ;
  EXPECT_EQ(open.places_tried, 1);
  EXPECT_GE(open.room_m, need);
  // The face, and no shift allowed: it stays, not found.
  const BasePlacement stuck = place_base(robot, wall, along, cfg, 0.0);
  EXPECT_FALSE(stuck.found);
  EXPECT_FALSE(stuck.moved);
  EXPECT_EQ(stuck.position_m, stuck.configured_m);
  // A wall across the tunnel 0.6 m behind the base too (a rig's carrier, floor to crown): no place
  // between the two has room, and the base is never carried through either to the open space
  // beyond them (1.5 m either way would be clear of both; the walls are one point thick).
  std::vector<Eigen::Vector3d> back;
  for (double y = -kR; y <= kR; y += 0.04)
    for (double z = -1.6; z <= kR; z += 0.04)
      if (std::hypot(y, z) < kR) back.emplace_back(0.0, y, z);
  Points boxed(closed.rows() + static_cast<Eigen::Index>(back.size()), 3);
  boxed.topRows(closed.rows()) = closed;
  for (std::size_t k = 0; k < back.size(); ++k) boxed.row(closed.rows() + static_cast<Eigen::Index>(k)) = back[k].transpose();
  const BasePlacement boxed_in = place_base(robot, WallOctree(boxed, cfg.octree_resolution_m), along, cfg, 1.5);
  EXPECT_FALSE(boxed_in.found);
  EXPECT_FALSE(boxed_in.moved);
  EXPECT_EQ(boxed_in.position_m, boxed_in.configured_m);
  EXPECT_LE(boxed_in.places_tried, 1 + 2 * 6);  // the places up to each wall (0.1 m apart), not past them
  EXPECT_THROW(place_base(robot, wall, Eigen::Vector3d::Zero(), cfg, 1.0), std::invalid_argument);
  EXPECT_THROW(place_base(robot, wall, along, cfg, -1.0), std::invalid_argument);
  EXPECT_THROW(place_base(robot, wall, along, cfg, std::numeric_limits<double>::infinity()), std::invalid_argument);
  EXPECT_THROW(swing_room(robot, wall, cfg, 0.0), std::invalid_argument);
}

// The rig's carrier (the URDF's carrier link, fixed to base_link off the chain) in the scan where
// the rig stood: its points are the machine's own (machine_points: its column up to its top, down
// to the ground), checked point by point against the box read from the shape; left in as
// obstacles, the carrier shape stands in them and the base cannot be placed; left out, the base
// is placed as in the scan without the rig (the same place), the carrier moved with it and kept
// base_margin_m from every other point (brute force).
TEST(Transit, TheRigsCarrierInTheScanIsTheMachinesOwnAndMovesWithTheBase) {
  const Robot robot = Robot::load(RobotConfig{});
  const ClearanceConfig cfg;
  const auto& shapes = robot.collision_shapes();
  const std::vector<char> fixed = fixed_shapes(robot);
  int carrier = -1;
  for (std::size_t k = 0; k < shapes.size(); ++k)
    if (shapes[k].carrier) {
      ASSERT_EQ(carrier, -1) << "one carrier shape";
      carrier = static_cast<int>(k);
    }
  ASSERT_GE(carrier, 0);
  const CollisionShape& box = shapes[static_cast<std::size_t>(carrier)];
  EXPECT_EQ(box.link, "carrier");
  EXPECT_EQ(box.kind, CollisionShape::Kind::box);
  EXPECT_EQ(box.frame, 0);
  EXPECT_TRUE(fixed[static_cast<std::size_t>(carrier)]);
  ASSERT_TRUE(box.origin.linear().isIdentity(1e-12));
  const Eigen::Vector3d base = robot.base_pose().translation();
  const Eigen::Vector3d lo = base + box.origin.translation() - 0.5 * box.size_m;  // tunnel frame
  const Eigen::Vector3d hi = base + box.origin.translation() + 0.5 * box.size_m;
  ASSERT_GT(lo.z(), base.z());  // it stops above the base's floor
  const double ground = base.z() - 0.3;  // the invert under the rig, as the generator's scene has it
  // The scan: the narrow bay, its face, the invert, and the rig's carrier down to the invert.
  const Points bay = wall_and_face(1.2);
  std::vector<Eigen::Vector3d> floor, rig;
  for (double x = -6.0; x <= 1.2; x += 0.05)
    for (double y = -3.0; y <= 3.0; y += 0.05) floor.emplace_back(x, y, ground);
  for (double x = lo.x(); x <= hi.x() + 1e-9; x += 0.05)
    for (double y = lo.y(); y <= hi.y() + 1e-9; y += 0.05) rig.emplace_back(x, y, hi.z());
  for (double z = ground; z < hi.z(); z += 0.05) {
    for (double x = lo.x(); x <= hi.x() + 1e-9; x += 0.05) rig.emplace_back(x, lo.y(), z), rig.emplace_back(x, hi.y(), z);
    for (double y = lo.y(); y <= hi.y() + 1e-9; y += 0.05) rig.emplace_back(lo.x(), y, z), rig.emplace_back(hi.x(), y, z);
  }
  // Probes at the tolerance's edges: beside the footprint, above the top.
  const double tol = cfg.carrier_tolerance_m;
  const std::vector<std::pair<Eigen::Vector3d, char>> probes = {
      {{lo.x() - tol + 0.01, 0.0, hi.z()}, 1}, {{lo.x() - tol - 0.01, 0.0, hi.z()}, 0},
      {{-2.0, hi.y() + tol - 0.01, ground + 0.5}, 1}, {{-2.0, hi.y() + tol + 0.01, ground + 0.5}, 0},
      {{-2.0, 0.0, hi.z() + tol - 0.01}, 1}, {{-2.0, 0.0, hi.z() + tol + 0.01}, 0},
      {{-2.0, 0.0, ground - 1.0}, 1}};
  const Eigen::Index n_bay = bay.rows(), n_floor = static_cast<Eigen::Index>(floor.size());
  Points scan(n_bay + n_floor + static_cast<Eigen::Index>(rig.size() + probes.size()), 3);
  scan.topRows(n_bay) = bay;
  Eigen::Index r = n_bay;
  for (const auto& p : floor) scan.row(r++) = p.transpose();
  for (const auto& p : rig) scan.row(r++) = p.transpose();
  for (const auto& p : probes) scan.row(r++) = p.first.transpose();
  const std::vector<char> machine = machine_points(scan, robot, tol);
  ASSERT_EQ(machine.size(), static_cast<std::size_t>(scan.rows()));
  for (Eigen::Index i = 0; i < n_bay; ++i) ASSERT_EQ(machine[static_cast<std::size_t>(i)], 0) << "the bay's wall and face";
  int floor_taken = 0;
  for (Eigen::Index i = 0; i < n_floor; ++i) {
    const Eigen::Vector3d p = scan.row(n_bay + i).transpose();
    const bool under = p.x() >= lo.x() - tol && p.x() <= hi.x() + tol && p.y() >= lo.y() - tol && p.y() <= hi.y() + tol;
    ASSERT_EQ(machine[static_cast<std::size_t>(n_bay + i)], under ? 1 : 0) << p.transpose();
    floor_taken += under;
  }
  EXPECT_GT(floor_taken, 0);
  for (std::size_t k = 0; k < rig.size(); ++k) ASSERT_EQ(machine[static_cast<std::size_t>(n_bay + n_floor) + k], 1) << "the rig";
  for (std::size_t k = 0; k < probes.size(); ++k)
    EXPECT_EQ(machine[machine.size() - probes.size() + k], probes[k].second) << probes[k].first.transpose();
  // Turned with the tunnel's heading (carrier_turned: the job turns it along the axis), the column
  // turns with it: the rig turned the same way about the base is the machine's, the rig as it
  // stood is not, where the two part.
  const double yaw = 0.5;
  const Robot turned = robot.carrier_turned(yaw);
  const Eigen::AngleAxisd turn(yaw, Eigen::Vector3d::UnitZ());
  Points rig_turned(static_cast<Eigen::Index>(rig.size()), 3), rig_as_was(static_cast<Eigen::Index>(rig.size()), 3);
  for (std::size_t k = 0; k < rig.size(); ++k) {
    rig_turned.row(static_cast<Eigen::Index>(k)) = (base + turn * (rig[k] - base)).transpose();
    rig_as_was.row(static_cast<Eigen::Index>(k)) = rig[k].transpose();
  }
  const std::vector<char> on_turned = machine_points(rig_turned, turned, tol);
  EXPECT_EQ(std::count(on_turned.begin(), on_turned.end(), 1), static_cast<long>(rig.size()));
  const std::vector<char> as_was = machine_points(rig_as_was, turned, tol);
  EXPECT_LT(std::count(as_was.begin(), as_was.end(), 1), static_cast<long>(rig.size()) / 2);
  EXPECT_THROW(robot.carrier_turned(std::numeric_limits<double>::infinity()), std::invalid_argument);
  EXPECT_THROW(machine_points(scan, robot, -0.1), std::invalid_argument);
  EXPECT_THROW(machine_points(scan, robot, std::numeric_limits<double>::quiet_NaN()), std::invalid_argument);

  const Eigen::Vector3d along(1.0, 0.0, 0.0);
  // The rig's points as obstacles: the carrier shape stands in them; no place.
  Points with_rig = scan.topRows(n_bay + n_floor + static_cast<Eigen::Index>(rig.size()));
  const BasePlacement stuck = place_base(robot, WallOctree(with_rig, cfg.octree_resolution_m), along, cfg, 1.5);
  EXPECT_LT(stuck.configured_base_room_m, 0.0);
  EXPECT_FALSE(stuck.found);
  EXPECT_FALSE(stuck.moved);
  // The machine's own left out: placed where the scan without the rig places it.
  std::vector<Eigen::Index> kept;
  for (Eigen::Index i = 0; i < with_rig.rows(); ++i)
    if (!machine[static_cast<std::size_t>(i)]) kept.push_back(i);
  Points obstacles(static_cast<Eigen::Index>(kept.size()), 3);
  for (std::size_t k = 0; k < kept.size(); ++k) obstacles.row(static_cast<Eigen::Index>(k)) = with_rig.row(kept[k]);
  Points no_rig(n_bay + n_floor, 3);
  no_rig = scan.topRows(n_bay + n_floor);
  const BasePlacement placed = place_base(robot, WallOctree(obstacles, cfg.octree_resolution_m), along, cfg, 1.5);
  const BasePlacement reference = place_base(robot, WallOctree(no_rig, cfg.octree_resolution_m), along, cfg, 1.5);
  ASSERT_TRUE(reference.found && reference.moved);
  EXPECT_TRUE(placed.found);
  EXPECT_TRUE(placed.moved);
  EXPECT_LT(placed.shift_m, 0.0);
  EXPECT_EQ(placed.position_m, reference.position_m);
  EXPECT_GE(placed.base_room_m, 0.0);
  // The carrier went with the base: at its new place it keeps base_margin_m from every point left.
  const Eigen::Isometry3d at(Eigen::Translation3d(placed.position_m));
  double least = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < obstacles.rows(); ++i)
    least = std::min(least, point_shape_distance(obstacles.row(i).transpose(), box, at));
  EXPECT_GE(least, cfg.base_margin_m);
  std::printf("[carrier] %zu rig points, %d invert points under it; placed %.1f m along (room %.3f m), carrier %.3f m "
              "from the scan; with the rig's points as obstacles: base room %.3f m\n",
              rig.size(), floor_taken, placed.shift_m, placed.room_m, least, stuck.configured_base_room_m);
}
