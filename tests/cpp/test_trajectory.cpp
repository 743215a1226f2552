// Joint-space timing: joint quintics, stop-and-go moves in joint space, bad input, and the speed
// caps learnt from a timed trajectory.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/trajectory.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

using shotcrete::test::axial_region;

TEST(Joint, QuinticMinDurationHitsTheBindingLimit) {
  Eigen::VectorXd q0(3), q1(3), vl(3), al(3);
  q0 << 0.0, 1.0, -0.5;
  q1 << 1.2, 0.8, 0.5;
  vl << 0.5, 1.0, 2.0;
  al << 2.0, 1.0, 0.2;
  const double T = quintic_min_duration(q0, q1, vl, al);
  EXPECT_NEAR(T, std::max({1.875 * 1.2 / 0.5, std::sqrt(10.0 / std::sqrt(3.0) * 1.0 / 0.2)}), 1e-12);
  double rv = 0.0, ra = 0.0;
  Eigen::VectorXd q, qd, qdd;
  for (int i = 0; i <= 10000; ++i) {
    quintic_joint(q0, q1, T, T * i / 10000.0, q, qd, qdd);
    rv = std::max(rv, qd.cwiseAbs().cwiseQuotient(vl).maxCoeff());
    ra = std::max(ra, qdd.cwiseAbs().cwiseQuotient(al).maxCoeff());
  }
  EXPECT_LE(rv, 1.0 + 1e-9);
  EXPECT_LE(ra, 1.0 + 1e-9);
  EXPECT_NEAR(std::max(rv, ra), 1.0, 1e-6);  // minimum: one limit is reached
  quintic_joint(q0, q1, T, T, q, qd, qdd);
  EXPECT_NEAR((q - q1).norm(), 0.0, 1e-12);
  EXPECT_NEAR(qd.norm() + qdd.norm(), 0.0, 1e-12);
}

namespace {
// Worst nozzle speed and acceleration of the quintic q0 -> q1 of duration T (FK on 4000 time steps,
// central differences): a second method beside quintic_nozzle_duration's.
std::pair<double, double> quintic_nozzle_peaks(const Robot& robot, const Eigen::VectorXd& q0, const Eigen::VectorXd& q1,
                                               double T) {
  const int n = 4000;
  const double h = T / n;
  std::vector<Eigen::Vector3d> p;
  Eigen::VectorXd q, qd, qdd;
  for (int k = 0; k <= n; ++k) {
    quintic_joint(q0, q1, T, k * h, q, qd, qdd);
    p.push_back(robot.fk(q).translation());
  }
  double v = 0.0, a = 0.0;
  for (std::size_t k = 1; k + 1 < p.size(); ++k) {
    v = std::max(v, (p[k + 1] - p[k - 1]).norm() / (2.0 * h));
    a = std::max(a, (p[k + 1] - 2.0 * p[k] + p[k - 1]).norm() / (h * h));
  }
  return {v, a};
}
}  // namespace

TEST(Joint, QuinticNozzleDurationStretchesFarMovesOnly) {
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig tc;  // 1 m/s, 2 m/s^2
  const Eigen::VectorXd lo = robot.lower_limits(), hi = robot.upper_limits();
  const Eigen::VectorXd q0 = lo + 0.2 * (hi - lo), q1 = lo + 0.8 * (hi - lo);
  const double t_joint = quintic_min_duration(q0, q1, robot.velocity_limits(), robot.acceleration_limits());
  const auto [v_joint, a_joint] = quintic_nozzle_peaks(robot, q0, q1, t_joint);
  ASSERT_GT(std::max(v_joint / tc.nozzle_max_speed_mps, a_joint / tc.nozzle_max_accel_mps2), 1.2)
      << "the far move keeps the nozzle within its limits at the joint-minimal duration: no test";
  const double T = quintic_nozzle_duration(robot, q0, q1, tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2);
  const auto [v, a] = quintic_nozzle_peaks(robot, q0, q1, T);
  EXPECT_LE(v, tc.nozzle_max_speed_mps);
  EXPECT_LE(a, tc.nozzle_max_accel_mps2);
  // No longer than needed: one limit is reached within the margin.
  EXPECT_GT(std::max(v / tc.nozzle_max_speed_mps, a / tc.nozzle_max_accel_mps2), 0.97);
  // A short move stays at the joint-minimal duration.
  const Eigen::VectorXd q2 = q0 + 0.01 * (hi - lo);
  const double t_short = quintic_min_duration(q0, q2, robot.velocity_limits(), robot.acceleration_limits());
  const auto [v_short, a_short] = quintic_nozzle_peaks(robot, q0, q2, t_short);
  ASSERT_LT(std::max(v_short / tc.nozzle_max_speed_mps, a_short / tc.nozzle_max_accel_mps2), 0.9);
  EXPECT_EQ(quintic_nozzle_duration(robot, q0, q2, tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2), t_short);
  EXPECT_EQ(quintic_nozzle_duration(robot, q0, q0, tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2), 0.0);
  EXPECT_THROW(quintic_nozzle_duration(robot, q0, q1, 0.0, 2.0), std::invalid_argument);
}

