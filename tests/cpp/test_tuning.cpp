// Timing tuning: the swarm on functions with a known minimum, the Cartesian-only tuning, the tuned
// timed trajectory of real passes on the robot, and the swarm's joint model against time_plan.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/pso.hpp"
#include "shotcrete/timing/sampling.hpp"
#include "shotcrete/timing/trajectory.hpp"
#include "shotcrete/timing/tuning.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

using shotcrete::test::axial_region;

TEST(Pso, FindsKnownMinima) {
  PsoOptions o;
  o.particles = 15;
  o.iterations = 200;
  o.seed = 7;
  // Shifted sphere in 5-D, minimum 0 at c.
  Eigen::VectorXd c(5), lo(5), hi(5);
  c << 0.3, -1.2, 2.5, 0.0, 1.7;
  lo.setConstant(-5.0);
  hi.setConstant(5.0);
  auto sphere = [&](const Eigen::VectorXd& x) { return (x - c).squaredNorm(); };
  const PsoResult r = pso_minimize(sphere, lo, hi, o);
  EXPECT_LT((r.best_x - c).norm(), 1e-3);
  EXPECT_LT(r.best_f, 1e-6);
  EXPECT_EQ(r.evaluations, 15 * 201);
  for (std::size_t i = 1; i < r.best_history.size(); ++i) EXPECT_LE(r.best_history[i], r.best_history[i - 1]);
  for (double b : r.success_history) {
    EXPECT_GE(b, 0.0);
    EXPECT_LE(b, 1.0);
  }
  // Deterministic for a seed.
  const PsoResult r2 = pso_minimize(sphere, lo, hi, o);
  EXPECT_EQ(r.best_x, r2.best_x);
  // Rosenbrock, minimum 0 at (1, 1); Himmelblau-like box with the optimum on a bound.
  auto rosen = [](const Eigen::VectorXd& x) { return 100 * std::pow(x[1] - x[0] * x[0], 2) + std::pow(1 - x[0], 2); };
  Eigen::VectorXd l2(2), h2(2);
  l2 << -2, -1;
  h2 << 2, 3;
  o.iterations = 300;
  const PsoResult rr = pso_minimize(rosen, l2, h2, o);
  EXPECT_LT(std::abs(rr.best_x[0] - 1.0), 0.05);
  EXPECT_LT(std::abs(rr.best_x[1] - 1.0), 0.1);
  auto onbound = [](const Eigen::VectorXd& x) { return x[0] + (x[1] - 0.5) * (x[1] - 0.5); };
  const PsoResult rb = pso_minimize(onbound, l2, h2, o);
  EXPECT_NEAR(rb.best_x[0], -2.0, 1e-9);
  EXPECT_NEAR(rb.best_x[1], 0.5, 1e-3);
  EXPECT_THROW(pso_minimize(sphere, hi, lo, o), std::invalid_argument);
  // Non-finite bounds (issue 17): refused, not a swarm of NaN positions.
  Eigen::VectorXd bad = lo;
  bad[2] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(pso_minimize(sphere, bad, hi, o), std::invalid_argument);
  bad[2] = std::numeric_limits<double>::infinity();
  EXPECT_THROW(pso_minimize(sphere, lo, bad, o), std::invalid_argument);
  // An objective that is NaN everywhere gives a result (every value counts as +inf), no crash.
  const PsoResult rn = pso_minimize([](const Eigen::VectorXd&) { return std::nan(""); }, lo, hi, o);
  EXPECT_TRUE(std::isinf(rn.best_f));
  EXPECT_EQ(rn.best_x.size(), 5);
}

