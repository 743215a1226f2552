#pragma once
// The executed deposit (docs/architecture.md §9): the concrete the arm lays along its timed
// trajectory, with the pump's flow at every instant (FlowConfig: minimum on/off spells, centred
// start/stop ramps), integrated round by round on the moved wall exactly as the planner deposits.
#include <Eigen/Core>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/flow.hpp"
#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/planning/planner.hpp"
#include "shotcrete/surface/surface.hpp"
#include "shotcrete/timing/trajectory.hpp"

namespace shotcrete {

/// Volumes of the executed deposit [m^3]: sprayed = flow x time x volume rate (rebound included);
/// rebound = sprayed x rebound_fraction; on_wall = the deposit on the scanned cells (cell mean of
/// its points' thickness x the cell's area on the design line); outside = what stays on the wall
/// off the scanned cells: per sample, the spot's rays (a quadrature of the spot disc weighted by
/// its rate) that meet the design surface outside every valid cell.
struct DepositVolumes {
  double sprayed_m3 = 0.0, rebound_m3 = 0.0, on_wall_m3 = 0.0, outside_m3 = 0.0;
  /// (sprayed - rebound - on_wall - outside) / sprayed; 0 without spraying.
  double balance_error() const;
};

struct ExecutedDeposit {
  Eigen::VectorXd deposited_m;  // per point of the surface cloud, all rounds
  Eigen::VectorXd td_after_m;   // per grid cell after the last round (NaN where invalid)
  std::vector<Eigen::VectorXd> round_deposited_m;  // per round, per point of the wall's cloud
  std::vector<Eigen::VectorXd> round_td_after_m;   // per round, per grid cell
  SprayedWall wall;             // the wall as sprayed (cloud, grid, levels)
  FlowSchedule flow;            // the pump's flow over the trajectory
  DepositVolumes volumes;
  double bridged_volume_m3 = 0.0;   // sprayed through the bridged gaps
  double extended_volume_m3 = 0.0;  // sprayed by extending short spells
};

/// The deposit of `trajectory` on `surface`: region r of the trajectory (region_index) belongs to
/// the round whose regions it falls in (regions_per_round[k] regions in round k, in spraying order
/// over all rounds); samples off a region belong to the round of the region before them. Round by
/// round, the flow-weighted dwells are accumulated on a SurfaceIndex of the wall as moved so far
/// (accumulate_dwells) and laid with deposit_layer, as plan_bay does. Throws std::invalid_argument
/// for a region_index beyond the rounds' regions or a surface without normals. The pump is
/// commanded by the trajectory's own spraying flags: it decides on the arm's timing which short
/// gaps it runs through and how it stretches short spells.
ExecutedDeposit execute_deposit(const Surface& surface, const std::vector<int>& regions_per_round,
                                const TimedTrajectory& trajectory, const Config& config);
/// Same with the rounds of `plan` (the plan the trajectory was timed from), the pump commanded by
/// the plan's program (planned_pump_program, program_schedule): the arm re-times the joins (eased turns, joint moves
/// for the stop-and-go middles, tuned parameters), and a pump deciding again on those durations
/// bridged a turn the plan switched off over, or dropped a spell the plan sprayed (33 mm on a patch).
ExecutedDeposit execute_deposit(const Surface& surface, const Plan& plan, const TimedTrajectory& trajectory,
                                const Config& config);

/// The pump's program: commanded spells [on_s[k], off_s[k]] [s], sorted and apart.
struct PumpProgram {
  std::vector<double> on_s, off_s;
};

/// The plan's pump program on the trajectory's timing: for region r of the trajectory (the plan's
/// r-th region in spraying order, its passes numbered on from the regions before it), the
/// planner's flow schedule of that region (region_spray's commanded switches, after its minimum
/// spells and ramps) with every switch on a pass moved to the time the trajectory reaches the same
/// place on it (the same share of its nozzle path), and every switch off the passes (in a join,
/// the lead-in or the lead-out) the same time from the nearer end of a pass, within its join: the
/// pump's rules are in time (a spell lengthened to min_on_s into a join stays that long). The pump then
/// runs it with program_schedule, which only changes it where the re-timing broke a minimum spell
/// or a joint move's clearance. A region with no samples on the trajectory gets no spells. Throws
/// std::invalid_argument when a sample's region or pass is not in the plan, or a region's passes
/// come out of order.
PumpProgram planned_pump_program(const Plan& plan, const TimedTrajectory& trajectory, const Config& config);

/// Share of the spot's volume at `nozzle` that lands off every valid cell of `grid`: the disc at
/// H0 split into 8 rings of equal volume x 16 directions; each ray meets the design surface, then
/// the surface through the TD of the cell it met there (DepositVolumes::outside_m3).
double spot_miss_fraction(const SpotModel& model, const Grid& grid, const NozzlePose& nozzle);

/// A bound that settles most of spot_miss_fraction's zeros without casting its rays: on a circle
/// design line, every ray of a spot whose nozzle points outward lands between the cylinders of the
/// grid's least and greatest TD, within an axial and angular window around the nozzle (closed-form
/// bounds on the ray's elevation, azimuth and length); when every cell of that window is valid,
/// none misses. False (no answer) on a section profile or where the window leaves the grid.
class SpotOnGridBound {
 public:
  SpotOnGridBound(const SpotModel& model, const Grid& grid);
  /// True only when spot_miss_fraction(model, grid, nozzle) is 0.
  bool surely_on_grid(const NozzlePose& nozzle) const;

 private:
  const Grid* grid_;
  double cone_rad_ = 0.0, rho_lo_ = 0.0, rho_hi_ = 0.0;
  bool usable_ = false;
  std::vector<int> invalid_sum_;  // 2-D prefix sums of the invalid cells, (n_theta + 1) x (n_d + 1)
};

/// Per-cell comparison of two TD maps over the valid cells [mm] (a - b).
struct DepositDifferenceMm {
  double rms = 0.0, max_abs = 0.0, mean = 0.0;
};
DepositDifferenceMm deposit_difference_mm(const Eigen::VectorXd& a_m, const Eigen::VectorXd& b_m,
                                          const std::vector<bool>& valid);

}  // namespace shotcrete
