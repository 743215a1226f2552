// Region ordering by genetic algorithm: see solve_ga in ordering.hpp.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>

#include "instance.hpp"

namespace shotcrete {

using namespace ordering_internal;

namespace {

// ---------------------------------------------------------------- genetic algorithm
// Order crossover: child keeps p1[i..j] in place, the rest follows p2's order from j + 1 on.
Path order_crossover(const Path& p1, const Path& p2, int i, int j, std::vector<char>& present) {
  const int n = static_cast<int>(p1.size());
  Path c(static_cast<size_t>(n), -1);
  std::fill(present.begin(), present.end(), 0);
  for (int k = i; k <= j; ++k) {
    c[k] = p1[k];
    present[static_cast<size_t>(p1[k] >> 1)] = 1;
  }
  int w = (j + 1) % n;
  for (int t = 0; t < n; ++t) {
    const int g = p2[(j + 1 + t) % n];
    if (present[static_cast<size_t>(g >> 1)]) continue;
    c[w] = g;
    w = (w + 1) % n;
  }
  return c;
}

SearchOutput ga(const Instance& inst, const OrderingConfig& cfg, const RunControl& ctl) {
  const int n = inst.n, P = std::max(2, cfg.ga_population);
  std::mt19937_64 rng(cfg.seed);
  std::vector<Path> pop(static_cast<size_t>(P)), next_pop(static_cast<size_t>(P));
  std::vector<double> fit(static_cast<size_t>(P)), next_fit(static_cast<size_t>(P));
  for (int k = 0; k < P; ++k) {
    Path s(static_cast<size_t>(n));
    for (int i = 0; i < n; ++i) s[i] = 2 * i;
    for (int i = n - 1; i > 0; --i) std::swap(s[i], s[uniform_int(rng, i + 1)]);
    for (int& e : s) e |= static_cast<int>(rng() >> 63);
    fit[k] = inst.cost(s);
    pop[k] = std::move(s);
  }
  auto tournament = [&]() {
    const int a = uniform_int(rng, P), b = uniform_int(rng, P);
    return fit[a] <= fit[b] ? a : b;
  };
  auto mutate = [&](Path& s) {
    if (n == 0) return;
    if (uniform01(rng) < cfg.ga_mutation) {  // inversion: spray a block backwards
      int i = uniform_int(rng, n), j = uniform_int(rng, n);
      if (i > j) std::swap(i, j);
      std::reverse(s.begin() + i, s.begin() + j + 1);
      for (int k = i; k <= j; ++k) s[k] ^= 1;
    }
    if (uniform01(rng) < cfg.ga_mutation) s[uniform_int(rng, n)] ^= 1;  // one direction bit
  };
  std::vector<char> present(static_cast<size_t>(n));
  SearchOutput out;
  int best = static_cast<int>(std::min_element(fit.begin(), fit.end()) - fit.begin());
  for (int g = 0; g < cfg.ga_generations; ++g) {
    next_pop[0] = pop[best];  // elitism
    next_fit[0] = fit[best];
    int k = 1;
    while (k < P) {
      const Path& p1 = pop[tournament()];
      const Path& p2 = pop[tournament()];
      Path c1 = p1, c2 = p2;
      if (n > 1 && uniform01(rng) < cfg.ga_crossover) {
        int i = uniform_int(rng, n), j = uniform_int(rng, n);
        if (i > j) std::swap(i, j);
        c1 = order_crossover(p1, p2, i, j, present);
        c2 = order_crossover(p2, p1, i, j, present);
      }
      mutate(c1);
      next_fit[k] = inst.cost(c1);
      next_pop[k++] = std::move(c1);
      if (k < P) {
        mutate(c2);
        next_fit[k] = inst.cost(c2);
        next_pop[k++] = std::move(c2);
      }
    }
    pop.swap(next_pop);
    fit.swap(next_fit);
    best = static_cast<int>(std::min_element(fit.begin(), fit.end()) - fit.begin());
    out.best_hist.push_back(fit[best]);
    out.mean_hist.push_back(std::accumulate(fit.begin(), fit.end(), 0.0) / P);
    ctl.report("genetic algorithm", static_cast<double>(g + 1) / cfg.ga_generations);
    if (ctl.spent()) break;  // time_budget_s: the best so far
  }
  out.best = pop[best];
  return out;
}

}  // namespace

OrderingResult solve_ga(const OrderingProblem& problem, const OrderingConfig& config, const ProgressFn& progress) {
  return solve_by_search(problem, config, "ga", progress,
                         [&](const Instance& inst, const RunControl& ctl) { return ga(inst, config, ctl); });
}

void apply_ga_preset(OrderingConfig& c, const std::string& preset) {
  if (preset == "a") {
    c.ga_population = 100;
    c.ga_crossover = 0.9;
    c.ga_mutation = 0.1;
    c.ga_generations = 400;
  } else if (preset == "b") {
    c.ga_population = 100;
    c.ga_crossover = 0.2;
    c.ga_mutation = 0.05;
    c.ga_generations = 100;
  } else {
    throw std::invalid_argument("ordering: GA preset must be 'a' (Pc 0.9, Pm 0.1, 400 generations) or 'b' "
                                "(Pc 0.2, Pm 0.05, 100 generations), got '" + preset + "'");
  }
}

}  // namespace shotcrete
