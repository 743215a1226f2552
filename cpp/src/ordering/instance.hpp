#pragma once
// Internals of the region ordering shared by its solvers (ordering.cpp: nearest neighbour, local
// search, exact DP and the dispatch; colony.cpp: ant colony; genetic.cpp: genetic algorithm).
//
// Internal representation: endpoint 2i is A_i, 2i+1 is B_i. A path is the sequence of the entry
// endpoints of its regions; the exit of entry e is e ^ 1 and region = e >> 1, reversed = e & 1.
// Distances live in one (2n + 1) x 2n row-major matrix whose last row is the start point (all zero
// when there is no start), so "before the first region" is just row 2n everywhere.
#include <algorithm>
#include <chrono>
#include <limits>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "shotcrete/ordering/ordering.hpp"

namespace shotcrete::ordering_internal {

using Clock = std::chrono::steady_clock;
using Path = std::vector<int>;  // entry endpoints in spraying order
constexpr double kImprove = 1e-10;  // a move must gain more than this [m]

inline double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Portable uniform [0, 1) from the 64-bit engine (same numbers with any standard library).
inline double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }
inline int uniform_int(std::mt19937_64& rng, int n) {  // [0, n)
  return std::min(n - 1, static_cast<int>(uniform01(rng) * n));
}

// Instances from kScalableMinRegions regions on take the scalable path (scalable.cpp) and keep no
// distance matrix: d() computes the same norm on the fly (bit-identical, the norm is symmetric).
constexpr int kScalableMinRegions = 150;

struct Instance {
  int n = 0;
  int E = 0;                 // 2n endpoints
  bool has_start = false;
  std::vector<Eigen::Vector3d> pts;  // endpoint e, then the start point (if any) at index E
  std::vector<double> D;     // (E + 1) x E below kScalableMinRegions, else empty

  explicit Instance(const OrderingProblem& p) : n(static_cast<int>(p.a_m.size())), E(2 * n), has_start(p.start_m.has_value()) {
    pts.resize(static_cast<size_t>(E) + 1, Eigen::Vector3d::Zero());
    for (int i = 0; i < n; ++i) {
      pts[2 * i] = p.a_m[i];
      pts[2 * i + 1] = p.b_m[i];
    }
    if (has_start) pts[static_cast<size_t>(E)] = *p.start_m;
    if (n >= kScalableMinRegions) return;
    D.assign(static_cast<size_t>(E + 1) * E, 0.0);
    for (int e = 0; e < E; ++e)
      for (int f = e + 1; f < E; ++f) D[e * E + f] = D[f * E + e] = (pts[e] - pts[f]).norm();
    if (has_start)
      for (int f = 0; f < E; ++f) D[static_cast<size_t>(E) * E + f] = (*p.start_m - pts[f]).norm();
  }
  bool has_matrix() const { return !D.empty(); }
  double d(int from_row, int to) const {
    if (has_matrix()) return D[static_cast<size_t>(from_row) * E + to];
    if (from_row == E && !has_start) return 0.0;  // virtual start
    return from_row == to ? 0.0 : (pts[static_cast<size_t>(from_row)] - pts[static_cast<size_t>(to)]).norm();
  }
  double cost(const Path& s) const {
    double c = 0.0;
    int row = E;
    for (int e : s) {
      c += d(row, e);
      row = e ^ 1;
    }
    return c;
  }
  double mean_distance() const {
    if (E < 2) return 1.0;
    double s = 0.0;
    for (int e = 0; e < E; ++e)
      for (int f = 0; f < E; ++f) s += d(e, f);
    return s / (static_cast<double>(E) * (E - 1));
  }
};

/// What bounds and reports one solve: the time budget from its start, and the progress callback
/// (stage names get the prefix "ordering: "; calls at most every 0.2 s, plus 0 and 1).
struct RunControl {
  Clock::time_point t0 = Clock::now();
  double budget_s = std::numeric_limits<double>::infinity();
  ProgressFn progress;
  mutable double last_report_s = -1.0;
  bool spent() const { return seconds_since(t0) > budget_s; }
  void report(const std::string& stage, double fraction) const {
    if (!progress) return;
    const double now = seconds_since(t0);
    if (fraction > 0.0 && fraction < 1.0 && now - last_report_s < 0.2) return;
    last_report_s = now;
    progress("ordering: " + stage, std::clamp(fraction, 0.0, 1.0));
  }
};

/// The result of a path; throws std::logic_error (a solver bug, never bad input) unless the path
/// holds every region exactly once with a valid endpoint.
OrderingResult to_result(const Instance& inst, const Path& s, const std::string& method);
Path to_path(const OrderingResult& r);
/// Nearest-neighbour path (the colony's initial pheromone scale), see solve_nearest_neighbour.
Path nearest_neighbour_path(const Instance& inst, const OrderingProblem& p);
/// 2-opt and or-opt passes until no move improves; from kScalableMinRegions regions on the
/// neighbour-list version (scalable.cpp).
void local_search(const Instance& inst, Path& s);
void local_search_neighbours(const Instance& inst, Path& s);
/// The scalable path for large instances (scalable.cpp): nearest neighbour, neighbour-list local
/// search, iterated local search with local double-bridge kicks within the budget.
Path scalable_path(const Instance& inst, const OrderingProblem& p, const OrderingConfig& cfg, const RunControl& ctl);
/// Throws std::invalid_argument for colony/GA parameters out of range.
void check_config(const OrderingConfig& c);

/// What a population search (colony, GA) returns: its best path and the convergence.
struct SearchOutput {
  Path best;
  std::vector<double> best_hist, mean_hist;  // per iteration / generation
};

/// solve_aco / solve_ga around `search(inst) -> SearchOutput`: the checks, the empty problem, the
/// result with its convergence and solve time.
template <class Search>
OrderingResult solve_by_search(const OrderingProblem& problem, const OrderingConfig& config, const std::string& method,
                               const ProgressFn& progress, Search&& search) {
  const auto t0 = Clock::now();
  validate_ordering_problem(problem);
  check_config(config);
  const Instance inst(problem);
  if (inst.n == 0) return to_result(inst, {}, method);
  RunControl ctl{t0, config.time_budget_s, progress};
  ctl.report(method, 0.0);
  SearchOutput o = search(inst, ctl);
  ctl.report(method, 1.0);
  OrderingResult r = to_result(inst, o.best, method);
  r.best_per_iteration = std::move(o.best_hist);
  r.mean_per_iteration = std::move(o.mean_hist);
  r.solve_time_s = seconds_since(t0);
  return r;
}

}  // namespace shotcrete::ordering_internal