TEST(RobotTiming, CycleTimeBreakdownAddsUpAndMatchesTheSamples) {
  // Two regions: a transit to each, turn-arounds and leads in the first, a stop-and-go move in the
  // second. The exact breakdown adds up to the duration; the per-sample attribution (each interval
  // to the kind of the sample ending it) is a second method that differs by at most a sample
  // interval at each piece boundary.
  const auto first = axial_region(3, 1.0, 0.2, 0.0, 1.2, {0.2, 0.25, 0.15});
  auto second = axial_region(2, 1.0, 0.3, 0.3, 1.6, {0.2});
  std::reverse(second[1].waypoints.begin(), second[1].waypoints.end());  // same heading: stop and go
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig tc;
  const TimedTrajectory tr = time_plan(robot, {first, second}, robot.neutral(), tc, RobotConfig{});
  const CycleTimeBreakdown& b = tr.cycle_time;
  EXPECT_NEAR(b.total_s(), tr.duration_s, 1e-9 * tr.duration_s);
  EXPECT_NEAR(tr.t_s.back(), tr.duration_s, 1e-9 * tr.duration_s);
  EXPECT_EQ(b.spraying_s, tr.spray_time_s);
  EXPECT_GT(b.turn_arounds_s, 0.0);
  EXPECT_GT(b.leads_s, 0.0);
  EXPECT_GT(b.transits_s, 0.0);
  EXPECT_GT(b.stop_and_go_s, 0.0);
  EXPECT_EQ(b.other_s, 0.0);
  // Per sample: joint moves between regions exactly, spraying and the rest up to the boundaries.
  double spraying = 0.0, transits = 0.0, joint_moves_inside = 0.0, rest = 0.0;
  int boundaries = 0;
  for (std::size_t i = 1; i < tr.size(); ++i) {
    const double dt = tr.t_s[i] - tr.t_s[i - 1];
    const bool joint_move = tr.kind[i] == static_cast<char>(SegmentKind::Transit);
    if (tr.spraying[i]) spraying += dt;
    else if (joint_move && tr.region_index[i] < 0) transits += dt;
    else if (joint_move) joint_moves_inside += dt;
    else rest += dt;
    boundaries += tr.kind[i] != tr.kind[i - 1] || tr.spraying[i] != tr.spraying[i - 1];
  }
  const double slack = boundaries / tc.trajectory_rate_hz;
  EXPECT_NEAR(transits, b.transits_s, 1e-9);
  EXPECT_NEAR(spraying, b.spraying_s, slack);
  EXPECT_GT(b.stop_and_go_s, joint_moves_inside);  // the stop-and-go runs besides the joint move
  EXPECT_NEAR(rest + joint_moves_inside, b.turn_arounds_s + b.leads_s + b.stop_and_go_s, slack);
}

// Central differences on a non-uniform grid (second order), written here: the reference of the
// limit check after slow_to_joint_limits. Worst |qd| / limit and |qdd| / limit over the interior.
std::pair<double, double> worst_rates(const Robot& robot, const std::vector<double>& t, const std::vector<Eigen::VectorXd>& q) {
  double v = 0.0, a = 0.0;
  for (std::size_t i = 1; i + 1 < t.size(); ++i) {
    const double h1 = t[i] - t[i - 1], h2 = t[i + 1] - t[i];
    const Eigen::VectorXd d1 = (q[i] - q[i - 1]) / h1, d2 = (q[i + 1] - q[i]) / h2;
    const Eigen::VectorXd qd = (h2 * d1 + h1 * d2) / (h1 + h2);  // the parabola's slope at t[i]
    const Eigen::VectorXd qdd = 2.0 * (d2 - d1) / (h1 + h2);
    v = std::max(v, qd.cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff());
    a = std::max(a, qdd.cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff());
  }
  return {v, a};
}

