#include "speeds.hpp"

#include <Eigen/Sparse>
#include <nlopt.hpp>

#include <algorithm>
#include <exception>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace shotcrete {

// ---------------------------------------------------------------------------------------------
// Graded rounds

namespace {

using Objective = std::function<double(const std::vector<double>&)>;

// BOBYQA from v within [min_speed, v_max]; v holds the best point on return.
void bobyqa_speeds(Objective& objective, std::vector<double>& v, const std::vector<double>& step,
                   const std::vector<double>& v_max, double min_speed_mps) {
  const int n = static_cast<int>(v.size());
  nlopt::opt opt(nlopt::LN_BOBYQA, n);
  opt.set_lower_bounds(std::vector<double>(n, min_speed_mps));
  opt.set_upper_bounds(v_max);
  opt.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>&, void* data) {
        return (*static_cast<Objective*>(data))(x);
      },
      &objective);
  opt.set_xtol_rel(1e-4);
  opt.set_maxeval(400 * n);
  // BOBYQA needs its first step within half the bound gap.
  opt.set_initial_step(step);
  double best = 0;
  try {
    opt.optimize(v, best);
  } catch (const nlopt::roundoff_limited&) {
    // BOBYQA stopped on rounding: v holds its best point, which is what we want.
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string("speed optimisation (BOBYQA) failed: ") + e.what());
  }
}

// Minimum of a unimodal f on [lo, hi] by golden-section search: the middle of the last bracket.
double golden_section_min(const std::function<double(double)>& f, double lo, double hi, int iterations) {
  const double g = (std::sqrt(5.0) - 1) / 2;
  double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
  double f1 = f(x1), f2 = f(x2);
  for (int it = 0; it < iterations; ++it) {
    if (f1 < f2) {
      hi = x2, x2 = x1, f2 = f1, x1 = hi - g * (hi - lo), f1 = f(x1);
    } else {
      lo = x1, x1 = x2, f1 = f2, x2 = lo + g * (hi - lo), f2 = f(x2);
    }
  }
  return 0.5 * (lo + hi);
}

// One pass: the 1-D problem is solved exactly by a golden-section search on 1/v (convex in it).
double golden_speed(const Objective& objective, double v_max, double min_speed_mps) {
  return 1.0 / golden_section_min([&](double w) { return objective({1.0 / w}); }, 1.0 / v_max, 1.0 / min_speed_mps, 80);
}

// The optimiser's inputs: no empty sets, no non-finite value, bounds the optimiser can use.
void check_speed_problem(const std::vector<PassPart>& parts, std::size_t n_passes, const SpeedTargets& t,
                         const PlannerConfig& cfg, const std::vector<double>& v_max) {
  if (parts.empty() || n_passes == 0 || t.slots.empty())
    throw std::invalid_argument("speed optimisation: no passes or no cells (" + std::to_string(n_passes) +
                                " passes, " + std::to_string(t.slots.size()) + " cells)");
  if (v_max.size() != n_passes) throw std::invalid_argument("speed optimisation: one speed bound per pass is needed");
  if (t.target_m.size() != t.slots.size() || t.guard_max_m.size() != t.guard_slots.size())
    throw std::invalid_argument("speed optimisation: one target per cell and one limit per guarded cell are needed");
  for (double x : t.target_m)
    if (!(x >= 0) || !std::isfinite(x))
      throw std::invalid_argument("speed optimisation: target thickness must be finite and >= 0, got " + std::to_string(x));
  if (*std::max_element(t.target_m.begin(), t.target_m.end()) <= 0)
    throw std::invalid_argument("speed optimisation: every target thickness is 0 (nothing to spray)");
  for (double x : t.guard_max_m)
    if (!(x >= 0) || !std::isfinite(x))
      throw std::invalid_argument("speed optimisation: a guarded cell's limit must be finite and >= 0, got " + std::to_string(x));
  if (!(t.guard_weight >= 0) || !std::isfinite(t.guard_weight))
    throw std::invalid_argument("speed optimisation: the guard weight must be finite and >= 0");
  if (t.background_m.size() > 0) {
    if (t.background_m.size() != parts.front().unit.size())
      throw std::invalid_argument("speed optimisation: the background has " + std::to_string(t.background_m.size()) +
                                  " cell slots, the passes' deposit " + std::to_string(parts.front().unit.size()));
    if (!t.background_m.allFinite()) throw std::invalid_argument("speed optimisation: the background deposit is not finite");
  }
  for (std::size_t j = 0; j < v_max.size(); ++j)
    if (!(v_max[j] > cfg.min_speed_mps) || std::isnan(v_max[j]))
      throw std::invalid_argument("speed optimisation: pass " + std::to_string(j) + " speed bound " +
                                  std::to_string(v_max[j]) + " m/s is not above the minimum speed");
  std::vector<char> seen(n_passes, 0);
  for (const PassPart& part : parts) {
    if (part.pass >= n_passes) throw std::invalid_argument("speed optimisation: a part names pass " + std::to_string(part.pass) + " of " + std::to_string(n_passes));
    seen[part.pass] = 1;
    if (!part.unit.allFinite())
      throw std::invalid_argument("speed optimisation: pass " + std::to_string(part.pass) + " has a non-finite deposit");
    if (!(part.w_floor_s_per_m >= 0) || !std::isfinite(part.w_floor_s_per_m))
      throw std::invalid_argument("speed optimisation: pass " + std::to_string(part.pass) + " has a bad least dwell");
    for (const auto* slots : {&t.slots, &t.guard_slots})
      for (int s : *slots)
        if (s < 0 || s >= part.unit.size())
          throw std::invalid_argument("speed optimisation: cell slot " + std::to_string(s) + " out of range");
  }
  for (std::size_t j = 0; j < n_passes; ++j)
    if (!seen[j]) throw std::invalid_argument("speed optimisation: pass " + std::to_string(j) + " has no deposit");
}

