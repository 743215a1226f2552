// Region ordering: nearest neighbour, local search, exact DP, the public entry points and the
// dispatch on ordering.method; the ant colony and the genetic algorithm live in colony.cpp and
// genetic.cpp (representation: instance.hpp).
#include "shotcrete/ordering/ordering.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

#include "instance.hpp"

namespace shotcrete {

namespace ordering_internal {

constexpr int kExactHardMax = 20;
constexpr int kBestKicks = 500;  // iterated-local-search kicks after the colony in method best

OrderingResult to_result(const Instance& inst, const Path& s, const std::string& method) {
  // Assert-style check of every solver's output (issue 17: overflowing distances once gave [127, 0]).
  std::vector<char> seen(static_cast<size_t>(inst.n), 0);
  bool ok = s.size() == static_cast<size_t>(inst.n);
  for (size_t k = 0; ok && k < s.size(); ++k) {
    ok = s[k] >= 0 && s[k] < inst.E && !seen[static_cast<size_t>(s[k] >> 1)];
    if (ok) seen[static_cast<size_t>(s[k] >> 1)] = 1;
  }
  if (!ok)
    throw std::logic_error("ordering: internal error: " + method + " returned an order that is not a permutation of " +
                           std::to_string(inst.n) + " regions");
  OrderingResult r;
  r.method = method;
  r.order.reserve(s.size());
  r.reversed.assign(static_cast<size_t>(inst.n), false);
  for (int e : s) {
    r.order.push_back(e >> 1);
    r.reversed[static_cast<size_t>(e >> 1)] = (e & 1) != 0;
  }
  r.link_length_m = inst.cost(s);
  return r;
}

Path to_path(const OrderingResult& r) {
  Path s;
  s.reserve(r.order.size());
  for (int i : r.order) s.push_back(2 * i + (r.reversed[static_cast<size_t>(i)] ? 1 : 0));
  return s;
}

// ---------------------------------------------------------------- nearest neighbour
Path greedy_from(const Instance& inst, int first_entry) {
  Path s;
  s.reserve(static_cast<size_t>(inst.n));
  std::vector<char> used(static_cast<size_t>(inst.n), 0);
  int e = first_entry;
  for (int k = 0; k < inst.n; ++k) {
    s.push_back(e);
    used[static_cast<size_t>(e >> 1)] = 1;
    if (k + 1 == inst.n) break;
    const int row = e ^ 1;
    int best = -1;
    double bd = std::numeric_limits<double>::infinity();
    for (int f = 0; f < inst.E; ++f)
      if (!used[static_cast<size_t>(f >> 1)] && inst.d(row, f) < bd) {
        bd = inst.d(row, f);
        best = f;
      }
    if (best < 0) throw std::logic_error("ordering: nearest neighbour found no finite distance to a free region");
    e = best;
  }
  return s;
}

Path nearest_neighbour_path(const Instance& inst, const OrderingProblem& p) {
  if (inst.n == 0) return {};
  std::vector<int> firsts;
  if (inst.has_start) {
    int best = 0;
    for (int f = 1; f < inst.E; ++f)
      if (inst.d(inst.E, f) < inst.d(inst.E, best)) best = f;
    firsts.push_back(best);
  } else {
    Eigen::Vector3d lo = p.a_m[0], hi = p.a_m[0];
    for (int i = 0; i < inst.n; ++i) {
      lo = lo.cwiseMin(p.a_m[i]).cwiseMin(p.b_m[i]);
      hi = hi.cwiseMax(p.a_m[i]).cwiseMax(p.b_m[i]);
    }
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d corner((c & 1) ? hi.x() : lo.x(), (c & 2) ? hi.y() : lo.y(), (c & 4) ? hi.z() : lo.z());
      int best = 0;
      double bd = std::numeric_limits<double>::infinity();
      for (int f = 0; f < inst.E; ++f) {
        const double dd = ((f & 1) ? p.b_m[f >> 1] : p.a_m[f >> 1]).operator-(corner).norm();
        if (dd < bd) {
          bd = dd;
          best = f;
        }
      }
      if (std::find(firsts.begin(), firsts.end(), best) == firsts.end()) firsts.push_back(best);
    }
  }
  Path best_path;
  double best_cost = std::numeric_limits<double>::infinity();
  for (int f : firsts) {
    Path s = greedy_from(inst, f);
    const double c = inst.cost(s);
    if (c < best_cost - kImprove) {
      best_cost = c;
      best_path = std::move(s);
    }
  }
  return best_path;
}

// ---------------------------------------------------------------- local search
// 2-opt: reverse s[i..j] and flip each region; inner links keep their length (symmetric metric).
bool two_opt_pass(const Instance& inst, Path& s) {
  const int n = static_cast<int>(s.size());
  bool improved = false;
  for (int i = 0; i < n; ++i) {
    const int prev = i == 0 ? inst.E : (s[i - 1] ^ 1);
    for (int j = i; j < n; ++j) {
      const bool has_next = j + 1 < n;
      const int next = has_next ? s[j + 1] : 0;
      const double before = inst.d(prev, s[i]) + (has_next ? inst.d(s[j] ^ 1, next) : 0.0);
      const double after = inst.d(prev, s[j] ^ 1) + (has_next ? inst.d(s[i], next) : 0.0);
      if (after < before - kImprove) {
        std::reverse(s.begin() + i, s.begin() + j + 1);
        for (int k = i; k <= j; ++k) s[k] ^= 1;
        improved = true;
      }
    }
  }
  return improved;
}

// or-opt: move the block s[i..i+L-1] (L = 1..3) into another gap, as it is or reversed.
bool or_opt_pass(const Instance& inst, Path& s) {
  const int n = static_cast<int>(s.size());
  bool improved = false;
  for (int L = 1; L <= 3; ++L) {
    for (int i = 0; i + L <= n; ++i) {
      const int first = s[i], last_exit = s[i + L - 1] ^ 1;
      const int prev = i == 0 ? inst.E : (s[i - 1] ^ 1);
      const bool has_next = i + L < n;
      const int next = has_next ? s[i + L] : 0;
      const double removal_gain =
          inst.d(prev, first) + (has_next ? inst.d(last_exit, next) - inst.d(prev, next) : 0.0);
      double best_delta = -kImprove;
      int best_q = -1;
      bool best_rev = false;
      for (int q = 0; q <= n; ++q) {
        if (q >= i && q <= i + L) continue;
        const int x = q == 0 ? inst.E : (s[q - 1] ^ 1);
        const bool has_y = q < n;
        const int y = has_y ? s[q] : 0;
        const double base = has_y ? -inst.d(x, y) : 0.0;
        // forward: enter at `first`, leave at `last_exit`; reversed: enter at last_exit, leave at first
        const double fwd = inst.d(x, first) + (has_y ? inst.d(last_exit, y) : 0.0) + base - removal_gain;
        const double rev = inst.d(x, last_exit) + (has_y ? inst.d(first, y) : 0.0) + base - removal_gain;
        if (fwd < best_delta) {
          best_delta = fwd;
          best_q = q;
          best_rev = false;
        }
        if (rev < best_delta) {
          best_delta = rev;
          best_q = q;
          best_rev = true;
        }
      }
      if (best_q < 0) continue;
      Path block(s.begin() + i, s.begin() + i + L);
      if (best_rev) {
        std::reverse(block.begin(), block.end());
        for (int& e : block) e ^= 1;
      }
      Path out;
      out.reserve(static_cast<size_t>(n));
      for (int q = 0; q <= n; ++q) {
        if (q == best_q) out.insert(out.end(), block.begin(), block.end());
        if (q < n && (q < i || q >= i + L)) out.push_back(s[q]);
      }
      s.swap(out);
      improved = true;
    }
  }
  return improved;
}

void local_search(const Instance& inst, Path& s) {
  if (inst.n >= kScalableMinRegions) return local_search_neighbours(inst, s);
  for (int pass = 0; pass < 100000; ++pass) {
    const bool a = two_opt_pass(inst, s);
    const bool b = or_opt_pass(inst, s);
    if (!a && !b) break;
  }
}

// Iterated local search: double-bridge kicks (blocks A B C D -> A C B D), each followed by the
// local search; a kicked path replaces the best only when it is shorter. Deterministic per rng.
void iterated_local_search(const Instance& inst, Path& best, int kicks, std::mt19937_64& rng, const RunControl& ctl) {
  const int n = static_cast<int>(best.size());
  if (n < 8) return;
  double best_cost = inst.cost(best);
  Path t;
  for (int k = 0; k < kicks; ++k) {
    int c[3];
    for (int& x : c) x = 1 + uniform_int(rng, n - 1);
    std::sort(c, c + 3);
    if (c[0] == c[1] || c[1] == c[2]) continue;
    t.clear();
    t.insert(t.end(), best.begin(), best.begin() + c[0]);
    t.insert(t.end(), best.begin() + c[1], best.begin() + c[2]);
    t.insert(t.end(), best.begin() + c[0], best.begin() + c[1]);
    t.insert(t.end(), best.begin() + c[2], best.end());
    local_search(inst, t);
    const double tc = inst.cost(t);
    if (tc < best_cost - kImprove) {
      best_cost = tc;
      best.swap(t);
    }
    ctl.report("iterated local search", static_cast<double>(k + 1) / kicks);
    if (ctl.spent()) break;  // time_budget_s: the best so far
  }
}

// ---------------------------------------------------------------- exact DP
Path exact_path(const Instance& inst) {
  const int n = inst.n, E = inst.E;
  if (n == 0) return {};
  if (n > kExactHardMax)
    throw std::invalid_argument("ordering: exact solver is limited to " + std::to_string(kExactHardMax) +
                                " regions (memory 2^n * 2n states), got " + std::to_string(n));
  const size_t masks = size_t{1} << n;
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> dp(masks * static_cast<size_t>(E), inf);
  std::vector<std::uint8_t> parent(masks * static_cast<size_t>(E), 0xFF);
  for (int e = 0; e < E; ++e) dp[(size_t{1} << (e >> 1)) * E + e] = inst.d(E, e);
  for (size_t mask = 1; mask < masks; ++mask) {
    const double* row = &dp[mask * E];
    for (int e = 0; e < E; ++e) {
      const double c = row[e];
      if (c == inf) continue;
      const double* de = &inst.D[static_cast<size_t>(e ^ 1) * E];
      for (int j = 0; j < n; ++j) {
        if (mask & (size_t{1} << j)) continue;
        const size_t nm = (mask | (size_t{1} << j)) * E;
        for (int f = 2 * j; f <= 2 * j + 1; ++f) {
          const double v = c + de[f];
          if (v < dp[nm + f]) {
            dp[nm + f] = v;
            parent[nm + f] = static_cast<std::uint8_t>(e);
          }
        }
      }
    }
  }
  const size_t full = masks - 1;
  int last = 0;
  for (int e = 1; e < E; ++e)
    if (dp[full * E + e] < dp[full * E + last]) last = e;
  if (!(dp[full * E + last] < inf)) throw std::logic_error("ordering: exact solver found no finite path");
  Path s(static_cast<size_t>(n));
  size_t mask = full;
  for (int k = n - 1; k >= 0; --k) {
    s[static_cast<size_t>(k)] = last;
    const int p = parent[mask * E + last];
    if (k > 0 && p == 0xFF) throw std::logic_error("ordering: exact solver lost its path");
    mask &= ~(size_t{1} << (last >> 1));
    last = p;
  }
  return s;
}

void check_config(const OrderingConfig& c) {
  if (!(c.aco_ants_per_region > 0)) throw std::invalid_argument("ordering.aco_ants_per_region must be > 0");
  if (c.aco_iterations < 1) throw std::invalid_argument("ordering.aco_iterations must be >= 1");
  if (!(c.aco_rho >= 0 && c.aco_rho <= 1)) throw std::invalid_argument("ordering.aco_rho must be in [0, 1]");
  if (!(c.aco_q > 0)) throw std::invalid_argument("ordering.aco_q must be > 0");
  if (c.ga_population < 2) throw std::invalid_argument("ordering.ga_population must be >= 2");
  if (c.ga_generations < 1) throw std::invalid_argument("ordering.ga_generations must be >= 1");
  if (!(c.time_budget_s > 0)) throw std::invalid_argument("ordering.time_budget_s must be > 0");
  if (c.ils_kicks_per_region < 0) throw std::invalid_argument("ordering.ils_kicks_per_region must be >= 0");
}

}  // namespace ordering_internal

