#pragma once
// Region ordering (docs/architecture.md §6): link the regions' rasters into one open path. Each region i
// is a segment A_i -> B_i sprayed either A->B (reversed = false) or B->A (reversed = true); the
// cost is the sum of transit lengths from the exit endpoint of one region to the entry endpoint of
// the next, plus start -> first entry when a start point is given. A generalised TSP with two
// "cities" per region; solvers: ant colony (Ant-Cycle), genetic algorithm, nearest neighbour,
// exact dynamic programming (small n) and a local search that polishes any of them.
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "shotcrete/config.hpp"

namespace shotcrete {

struct OrderingProblem {
  std::vector<Eigen::Vector3d> a_m, b_m;       // endpoints A_i, B_i of every region [m]
  std::optional<Eigen::Vector3d> start_m;      // fixed start (nozzle position), optional
};

struct OrderingResult {
  std::vector<int> order;                      // region indices in spraying order
  std::vector<bool> reversed;                  // reversed[i]: region i sprayed B->A (indexed by region)
  double link_length_m = 0.0;                  // transit length of the whole open path
  double solve_time_s = 0.0;
  std::string method;                          // solver(s) that produced it, e.g. "aco+ls"
  // Convergence (ACO: per iteration, GA: per generation): best-so-far and population mean length.
  std::vector<double> best_per_iteration, mean_per_iteration;
};

/// Largest |coordinate| of an endpoint or the start point [m]: a tunnel bay is metres across, so
/// anything beyond is a unit or data error (and squares of 1e155 overflow every distance).
constexpr double kMaxOrderingCoordinate_m = 1e6;

/// Throws std::invalid_argument for a/b of different sizes, a non-finite coordinate or one beyond
/// kMaxOrderingCoordinate_m (naming the region, endpoint and value).
void validate_ordering_problem(const OrderingProblem& problem);

/// Transit length of a given order. `reversed` is indexed by region (size n); `order` must be a
/// permutation of 0..n-1 (std::invalid_argument otherwise).
double link_length(const OrderingProblem& problem, const std::vector<int>& order,
                   const std::vector<bool>& reversed);

/// Dispatch on config.method: aco | ga | nn | exact | best. aco/ga/nn are passed through
/// improve_local when config.local_search is true. best = exact when n <= exact_max_regions, else
/// the hybrid ant colony + local search (local_search forced on) followed by an iterated local
/// search (500 double-bridge kicks, seeded from config.seed); method string "aco+ils". From
/// 150 regions on (the scalable path, docs/architecture.md §6) best is nearest neighbour, then
/// 2-opt / or-opt over the 10 nearest endpoints and an iterated local search with local
/// double-bridge kicks (ils_kicks_per_region * n); method string "nn+ils". The colony, the GA and
/// the kicks stop once config.time_budget_s is spent (the best so far is returned). progress, if
/// given, is called per phase / iteration with a stage name ("ordering: ...") and the fraction done.
/// Every order returned is checked to be a permutation (std::logic_error otherwise: a bug).
OrderingResult solve_ordering(const OrderingProblem& problem, const OrderingConfig& config,
                              const ProgressFn& progress = {});

/// Ant colony, Ant-Cycle model (ants = aco_ants_per_region * n, alpha, beta, rho, Q, iterations).
/// Pheromone lives on (exit endpoint -> entry endpoint) edges; for every candidate region the
/// direction with the larger transition probability is taken, then a region is drawn with
/// probability proportional to that value. Candidates are limited to the 20 nearest regions when n
/// is larger (falling back to the best unvisited region when all of them are used), which keeps
/// n = 100 fast. Every ant starts from the start point, or from a virtual start at distance zero
/// when there is none (so the colony learns where the open path begins). With
/// config.local_search the colony is a hybrid: each iteration's best path is polished by the local
/// search and deposits pheromone like one more ant (the direction rule alone never tries the
/// farther entry of a region); without it, plain Ant-Cycle.
/// Throws std::invalid_argument above kMaxColonyRegions (its three (2n + 1) x 2n matrices).
OrderingResult solve_aco(const OrderingProblem& problem, const OrderingConfig& config, const ProgressFn& progress = {});
constexpr int kMaxColonyRegions = 2500;

/// Genetic algorithm: chromosome = region order + one direction bit per region; tournament
/// selection (size 2) with the best individual kept, order crossover (OX, the bit travels with its
/// region) with probability ga_crossover, inversion mutation (a reversed sub-sequence, each region
/// in it flipped, as in spraying the block backwards) plus one direction-bit flip, each with
/// probability ga_mutation; ga_population individuals for ga_generations generations.
OrderingResult solve_ga(const OrderingProblem& problem, const OrderingConfig& config, const ProgressFn& progress = {});

/// The two published GA parameter sets: "a" = Pc 0.9 / Pm 0.1 / 400 generations (the defaults),
/// "b" = Pc 0.2 / Pm 0.05 / 100 generations; population 100 in both. Other names throw.
void apply_ga_preset(OrderingConfig& config, const std::string& preset);

/// Nearest neighbour: start at the given start point, or else at the region endpoint closest to a
/// corner of the endpoints' bounding box (every corner is tried, the shortest path kept), then
/// always go to the nearest free endpoint (its region is entered there).
OrderingResult solve_nearest_neighbour(const OrderingProblem& problem);

/// Exact dynamic programming over (visited subset, last region, its direction); O(2^n n^2) time,
/// about 2^n * 2n * 9 bytes of memory. Throws std::invalid_argument above 20 regions.
OrderingResult solve_exact(const OrderingProblem& problem);

/// Local search until no move improves: 2-opt on the sequence (reversing a block also flips every
/// region in it; a block of one is a direction flip) and or-opt (moving a block of 1-3 regions
/// elsewhere, forwards or reversed). Returns a copy with method + "+ls" and the time added. From
/// 150 regions on the moves are limited to the 10 nearest endpoints (neighbour lists, as in LKH).
OrderingResult improve_local(const OrderingProblem& problem, const OrderingResult& initial);

}  // namespace shotcrete