// A deadline stops the iterations, never the initial swarm; the result is the best of what ran.
TEST(Pso, DeadlineStopsTheIterations) {
  PsoOptions o;
  o.particles = 6;
  o.iterations = 1000;
  Eigen::VectorXd lo = Eigen::VectorXd::Constant(3, -1.0), hi = Eigen::VectorXd::Constant(3, 1.0);
  std::vector<double> seen;
  auto f = [&](const Eigen::VectorXd& x) {
    seen.push_back(x.squaredNorm());
    return seen.back();
  };
  o.deadline = std::chrono::steady_clock::now();  // already spent
  const PsoResult r0 = pso_minimize(f, lo, hi, o);
  EXPECT_TRUE(r0.stopped_by_deadline);
  EXPECT_EQ(r0.evaluations, 6);
  EXPECT_EQ(r0.best_history.size(), 1u);
  EXPECT_EQ(r0.best_f, *std::min_element(seen.begin(), seen.end()));
  // A slow objective against a 0.2 s deadline: fewer than the 1000 iterations, the best of them.
  seen.clear();
  auto slow = [&](const Eigen::VectorXd& x) {
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    return f(x);
  };
  o.deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(200);
  const PsoResult r1 = pso_minimize(slow, lo, hi, o);
  EXPECT_TRUE(r1.stopped_by_deadline);
  EXPECT_LT(r1.evaluations, 6 * 1001);
  EXPECT_EQ(static_cast<std::size_t>(r1.evaluations), seen.size());
  EXPECT_EQ(r1.best_f, *std::min_element(seen.begin(), seen.end()));
  // The default deadline never stops it.
  o.deadline = PsoOptions{}.deadline;
  o.iterations = 20;
  const PsoResult r2 = pso_minimize(f, lo, hi, o);
  EXPECT_FALSE(r2.stopped_by_deadline);
  EXPECT_EQ(r2.evaluations, 6 * 21);
}

TEST(Tuning, CartesianOnlySwarmBeatsDefaultsWithinNozzleLimits) {
  const auto passes = axial_region(8, 1.2, 0.2, 0.0, 1.0, {0.25, 0.2});
  for (double amax : {2.0, 1.2}) {
    TimingConfig tc;
    tc.nozzle_max_accel_mps2 = amax;
    tc.min_lead_s = 0.0;  // the config's 0.1 m leads as they are (the pump's 1 s floor lengthens them)
    const TimingTuning t = tune_timing(nullptr, {passes}, Eigen::VectorXd(), tc, RobotConfig{});
    // Defaults: start peak 2 v / t1 = 1.875 m/s^2 at 0.25 m/s, end 1.2 at 0.2 -> feasible at 2.0 only.
    EXPECT_EQ(t.initial_feasible, amax == 2.0);
    if (t.initial_feasible) {
      EXPECT_LE(t.duration_s, t.initial_duration_s);
    }
    ASSERT_LT(t.duration_s, 1e5) << "no feasible timing found at " << amax;
    ASSERT_EQ(t.feasible, std::vector<char>{1}) << "the swarm fell back to the config at " << amax;
    // Re-check the tuned particle independently, on a finer sampling.
    ASSERT_EQ(t.params.size(), 1u);
    const TimingParams& tuned = t.params[0];
    const CartesianPath path = timing_region_path(passes, tuned.start_length_m, tuned.end_length_m, tc);
    const SpeedProfile prof = region_profile(path, tuned);
    EXPECT_NEAR(prof.duration_s(), t.duration_s, 1e-9);
    EXPECT_LE(check_nozzle(path, prof, NozzleLimits{tc.nozzle_max_speed_mps, amax}, 2000.0).accel_ratio, 1.0 + 1e-3);
    EXPECT_EQ(t.regions_cut_by_budget, 0);
  }
}

// timing.pso_time_budget_s: progress per region, and a spent budget cuts every swarm to its
// initial particles (the config's parameters among them), still a valid tuning.
TEST(Tuning, ProgressAndTimeBudget) {
  const auto passes = axial_region(8, 1.2, 0.2, 0.0, 1.0, {0.25, 0.2});
  TimingConfig tc;
  std::vector<double> fractions;
  const ProgressFn progress = [&](const std::string& stage, double f) {
    EXPECT_EQ(stage, "tuning timing");
    fractions.push_back(f);
  };
  const TimingTuning full = tune_timing(nullptr, {passes, passes, passes}, Eigen::VectorXd(), tc, RobotConfig{}, progress);
  EXPECT_EQ(fractions, (std::vector<double>{0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0}));
  EXPECT_EQ(full.regions_cut_by_budget, 0);
  tc.pso_time_budget_s = 0.0;
  const TimingTuning cut = tune_timing(nullptr, {passes, passes, passes}, Eigen::VectorXd(), tc, RobotConfig{});
  EXPECT_EQ(cut.regions_cut_by_budget, 3);
  ASSERT_EQ(cut.pso.size(), 3u);
  for (const auto& p : cut.pso) EXPECT_EQ(p.evaluations, tc.pso_particles);
  EXPECT_LE(cut.duration_s, cut.initial_duration_s);  // the config's particle is in the initial swarm
  EXPECT_GE(cut.duration_s, full.duration_s - 1e-9);
}