// The slew at twice its velocity limit the whole 4 s (no acceleration: a straight joint line):
// every interval needs 2 x 1.005 (the headroom), so one round doubles the time exactly, closed
// form 8.04 s, and the velocity is then the limit / 1.005. Bad input is refused by name.
TEST(RobotTiming, SlowToJointLimitsClosedFormOfAConstantSpeed) {
  const Robot robot = Robot::load(RobotConfig{});
  const double v = 2.0 * robot.velocity_limits()[0];
  TimedTrajectory tr;
  for (int k = 0; k <= 200; ++k) {
    const double t = 0.02 * k;
    Eigen::VectorXd q = robot.neutral();
    q[0] = -0.5 * v * 4.0 + v * t;
    tr.t_s.push_back(t), tr.q.push_back(q);
  }
  tr.duration_s = 4.0;
  const TimedTrajectory before = tr;
  EXPECT_TRUE(slow_to_joint_limits(robot, tr));
  EXPECT_NEAR(tr.ratio_before_slowing, 2.0, 1e-9);
  EXPECT_NEAR(tr.duration_s, 4.0 * 2.0 * 1.005, 1e-9);
  EXPECT_NEAR(tr.t_s.back(), tr.duration_s, 1e-9);
  EXPECT_NEAR(tr.slowed_s, tr.duration_s - 4.0, 1e-9);
  EXPECT_EQ(tr.slowed_intervals, 200);
  EXPECT_NEAR(tr.cycle_time.other_s, tr.slowed_s, 1e-9);  // no flags: nothing tells the bucket
  EXPECT_NEAR(worst_rates(robot, tr.t_s, tr.q).first, 1.0 / 1.005, 1e-9);
  for (std::size_t k = 0; k < tr.size(); ++k) EXPECT_EQ(tr.q[k], before.q[k]);
  EXPECT_THROW(slow_to_joint_limits(robot, tr, 0.0), std::invalid_argument);
  TimedTrajectory bad = before;
  bad.t_s[7] = bad.t_s[5];  // back in time
  EXPECT_THROW(slow_to_joint_limits(robot, bad), std::invalid_argument);
  bad = before;
  bad.t_s[3] = std::nan("");
  EXPECT_THROW(slow_to_joint_limits(robot, bad), std::invalid_argument);
  bad = before;
  bad.q[4] = Eigen::VectorXd::Zero(3);
  EXPECT_THROW(slow_to_joint_limits(robot, bad), std::invalid_argument);
  bad = before;
  bad.q.pop_back();
  EXPECT_THROW(slow_to_joint_limits(robot, bad), std::invalid_argument);
}

// The windows, against a brute force written here: the slew at rest for 20 s but for one cosine
// bump of 0.4 s at t = 10 s whose peak acceleration is 4x its limit (velocity within it). Per
// interval the need (1.005 max(velocity ratio, sqrt(acceleration ratio)) of its two samples, by
// this test's central differences, where over 1), the largest within +-w of its midpoint, the mean
// of those within +-w: each interval's length times that factor gives times within the limits
// after one round, and the core's times equal them. So every interval farther than the needs'
// reach plus 2 w keeps its length; the factor is symmetric about the bump (w = 1.01 s: no tie with
// the 20 ms samples) and never rises away from it; the stretched intervals are counted.
TEST(RobotTiming, SlowToJointLimitsWindowsAroundOneBump) {
  const Robot robot = Robot::load(RobotConfig{});
  const double T = 0.4, t_c = 10.0, a_peak = 4.0 * robot.acceleration_limits()[0];
  // q = A (1 - cos(2 pi (t - t0) / T)) on the bump: peak acceleration A (2 pi / T)^2.
  const double A = a_peak / std::pow(2.0 * M_PI / T, 2);
  TimedTrajectory tr;
  for (int k = 0; k <= 1000; ++k) {
    const double t = 0.02 * k, u = t - (t_c - 0.5 * T);
    Eigen::VectorXd q = robot.neutral();
    if (u > 0.0 && u < T) q[0] += A * (1.0 - std::cos(2.0 * M_PI * u / T));
    tr.t_s.push_back(t), tr.q.push_back(q);
  }
  tr.duration_s = 20.0;
  ASSERT_GT(worst_rates(robot, tr.t_s, tr.q).second, 3.5);
  ASSERT_LT(worst_rates(robot, tr.t_s, tr.q).first, 1.0);
  const TimedTrajectory before = tr;
  const double w = 1.01;
  // The brute force.
  const std::size_t n = tr.size();
  std::vector<double> need(n, 1.0);
  for (std::size_t i = 1; i + 1 < n; ++i) {
    const std::vector<double> t3{tr.t_s[i - 1], tr.t_s[i], tr.t_s[i + 1]};
    const std::vector<Eigen::VectorXd> q3{tr.q[i - 1], tr.q[i], tr.q[i + 1]};
    const auto [rv, ra] = worst_rates(robot, t3, q3);
    const double s = std::max(rv, std::sqrt(ra));
    need[i] = s > 1.0 ? 1.005 * s : 1.0;
  }
  std::vector<double> mid(n, 0.0), interval(n, 1.0), widest(n, 1.0), factor(n, 1.0), t_ref(n, 0.0);
  for (std::size_t k = 1; k < n; ++k) mid[k] = 0.5 * (tr.t_s[k - 1] + tr.t_s[k]), interval[k] = std::max(need[k - 1], need[k]);
  for (std::size_t k = 1; k < n; ++k)
    for (std::size_t j = 1; j < n; ++j)
      if (std::abs(mid[j] - mid[k]) <= w) widest[k] = std::max(widest[k], interval[j]);
  double reach = 0.0;  // of the needs from the bump's centre
  for (std::size_t k = 1; k < n; ++k) {
    double sum = 0.0;
    int count = 0;
    for (std::size_t j = 1; j < n; ++j)
      if (std::abs(mid[j] - mid[k]) <= w) sum += widest[j], ++count;
    factor[k] = std::max(1.0, sum / count);
    t_ref[k] = t_ref[k - 1] + factor[k] * (tr.t_s[k] - tr.t_s[k - 1]);
    if (interval[k] > 1.0) reach = std::max(reach, std::abs(mid[k] - t_c));
  }
  ASSERT_LE(worst_rates(robot, t_ref, tr.q).second, 1.0);  // one round is enough
  ASSERT_LE(worst_rates(robot, t_ref, tr.q).first, 1.0);
  ASSERT_TRUE(slow_to_joint_limits(robot, tr, w));
  int stretched = 0;
  for (std::size_t k = 1; k < n; ++k) {
    EXPECT_NEAR(tr.t_s[k], t_ref[k], 1e-9) << "sample " << k;
    if (std::abs(mid[k] - t_c) > reach + 2 * w) {
      EXPECT_NEAR(factor[k], 1.0, 1e-12) << "interval " << k;
    }
    stretched += factor[k] > 1.0 + 1e-12;
    const std::size_t mirror = n - k;  // the interval the same distance the other side
    EXPECT_NEAR(factor[k], factor[mirror], 1e-9) << "interval " << k;
    if (mid[k] > t_c && k + 1 < n) {
      EXPECT_LE(factor[k + 1], factor[k] + 1e-12);
    }
  }
  EXPECT_GT(stretched, 0);
  EXPECT_EQ(tr.slowed_intervals, stretched);
  EXPECT_NEAR(tr.duration_s - before.duration_s, tr.slowed_s, 1e-9);
  EXPECT_NEAR(tr.duration_s, t_ref.back(), 1e-9);
}

