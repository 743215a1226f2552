// AIWCPSO: particle swarm whose inertia weight and acceleration coefficients follow the share of
// particles that improved their personal best in the last iteration.
#include "shotcrete/timing/pso.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

namespace shotcrete {

namespace {

using Objective = std::function<double(const Eigen::VectorXd&)>;

struct Swarm {
  std::vector<Eigen::VectorXd> x, v, pb;  // positions, velocities, personal bests
  std::vector<double> pf;                 // personal best values
  int best = 0;                           // the global best particle
  void find_best() { best = static_cast<int>(std::min_element(pf.begin(), pf.end()) - pf.begin()); }
};

void check_pso_input(const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, const PsoOptions& o) {
  if (lower.size() == 0 || upper.size() != lower.size())
    throw std::invalid_argument("pso_minimize: lower and upper must be non-empty and of equal size");
  if (!lower.allFinite() || !upper.allFinite()) throw std::invalid_argument("pso_minimize: bounds must be finite");
  if ((upper.array() < lower.array()).any()) throw std::invalid_argument("pso_minimize: upper bound below lower bound");
  if (o.particles < 1 || o.iterations < 0) throw std::invalid_argument("pso_minimize: particles must be >= 1, iterations >= 0");
}

// Random particles in the box with small random velocities; `initial` ones replace the first
// positions (clamped). Every particle is evaluated once.
Swarm initial_swarm(const Objective& eval, const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, int n,
                    const std::vector<Eigen::VectorXd>& initial, std::mt19937_64& rng) {
  const Eigen::Index D = lower.size();
  const Eigen::VectorXd range = upper - lower;
  std::uniform_real_distribution<double> U(0.0, 1.0);
  Swarm s;
  s.x.resize(n);
  s.v.resize(n);
  s.pb.resize(n);
  s.pf.resize(n);
  for (int i = 0; i < n; ++i) {
    s.x[i].resize(D);
    s.v[i].resize(D);
    for (Eigen::Index d = 0; d < D; ++d) s.x[i][d] = lower[d] + U(rng) * range[d];
    for (Eigen::Index d = 0; d < D; ++d) s.v[i][d] = (2.0 * U(rng) - 1.0) * 0.1 * range[d];
    if (static_cast<std::size_t>(i) < initial.size()) {
      if (initial[i].size() != D) throw std::invalid_argument("pso_minimize: initial particle of the wrong size");
      s.x[i] = initial[i].cwiseMax(lower).cwiseMin(upper);
    }
    s.pb[i] = s.x[i];
    s.pf[i] = eval(s.x[i]);
  }
  s.find_best();
  return s;
}

// One velocity and position update of every particle with inertia w and the cognitive / social
// coefficients c1 / c2; velocities are clamped to half the box, a particle stops at a wall.
void move_particles(Swarm& s, double w, double c1, double c2, const Eigen::VectorXd& lower,
                    const Eigen::VectorXd& upper, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const Eigen::VectorXd vmax = 0.5 * (upper - lower);
  const auto& g = s.pb[static_cast<std::size_t>(s.best)];
  for (std::size_t i = 0; i < s.x.size(); ++i) {
    for (Eigen::Index d = 0; d < lower.size(); ++d) {
      const double r1 = U(rng), r2 = U(rng);
      double vd = w * s.v[i][d] + c1 * r1 * (s.pb[i][d] - s.x[i][d]) + c2 * r2 * (g[d] - s.x[i][d]);
      vd = std::clamp(vd, -vmax[d], vmax[d]);
      double xd = s.x[i][d] + vd;
      if (xd < lower[d] || xd > upper[d]) {  // stop at the wall
        xd = std::clamp(xd, lower[d], upper[d]);
        vd = 0.0;
      }
      s.v[i][d] = vd;
      s.x[i][d] = xd;
    }
  }
}

// Evaluates every particle; returns how many improved their personal best.
int update_bests(Swarm& s, const Objective& eval) {
  int improved = 0;
  for (std::size_t i = 0; i < s.x.size(); ++i) {
    const double y = eval(s.x[i]);
    if (y < s.pf[i]) {
      s.pf[i] = y;
      s.pb[i] = s.x[i];
      ++improved;
    }
  }
  s.find_best();
  return improved;
}

}  // namespace

PsoOptions PsoOptions::from_config(const TimingConfig& c) {
  PsoOptions o;
  o.particles = c.pso_particles;
  o.iterations = c.pso_iterations;
  o.seed = c.pso_seed;
  o.a = c.pso_a;
  o.b = c.pso_b;
  o.w_min = c.pso_w_min;
  o.w_max = c.pso_w_max;
  return o;
}

PsoResult pso_minimize(const Objective& f, const Eigen::VectorXd& lower, const Eigen::VectorXd& upper,
                       const PsoOptions& o, const std::vector<Eigen::VectorXd>& initial) {
  check_pso_input(lower, upper, o);
  std::mt19937_64 rng(o.seed);
  PsoResult res;
  const Objective eval = [&](const Eigen::VectorXd& p) {
    ++res.evaluations;
    const double y = f(p);
    return std::isnan(y) ? std::numeric_limits<double>::infinity() : y;
  };
  Swarm s = initial_swarm(eval, lower, upper, o.particles, initial, rng);
  res.best_history.push_back(s.pf[s.best]);
  double bs = 1.0;  // every personal best is new after the initial evaluation
  for (int it = 0; it < o.iterations; ++it) {
    if (std::chrono::steady_clock::now() > o.deadline) {
      res.stopped_by_deadline = true;
      break;
    }
    const double w = (o.w_max - o.w_min) * bs + o.w_min;
    const double c1 = o.a * bs + o.b, c2 = o.a * (1.0 - bs) + o.b;
    move_particles(s, w, c1, c2, lower, upper, rng);
    bs = static_cast<double>(update_bests(s, eval)) / o.particles;
    res.best_history.push_back(s.pf[s.best]);
    res.success_history.push_back(bs);
  }
  res.best_x = s.pb[s.best];
  res.best_f = s.pf[s.best];
  return res;
}

}  // namespace shotcrete
