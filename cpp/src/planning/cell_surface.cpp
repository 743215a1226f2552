#include "cell_surface.hpp"

namespace shotcrete {

CellSurface::CellSurface(const Grid& g) : slot(g.size(), -1) {
  Cloud c;
  for (int i = 0; i < g.size(); ++i)
    if (g.valid[i]) {
      slot[i] = static_cast<int>(cell_ids.size());
      cell_ids.push_back(i);
    }
  c.xyz.resize(cell_ids.size(), 3);
  c.normals.resize(cell_ids.size(), 3);
  for (std::size_t k = 0; k < cell_ids.size(); ++k) {
    c.xyz.row(k) = g.mean_xyz.row(cell_ids[k]);
    c.normals.row(k) = g.mean_normal.row(cell_ids[k]);
  }
  index = std::make_unique<SurfaceIndex>(c, g.cell_size_m * 2);
}

Eigen::VectorXd unit_deposit(const SpotModel& model, const CellSurface& cells, const std::vector<NozzlePose>& poses,
                             const std::vector<double>& dwell_s, double rebound) {
  Eigen::VectorXd out = Eigen::VectorXd::Zero(cells.cell_ids.size());
  accumulate_dwells(model, *cells.index, poses, dwell_s, rebound, out);
  return out;
}

}  // namespace shotcrete