// Thickness on the cells `slots` per part at 1 m/s (sparse: a pass reaches a few hundred cells).
Eigen::SparseMatrix<double> unit_matrix(const std::vector<PassPart>& parts, const std::vector<int>& slots) {
  std::vector<Eigen::Triplet<double>> nz;
  for (std::size_t k = 0; k < parts.size(); ++k)
    for (std::size_t i = 0; i < slots.size(); ++i) {
      const double a = parts[k].unit[slots[i]];
      if (a > 1e-12) nz.emplace_back(static_cast<int>(i), static_cast<int>(k), a);
    }
  Eigen::SparseMatrix<double> A(static_cast<Eigen::Index>(slots.size()), static_cast<Eigen::Index>(parts.size()));
  A.setFromTriplets(nz.begin(), nz.end());
  return A;
}

// The graded objective over the parts' dwells z_k = max(w_pass, w_floor_k).
struct GradedObjective {
  Eigen::SparseMatrix<double> A, G;  // region cells, guarded cells x parts
  Eigen::VectorXd t, hi;
  double guard_weight = 0;
  std::vector<std::size_t> pass_of;  // per part
  std::vector<double> floor_of;      // per part

  Eigen::VectorXd part_dwells(const Eigen::VectorXd& w) const {
    Eigen::VectorXd z(static_cast<Eigen::Index>(pass_of.size()));
    for (std::size_t k = 0; k < pass_of.size(); ++k) z[k] = std::max(w[pass_of[k]], floor_of[k]);
    return z;
  }
  double operator()(const Eigen::VectorXd& w) const {
    const Eigen::VectorXd z = part_dwells(w);
    double f = (A * z - t).array().abs().sum();
    if (G.rows() > 0) f += guard_weight * (G * z - hi).array().max(0.0).sum();
    return f;
  }
};

// The objective is convex in the dwells w = 1/v where no cap binds (a sum of |linear - t| and
// hinges), but BOBYQA's quadratic models stall on its kinks (on a 2-pass test 13 % above a
// brute-force search). Sweeps of exact line minimisations (golden section) along each pass's
// dwell and along the sum and difference of neighbouring passes' dwells (the kinks where two
// passes trade cells) finish the job; each evaluation touches only the cells of those passes.
// lead (empty: none): per variable, the one it was tied to (a pass's end speed: its pass); the
// sum and difference of each tied pair are searched too (where a pass's middle and end trade cells).
void polish_dwells(const GradedObjective& obj, const std::vector<double>& w_lo, const std::vector<double>& w_hi,
                   Eigen::VectorXd& w, const std::vector<std::size_t>& lead = {}) {
  const Eigen::Index n = w.size();
  std::vector<std::vector<std::size_t>> parts_of(static_cast<std::size_t>(n));
  for (std::size_t k = 0; k < obj.pass_of.size(); ++k) parts_of[obj.pass_of[k]].push_back(k);
  using Direction = std::vector<std::pair<Eigen::Index, double>>;
  std::vector<Direction> dirs;
  for (Eigen::Index j = 0; j < n; ++j) {
    dirs.push_back({{j, 1.0}});
    if (j + 1 < n) {
      dirs.push_back({{j, 1.0}, {j + 1, 1.0}});
      dirs.push_back({{j, 1.0}, {j + 1, -1.0}});
    }
    const Eigen::Index l = lead.empty() ? j : static_cast<Eigen::Index>(lead[static_cast<std::size_t>(j)]);
    if (l != j && l != j - 1 && l != j + 1) {
      dirs.push_back({{j, 1.0}, {l, 1.0}});
      dirs.push_back({{j, 1.0}, {l, -1.0}});
    }
  }
  Eigen::VectorXd z = obj.part_dwells(w);
  Eigen::VectorXd Ta = obj.A * z, Tg = obj.G * z;
  // Entries (row, part, value) of the parts a direction moves, by row; rows listed once.
  struct Entry { Eigen::Index row; std::size_t part; double a; };
  auto entries = [&](const Eigen::SparseMatrix<double>& M, const Direction& d, std::vector<Entry>& out,
                     std::vector<Eigen::Index>& rows) {
    out.clear();
    rows.clear();
    for (const auto& [j, dj] : d)
      for (std::size_t k : parts_of[static_cast<std::size_t>(j)])
        for (Eigen::SparseMatrix<double>::InnerIterator it(M, static_cast<Eigen::Index>(k)); it; ++it)
          out.push_back({it.row(), k, it.value()});
    for (const auto& e : out) rows.push_back(e.row);
    std::sort(rows.begin(), rows.end());
    rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
  };
  std::vector<Entry> ea, eg;
  std::vector<Eigen::Index> ra, rg;
  // Deposit change per row at a step: dense, only the rows a direction touches reset and read.
  std::vector<double> delta_a(static_cast<std::size_t>(obj.A.rows()), 0.0), delta_g(static_cast<std::size_t>(obj.G.rows()), 0.0);
  for (int sweep = 0; sweep < 30; ++sweep) {
    double gain = 0;
    for (const Direction& d : dirs) {
      double s_lo = -std::numeric_limits<double>::infinity(), s_hi = std::numeric_limits<double>::infinity();
      for (const auto& [j, dj] : d) {
        const double a = (w_lo[j] - w[j]) / dj, b = (w_hi[j] - w[j]) / dj;
        s_lo = std::max(s_lo, std::min(a, b));
        s_hi = std::min(s_hi, std::max(a, b));
      }
      if (!(s_hi > s_lo)) continue;
      entries(obj.A, d, ea, ra);
      entries(obj.G, d, eg, rg);
      // Change of every moved part's dwell at step s.
      auto dz = [&](std::size_t k, double step) {
        double dj = 0;
        for (const auto& [j, c] : d)
          if (static_cast<std::size_t>(j) == obj.pass_of[k]) dj = c;
        return std::max(w[obj.pass_of[k]] + dj * step, obj.floor_of[k]) - z[k];
      };
      auto cost = [&](double step) {
        double f = 0;
        for (Eigen::Index r : ra) delta_a[static_cast<std::size_t>(r)] = 0.0;
        for (const auto& e : ea) delta_a[static_cast<std::size_t>(e.row)] += e.a * dz(e.part, step);
        for (Eigen::Index r : ra) f += std::abs(Ta[r] + delta_a[static_cast<std::size_t>(r)] - obj.t[r]);
        for (Eigen::Index r : rg) delta_g[static_cast<std::size_t>(r)] = 0.0;
        for (const auto& e : eg) delta_g[static_cast<std::size_t>(e.row)] += e.a * dz(e.part, step);
        for (Eigen::Index r : rg) f += obj.guard_weight * std::max(0.0, Tg[r] + delta_g[static_cast<std::size_t>(r)] - obj.hi[r]);
        return f;
      };
      const double best = golden_section_min(cost, s_lo, s_hi, 50), before = cost(0.0), after = cost(best);
      if (!(after < before)) continue;
      gain += before - after;
      for (const auto& [j, dj] : d) w[j] = std::clamp(w[j] + dj * best, w_lo[j], w_hi[j]);
      z = obj.part_dwells(w);
      Ta = obj.A * z;
      Tg = obj.G * z;
    }
    if (gain < 1e-9 * std::max(1.0, (Ta - obj.t).array().abs().sum())) break;
  }
}

}  // namespace

