#pragma once
// Graded region planner (docs/architecture.md §5): rounds of levels -> regions -> passes -> speeds ->
// order -> simulated deposition, plus an optimising mode that targets the final residual and time.
// plan_bay runs the rounds as one loop (grade -> plan the round -> order -> deposit -> stop test);
// the graded (thesis) and the levelling (optimal mode) rounds differ only in the steps of
// src/planning/rounds.hpp.
#include <array>
#include <functional>
#include <map>
#include <ostream>
#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/planning/passes.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/surface/surface.hpp"

namespace shotcrete {

struct RegionPlan {
  Region region;                   // cells of the grid (as of the round)
  double target_thickness_m = 0.0; // largest drop needed to take all its cells one level down
  double spacing_m = 0.0;          // distance between neighbouring passes
  std::vector<Pass> passes;        // in spraying order (serpentine)
  bool reversed = false;           // sprayed from the last pass back to the first
  std::string note;                // why a target could not be met, if so
  /// Raster endpoints for the ordering: first waypoint of the first pass, last of the last.
  Eigen::Vector3d entry_m() const { return passes.front().waypoints.front().position_m; }
  Eigen::Vector3d exit_m() const { return passes.back().waypoints.back().position_m; }
};

/// graded: one level per round (thesis); levelling: every cell still short of flush (optimal mode).
enum class RoundKind { graded, levelling };
constexpr std::array<EnumName<RoundKind>, 2> enum_names(RoundKind) {
  return {{{RoundKind::graded, "graded"}, {RoundKind::levelling, "levelling"}}};
}

struct Round {
  RoundKind kind = RoundKind::graded;
  int level = 0;                            // the level sprayed in this round
  std::vector<RegionPlan> regions;          // in spraying order
  std::vector<int> order;                   // region order (indices before sorting) from the solver
  double link_length_m = 0.0;               // transit length between regions
  std::string order_method;
  std::map<int, int> levels_before, levels_after;
  Eigen::VectorXd td_after_m;               // per grid cell after the simulated spraying
  double spray_time_s = 0.0;                // the pump's flow-on time (region_spray: ramps, minimum spells)
};

/// Why the rounds stopped.
enum class StopKind { flush, no_progress, max_rounds, levelled, time_budget };
constexpr std::array<EnumName<StopKind>, 5> enum_names(StopKind) {
  return {{{StopKind::flush, "flush"},
           {StopKind::no_progress, "no progress"},
           {StopKind::max_rounds, "max rounds reached (planner.max_rounds)"},
           {StopKind::levelled, "levelled"},
           {StopKind::time_budget, "time budget spent (planner.time_budget_s)"}}};
}

struct StopReason {
  StopKind kind = StopKind::flush;
  std::string detail;  // what made no progress, why levelling ends, or the time spent; empty for flush / max rounds
  /// "<kind>" or "<kind>: <detail>", as report.json prints it ("no progress: ...").
  std::string text() const { return detail.empty() ? std::string(enum_name(kind)) : enum_name(kind) + (": " + detail); }
};
inline std::ostream& operator<<(std::ostream& out, const StopReason& r) { return out << r.text(); }

struct Plan {
  std::vector<Round> rounds;
  Grid grid_before;                         // grid of the scan
  Eigen::VectorXd td_after_m;               // per grid cell after the last round
  Eigen::VectorXd deposited_m;              // per point of the surface cloud, all rounds
  Cloud sprayed_cloud;                      // surface cloud moved by the deposit
  double spray_time_s = 0.0;
  double required_volume_m3 = 0.0;          // concrete missing behind the design line (TD > 0), ring sectors (missing_volume_m3)
  double deposition_rate_m3ps = 0.0;        // concrete that stays on the wall per second of spraying
  double physical_limit_s = 0.0;            // required volume / deposition rate
  StopReason stop_reason;
  std::vector<int> unreachable_cells;       // cells left above level 0 that no pass could fill
  std::vector<std::string> warnings;        // targets that could not be met, and why
  int speed_capped = 0;                     // passes (graded) / segments (optimal), all rounds, whose
                                            // speed bound the speed cap lowered below max speed
  std::map<std::string, double> timings_s;  // per stage
};

/// Highest nozzle speed [m/s] at each of a pass's waypoints that the machine can follow (e.g. the
/// arm's joint limits along the pass: arm_speed_caps in timing.hpp); +inf where nothing binds.
using SpeedCapFn = std::function<std::vector<double>(const std::vector<NozzlePose>& waypoints)>;

/// Plans and simulates a bay until every cell is at level 0 or below, or no round makes progress.
/// speed_cap (optional) lowers the speed bound of every pass (graded mode: its slowest waypoint) or
/// segment (optimal mode; a spray-off gap also bounds the segments on either side, since the nozzle
/// crosses it at their speeds), so the simulated deposit is the one the arm can actually spray.
/// excluded_cells (grid cell indices): cells no round plans, grades or counts as unreachable (cells
/// no clear pose can spray, obstructed_cells): no pass is laid for them, so the nozzle is not put
/// where only they would need it; the deposit of their neighbours' passes still lands on them.
/// lean (empty, or one entry per grid cell): the nozzle's lean over each cell (plan_passes), the
/// poses that keep the nozzle clear of what is not wall (nozzle_lean in pipeline/arm_plan.hpp).
Plan plan_bay(const Surface& surface, const Config& config, const ProgressFn& progress = {},
              const SpeedCapFn& speed_cap = {}, const std::vector<int>& excluded_cells = {},
              const std::vector<Eigen::Vector3d>& lean = {});

}  // namespace shotcrete