using namespace ordering_internal;

namespace {

// Finite and within kMaxOrderingCoordinate_m, else std::invalid_argument naming what and the value.
void check_point(const Eigen::Vector3d& v, const std::string& what) {
  for (int k = 0; k < 3; ++k) {
    const double x = v[k];
    if (std::isfinite(x) && std::abs(x) <= kMaxOrderingCoordinate_m) continue;
    std::ostringstream os;
    os << "ordering: " << what << " has " << "xyz"[k] << " = " << x << " m, ";
    if (std::isfinite(x)) os << "outside the physical range |" << "xyz"[k] << "| <= " << kMaxOrderingCoordinate_m << " m";
    else os << "a non-finite coordinate";
    throw std::invalid_argument(os.str());
  }
}

}  // namespace

void validate_ordering_problem(const OrderingProblem& p) {
  if (p.a_m.size() != p.b_m.size())
    throw std::invalid_argument("ordering: " + std::to_string(p.a_m.size()) + " A endpoints but " +
                                std::to_string(p.b_m.size()) + " B endpoints");
  if (p.a_m.size() > static_cast<size_t>(std::numeric_limits<int>::max() / 4))
    throw std::invalid_argument("ordering: too many regions");
  for (size_t i = 0; i < p.a_m.size(); ++i) {
    check_point(p.a_m[i], "region " + std::to_string(i) + " endpoint a");
    check_point(p.b_m[i], "region " + std::to_string(i) + " endpoint b");
  }
  if (p.start_m) check_point(*p.start_m, "the start point");
}

