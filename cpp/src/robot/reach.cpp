// Reachability of a bay and the IK benchmark.
#include <chrono>
#include <cmath>
#include <random>
#include <stdexcept>

#include "detail.hpp"
#include "shotcrete/robot/robot.hpp"

namespace shotcrete {

using robot_detail::axis_angle;

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