// A real trajectory (two regions: transits, turn-arounds, leads, a stop-and-go move) run 1 / 0.7
// times too fast (measured: velocities 1.37x, accelerations 1.53x the limits). Slowed: within
// every limit by central differences written in the test, the same joint samples and flags in
// the same order, no interval shorter; the added time in duration_s, slowed_s and the buckets
// (which still add up to it), the transits' share exactly that of their samples' intervals,
// spraying's in spray_time_s too. The trajectory at its own speed is within its limits and left
// as it is, to the bit.
TEST(RobotTiming, SlowToJointLimitsStretchesTimeWhereALimitBreaks) {
  const auto first = axial_region(3, 1.0, 0.2, 0.0, 1.2, {0.2, 0.25, 0.15});
  auto second = axial_region(2, 1.0, 0.3, 0.3, 1.6, {0.2});
  std::reverse(second[1].waypoints.begin(), second[1].waypoints.end());  // same heading: stop and go
  const Robot robot = Robot::load(RobotConfig{});
  const TimedTrajectory own = time_plan(robot, {first, second}, robot.neutral(), TimingConfig{}, RobotConfig{});
  ASSERT_LE(std::max(own.max_velocity_ratio, own.max_acceleration_ratio), 1.0);
  TimedTrajectory same = own;
  EXPECT_TRUE(slow_to_joint_limits(robot, same));
  EXPECT_EQ(same.t_s, own.t_s);
  EXPECT_EQ(same.slowed_s, 0.0);
  EXPECT_EQ(same.slowed_intervals, 0);
  EXPECT_EQ(same.duration_s, own.duration_s);

  constexpr double c = 0.7;
  TimedTrajectory fast = own;
  for (double& t : fast.t_s) t *= c;
  fast.duration_s *= c, fast.spray_time_s *= c, fast.transit_time_s *= c;
  for (double* b : {&fast.cycle_time.spraying_s, &fast.cycle_time.turn_arounds_s, &fast.cycle_time.leads_s,
                    &fast.cycle_time.transits_s, &fast.cycle_time.stop_and_go_s, &fast.cycle_time.other_s})
    *b *= c;
  const auto [v_fast, a_fast] = worst_rates(robot, fast.t_s, fast.q);
  ASSERT_GT(a_fast, 1.5);
  TimedTrajectory slowed = fast;
  ASSERT_TRUE(slow_to_joint_limits(robot, slowed));
  EXPECT_NEAR(slowed.ratio_before_slowing, std::max(v_fast, a_fast), 0.05);
  const auto [v, a] = worst_rates(robot, slowed.t_s, slowed.q);
  EXPECT_LE(v, 1.0 + 1e-9);
  EXPECT_LE(a, 1.0 + 1e-9);
  ASSERT_EQ(slowed.size(), fast.size());
  double transits_added = 0.0, spraying_added = 0.0;
  for (std::size_t k = 0; k < slowed.size(); ++k) {
    ASSERT_EQ(slowed.q[k], fast.q[k]);
    ASSERT_EQ(slowed.kind[k], fast.kind[k]);
    ASSERT_EQ(slowed.spraying[k], fast.spraying[k]);
    if (k == 0) continue;
    const double dt = slowed.t_s[k] - slowed.t_s[k - 1], dt_fast = fast.t_s[k] - fast.t_s[k - 1];
    ASSERT_GE(dt, dt_fast - 1e-12);
    const bool joint_move = fast.kind[k] == static_cast<char>(SegmentKind::Transit);
    if (joint_move && fast.region_index[k] < 0) transits_added += dt - dt_fast;
    if (fast.spraying[k]) spraying_added += dt - dt_fast;
  }
  const double added = slowed.duration_s - fast.duration_s;
  EXPECT_GT(added, 0.0);
  EXPECT_NEAR(slowed.slowed_s, added, 1e-9);
  EXPECT_NEAR(slowed.t_s.back() - slowed.t_s.front(), slowed.duration_s, 1e-9);
  EXPECT_NEAR(slowed.cycle_time.total_s(), slowed.duration_s, 1e-9);
  EXPECT_NEAR(slowed.cycle_time.transits_s - fast.cycle_time.transits_s, transits_added, 1e-9);
  EXPECT_NEAR(slowed.cycle_time.spraying_s - fast.cycle_time.spraying_s, spraying_added, 1e-9);
  EXPECT_NEAR(slowed.spray_time_s - fast.spray_time_s, spraying_added, 1e-9);
  EXPECT_NEAR(slowed.slowed_spraying_s, spraying_added, 1e-9);
  EXPECT_GT(slowed.slowed_intervals, 0);
  std::printf("0.7x too fast (%.2fx velocity, %.2fx acceleration): %.1f s -> %.1f s (own speed %.1f s), %d intervals\n",
              v_fast, a_fast, fast.duration_s, slowed.duration_s, own.duration_s, slowed.slowed_intervals);
}