PassSpeeds optimise_speeds(const std::vector<PassPart>& parts, std::size_t n_passes, const SpeedTargets& targets,
                           const PlannerConfig& cfg, const std::vector<double>& v_max, const std::vector<double>& v_start,
                           const std::vector<std::size_t>& tied_to) {
  check_speed_problem(parts, n_passes, targets, cfg, v_max);
  if (!v_start.empty() && v_start.size() != n_passes)
    throw std::invalid_argument("speed optimisation: " + std::to_string(v_start.size()) + " start speeds for " +
                                std::to_string(n_passes) + " passes");
  // The speeds BOBYQA searches: every variable, or those no other is tied to (the rest follow).
  std::vector<std::size_t> lead(n_passes);
  for (std::size_t j = 0; j < n_passes; ++j) lead[j] = j;
  if (!tied_to.empty()) {
    if (tied_to.size() != n_passes) throw std::invalid_argument("speed optimisation: one tie per speed variable is needed");
    for (std::size_t j = 0; j < n_passes; ++j) {
      if (tied_to[j] >= n_passes)
        throw std::invalid_argument("speed optimisation: speed " + std::to_string(j) + " is tied to speed " +
                                    std::to_string(tied_to[j]) + " of " + std::to_string(n_passes));
      if (tied_to[tied_to[j]] != tied_to[j])
        throw std::invalid_argument("speed optimisation: speed " + std::to_string(j) + " is tied to one that is tied itself");
      lead[j] = tied_to[j];
    }
  }
  std::vector<int> leaders;  // the searched variables
  for (std::size_t j = 0; j < n_passes; ++j)
    if (lead[j] == j) leaders.push_back(static_cast<int>(j));
  const int n_all = static_cast<int>(n_passes);
  const int n = static_cast<int>(leaders.size());
  const int m = static_cast<int>(targets.slots.size());
  GradedObjective obj;
  obj.A = unit_matrix(parts, targets.slots);
  obj.G = unit_matrix(parts, targets.guard_slots);
  obj.t = Eigen::Map<const Eigen::VectorXd>(targets.target_m.data(), m);
  obj.hi = Eigen::Map<const Eigen::VectorXd>(targets.guard_max_m.data(), obj.G.rows());
  obj.guard_weight = targets.guard_weight;
  if (targets.background_m.size() > 0) {  // |T + b - t| = |T - (t - b)|, likewise the guard
    for (int i = 0; i < m; ++i) obj.t[i] -= targets.background_m[targets.slots[i]];
    for (Eigen::Index i = 0; i < obj.hi.size(); ++i) obj.hi[i] -= targets.background_m[targets.guard_slots[i]];
  }
  for (const auto& p : parts) obj.pass_of.push_back(p.pass), obj.floor_of.push_back(p.w_floor_s_per_m);
  std::vector<int> slot_of(n_passes);  // variable -> index among the searched ones
  for (int k = 0; k < n; ++k) slot_of[static_cast<std::size_t>(leaders[k])] = k;
  auto dwells = [&](const std::vector<double>& v) {  // every variable's dwell from the searched speeds
    Eigen::VectorXd w(n_all);
    for (int j = 0; j < n_all; ++j) w[j] = 1.0 / std::min(v[static_cast<std::size_t>(slot_of[lead[j]])], v_max[j]);
    return w;
  };
  Objective objective = [&](const std::vector<double>& v) { return obj(dwells(v)) / m; };
  // Start: one common speed that gives the median target on the median cell.
  std::vector<double> sums(m), tt(obj.t.data(), obj.t.data() + m);
  const Eigen::VectorXd row_sums = obj.A * Eigen::VectorXd::Ones(obj.A.cols());
  for (int i = 0; i < m; ++i) sums[i] = row_sums[i];
  std::nth_element(sums.begin(), sums.begin() + m / 2, sums.end());
  std::nth_element(tt.begin(), tt.begin() + m / 2, tt.end());
  const double t_mid = std::max(tt[m / 2], 1e-3);
  double v0 = sums[m / 2] > 0 ? sums[m / 2] / t_mid : cfg.min_speed_mps;
  PassSpeeds out;
  std::vector<double>& v = out.speeds_mps;
  std::vector<double> vs(n), step(n), vs_max(n);  // the searched speeds
  const bool warm_start = !v_start.empty();
  for (int k = 0; k < n; ++k) {
    const std::size_t j = static_cast<std::size_t>(leaders[k]);
    const bool warm = warm_start && std::isfinite(v_start[j]);
    vs_max[k] = v_max[j];
    vs[k] = std::clamp(warm ? v_start[j] : v0, cfg.min_speed_mps, v_max[j]);
    step[k] = std::min((warm ? 0.1 : 0.25) * vs[k], 0.45 * (v_max[j] - cfg.min_speed_mps));
  }
  if (n >= 2)
    bobyqa_speeds(objective, vs, step, vs_max, cfg.min_speed_mps);
  else
    vs[0] = golden_speed(objective, vs_max[0], cfg.min_speed_mps);
  v.resize(n_passes);
  for (int j = 0; j < n_all; ++j) {
    const std::size_t l = lead[j];
    double vj = vs[static_cast<std::size_t>(slot_of[l])];
    // A warm start keeps a tied speed's ratio to its leader for the polish to start from.
    if (warm_start && l != static_cast<std::size_t>(j) && std::isfinite(v_start[j]) && std::isfinite(v_start[l]) && v_start[l] > 0)
      vj *= v_start[j] / v_start[l];
    v[j] = std::clamp(vj, cfg.min_speed_mps, v_max[j]);
  }
  // The polish frees the tied speeds too (coordinate steps are cheap where BOBYQA's are not).
  if (n_all >= 2) {
    Eigen::VectorXd w(n_all);
    std::vector<double> w_lo(n_all), w_hi(n_all, 1.0 / cfg.min_speed_mps);
    for (int j = 0; j < n_all; ++j) w[j] = 1.0 / v[j], w_lo[j] = 1.0 / v_max[j];
    polish_dwells(obj, w_lo, w_hi, w, lead);
    for (int j = 0; j < n_all; ++j) v[j] = std::clamp(1.0 / w[j], cfg.min_speed_mps, v_max[j]);
  }
  // Can the slowest passes reach the targets at all?
  const Eigen::VectorXd slowest = obj.A * Eigen::VectorXd::Constant(obj.A.cols(), 1.0 / cfg.min_speed_mps);
  const double t_max = obj.t.maxCoeff();
  if (slowest.maxCoeff() < t_max) {
    std::ostringstream msg;
    msg << "target " << std::round(t_max * 1000) << " mm exceeds the " << std::round(slowest.maxCoeff() * 1000)
        << " mm that passes at the slowest speed " << cfg.min_speed_mps << " m/s leave; the cells need more rounds";
    out.note = msg.str();
  }
  return out;
}

