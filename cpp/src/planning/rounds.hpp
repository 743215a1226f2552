#pragma once
// The rounds of the planner as stages, composed the way ROS-Industrial noether composes its tool
// path planners: plan_bay (planner.cpp) runs one loop per round --
//   grade -> plan the round -> order -> deposit -> stop test --
// and a RoundStages implementation supplies the steps that differ between the two kinds of round:
//   graded_rounds()    planner.mode graded (the thesis): the regions of the highest level, one
//                      BOBYQA speed per pass, until every cell is at level 0 or below;
//   levelling_rounds() planner.mode optimal: every cell still short of flush, one least-squares
//                      dwell per segment of a pass, until another round does not pay off.
// Ordering and deposit are the same for both (planner.cpp).
#include <map>
#include <memory>
#include <optional>
#include <vector>

#include "cell_surface.hpp"
#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/planning/planner.hpp"
#include "speeds.hpp"

namespace shotcrete {

/// The bay at the start of a round, as the loop grades it.
struct Grade {
  int top_level = 0;      // highest of the levels still worked on
  double max_td_m = 0.0;  // largest TD of any valid cell
};

/// Highest level among the valid cells (INT_MIN when there is none).
int top_level(const std::vector<int>& levels);
/// Largest TD of any valid cell (-inf when there is none).
double max_td_m(const Grid& grid);

/// What every round shares: the bay's fixed inputs, and the plan its warnings and counts go to.
struct RoundContext {
  const Config& config;
  const SpotModel& model;
  double spacing_m;            // two-pass spacing of the spot model (golden section)
  WaypointCaps& caps;          // the machine's speed caps along a pass
  Plan& plan;                  // warnings and speed_capped are added here
  const ProgressFn& progress;  // stage "round <number>"
  const std::vector<Eigen::Vector3d>* lean = nullptr;  // per cell, the nozzle's lean (plan_passes); null: square
  mutable std::map<double, double> pitch_m = {};  // levelling lines' pitch per spacing ratio, found once a plan

  void report(int round_number, double fraction) const;
};

/// One round as the stages see it.
struct RoundInput {
  int number = 0;           // 1-based
  Grade grade;              // before the round
  const SprayedWall& wall;  // the wall before the round's deposit (after it, in stop_test)
};

class RoundStages {
 public:
  virtual ~RoundStages() = default;
  /// Cells no round plans (per grid cell, 1 = left out: cells no clear pose can spray): they hold
  /// no level the rounds work on and no TD they grade.
  void exclude(std::vector<char> cells) { excluded_ = std::move(cells); }
  bool excluded(int cell) const { return static_cast<std::size_t>(cell) < excluded_.size() && excluded_[cell]; }
  /// The grid with the excluded cells invalid (the cells the rounds see).
  Grid worked_grid(const Grid& grid) const;
  virtual RoundKind kind() const = 0;
  /// The levels the rounds still work on (the graded rounds leave out the cells set aside).
  virtual std::vector<int> active_levels(const SprayedWall& wall) const = 0;
  /// Nothing left to spray before a round.
  virtual bool finished(const Grade& grade) const = 0;
  /// Regions with passes and speeds for the round, not yet ordered; empty: nothing to spray.
  virtual std::vector<RegionPlan> plan_regions(const RoundInput& in, const CellSurface& cells,
                                               RoundContext& ctx) = 0;
  /// Why the rounds stop when one found nothing to spray.
  virtual StopReason nothing_to_spray(const Grade& grade) const = 0;
  /// After the round's deposit (in.wall is sprayed): a reason to stop, or none to go on.
  virtual std::optional<StopReason> stop_test(const RoundInput& in, const Round& round, RoundContext& ctx) = 0;

 protected:
  void mask(std::vector<int>& levels) const {
    for (std::size_t c = 0; c < excluded_.size() && c < levels.size(); ++c)
      if (excluded_[c]) levels[c] = kNoDataLevel;
  }

 private:
  std::vector<char> excluded_;
};

/// level_margin_m: planner.graded_level_margin_m, how far below level 1's floor (+50 mm) a cell
/// still counts as level 1 for the rounds.
std::unique_ptr<RoundStages> graded_rounds(double level_margin_m);
/// finish_tolerance_m: planner.finish_tolerance_m, the TD every cell must be within to be flush.
std::unique_ptr<RoundStages> levelling_rounds(double finish_tolerance_m);

}  // namespace shotcrete
