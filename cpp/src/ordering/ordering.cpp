// Region ordering: ant colony, genetic algorithm, nearest neighbour, exact DP, local search.
//
// Internal representation: endpoint 2i is A_i, 2i+1 is B_i. A path is the sequence of the entry
// endpoints of its regions; the exit of entry e is e ^ 1 and region = e >> 1, reversed = e & 1.
// Distances live in one (2n + 1) x 2n row-major matrix whose last row is the start point (all zero
// when there is no start), so "before the first region" is just row 2n everywhere.
#include "shotcrete/ordering/ordering.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>

namespace shotcrete {

namespace {

using Clock = std::chrono::steady_clock;
using Path = std::vector<int>;  // entry endpoints in spraying order
constexpr int kExactHardMax = 20;
constexpr int kBestKicks = 500;     // iterated-local-search kicks after the colony in method best
constexpr double kImprove = 1e-10;  // a move must gain more than this [m]

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Portable uniform [0, 1) from the 64-bit engine (same numbers with any standard library).
double uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }
int uniform_int(std::mt19937_64& rng, int n) {  // [0, n)
  return std::min(n - 1, static_cast<int>(uniform01(rng) * n));
}

struct Instance {
  int n = 0;
  int E = 0;                 // 2n endpoints
  bool has_start = false;
  std::vector<double> D;     // (E + 1) x E