double graded_deposit_cost(const SpeedTargets& targets, const Eigen::VectorXd& deposit_m) {
  if (targets.target_m.size() != targets.slots.size() || targets.guard_max_m.size() != targets.guard_slots.size())
    throw std::invalid_argument("graded_deposit_cost: one target per cell and one limit per guarded cell are needed");
  auto at = [&](int s) {
    if (s < 0 || s >= deposit_m.size()) throw std::invalid_argument("graded_deposit_cost: cell slot " + std::to_string(s) + " out of range");
    return deposit_m[s];
  };
  double f = 0;
  for (std::size_t i = 0; i < targets.slots.size(); ++i) f += std::abs(at(targets.slots[i]) - targets.target_m[i]);
  for (std::size_t i = 0; i < targets.guard_slots.size(); ++i)
    f += targets.guard_weight * std::max(0.0, at(targets.guard_slots[i]) - targets.guard_max_m[i]);
  return f;
}

PassSpeeds optimise_speeds(const std::vector<Eigen::VectorXd>& unit_per_pass, const SpeedTargets& targets,
                           const PlannerConfig& cfg, const std::vector<double>& v_max) {
  std::vector<PassPart> parts;
  for (std::size_t j = 0; j < unit_per_pass.size(); ++j) parts.push_back({j, 0.0, unit_per_pass[j]});
  return optimise_speeds(parts, unit_per_pass.size(), targets, cfg, v_max);
}

// ---------------------------------------------------------------------------------------------
// Levelling rounds

Sparse sparsify(const Eigen::VectorXd& v) {
  Sparse s;
  for (Eigen::Index i = 0; i < v.size(); ++i)
    if (v[i] > 1e-9) {
      s.idx.push_back(static_cast<int>(i));
      s.val.push_back(v[i]);
    }
  return s;
}

void set_guard(DwellProblem& problem, const Eigen::VectorXd& td_mm, double band_mm, double weight) {
  problem.guard_weight = weight;
  if (weight <= 0) {
    problem.guard_hi_mm.resize(0);
    problem.guard_lo_mm.resize(0);
    return;
  }
  problem.guard_hi_mm = (td_mm.array() + band_mm).max(0.0).matrix();
  problem.guard_lo_mm = (td_mm.array() - band_mm).max(0.0).matrix();
}

namespace {

// Cost of one cell at deposit x (DwellProblem), and its first and second derivatives in x.
struct CellCost {
  double t = 0, hi = 0, lo = 0, weight = 0;
  double value(double x) const {
    const double over = std::max(0.0, x - hi), under = std::max(0.0, lo - x);
    return 0.5 * ((x - t) * (x - t) + weight * (over * over + under * under));
  }
  double slope(double x) const { return (x - t) + weight * (std::max(0.0, x - hi) - std::max(0.0, lo - x)); }
  double curvature(double x) const { return 1.0 + weight * ((x > hi) + (x < lo)); }
};

// Coordinate descent state: the dwells w and the deposit U w, updated together.
struct DwellSolver {
  const DwellProblem& p;
  std::vector<double> w, w_min;
  Eigen::VectorXd dep;
  bool guarded;

