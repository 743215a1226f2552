#pragma once
// Particle swarm with adaptive inertia weight and acceleration coefficients (AIWCPSO, design
// section 7b): a seeded box-constrained minimiser.
#include <Eigen/Core>
#include <cstdint>
#include <chrono>
#include <functional>
#include <vector>

#include "shotcrete/config.hpp"  // TimingConfig

namespace shotcrete {

struct PsoOptions {
  int particles = 15;
  int iterations = 30;
  std::uint64_t seed = 1;
  double a = 2.05, b = 0.5;          // c1 = a Bs + b, c2 = a (1 - Bs) + b
  double w_min = 0.0, w_max = 1.0;   // w = (w_max - w_min) Bs + w_min
  // No iteration starts after this point in time (the initial swarm is always evaluated);
  // the default never stops early.
  std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
  static PsoOptions from_config(const TimingConfig& config);
};
struct PsoResult {
  Eigen::VectorXd best_x;
  double best_f = 0.0;
  std::vector<double> best_history;  // global best after each iteration (first = initial swarm)
  std::vector<double> success_history;  // Bs per iteration
  int evaluations = 0;
  bool stopped_by_deadline = false;     // fewer iterations than options.iterations ran
};
/// Minimises f over the box [lower, upper]; `initial` particles (clamped) replace the first random
/// ones. Deterministic for a given seed. Infeasible points should return +inf or a penalty.
PsoResult pso_minimize(const std::function<double(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& lower,
                       const Eigen::VectorXd& upper, const PsoOptions& options,
                       const std::vector<Eigen::VectorXd>& initial = {});

}  // namespace shotcrete
