#pragma once
// Graded region planner (design section 5): rounds of levels -> regions -> passes -> speeds ->
// order -> simulated deposition, plus an optimising mode that targets the final residual and time.
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition.hpp"
#include "shotcrete/grid.hpp"
#include "shotcrete/surface.hpp"

namespace shotcrete {

/// One nozzle pass: waypoints (position + spray axis, tunnel frame) at one constant speed.
struct Pass {
  std::vector<NozzlePose> waypoints;  // spline samples, sample_step_m apart
  double speed_mps = 0.0;
  double length_m = 0.0;
};

struct RegionPlan {
  Region region;                   // cells of the grid (as of the round)
  double target_thickness_m = 0.0; // largest drop needed to take all its cells one level down
  double spacing_m = 0.0;          // distance between neighbouring passes
  std::vector<Pass> passes;        // in spraying order (serpentine)
  bool reversed = false;           // sprayed from the last pass back to the first
};

struct Round {
  int level = 0;                            // the level sprayed in this round
  std::vector<RegionPlan> regions;          // in spraying order
  std::vector<int> order;                   // region order (indices before sorting) from the solver
  double link_length_m = 0.0;               // transit length between regions
  std::string order_method;
  std::map<int, int> levels_before, levels_after;
  Eigen::VectorXd td_after_m;               // per grid cell after the simulated spraying
  double spray_time_s = 0.0;                // nozzle time while spraying
};

struct Plan {
  std::vector<Round> rounds;
  Grid grid_before;                         // grid of the scan
  Eigen::VectorXd td_after_m;               // per grid cell after the last round
  Eigen::VectorXd deposited_m;              // per point of the surface cloud, all rounds
  Cloud sprayed_cloud;                      // surface cloud moved by the deposit
  double spray_time_s = 0.0;
  std::string stop_reason;                  // "flush", "no progress: ...", "max rounds"
  std::vector<int> unreachable_cells;       // cells left above level 0 that no pass could fill
};

using ProgressFn = std::function<void(const std::string& stage, double fraction)>;

/// Plans and simulates a bay until every cell is at level 0 or below, or no round makes progress.
Plan plan_bay(const Surface& surface, const Config& config, const ProgressFn& progress = {});

}  // namespace shotcrete