TEST(RobotTiming, StopAndGoMovesHappenInJointSpace) {
  // Two axial passes both heading +x on neighbouring lines: stop-and-go between them. The move
  // from the run-out's end to the run-in's start is a joint quintic at the limits (kind Transit
  // inside the region), not a straight nozzle line.
  auto passes = axial_region(2, 1.0, 0.3, 0.0, 1.2, {0.2});
  std::reverse(passes[1].waypoints.begin(), passes[1].waypoints.end());
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig tc;
  const TimedTrajectory tr = time_plan(robot, {passes}, robot.neutral(), tc, RobotConfig{});
  EXPECT_EQ(tr.untracked_regions, 0);
  std::size_t first = tr.size(), last = 0;
  for (std::size_t i = 0; i < tr.size(); ++i)
    if (tr.kind[i] == static_cast<char>(SegmentKind::Transit) && tr.region_index[i] == 0)
      first = std::min(first, i), last = std::max(last, i);
  ASSERT_LT(first, last) << "no joint-space move inside the region";
  // At rest at both ends; its duration is the minimal quintic between them.
  const Eigen::VectorXd& q0 = tr.q[first - 1];
  const Eigen::VectorXd& q1 = tr.q[last];
  const double T = quintic_nozzle_duration(robot, q0, q1, tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2);
  EXPECT_GE(T, quintic_min_duration(q0, q1, robot.velocity_limits(), robot.acceleration_limits()));
  EXPECT_NEAR(tr.t_s[last] - tr.t_s[first - 1], T, 1e-9);
  for (std::size_t i = first; i <= last; ++i) {
    Eigen::VectorXd q, qd, qdd;
    quintic_joint(q0, q1, T, tr.t_s[i] - tr.t_s[first - 1], q, qd, qdd);
    ASSERT_LT((q - tr.q[i]).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_LE(tr.max_velocity_ratio, 1.0 + 1e-3);
  EXPECT_LE(tr.max_acceleration_ratio, 1.03);
}

// Turn-arounds at their own speed (timing.turn_speed_mps) over a joint limit that no easing
// removes are timed at the passes' speeds as well, each is slowed to the limits
// (slow_to_joint_limits, as plan_for_arm does), and the one that then ends sooner is kept. Arms
// whose joints are 5x / 50x slower than the bundled one's (the 0.28 m/s arcs between 0.05 m/s
// passes break their velocity limits): at 5x, slowing the fast turns costs less than turning at
// the passes' speeds (the face scene's left wall: 1.04x in one join against 42 turns of 6-17 s);
// at 50x, with every turn slowed 10x, the passes' speeds win. On the bundled arm the region keeps
// its fast turns, within the limits.
TEST(RobotTiming, OwnSpeedTurnsOverALimitAreKeptWhenSlowingThemCostsLessThanThePassSpeeds) {
  std::ifstream in(std::string(SHOTCRETE_DATA_DIR) + "/shotcrete_manipulator.urdf");
  std::stringstream text;
  text << in.rdbuf();
  const std::string urdf = text.str();
  auto slowed_urdf = [&](double factor) {
    std::string out;
    const std::regex velocity(R"re(velocity="([0-9][0-9.]*)")re");
    auto last = urdf.cbegin();
    for (std::sregex_iterator it(urdf.begin(), urdf.end(), velocity), end; it != end; ++it) {
      out.append(last, (*it)[0].first);
      out += "velocity=\"" + std::to_string(factor * std::stod((*it)[1].str())) + "\"";
      last = (*it)[0].second;
    }
    out.append(last, urdf.cend());
    return out;
  };
  const Eigen::Vector3d base = RobotConfig{}.base_position_m;
  const auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.2, {0.05});
  TimingConfig fast;
  fast.turn_speed_mps = 0.5;
  fast.turn_accel_mps2 = 1.0;
  TimingConfig slow = fast;
  slow.turn_speed_mps = 0.0;
  slow.turn_accel_mps2 = 0.0;
  auto fastest_turn_mps = [](const TimedTrajectory& tr) {
    double v = 0.0;
    for (std::size_t i = 1; i < tr.size(); ++i)
      if (tr.kind[i] == static_cast<char>(SegmentKind::Turn))
        v = std::max(v, (tr.nozzle[i].position_m - tr.nozzle[i - 1].position_m).norm() / (tr.t_s[i] - tr.t_s[i - 1]));
    return v;
  };
  auto slowed = [](const Robot& robot, TimedTrajectory tr) {
    EXPECT_TRUE(slow_to_joint_limits(robot, tr));
    return tr;
  };
  const Robot bundled = Robot::from_string(urdf, base);
  const TimedTrajectory kept = time_plan(bundled, {passes}, bundled.stow(), fast, RobotConfig{});
  EXPECT_GT(fastest_turn_mps(kept), 0.2);  // the arcs run at their own speed
  EXPECT_LE(std::max(kept.max_velocity_ratio, kept.max_acceleration_ratio), 1.0 + 1e-3);
  for (const double factor : {0.2, 0.02}) {
    SCOPED_TRACE("joint velocity limits x" + std::to_string(factor));
    const Robot sluggish = Robot::from_string(slowed_urdf(factor), base);
    const TimedTrajectory chosen = time_plan(sluggish, {passes}, sluggish.stow(), fast, RobotConfig{});
    const TimedTrajectory at_pass_speeds = time_plan(sluggish, {passes}, sluggish.stow(), slow, RobotConfig{});
    EXPECT_GT(std::max(chosen.max_velocity_ratio, chosen.max_acceleration_ratio), 1.0);  // a limit to slow to
    const double chosen_s = slowed(sluggish, chosen).duration_s, pass_speeds_s = slowed(sluggish, at_pass_speeds).duration_s;
    std::printf("x%.2f: kept %.1f s slowed (fastest turn %.3f m/s), passes' speeds %.1f s slowed\n", factor, chosen_s,
                fastest_turn_mps(chosen), pass_speeds_s);
    EXPECT_LE(chosen_s, pass_speeds_s + 1e-6);
    if (factor == 0.2) {
      EXPECT_GT(fastest_turn_mps(chosen), 0.2);  // own speed, slowed later
      EXPECT_LT(chosen_s, pass_speeds_s - 5.0);
    } else {  // the passes' speeds: the same trajectory as the slow-turn timing
      EXPECT_LT(fastest_turn_mps(chosen), 0.051);
      EXPECT_EQ(chosen.size(), at_pass_speeds.size());
      EXPECT_NEAR(chosen.duration_s, at_pass_speeds.duration_s, 1e-9);
    }
  }
}

TEST(RobotTiming, BadInput) {
  const Robot robot = Robot::load(RobotConfig{});
  EXPECT_THROW(time_plan(robot, {}, Eigen::VectorXd::Zero(3), TimingConfig{}, RobotConfig{}), std::invalid_argument);
  auto passes = axial_region(2, 1.0, 0.2, 0.0, 1.0, {0.2});
  passes[1].speed_mps = 0.0;
  EXPECT_THROW(time_plan(robot, {passes}, robot.neutral(), TimingConfig{}, RobotConfig{}), std::invalid_argument);
  // A pass far outside the reach: a runtime_error naming the region.
  auto far = axial_region(2, 1.0, 0.2, 30.0, 1.0, {0.2});
  try {
    time_plan(robot, {far}, robot.neutral(), TimingConfig{}, RobotConfig{});
    FAIL() << "no error for an unreachable region";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("region 0"), std::string::npos) << e.what();
  }
}