  explicit Instance(const OrderingProblem& p) : n(static_cast<int>(p.a_m.size())), E(2 * n), has_start(p.start_m.has_value()) {
    std::vector<Eigen::Vector3d> pts(static_cast<size_t>(E));
    for (int i = 0; i < n; ++i) {
      pts[2 * i] = p.a_m[i];
      pts[2 * i + 1] = p.b_m[i];
    }
    D.assign(static_cast<size_t>(E + 1) * E, 0.0);
    for (int e = 0; e < E; ++e)
      for (int f = e + 1; f < E; ++f) D[e * E + f] = D[f * E + e] = (pts[e] - pts[f]).norm();
    if (has_start)
      for (int f = 0; f < E; ++f) D[static_cast<size_t>(E) * E + f] = (*p.start_m - pts[f]).norm();
  }
  double d(int from_row, int to) const { return D[static_cast<size_t>(from_row) * E + to]; }
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

OrderingResult to_result(const Instance& inst, const Path& s, const std::string& method) {
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
  for (int pass = 0; pass < 100000; ++pass) {
    const bool a = two_opt_pass(inst, s);
    const bool b = or_opt_pass(inst, s);
    if (!a && !b) break;
  }
}

// Iterated local search: double-bridge kicks (blocks A B C D -> A C B D), each followed by the
// local search; a kicked path replaces the best only when it is shorter. Deterministic per rng.
void iterated_local_search(const Instance& inst, Path& best, int kicks, std::mt19937_64& rng) {
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
  Path s(static_cast<size_t>(n));
  size_t mask = full;
  for (int k = n - 1; k >= 0; --k) {
    s[static_cast<size_t>(k)] = last;
    const int p = parent[mask * E + last];
    mask &= ~(size_t{1} << (last >> 1));
    last = p;
  }
  return s;
}

// ---------------------------------------------------------------- ant colony
struct AcoOutput {
  Path best;
  std::vector<double> best_hist, mean_hist;
};

AcoOutput aco(const Instance& inst, const OrderingConfig& cfg, const Path& nn_path) {
  const int n = inst.n, E = inst.E, R = E + 1;
  std::mt19937_64 rng(cfg.seed);
  const int ants = std::max(1, static_cast<int>(std::lround(cfg.aco_ants_per_region * n)));
  const int K = 20;  // candidate list length (all other regions when n <= 21)

  // Heuristic eta^beta = 1 / (d + eps)^beta; eps keeps coincident endpoints finite.
  const double eps = 1e-9 + 1e-6 * inst.mean_distance();
  std::vector<double> eta_b(static_cast<size_t>(R) * E);
  for (size_t k = 0; k < eta_b.size(); ++k) eta_b[k] = std::pow(1.0 / (inst.D[k] + eps), cfg.aco_beta);

  // Candidate regions per row: the K regions with the nearest endpoint (own region excluded). The
  // start row (2n) lists every region: without a start point it is a virtual start at distance 0
  // from everything, so the colony learns where to begin an open path.
  std::vector<int> cand_off(static_cast<size_t>(R) + 1, 0), cand;
  {
    std::vector<int> idx;
    std::vector<double> key(static_cast<size_t>(n));
    for (int r = 0; r < R; ++r) {
      for (int j = 0; j < n; ++j) key[j] = std::min(inst.d(r, 2 * j), inst.d(r, 2 * j + 1));
      idx.clear();
      for (int j = 0; j < n; ++j)
        if (r == E || j != (r >> 1)) idx.push_back(j);
      const int take = r == E ? n : std::min<int>(K, static_cast<int>(idx.size()));
      std::partial_sort(idx.begin(), idx.begin() + take, idx.end(), [&](int a, int b) {
        return key[a] < key[b] || (key[a] == key[b] && a < b);
      });
      cand.insert(cand.end(), idx.begin(), idx.begin() + take);
      cand_off[static_cast<size_t>(r) + 1] = static_cast<int>(cand.size());
    }
  }
  if (!inst.has_start)  // virtual start: no heuristic preference, pheromone alone decides
    std::fill(eta_b.begin() + static_cast<std::ptrdiff_t>(E) * E, eta_b.end(), 1.0);

  const double c_nn = inst.cost(nn_path);
  const double tau0 = c_nn > 0 ? ants * cfg.aco_q / c_nn : 1.0;
  std::vector<double> tau(static_cast<size_t>(R) * E, tau0), choice(tau.size());

  AcoOutput out;
  double best_cost = std::numeric_limits<double>::infinity();
  std::vector<Path> paths(static_cast<size_t>(ants), Path(static_cast<size_t>(n)));
  std::vector<double> lengths(static_cast<size_t>(ants));
  std::vector<char> used(static_cast<size_t>(n));
  std::vector<int> cj(static_cast<size_t>(n)), cf(cj.size());
  std::vector<double> cw(cj.size());

  for (int it = 0; it < cfg.aco_iterations; ++it) {
    for (size_t k = 0; k < tau.size(); ++k)
      choice[k] = (cfg.aco_alpha == 1.0 ? tau[k] : std::pow(tau[k], cfg.aco_alpha)) * eta_b[k];
    for (int a = 0; a < ants; ++a) {
      Path& s = paths[static_cast<size_t>(a)];
      std::fill(used.begin(), used.end(), 0);
      int row = E;
      for (int pos = 0; pos < n; ++pos) {
        const double* ch = &choice[static_cast<size_t>(row) * E];
        const int* cl = cand.data() + cand_off[static_cast<size_t>(row)];
        const int len = cand_off[static_cast<size_t>(row) + 1] - cand_off[static_cast<size_t>(row)];
        int m = 0;
        double sum = 0.0;
        for (int k = 0; k < len; ++k) {
          const int j = cl[k];
          if (used[static_cast<size_t>(j)]) continue;
          // direction = the endpoint with the larger transition probability
          const bool b = ch[2 * j + 1] > ch[2 * j];
          cj[m] = j;
          cf[m] = 2 * j + (b ? 1 : 0);
          cw[m] = ch[cf[m]];
          sum += cw[m];
          ++m;
        }
        int next = -1;
        if (m > 0 && sum > 0.0 && std::isfinite(sum)) {
          double r = uniform01(rng) * sum;
          next = cf[m - 1];
          for (int k = 0; k < m; ++k) {
            r -= cw[k];
            if (r < 0.0) {
              next = cf[k];
              break;
            }
          }
        } else if (m > 0) {
          next = cf[0];
          for (int k = 1; k < m; ++k)
            if (cw[k] > ch[next]) next = cf[k];
        } else {  // candidate list exhausted: the best unvisited region
          double bw = -1.0;
          for (int f = 0; f < E; ++f)
            if (!used[static_cast<size_t>(f >> 1)] && ch[f] > bw) {
              bw = ch[f];
              next = f;
            }
        }
        s[pos] = next;
        used[static_cast<size_t>(next >> 1)] = 1;
        row = next ^ 1;
      }
      lengths[static_cast<size_t>(a)] = inst.cost(s);
    }
    double mean = 0.0;
    for (int a = 0; a < ants; ++a) {
      mean += lengths[a];
      if (lengths[a] < best_cost - kImprove) {
        best_cost = lengths[a];
        out.best = paths[a];
      }
    }
    // Hybrid step (local_search on): the iteration's best path, polished, deposits like one more
    // ant. The direction rule never takes a farther entry, so only this teaches the colony the
    // entries that pay off later.
    Path polished;
    double polished_len = 0.0;
    if (cfg.local_search) {
      const int ib = static_cast<int>(std::min_element(lengths.begin(), lengths.end()) - lengths.begin());
      polished = paths[static_cast<size_t>(ib)];
      local_search(inst, polished);
      polished_len = inst.cost(polished);
      if (polished_len < best_cost - kImprove) {
        best_cost = polished_len;
        out.best = polished;
      }
    }
    out.best_hist.push_back(best_cost);
    out.mean_hist.push_back(mean / ants);
    // Ant-Cycle update: evaporate, then every ant deposits Q / L_k on the links of its path.
    for (double& t : tau) t *= (1.0 - cfg.aco_rho);
    if (cfg.local_search) {
      const double dep = cfg.aco_q / std::max(polished_len, 1e-12);
      int r = E;
      for (int e : polished) {
        tau[static_cast<size_t>(r) * E + e] += dep;
        r = e ^ 1;
      }
    }
    for (int a = 0; a < ants; ++a) {
      const double dep = cfg.aco_q / std::max(lengths[a], 1e-12);
      int r = E;
      for (int e : paths[a]) {
        tau[static_cast<size_t>(r) * E + e] += dep;
        r = e ^ 1;
      }
    }
  }
  return out;
}

// ---------------------------------------------------------------- genetic algorithm
struct GaOutput {
  Path best;
  std::vector<double> best_hist, mean_hist;
};

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

GaOutput ga(const Instance& inst, const OrderingConfig& cfg) {
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
  GaOutput out;
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
  }
  out.best = pop[best];
  return out;
}

void check_config(const OrderingConfig& c) {
  if (!(c.aco_ants_per_region > 0)) throw std::invalid_argument("ordering.aco_ants_per_region must be > 0");
  if (c.aco_iterations < 1) throw std::invalid_argument("ordering.aco_iterations must be >= 1");
  if (!(c.aco_rho >= 0 && c.aco_rho <= 1)) throw std::invalid_argument("ordering.aco_rho must be in [0, 1]");
  if (!(c.aco_q > 0)) throw std::invalid_argument("ordering.aco_q must be > 0");
  if (c.ga_population < 2) throw std::invalid_argument("ordering.ga_population must be >= 2");
  if (c.ga_generations < 1) throw std::invalid_argument("ordering.ga_generations must be >= 1");
}

}  // namespace