double link_length(const OrderingProblem& problem, const std::vector<int>& order, const std::vector<bool>& reversed) {
  validate_ordering_problem(problem);
  const size_t n = problem.a_m.size();
  if (order.size() != n || reversed.size() != n)
    throw std::invalid_argument("ordering: order and reversed must have one entry per region (" + std::to_string(n) + ")");
  std::vector<char> seen(n, 0);
  for (int i : order) {
    if (i < 0 || static_cast<size_t>(i) >= n || seen[static_cast<size_t>(i)])
      throw std::invalid_argument("ordering: order is not a permutation of 0.." + std::to_string(n) + "-1 (entry " +
                                  std::to_string(i) + ")");
    seen[static_cast<size_t>(i)] = 1;
  }
  double c = 0.0;
  bool has_prev = problem.start_m.has_value();
  Eigen::Vector3d prev = has_prev ? *problem.start_m : Eigen::Vector3d::Zero();
  for (int i : order) {
    const bool r = reversed[static_cast<size_t>(i)];
    const Eigen::Vector3d& entry = r ? problem.b_m[i] : problem.a_m[i];
    if (has_prev) c += (entry - prev).norm();
    prev = r ? problem.a_m[i] : problem.b_m[i];
    has_prev = true;
  }
  return c;
}