TEST(ArmPlan, SpeedCapMapLearnsFromLimitBreakingSamples) {
  // A straight pass at 0.5 m/s whose middle sample breaks joint 0's velocity limit 2x and joint 1's
  // acceleration limit 3x; a link sample over an acceleration limit only (not the planner's).
  const Eigen::VectorXd vel = Eigen::VectorXd::Constant(2, 1.0), acc = Eigen::VectorXd::Constant(2, 1.0);
  TimedTrajectory tr;
  for (int i = 0; i < 9; ++i) {
    tr.t_s.push_back(0.1 * i);
    NozzlePose p;
    p.position_m = Eigen::Vector3d(0.05 * i, 0, 0);
    tr.nozzle.push_back(p);
    tr.q.push_back(Eigen::VectorXd::Zero(2));
    tr.qd.push_back(Eigen::VectorXd::Constant(2, 0.5));
    tr.qdd.push_back(Eigen::VectorXd::Zero(2));
    tr.spraying.push_back(i < 6);
    tr.pass_index.push_back(i < 6 ? 0 : -1);
    tr.region_index.push_back(0);
    tr.kind.push_back(static_cast<char>(i < 6 ? SegmentKind::Pass : SegmentKind::Link));
  }
  tr.qd[3] = Eigen::Vector2d(2.0, 0.5);
  tr.qdd[3] = Eigen::Vector2d(0.0, 3.0);
  tr.qdd[7] = Eigen::Vector2d(5.0, 0.0);
  SpeedCapMap map;
  EXPECT_EQ(map.learn(tr, vel, acc, 0.9), 2);
  ASSERT_EQ(map.speed_mps.size(), 2u);
  // A lone sample over the acceleration limit (its neighbours at 0) is a step in the joint's
  // velocity, which scales with v: min(0.9 / 2, 0.9 / 3) * 0.5 m/s.
  EXPECT_NEAR(map.speed_mps[0], 0.5 * std::min(0.45, 0.3), 1e-12);
  EXPECT_NEAR(map.at(Eigen::Vector3d(0.15 - 0.09, 0, 0)), map.speed_mps[0], 1e-12);
  EXPECT_TRUE(std::isinf(map.at(Eigen::Vector3d(0.15 - 0.11, 0, 0))));
  // The link sample over the acceleration limit (its run stops from the pass end): the bound goes
  // to the last pass sample (5), 0.9 / 5 of its speed (a lone sample again: linear).
  EXPECT_EQ(map.points_m[1], tr.nozzle[5].position_m);
  EXPECT_NEAR(map.speed_mps[1], 0.5 * 0.9 / 5.0, 1e-12);
  // A link sample over a velocity limit counts at its own position (it cruises at the speed of a
  // pass next to it) and at the pass end its run leaves, which may lie beyond the bounds' radius
  // (here 0.1 m: the default bay's graded lead-in reached 1 m/s 0.3 m before its pass).
  tr.qdd[7].setZero();
  tr.qd[7] = Eigen::Vector2d(0.0, 1.5);
  EXPECT_EQ(map.learn(tr, vel, acc, 0.9), 3);  // sample 3 again, sample 7, and pass end 5
  const std::size_t n = map.points_m.size();
  EXPECT_EQ(map.points_m[n - 2], tr.nozzle[7].position_m);
  EXPECT_NEAR(map.speed_mps[n - 2], 0.5 * 0.9 / 1.5, 1e-12);
  EXPECT_EQ(map.points_m[n - 1], tr.nozzle[5].position_m);
  EXPECT_NEAR(map.speed_mps[n - 1], 0.5 * 0.9 / 1.5, 1e-12);
  EXPECT_LE(map.at(tr.nozzle[5].position_m), 0.5 * 0.9 / 1.5 + 1e-12);
  // A run well below the pass speed (a turn at its own speed) keeps its velocity bound to itself.
  TimedTrajectory slow = tr;
  for (int i = 6; i < 9; ++i) slow.nozzle[i].position_m = Eigen::Vector3d(0.25 + 0.02 * (i - 5), 0, 0);
  SpeedCapMap own;
  EXPECT_EQ(own.learn(slow, vel, acc, 0.9), 2);  // sample 3 and sample 7 only
  EXPECT_EQ(own.points_m.back(), slow.nozzle[7].position_m);
  EXPECT_NEAR(own.speed_mps.back(), 0.2 * 0.9 / 1.5, 1e-12);
  // A turn-around between two passes (samples 3-5: run, arc, run) over a velocity limit at the
  // passes' speed bounds both pass ends it joins; a turn at its own lower speed bounds neither.
  // tr's samples relabelled (spraying on the passes), joint 1 at half its velocity limit.
  const auto relabelled = [&tr](auto kind_of) {
    TimedTrajectory out = tr;
    for (int i = 0; i < 9; ++i) {
      out.kind[i] = static_cast<char>(kind_of(i));
      out.spraying[i] = kind_of(i) == SegmentKind::Pass;
      out.qd[i] = Eigen::Vector2d(0.0, 0.5);
      out.qdd[i].setZero();
    }
    return out;
  };
  TimedTrajectory turn = relabelled([](int i) {
    return i == 4 ? SegmentKind::Turn : i == 3 || i == 5 ? SegmentKind::Link : SegmentKind::Pass;
  });
  turn.qd[4] = Eigen::Vector2d(2.0, 0.0);
  SpeedCapMap around;
  EXPECT_EQ(around.learn(turn, vel, acc, 0.9), 2);
  EXPECT_EQ(around.points_m[0], turn.nozzle[2].position_m);
  EXPECT_EQ(around.points_m[1], turn.nozzle[6].position_m);
  EXPECT_NEAR(around.speed_mps[0], 0.5 * 0.45, 1e-12);
  EXPECT_NEAR(around.speed_mps[1], 0.5 * 0.45, 1e-12);
  for (int i = 4; i < 9; ++i)  // 0.1 m/s over the turn, the passes at 0.5 m/s
    turn.nozzle[i].position_m = Eigen::Vector3d(i == 4 ? 0.16 : 0.17 + 0.05 * (i - 5), 0, 0);
  SpeedCapMap slow_turn;
  EXPECT_EQ(slow_turn.learn(turn, vel, acc, 0.9), 0);
  // A pass sample over an acceleration limit only by its speed change (qdd = q' dv/dt; joint 0
  // follows the path, s = 0.5 t + t^2): a lower speed there would not help (it only steepens the
  // change into it), so no bound; with a path curvature on top (q'' v^2) the bound follows that.
  TimedTrajectory ramp = tr;
  for (int i = 0; i < 9; ++i) {
    const double t = 0.1 * i, v = 0.5 + 2.0 * t;
    ramp.nozzle[i].position_m = Eigen::Vector3d(0.5 * t + t * t, 0, 0);
    ramp.qd[i] = Eigen::Vector2d(v, 0.0);
    ramp.qdd[i] = Eigen::Vector2d(2.0, 0.0);
    const bool on = i >= 2 && i <= 6;  // the ends are joint moves (no central difference of the speed change)
    ramp.kind[i] = static_cast<char>(on ? SegmentKind::Pass : SegmentKind::Transit);
    ramp.spraying[i] = on;
  }
  const Eigen::VectorXd fast = Eigen::VectorXd::Constant(2, 10.0);  // velocities within their limits
  SpeedCapMap change;
  EXPECT_EQ(change.learn(ramp, fast, acc, 0.9), 0);
  // joint 1: q'' v^2 = 3 over samples 3-5 (a curve; v = 1.1, 1.3, 1.5 m/s): bounds by sqrt.
  for (int i = 3; i <= 5; ++i) ramp.qdd[i] = Eigen::Vector2d(2.0, 3.0);
  EXPECT_EQ(change.learn(ramp, fast, acc, 0.9), 3);
  EXPECT_NEAR(change.speed_mps[1], 1.3 * std::sqrt(0.9 / 3.0), 1e-9);
  // The same excess at sample 4 alone: a step in joint 1's velocity (the nozzle's axis starting
  // to turn where a lead meets a curved pass) scales with v, so the bound is linear.
  ramp.qdd[3] = ramp.qdd[5] = Eigen::Vector2d(2.0, 0.0);
  SpeedCapMap step;
  EXPECT_EQ(step.learn(ramp, fast, acc, 0.9), 1);
  EXPECT_NEAR(step.speed_mps[0], 1.3 * 0.9 / 3.0, 1e-9);
  // A zig-zag (joint 1's acceleration flips sign from sample to sample) is no curve a lower speed
  // would follow: no bound.
  for (int i = 0; i < 9; ++i) ramp.qdd[i] = Eigen::Vector2d(2.0, i % 2 ? 3.0 : -3.0);
  SpeedCapMap zigzag;
  EXPECT_EQ(zigzag.learn(ramp, fast, acc, 0.9), 0);
  // A run-in (the link comes after a joint move and before a pass): the next pass's first sample.
  TimedTrajectory in = relabelled([](int i) {
    return i < 2 ? SegmentKind::Transit : i < 4 ? SegmentKind::Link : SegmentKind::Pass;
  });
  in.qdd[2] = Eigen::Vector2d(0.0, 4.0);
  SpeedCapMap run_in;
  EXPECT_EQ(run_in.learn(in, vel, acc, 0.9), 1);
  EXPECT_EQ(run_in.points_m[0], in.nozzle[4].position_m);
  EXPECT_NEAR(run_in.speed_mps[0], 0.5 * 0.9 / 4.0, 1e-12);  // a lone sample: linear
  // Over two samples (a stop the run cannot lengthen): sqrt.
  in.qdd[3] = Eigen::Vector2d(0.0, 4.0);
  SpeedCapMap run_in_curve;
  EXPECT_EQ(run_in_curve.learn(in, vel, acc, 0.9), 1);
  EXPECT_NEAR(run_in_curve.speed_mps[0], 0.5 * std::sqrt(0.9 / 4.0), 1e-12);
}