TEST(RobotTiming, TunedRegionsRespectJointLimits) {
  const Robot robot = Robot::load(RobotConfig{});
  const RobotConfig rc;
  TimingConfig tc;
  // Two regions of a 5.6 m wall (nozzle at 1 m standoff): 4 axial passes each, 0.2 m apart.
  const std::vector<std::vector<Pass>> regions{axial_region(4, 1.2, 0.2, 0.0, 1.2, {0.25, 0.2}),
                                               axial_region(3, 1.0, 0.2, 0.1, 0.7, {0.3})};
  const TimingTuning tun = tune_timing(&robot, regions, robot.neutral(), tc, rc);
  ASSERT_LT(tun.duration_s, 1e5) << "no feasible timing";
  ASSERT_EQ(tun.feasible, std::vector<char>(regions.size(), 1)) << "the swarm fell back to the config";
  ASSERT_EQ(tun.params.size(), regions.size());
  const TimedTrajectory tr = time_plan(robot, regions, robot.neutral(), tc, rc, tun.params);
  EXPECT_EQ(tr.untracked_regions, 0);
  // Finite-difference velocities / accelerations of the sampled joint path within the limits
  // (the swarm judged them on its arc-length model; the tolerance covers the two discretisations).
  EXPECT_LE(tr.max_velocity_ratio, 1.0 + 1e-3);
  EXPECT_LE(tr.max_acceleration_ratio, 1.03);
  EXPECT_LE(tr.max_position_violation_rad, 0.0);
  EXPECT_LE(tr.max_position_violation_m, 0.0);
  // Region durations are those of the tuned profiles; the transits (joint quintics between the
  // regions' end configurations) may differ slightly from the swarm's model.
  double regions_s = 0.0;
  for (std::size_t r = 0; r < regions.size(); ++r) {
    const TimingParams& p = tun.params[r];
    const CartesianPath path = timing_region_path(regions[r], p.start_length_m, p.end_length_m, tc);
    regions_s += region_profile(path, p).duration_s();
  }
  EXPECT_NEAR(tr.duration_s - tr.transit_time_s, regions_s, 1e-9);
  EXPECT_NEAR(tr.duration_s, tun.duration_s, 0.01 * tun.duration_s);
  ASSERT_EQ(tr.q.size(), tr.size());
  ASSERT_EQ(tr.qdd.size(), tr.size());
  double pass_time = 0.0;
  for (const auto& reg : regions)
    for (const auto& p : reg) pass_time += p.length_m / p.speed_mps;
  EXPECT_NEAR(tr.spray_time_s, pass_time, 1e-6);
  double dwell = 0.0;
  for (double d : spray_dwells(tr.t_s, tr.spraying)) dwell += d;
  EXPECT_NEAR(dwell, pass_time, 7.0 / tc.trajectory_rate_hz);  // within a sample per pass
  int checked = 0, transit = 0;
  for (std::size_t i = 0; i < tr.size(); ++i) {
    if (i > 0) {
      ASSERT_LE(tr.t_s[i] - tr.t_s[i - 1], 1.0 / tc.trajectory_rate_hz + 1e-12);
    }
    const Eigen::Isometry3d T = robot.fk(tr.q[i]);
    if (tr.kind[i] == static_cast<char>(SegmentKind::Transit)) {
      ++transit;
      EXPECT_EQ(tr.region_index[i], -1);
      continue;
    }
    // FK of the timed joints is the nozzle pose of the sample (exact tracking).
    ASSERT_LT((T.translation() - tr.nozzle[i].position_m).norm(), 1e-6) << "sample " << i;
    ASSERT_LT(std::acos(std::min(1.0, T.linear().col(2).dot(tr.nozzle[i].axis))), 1e-5) << "sample " << i;
    // J(q) qd reproduces the planned nozzle speed on the passes (independent of the profile code).
    if (tr.kind[i] == static_cast<char>(SegmentKind::Pass) && i + 1 < tr.size() &&
        tr.kind[i - 1] == tr.kind[i] && tr.kind[i + 1] == tr.kind[i]) {
      const double v = (robot.jacobian(tr.q[i]).topRows<3>() * tr.qd[i]).norm();
      const auto& reg = regions[static_cast<std::size_t>(tr.region_index[i])];
      const int first = tr.region_index[i] == 0 ? 0 : static_cast<int>(regions[0].size());
      ASSERT_NEAR(v, reg[static_cast<std::size_t>(tr.pass_index[i] - first)].speed_mps, 2e-3) << "sample " << i;
      ++checked;
    }
  }
  EXPECT_GT(checked, 500);
  EXPECT_GT(transit, 10);
  EXPECT_GT(tr.transit_time_s, 0.0);
  // The CSV carries every sample.
  const std::string csv = tr.to_csv();
  EXPECT_EQ(static_cast<std::size_t>(std::count(csv.begin(), csv.end(), '\n')), tr.size() + 1);
  EXPECT_EQ(tr.joint_table().cols(), 1 + 3 * robot.dof());
  // The config's untuned defaults start too hard for the slew joint (the swarm's model says so, and
  // this check failed before time_plan re-timed regions): time_plan's joint check lengthens the
  // leads until the joints are within their limits, so the region takes longer than its nominal
  // profile.
  EXPECT_FALSE(tun.initial_feasible);
  const TimedTrajectory raw = time_plan(robot, {regions[0]}, robot.neutral(), tc, rc);
  EXPECT_LE(raw.max_acceleration_ratio, 1.0);
  const TimingParams nominal = TimingParams::from_config(tc);
  const double nominal_s =
      region_profile(timing_region_path(regions[0], nominal.start_length_m, nominal.end_length_m, tc), nominal)
          .duration_s();
  EXPECT_GT(raw.duration_s - raw.transit_time_s, nominal_s + 0.05);
}

