#pragma once
// The planner's model of the wall for choosing speeds: one point per valid grid cell (its mean
// position and normal), on which a pass's deposit is cheap to evaluate.
#include <memory>
#include <vector>

#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/surface/grid.hpp"

namespace shotcrete {

/// The valid cells of a grid as a cloud of cell means, with its spatial index.
struct CellSurface {
  std::vector<int> cell_ids;  // valid cells, in index order
  std::vector<int> slot;      // grid cell -> position in cell_ids (-1 if invalid)
  std::unique_ptr<SurfaceIndex> index;

  explicit CellSurface(const Grid& grid);
};

/// Deposit on the cells (per valid-cell slot) of a run of waypoints, each dwelling `dwell_s`.
Eigen::VectorXd unit_deposit(const SpotModel& model, const CellSurface& cells, const std::vector<NozzlePose>& poses,
                             const std::vector<double>& dwell_s, double rebound);

}  // namespace shotcrete
