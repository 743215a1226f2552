// Region ordering by ant colony (Ant-Cycle, with the hybrid local-search step): see solve_aco in
// ordering.hpp. One iteration: construction of every ant's tour, the best so far, the polished
// iteration best (hybrid), then the pheromone update (evaporation and deposits).
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "instance.hpp"

namespace shotcrete {

using namespace ordering_internal;

namespace {

// ---------------------------------------------------------------- ant colony
// The colony's fixed data: the heuristic eta^beta of every edge and the candidate lists.
struct AcoGraph {
  std::vector<double> eta_b;        // (2n + 1) x 2n, row = exit endpoint (or the start)
  std::vector<int> cand_off, cand;  // candidate regions of row r: cand[cand_off[r] .. cand_off[r + 1])
};

AcoGraph aco_graph(const Instance& inst, const OrderingConfig& cfg) {
  const int n = inst.n, E = inst.E, R = E + 1;
  const int K = 20;  // candidate list length (all other regions when n <= 21)
  AcoGraph g;
  // Heuristic eta^beta = 1 / (d + eps)^beta; eps keeps coincident endpoints finite.
  const double eps = 1e-9 + 1e-6 * inst.mean_distance();
  g.eta_b.resize(static_cast<size_t>(R) * E);
  for (size_t k = 0; k < g.eta_b.size(); ++k) g.eta_b[k] = std::pow(1.0 / (inst.d(static_cast<int>(k / E), static_cast<int>(k % E)) + eps), cfg.aco_beta);
  // Candidate regions per row: the K regions with the nearest endpoint (own region excluded). The
  // start row (2n) lists every region: without a start point it is a virtual start at distance 0
  // from everything, so the colony learns where to begin an open path.
  g.cand_off.assign(static_cast<size_t>(R) + 1, 0);
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
    g.cand.insert(g.cand.end(), idx.begin(), idx.begin() + take);
    g.cand_off[static_cast<size_t>(r) + 1] = static_cast<int>(g.cand.size());
  }
  if (!inst.has_start)  // virtual start: no heuristic preference, pheromone alone decides
    std::fill(g.eta_b.begin() + static_cast<std::ptrdiff_t>(E) * E, g.eta_b.end(), 1.0);
  return g;
}

// One ant's working memory, reused across ants.
struct AntScratch {
  std::vector<char> used;     // per region
  std::vector<int> cj, cf;    // free candidates: region, entry endpoint
  std::vector<double> cw;     // their transition values
  explicit AntScratch(int n)
      : used(static_cast<size_t>(n)), cj(static_cast<size_t>(n)), cf(cj.size()), cw(cj.size()) {}
};

// The entry an ant takes next from `row` (ch: the transition values of that row). For every free
// candidate the direction with the larger value is taken, then a region is drawn with probability
// proportional to it; with no usable value the largest wins, and with the candidates all used the
// best unvisited region.
int next_entry(const Instance& inst, const AcoGraph& g, const double* ch, int row, AntScratch& t,
               std::mt19937_64& rng) {
  const int* cl = g.cand.data() + g.cand_off[static_cast<size_t>(row)];
  const int len = g.cand_off[static_cast<size_t>(row) + 1] - g.cand_off[static_cast<size_t>(row)];
  int m = 0;
  double sum = 0.0;
  for (int k = 0; k < len; ++k) {
    const int j = cl[k];
    if (t.used[static_cast<size_t>(j)]) continue;
    // direction = the endpoint with the larger transition probability
    const bool b = ch[2 * j + 1] > ch[2 * j];
    t.cj[m] = j;
    t.cf[m] = 2 * j + (b ? 1 : 0);
    t.cw[m] = ch[t.cf[m]];
    sum += t.cw[m];
    ++m;
  }
  int next = -1;
  if (m > 0 && sum > 0.0 && std::isfinite(sum)) {
    double r = uniform01(rng) * sum;
    next = t.cf[m - 1];
    for (int k = 0; k < m; ++k) {
      r -= t.cw[k];
      if (r < 0.0) {
        next = t.cf[k];
        break;
      }
    }
  } else if (m > 0) {
    next = t.cf[0];
    for (int k = 1; k < m; ++k)
      if (t.cw[k] > ch[next]) next = t.cf[k];
  } else {  // candidate list exhausted: the best unvisited region
    double bw = -1.0;
    for (int f = 0; f < inst.E; ++f)
      if (!t.used[static_cast<size_t>(f >> 1)] && ch[f] > bw) {
        bw = ch[f];
        next = f;
      }
  }
  // Only a non-finite transition value (a distance that overflowed) leaves no choice: never index
  // with -1 (issue 17: coordinates of 1e155 corrupted the heap here).
  if (next < 0) throw std::logic_error("ordering: the ant colony found no next region (non-finite transition values)");
  return next;
}

// Construction of one ant's tour from the start row: every region once, by the transition rule.
void construct_tour(const Instance& inst, const AcoGraph& g, const std::vector<double>& choice, Path& s,
                    AntScratch& t, std::mt19937_64& rng) {
  std::fill(t.used.begin(), t.used.end(), 0);
  int row = inst.E;
  for (int pos = 0; pos < inst.n; ++pos) {
    const int next = next_entry(inst, g, &choice[static_cast<size_t>(row) * inst.E], row, t, rng);
    s[pos] = next;
    t.used[static_cast<size_t>(next >> 1)] = 1;
    row = next ^ 1;
  }
}

// Pheromone deposit of one path: Q / L on each of its links.
void deposit_pheromone(std::vector<double>& tau, int E, const Path& path, double dep) {
  int r = E;
  for (int e : path) {
    tau[static_cast<size_t>(r) * E + e] += dep;
    r = e ^ 1;
  }
}

// Hybrid step (local_search on): the iteration's best path, polished; it deposits like one more
// ant. The direction rule never takes a farther entry, so only this teaches the colony the entries
// that pay off later.
Path polished_best(const Instance& inst, const std::vector<Path>& paths, const std::vector<double>& lengths) {
  const int ib = static_cast<int>(std::min_element(lengths.begin(), lengths.end()) - lengths.begin());
  Path polished = paths[static_cast<size_t>(ib)];
  local_search(inst, polished);
  return polished;
}

SearchOutput aco(const Instance& inst, const OrderingConfig& cfg, const Path& nn_path, const RunControl& ctl) {
  const int n = inst.n, E = inst.E, R = E + 1;
  std::mt19937_64 rng(cfg.seed);
  const int ants = std::max(1, static_cast<int>(std::lround(cfg.aco_ants_per_region * n)));
  const AcoGraph graph = aco_graph(inst, cfg);
  const double c_nn = inst.cost(nn_path);
  const double tau0 = c_nn > 0 ? ants * cfg.aco_q / c_nn : 1.0;
  std::vector<double> tau(static_cast<size_t>(R) * E, tau0), choice(tau.size());

  SearchOutput out;
  double best_cost = std::numeric_limits<double>::infinity();
  std::vector<Path> paths(static_cast<size_t>(ants), Path(static_cast<size_t>(n)));
  std::vector<double> lengths(static_cast<size_t>(ants));
  AntScratch scratch(n);
  for (int it = 0; it < cfg.aco_iterations; ++it) {
    for (size_t k = 0; k < tau.size(); ++k)
      choice[k] = (cfg.aco_alpha == 1.0 ? tau[k] : std::pow(tau[k], cfg.aco_alpha)) * graph.eta_b[k];
    for (int a = 0; a < ants; ++a) {
      construct_tour(inst, graph, choice, paths[static_cast<size_t>(a)], scratch, rng);
      lengths[static_cast<size_t>(a)] = inst.cost(paths[static_cast<size_t>(a)]);
    }
    double mean = 0.0;
    for (int a = 0; a < ants; ++a) {
      mean += lengths[a];
      if (lengths[a] < best_cost - kImprove) {
        best_cost = lengths[a];
        out.best = paths[a];
      }
    }
    Path polished;
    double polished_len = 0.0;
    if (cfg.local_search) {
      polished = polished_best(inst, paths, lengths);
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
    if (cfg.local_search) deposit_pheromone(tau, E, polished, cfg.aco_q / std::max(polished_len, 1e-12));
    for (int a = 0; a < ants; ++a) deposit_pheromone(tau, E, paths[a], cfg.aco_q / std::max(lengths[a], 1e-12));
    ctl.report("ant colony", static_cast<double>(it + 1) / cfg.aco_iterations);
    if (ctl.spent()) break;  // time_budget_s: the best so far
  }
  return out;
}

}  // namespace

OrderingResult solve_aco(const OrderingProblem& problem, const OrderingConfig& config, const ProgressFn& progress) {
  if (problem.a_m.size() > static_cast<size_t>(kMaxColonyRegions))
    throw std::invalid_argument("ordering: the ant colony is limited to " + std::to_string(kMaxColonyRegions) +
                                " regions (three (2n + 1) x 2n matrices), got " + std::to_string(problem.a_m.size()) +
                                "; use method best or nn");
  return solve_by_search(problem, config, "aco", progress, [&](const Instance& inst, const RunControl& ctl) {
    return aco(inst, config, nearest_neighbour_path(inst, problem), ctl);
  });
}

}  // namespace shotcrete