  explicit DwellSolver(const DwellProblem& problem)
      : p(problem), w(problem.unit_mm.size(), 0.0), dep(Eigen::VectorXd::Zero(problem.target_mm.size())),
        guarded(problem.guard_weight > 0 && problem.guard_hi_mm.size() == problem.target_mm.size() &&
                problem.guard_lo_mm.size() == problem.target_mm.size()) {
    if (problem.background_mm.size() == dep.size()) dep = problem.background_mm;
    for (std::size_t j = 0; j < w.size(); ++j) w_min.push_back(1.0 / p.segments[j].cap_mps);
  }
  CellCost cell(int k) const {
    if (!guarded) return {p.target_mm[k], std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(), 0.0};
    return {p.target_mm[k], p.guard_hi_mm[k], p.guard_lo_mm[k],
            p.guard_weight_cell.size() == p.target_mm.size() ? p.guard_weight_cell[k] : p.guard_weight};
  }
  void set(std::size_t j, double value) {
    const double d = value - w[j];
    if (d == 0) return;
    for (std::size_t k = 0; k < p.unit_mm[j].idx.size(); ++k) dep[p.unit_mm[j].idx[k]] += d * p.unit_mm[j].val[k];
    w[j] = value;
  }
  // Slope and curvature of the objective along w[j] at w[j] + d.
  std::pair<double, double> derivatives(std::size_t j, double d) const {
    double g = p.lambda_mm2_per_s * p.segments[j].length_m, h = 0.0;
    for (std::size_t k = 0; k < p.unit_mm[j].idx.size(); ++k) {
      const int c = p.unit_mm[j].idx[k];
      const double a = p.unit_mm[j].val[k], x = dep[c] + d * a;
      const CellCost cc = cell(c);
      g += a * cc.slope(x);
      h += a * a * cc.curvature(x);
    }
    return {g, h};
  }
  // The minimiser of the objective along w[j] within [lo, hi]: Newton steps on the piecewise
  // linear, increasing slope, kept inside a bracket (bisection when a step leaves it); one
  // step is exact without the guard.
  double line_min(std::size_t j, double lo, double hi) const {
    double a = lo - w[j], b = hi - w[j];  // the bracket, as steps from w[j]
    bool a_seen = false, b_seen = false;  // bracket ends where the slope is known (else bounds)
    const double tol = 1e-9 * (hi - lo) + 1e-15;
    double d = std::clamp(0.0, a, b);
    for (int it = 0; it < 60; ++it) {
      const auto [g, h] = derivatives(j, d);
      if (g > 0) {
        b = d, b_seen = true;
      } else if (g < 0) {
        a = d, a_seen = true;
      } else {
        break;
      }
      if (b - a <= tol) break;  // at a bound, or the bracket closed
      double next = h > 0 ? d - g / h : (g > 0 ? a : b);
      if (next <= a) next = a_seen ? 0.5 * (a + b) : a;
      if (next >= b) next = b_seen ? 0.5 * (a + b) : b;
      const bool done = std::abs(next - d) <= tol;
      d = next;
      if (done) break;
    }
    return w[j] + d;
  }
  // The objective at the current dwells (dwell_objective).
  double objective() const {
    double f = 0.0;
    for (Eigen::Index c = 0; c < dep.size(); ++c) f += cell(static_cast<int>(c)).value(dep[c]);
    for (std::size_t j = 0; j < w.size(); ++j) f += p.lambda_mm2_per_s * p.segments[j].length_m * w[j];
    return f;
  }
  // Change of the objective if w[j] became `value`.
  double objective_delta(std::size_t j, double value) const {
    const double d = value - w[j];
    double delta = p.lambda_mm2_per_s * p.segments[j].length_m * d;
    for (std::size_t k = 0; k < p.unit_mm[j].idx.size(); ++k) {
      const int c = p.unit_mm[j].idx[k];
      const CellCost cc = cell(c);
      delta += cc.value(dep[c] + d * p.unit_mm[j].val[k]) - cc.value(dep[c]);
    }
    return delta;
  }
};

}  // namespace

double dwell_objective(const DwellProblem& problem, const std::vector<double>& w) {
  DwellSolver s(problem);
  for (std::size_t j = 0; j < w.size(); ++j) s.set(j, w[j]);
  return s.objective();
}

double deposit_cost(const DwellProblem& problem, const Eigen::VectorXd& deposit_mm) {
  if (deposit_mm.size() != problem.target_mm.size())
    throw std::invalid_argument("deposit_cost: one deposit per cell slot of the problem");
  const DwellSolver s(problem);
  double f = 0.0;
  for (Eigen::Index c = 0; c < deposit_mm.size(); ++c) f += s.cell(static_cast<int>(c)).value(deposit_mm[c]);
  return f;
}

std::vector<double> dwell_bounds(const DwellProblem& problem) {
  const int rounds = std::max(1, problem.lookahead_rounds);
  const bool later = std::any_of(problem.segments.begin(), problem.segments.end(), [](const Segment& s) { return s.later; });
  std::vector<double> out(problem.segments.size());
  for (std::size_t j = 0; j < out.size(); ++j)
    out[j] = round_dwell_max(problem, j) * (!later ? rounds : problem.segments[j].later ? rounds - 1 : 1);
  return out;
}

double lean_slowdown(const std::vector<NozzlePose>& poses, double standoff_m, const TunnelAxis& axis,
                     const DesignProfile& profile) {
  double nozzle_m = 0.0, square_m = 0.0;
  Eigen::Vector3d prev = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Vector3d spot = poses[i].position_m + standoff_m * poses[i].axis;
    const Eigen::Vector3d square = spot - standoff_m * square_axis(axis, profile, spot);
    if (i > 0) {
      nozzle_m += (poses[i].position_m - poses[i - 1].position_m).norm();
      square_m += (square - prev).norm();
    }
    prev = square;
  }
  // A square pose's two paths differ by a hair (between the knots the spline turns the axis up to
  // 4e-5 off the design's normal on the default bay): within 0.1 % they are square, 1 exactly.
  if (!(nozzle_m > 0.0) || !(square_m > nozzle_m * (1.0 + 1e-3))) return 1.0;
  return std::min(square_m / nozzle_m, kMaxLeanSlowdown);
}

// Coordinate descent crawls along directions where two segments trade cells (a close line and
// the later wide line over it): on the default bay's first round (2,223 segments) no sweep count
// up to 3,000 met the change test, while the objective had settled within 0.06 % by sweep 300
// (and ends 0.13 % above the optimum of a projected gradient run 20,000 steps). The objective
// test ends it there; with warm starts the first round's solves take 0.6 s instead of 7.5 s
// (docs/architecture.md §5: the executed residuals on seeds 1-6).
constexpr double kDwellObjectiveTolerance = 1e-4;  // relative decrease over 10 sweeps