void validate_ordering_problem(const OrderingProblem& p) {
  if (p.a_m.size() != p.b_m.size())
    throw std::invalid_argument("ordering: " + std::to_string(p.a_m.size()) + " A endpoints but " +
                                std::to_string(p.b_m.size()) + " B endpoints");
  if (p.a_m.size() > static_cast<size_t>(std::numeric_limits<int>::max() / 4))
    throw std::invalid_argument("ordering: too many regions");
  for (size_t i = 0; i < p.a_m.size(); ++i) {
    if (!p.a_m[i].allFinite())
      throw std::invalid_argument("ordering: region " + std::to_string(i) + " endpoint a has a non-finite coordinate");
    if (!p.b_m[i].allFinite())
      throw std::invalid_argument("ordering: region " + std::to_string(i) + " endpoint b has a non-finite coordinate");
  }
  if (p.start_m && !p.start_m->allFinite())
    throw std::invalid_argument("ordering: the start point has a non-finite coordinate");
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

OrderingResult solve_aco(const OrderingProblem& problem, const OrderingConfig& config) {
  const auto t0 = Clock::now();
  validate_ordering_problem(problem);
  check_config(config);
  const Instance inst(problem);
  if (inst.n == 0) return to_result(inst, {}, "aco");
  AcoOutput o = aco(inst, config, nearest_neighbour_path(inst, problem));
  OrderingResult r = to_result(inst, o.best, "aco");
  r.best_per_iteration = std::move(o.best_hist);
  r.mean_per_iteration = std::move(o.mean_hist);
  r.solve_time_s = seconds_since(t0);
  return r;
}

OrderingResult solve_ga(const OrderingProblem& problem, const OrderingConfig& config) {
  const auto t0 = Clock::now();
  validate_ordering_problem(problem);
  check_config(config);
  const Instance inst(problem);
  if (inst.n == 0) return to_result(inst, {}, "ga");
  GaOutput o = ga(inst, config);
  OrderingResult r = to_result(inst, o.best, "ga");
  r.best_per_iteration = std::move(o.best_hist);
  r.mean_per_iteration = std::move(o.mean_hist);
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

OrderingResult solve_ordering(const OrderingProblem& problem, const OrderingConfig& config) {
  validate_ordering_problem(problem);
  const int n = static_cast<int>(problem.a_m.size());
  const std::string& m = config.method;
  const bool ls = config.local_search;
  if (m == "exact") return solve_exact(problem);
  if (m == "nn") return ls ? improve_local(problem, solve_nearest_neighbour(problem)) : solve_nearest_neighbour(problem);
  if (m == "aco") return ls ? improve_local(problem, solve_aco(problem, config)) : solve_aco(problem, config);
  if (m == "ga") return ls ? improve_local(problem, solve_ga(problem, config)) : solve_ga(problem, config);
  if (m == "best") {
    if (n <= std::min(config.exact_max_regions, kExactHardMax)) return solve_exact(problem);
    OrderingConfig hybrid = config;
    hybrid.local_search = true;
    const OrderingResult aco_ls = improve_local(problem, solve_aco(problem, hybrid));
    // Measured on 30 runs at n = 100 (partial rasters): the hybrid colony alone ends 1.0 % (max
    // 2.2 %) above the best known; 200 kicks: 0.12 % (max 0.86 %), 500 kicks: 0.05 % (max 0.27 %)
    // for about 0.4 s of CPU in all.
    const auto t0 = Clock::now();
    const Instance inst(problem);
    Path s = to_path(aco_ls);
    std::mt19937_64 rng(config.seed ^ 0x9E3779B97F4A7C15ULL);
    iterated_local_search(inst, s, kBestKicks, rng);
    OrderingResult r = to_result(inst, s, "aco+ils");
    r.best_per_iteration = aco_ls.best_per_iteration;
    r.mean_per_iteration = aco_ls.mean_per_iteration;
    r.solve_time_s = aco_ls.solve_time_s + seconds_since(t0);
    return r;
  }
  throw std::invalid_argument("ordering.method must be one of aco, ga, nn, exact, best; got '" + m + "'");
}

}  // namespace shotcrete