OrderingResult solve_nearest_neighbour(const OrderingProblem& problem) {
  const auto t0 = Clock::now();
  validate_ordering_problem(problem);
  const Instance inst(problem);
  OrderingResult r = to_result(inst, nearest_neighbour_path(inst, problem), "nn");
  r.solve_time_s = seconds_since(t0);
  return r;
}

OrderingResult solve_exact(const OrderingProblem& problem) {
  const auto t0 = Clock::now();
  validate_ordering_problem(problem);
  const Instance inst(problem);
  OrderingResult r = to_result(inst, exact_path(inst), "exact");
  r.solve_time_s = seconds_since(t0);
  return r;
}

OrderingResult improve_local(const OrderingProblem& problem, const OrderingResult& initial) {
  const auto t0 = Clock::now();
  validate_ordering_problem(problem);
  const Instance inst(problem);
  if (initial.order.size() != static_cast<size_t>(inst.n) || initial.reversed.size() != static_cast<size_t>(inst.n))
    throw std::invalid_argument("ordering: the initial result does not have one entry per region");
  link_length(problem, initial.order, initial.reversed);  // checks the permutation
  Path s = to_path(initial);
  local_search(inst, s);
  OrderingResult r = to_result(inst, s, initial.method + "+ls");
  r.best_per_iteration = initial.best_per_iteration;
  r.mean_per_iteration = initial.mean_per_iteration;
  r.solve_time_s = initial.solve_time_s + seconds_since(t0);
  return r;
}