std::vector<double> optimise_dwell(const DwellProblem& problem, const std::vector<double>& w_floor,
                                   const std::vector<double>& w_start) {
  const std::size_t n = problem.unit_mm.size();
  if (problem.segments.size() != n || w_floor.size() != n)
    throw std::invalid_argument("optimise_dwell: one segment and one floor per unit deposit");
  if (!w_start.empty() && w_start.size() != n)
    throw std::invalid_argument("optimise_dwell: " + std::to_string(w_start.size()) + " start dwells for " +
                                std::to_string(n) + " segments");
  DwellSolver s(problem);
  const std::vector<double> bound = dwell_bounds(problem);
  const double w_max = bound.empty() ? 0.0 : *std::max_element(bound.begin(), bound.end());
  std::vector<char> empty(n);
  for (std::size_t j = 0; j < n; ++j) empty[j] = problem.unit_mm[j].idx.empty();
  if (!w_start.empty())
    for (std::size_t j = 0; j < n; ++j)
      if (!empty[j] && !std::isnan(w_start[j])) s.set(j, std::clamp(w_start[j], std::min(w_floor[j], bound[j]), bound[j]));
  double f_before = std::numeric_limits<double>::infinity();
  for (int sweep = 0; sweep < 300; ++sweep) {
    if (sweep % 10 == 0) {
      const double f = s.objective();
      if (f_before - f <= kDwellObjectiveTolerance * std::abs(f)) break;
      f_before = f;
    }
    double change = 0;
    for (std::size_t j = 0; j < n; ++j) {
      if (empty[j]) continue;
      const double next = s.line_min(j, std::min(w_floor[j], bound[j]), bound[j]);
      change = std::max(change, std::abs(next - s.w[j]));
      s.set(j, next);
    }
    if (change < 1e-4 * w_max) break;
  }
  // The nozzle cannot move faster than max speed while spraying: below w_min, either stop
  // spraying there or spray at max speed, whichever leaves the smaller objective; then polish.
  for (int pass = 0; pass < 3; ++pass) {
    for (std::size_t j = 0; j < n; ++j) {
      if (s.w[j] <= 0 || s.w[j] >= s.w_min[j] || w_floor[j] > 0) continue;
      s.set(j, s.objective_delta(j, 0.0) <= s.objective_delta(j, s.w_min[j]) ? 0.0 : s.w_min[j]);
    }
    for (std::size_t j = 0; j < n; ++j) {
      if (s.w[j] <= 0 || empty[j]) continue;  // skipped segments stay skipped
      s.set(j, s.line_min(j, std::min(std::max(s.w_min[j], w_floor[j]), bound[j]), bound[j]));
    }
  }
  return s.w;
}