TEST(RobotTiming, JointModelAgreesWithTimePlan) {
  // The swarm's arc-length model against the sampled trajectory (a second method: IK per sample,
  // finite differences in time) on a region with turns and a stop-and-go move: same duration (the
  // joint move's quintic included) and about the same worst joint ratios.
  auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.2, {0.2, 0.25, 0.15});
  auto last = axial_region(4, 1.0, 0.2, 0.0, 1.2, {0.2})[3];
  std::reverse(last.waypoints.begin(), last.waypoints.end());  // heads like pass 2: stop and go
  passes.push_back(last);
  const Robot robot = Robot::load(RobotConfig{});
  const RobotConfig rc;
  TimingConfig tc;
  TimingParams p = TimingParams::from_config(tc);
  p.k1 = 0.8;  // gentle enough that time_plan keeps the geometry (no easing)
  p.k2 = 0.2;
  p.start_length_m = p.end_length_m = 0.3;
  const RegionJointModel model(robot, passes, tc.max_lead_length_m, tc, robot.neutral(), rc);
  ASSERT_TRUE(model.tracked());
  const auto ev = model.evaluate(p, NozzleLimits{tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2});
  const TimedTrajectory tr = time_plan(robot, {passes}, robot.neutral(), tc, rc, {p});
  ASSERT_LE(tr.max_acceleration_ratio, 1.0) << "time_plan eased the region: the geometries differ";
  int moves = 0;
  for (std::size_t i = 0; i < tr.size(); ++i) moves += tr.kind[i] == static_cast<char>(SegmentKind::Transit) && tr.region_index[i] == 0;
  ASSERT_GT(moves, 0) << "no stop-and-go move";
  const double transit =
      quintic_nozzle_duration(robot, robot.neutral(), ev.q_first, tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2);
  EXPECT_NEAR(ev.duration_s + transit, tr.duration_s, 1e-3 * tr.duration_s);  // measured: 1e-5
  // Worst ratios off the joint moves (the model skips them).
  double vel = 0.0, acc = 0.0;
  for (std::size_t i = 0; i < tr.size(); ++i) {
    if (tr.kind[i] == static_cast<char>(SegmentKind::Transit)) continue;
    vel = std::max(vel, tr.qd[i].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff());
    acc = std::max(acc, tr.qdd[i].cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff());
  }
  EXPECT_NEAR(ev.velocity_ratio, vel, 0.01 * vel);  // measured: 4e-5
  EXPECT_NEAR(ev.acceleration_ratio, acc, 0.01 * acc);
  // One parameter set per region or none; anything else names the mismatch.
  EXPECT_THROW(time_plan(robot, {passes}, robot.neutral(), tc, rc, {p, p}), std::invalid_argument);
}