namespace {

// best: exact for small n, the scalable path for large n, else the hybrid colony followed by an
// iterated local search.
OrderingResult solve_best(const OrderingProblem& problem, const OrderingConfig& config, const ProgressFn& progress) {
  const int n = static_cast<int>(problem.a_m.size());
  if (n <= std::min(config.exact_max_regions, kExactHardMax)) return solve_exact(problem);
  if (n >= kScalableMinRegions) {
    const auto t0 = Clock::now();
    check_config(config);
    const Instance inst(problem);
    const RunControl ctl{t0, config.time_budget_s, progress};
    OrderingResult r = to_result(inst, scalable_path(inst, problem, config, ctl), "nn+ils");
    r.solve_time_s = seconds_since(t0);
    return r;
  }
  OrderingConfig hybrid = config;
  hybrid.local_search = true;
  const auto t_start = Clock::now();
  const OrderingResult aco_ls = improve_local(problem, solve_aco(problem, hybrid, progress));
  // Measured on 30 runs at n = 100 (partial rasters): the hybrid colony alone ends 1.0 % (max
  // 2.2 %) above the best known; 200 kicks: 0.12 % (max 0.86 %), 500 kicks: 0.05 % (max 0.27 %)
  // for about 0.4 s of CPU in all.
  const auto t0 = Clock::now();
  const Instance inst(problem);
  Path s = to_path(aco_ls);
  std::mt19937_64 rng(config.seed ^ 0x9E3779B97F4A7C15ULL);
  const RunControl ctl{t_start, config.time_budget_s, progress};
  if (!ctl.spent()) iterated_local_search(inst, s, kBestKicks, rng, ctl);
  OrderingResult r = to_result(inst, s, "aco+ils");
  r.best_per_iteration = aco_ls.best_per_iteration;
  r.mean_per_iteration = aco_ls.mean_per_iteration;
  r.solve_time_s = aco_ls.solve_time_s + seconds_since(t0);
  return r;
}

}  // namespace

OrderingResult solve_ordering(const OrderingProblem& problem, const OrderingConfig& config, const ProgressFn& progress) {
  validate_ordering_problem(problem);
  auto polish = [&](const OrderingResult& r) { return config.local_search ? improve_local(problem, r) : r; };
  switch (config.method) {
    case OrderingMethod::exact: return solve_exact(problem);
    case OrderingMethod::nn: return polish(solve_nearest_neighbour(problem));
    case OrderingMethod::aco: return polish(solve_aco(problem, config, progress));
    case OrderingMethod::ga: return polish(solve_ga(problem, config, progress));
    case OrderingMethod::best: return solve_best(problem, config, progress);
  }
  throw std::invalid_argument("ordering.method must be one of " + enum_choices<OrderingMethod>() + "; got value " +
                              std::to_string(static_cast<int>(config.method)));
}

}  // namespace shotcrete