namespace {

// Runs of segments j in [a, b) of one pass line, all sprayed or all off.
struct SpellRun {
  std::size_t a = 0, b = 0;
  bool on = false;
};

std::vector<SpellRun> line_runs(const std::vector<double>& w, std::size_t a, std::size_t b) {
  std::vector<SpellRun> runs;
  for (std::size_t j = a; j < b; ++j) {
    const bool on = w[j] > 0;
    if (runs.empty() || runs.back().on != on) runs.push_back({j, j, on});
    runs.back().b = j + 1;
  }
  return runs;
}

// Sprayed time of a run [s] (dwell w per metre), and the time to cross an off-run between two
// sprayed segments (the nozzle changes speed from one to the other over it).
double on_time_s(const std::vector<Segment>& segs, const std::vector<double>& w, const SpellRun& r) {
  double t = 0.0;
  for (std::size_t j = r.a; j < r.b; ++j) t += w[j] * segs[j].length_m;
  return t;
}
double crossing_time_s(const std::vector<Segment>& segs, const std::vector<double>& w, const SpellRun& r) {
  double len = 0.0;
  for (std::size_t j = r.a; j < r.b; ++j) len += segs[j].length_m;
  const double v_mean = 0.5 * (1.0 / w[r.a - 1] + 1.0 / w[r.b]);
  return len / v_mean;
}

// A pattern change: segments switched on (w > 0: the dwell they could have, used to count time)
// or off (w = 0).
struct Change {
  std::vector<std::size_t> seg;
  std::vector<double> w;
};

// The dwell a segment switched on next to a sprayed one at speed v_from_mps, d_m further along the
// line, can have: as fast as its cap and the speed-change limit allow (limit_speed_changes).
double reachable_dwell(const Segment& seg, double v_from_mps, double d_m, double accel_mps2) {
  return 1.0 / std::min(seg.cap_mps, std::sqrt(v_from_mps * v_from_mps + accel_mps2 * d_m));
}

// Switch on the off segments on both sides of a short sprayed run (alternating, as fast as they
// can go) until it lasts min_s, or it meets another run or the line's ends.
Change lengthen_run(const std::vector<Segment>& segs, const std::vector<double>& w, const SpellRun& r, std::size_t a,
                    std::size_t b, double min_s, double accel_mps2) {
  Change c;
  double t = on_time_s(segs, w, r), d_lo = 0.0, d_hi = 0.0;
  std::size_t lo = r.a, hi = r.b;
  const double v_lo = 1.0 / w[r.a], v_hi = 1.0 / w[r.b - 1];
  while (t < min_s) {
    const bool can_lo = lo > a && w[lo - 1] <= 0 && !(lo - 1 > a && w[lo - 2] > 0);
    const bool can_hi = hi < b && w[hi] <= 0 && !(hi + 1 < b && w[hi + 1] > 0);
    if (!can_lo && !can_hi) break;
    const bool take_lo = can_lo && (!can_hi || d_lo <= d_hi);
    const std::size_t j = take_lo ? --lo : hi++;
    double& d = take_lo ? d_lo : d_hi;
    d += segs[j].length_m;
    c.seg.push_back(j);
    c.w.push_back(reachable_dwell(segs[j], take_lo ? v_lo : v_hi, d, accel_mps2));
    t += c.w.back() * segs[j].length_m;
  }
  return c;
}

// A short gap sprayed through (its dwells are left to the next least-squares solve).
Change spray_gap(const std::vector<Segment>& segs, const SpellRun& r) {
  Change c;
  for (std::size_t j = r.a; j < r.b; ++j) c.seg.push_back(j), c.w.push_back(1.0 / segs[j].cap_mps);
  return c;
}

// Switch off the ends of the sprayed runs on either side of a short gap (each step the one sprayed
// for less time) until the nozzle takes min_s to cross it, or a run is off altogether (the gap
// then reaches the next gap or the line's end).
Change widen_gap(const std::vector<Segment>& segs, const std::vector<double>& w, const SpellRun& left, const SpellRun& gap,
                 const SpellRun& right, double min_s) {
  Change c;
  std::size_t lo = gap.a, hi = gap.b;  // the gap [lo, hi)
  while (lo > left.a && hi < right.b && crossing_time_s(segs, w, SpellRun{lo, hi, false}) < min_s) {
    const bool take_left = w[lo - 1] * segs[lo - 1].length_m <= w[hi] * segs[hi].length_m;
    const std::size_t j = take_left ? --lo : hi++;
    c.seg.push_back(j);
    c.w.push_back(0.0);
  }
  return c;
}

Change switch_off(const SpellRun& r) {
  Change c;
  for (std::size_t j = r.a; j < r.b; ++j) c.seg.push_back(j), c.w.push_back(0.0);
  return c;
}

void add_deposit(Eigen::VectorXd& dep, const Sparse& unit_mm, double dwell) {
  for (std::size_t k = 0; k < unit_mm.idx.size(); ++k) dep[unit_mm.idx[k]] += dwell * unit_mm.val[k];
}

// Segments forced on (a short run lengthened over its neighbours, a short gap sprayed through)
// lay at least their fastest dwell (1 / cap, the floor the next solve gets). That over-fills
// when it pushes a cell more than kForcedOverfill_mm past the guard's upper limit: with the
// machine's caps low (a leaned nozzle's joints, 0.07 m/s) a 0.1 m segment lays 38 mm at its
// fastest, and lengthening short runs side by side laid 80 mm where 30 were left (the face
// scene's level -1 cells). A round cannot take concrete back; the cells a run switched off
// leaves go to the next round's lines.
constexpr double kForcedOverfill_mm = 5.0;
bool forcing_on_overfills(const DwellProblem& problem, const Eigen::VectorXd& dep, const Change& c) {
  if (problem.guard_hi_mm.size() != dep.size()) return false;  // no guard: no over-fill defined
  std::vector<std::pair<int, double>> added;
  for (std::size_t k = 0; k < c.seg.size(); ++k) {
    const Sparse& u = problem.unit_mm[c.seg[k]];
    const double w_least = 1.0 / problem.segments[c.seg[k]].cap_mps;
    for (std::size_t i = 0; i < u.idx.size(); ++i) added.emplace_back(u.idx[i], w_least * u.val[i]);
  }
  std::sort(added.begin(), added.end());
  for (std::size_t i = 0; i < added.size();) {
    const int cell = added[i].first;
    double more = 0.0;
    for (; i < added.size() && added[i].first == cell; ++i) more += added[i].second;
    if (dep[cell] + more > std::max(dep[cell], problem.guard_hi_mm[cell]) + kForcedOverfill_mm) return true;
  }
  return false;
}

}  // namespace

Eigen::VectorXd solved_deposit_mm(const DwellProblem& problem, const std::vector<double>& w) {
  Eigen::VectorXd dep = Eigen::VectorXd::Zero(problem.target_mm.size());
  for (std::size_t j = 0; j < w.size(); ++j)
    if (!problem.segments[j].later) add_deposit(dep, problem.unit_mm[j], w[j]);
  return dep;
}

FlowSpellFix flow_spell_fix(const DwellProblem& problem, const std::vector<double>& w, const FlowConfig& flow,
                            double accel_mps2, double margin_ratio) {
  const std::vector<Segment>& segs = problem.segments;
  if (w.size() != segs.size() || problem.unit_mm.size() != segs.size())
    throw std::invalid_argument("flow_spell_fix: one dwell and one unit deposit per segment");
  FlowSpellFix fix;
  // The dwells and the deposit as the changes so far leave them (a segment forced on at its
  // floor); a change to the state a segment is already in is no change.
  std::vector<double> cur = w;
  Eigen::VectorXd dep = solved_deposit_mm(problem, w);
  if (problem.background_mm.size() == dep.size()) dep += problem.background_mm;
  auto apply = [&](const Change& c) {
    for (std::size_t k = 0; k < c.seg.size(); ++k) {
      const std::size_t j = c.seg[k];
      if ((c.w[k] > 0) == (cur[j] > 0)) continue;
      (c.w[k] > 0 ? fix.force_on : fix.force_off).push_back(j);
      const double now = c.w[k] > 0 ? 1.0 / segs[j].cap_mps : 0.0;  // forced on: the floor
      add_deposit(dep, problem.unit_mm[j], now - std::max(cur[j], 0.0));
      cur[j] = now;
    }
  };
  const double min_on = margin_ratio * flow.min_on_s, min_off = margin_ratio * flow.min_off_s;
  for (std::size_t a = 0; a < segs.size();) {
    std::size_t b = a;
    while (b < segs.size() && segs[b].side == segs[a].side && segs[b].pass == segs[a].pass) ++b;
    if (segs[a].later) {  // a later round's line: not sprayed in this one
      a = b;
      continue;
    }
    const auto runs = line_runs(w, a, b);
    for (std::size_t k = 0; k < runs.size(); ++k) {
      const SpellRun& r = runs[k];
      if (!r.on && k > 0 && k + 1 < runs.size() && crossing_time_s(segs, w, r) < min_off) {
        // A gap that would over-fill sprayed through (forcing_on_overfills) is widened instead
        // (widen_gap); the run after it, trimmed, is left to the check after the next solve.
        const Change through = spray_gap(segs, r);
        if (!forcing_on_overfills(problem, dep, through)) {
          apply(through);
        } else {
          const Change wider = widen_gap(segs, w, runs[k - 1], r, runs[k + 1], min_off);
          apply(wider);
          if (std::any_of(wider.seg.begin(), wider.seg.end(), [&](std::size_t j) { return j >= runs[k + 1].a; })) ++k;
        }
      } else if (r.on && on_time_s(segs, w, r) < min_on) {
        // Measured on the default bay (seed 1): dropping only the stretches shorter than half
        // the minimum and lengthening the others leaves the smallest residual (weighing the two
        // by the objective at fixed dwells left RMS 10-11 mm instead of 9).
        // A lengthening that would over-fill (forcing_on_overfills) is dropped instead.
        if (on_time_s(segs, w, r) < 0.5 * min_on) {
          apply(switch_off(r));
        } else {
          const Change longer = lengthen_run(segs, w, r, a, b, min_on, accel_mps2);
          apply(forcing_on_overfills(problem, dep, longer) ? switch_off(r) : longer);
        }
      }
    }
    a = b;
  }
  return fix;
}

// A cycloidal change from v0 to v1 over a length D peaks at |v1^2 - v0^2| / D. Along every pass
// line, cap the speeds (forward, then backward) so that this stays within accel_mps2; D is the
// shorter neighbouring segment (the timing changes speed across segment boundaries) or the
// spray-off gap between two sprayed segments. The nozzle crosses a gap at speeds between those of
// the segments on either side, so first both are capped by the slowest speed the machine allows
// in the gap (cap_mps per segment, +inf: no cap).
std::vector<double> limit_speed_changes(const std::vector<Segment>& segs, std::vector<double> w, double accel_mps2) {
  auto same_line = [&](std::size_t a, std::size_t b) { return segs[a].side == segs[b].side && segs[a].pass == segs[b].pass; };
  for (std::size_t j = 0; j < segs.size(); ++j) {
    if (w[j] <= 0 || j + 1 >= segs.size() || w[j + 1] > 0 || !same_line(j, j + 1)) continue;
    std::size_t k = j + 1;
    double gap_cap = std::numeric_limits<double>::infinity();
    for (; k < segs.size() && same_line(j, k) && w[k] <= 0; ++k) gap_cap = std::min(gap_cap, segs[k].cap_mps);
    if (k >= segs.size() || !same_line(j, k)) continue;  // the line ends: no gap to cross
    for (std::size_t e : {j, k})
      if (1.0 / w[e] > gap_cap) w[e] = 1.0 / gap_cap;
  }
  auto sweep = [&](bool forward) {
    const std::size_t n = segs.size();
    int prev = -1;
    double gap = 0.0;
    for (std::size_t k = 0; k < n; ++k) {
      const std::size_t j = forward ? k : n - 1 - k;
      if (prev >= 0 && (segs[j].side != segs[prev].side || segs[j].pass != segs[prev].pass)) prev = -1;
      if (w[j] <= 0) {
        if (prev >= 0) gap += segs[j].length_m;
        continue;
      }
      if (prev >= 0) {
        const double d = gap > 0 ? gap : std::min(segs[j].length_m, segs[prev].length_m);
        const double v_prev = 1.0 / w[prev], v_cap = std::sqrt(v_prev * v_prev + accel_mps2 * d);
        if (1.0 / w[j] > v_cap) w[j] = 1.0 / v_cap;
      }
      prev = static_cast<int>(j);
      gap = 0.0;
    }
  };
  sweep(true);
  sweep(false);
  return w;
}

// ---------------------------------------------------------------------------------------------
// Speed caps

std::vector<std::vector<double>> WaypointCaps::operator()(const std::vector<const Pass*>& passes,
                                                          const std::vector<std::string>& where) {
  if (where.size() != passes.size()) throw std::invalid_argument("WaypointCaps: one name per pass");
  std::vector<std::vector<double>> out(passes.size());
  if (!fn_) {
    for (std::size_t i = 0; i < passes.size(); ++i) out[i].assign(passes[i]->waypoints.size(), config_.max_speed_mps);
    return out;
  }
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<std::exception_ptr> failed(passes.size());
#pragma omp parallel for schedule(dynamic, 1) if (passes.size() > 1)
  for (long i = 0; i < static_cast<long>(passes.size()); ++i) {
    const auto k = static_cast<std::size_t>(i);
    try {
      out[k] = fn_(passes[k]->waypoints);
    } catch (...) {
      failed[k] = std::current_exception();
    }
  }
  seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (std::size_t i = 0; i < passes.size(); ++i) {  // errors and warnings in pass order
    if (failed[i]) std::rethrow_exception(failed[i]);
    out[i] = checked(*passes[i], out[i], where[i]);
  }
  return out;
}

std::vector<double> WaypointCaps::checked(const Pass& pass, const std::vector<double>& c, const std::string& where) {
  const PlannerConfig& pc = config_;
  std::vector<double> cap(pass.waypoints.size(), pc.max_speed_mps);
  if (c.size() != cap.size())
    throw std::runtime_error("plan_bay: the speed cap returned " + std::to_string(c.size()) + " values for " +
                             std::to_string(cap.size()) + " waypoints");
  double lowest = pc.max_speed_mps;
  for (std::size_t k = 0; k < cap.size(); ++k) {
    if (std::isnan(c[k])) throw std::runtime_error("plan_bay: the speed cap is NaN at waypoint " + std::to_string(k) + " of " + where);
    lowest = std::min(lowest, c[k]);
    cap[k] = std::clamp(c[k], pc.min_speed_mps, pc.max_speed_mps);
  }
  if (lowest < pc.min_speed_mps) {
    std::ostringstream msg;
    msg << where << ": the machine allows only " << lowest << " m/s on part of the pass, below planner.min_speed_mps "
        << pc.min_speed_mps << " m/s; sprayed at the slowest speed there";
    warnings_.push_back(msg.str());
  }
  return cap;
}

}  // namespace shotcrete
