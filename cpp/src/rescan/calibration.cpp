// Grid of a finished job, comparison and flow calibration (docs/architecture.md §12).
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "shotcrete/rescan/rescan.hpp"

namespace shotcrete {

Grid grid_from_cells(const TunnelAxis& axis, const DesignProfile& profile, double cell_size_m,
                     const std::vector<int>& rows, const std::vector<int>& cols, const std::vector<double>& theta_rad,
                     const std::vector<double>& d_m, const std::vector<double>& td_before_m) {
  const size_t n = rows.size();
  if (n == 0) throw std::invalid_argument("job grid: no cells");
  if (cols.size() != n || theta_rad.size() != n || d_m.size() != n || td_before_m.size() != n)
    throw std::invalid_argument("job grid: rows, cols, theta, d and TD must have one entry per cell");
  if (!(cell_size_m > 0) || !(profile.radius_m > 0)) throw std::invalid_argument("job grid: cell size and radius must be > 0");
  Grid g;
  g.axis = axis;
  g.profile = profile;
  g.cell_size_m = cell_size_m;
  g.dtheta_rad = cell_size_m / profile.radius_m;
  // build_grid puts the lattice's first edges on multiples of the cell size (and of dtheta).
  g.theta0_rad = std::round((theta_rad[0] - (rows[0] + 0.5) * g.dtheta_rad) / g.dtheta_rad) * g.dtheta_rad;
  g.d0_m = std::round((d_m[0] - (cols[0] + 0.5) * cell_size_m) / cell_size_m) * cell_size_m;
  int max_row = 0, max_col = 0;
  for (size_t i = 0; i < n; ++i) {
    if (rows[i] < 0 || cols[i] < 0 || rows[i] > 1000000 || cols[i] > 1000000)
      throw std::invalid_argument("job grid: cell row/col out of range in cell " + std::to_string(i));
    if (!std::isfinite(theta_rad[i]) || !std::isfinite(d_m[i]) || !std::isfinite(td_before_m[i]))
      throw std::invalid_argument("job grid: non-finite theta, d or TD in cell " + std::to_string(i));
    // cells.csv rounds theta to 1e-6 rad and d to 0.1 mm.
    if (std::abs(g.theta_center(rows[i]) - theta_rad[i]) > 1e-5 || std::abs(g.d_center(cols[i]) - d_m[i]) > 1e-3)
      throw std::invalid_argument("job grid: cell " + std::to_string(i) + " (row " + std::to_string(rows[i]) + ", col " +
                                  std::to_string(cols[i]) + ") is not on the lattice of grid.cell_size_m " +
                                  std::to_string(cell_size_m) + " m and design radius " + std::to_string(profile.radius_m) +
                                  " m: another config than the job's");
    max_row = std::max(max_row, rows[i]);
    max_col = std::max(max_col, cols[i]);
  }
  g.n_theta = max_row + 1;
  g.n_d = max_col + 1;
  if (static_cast<double>(g.n_theta) * g.n_d > 5e7) throw std::invalid_argument("job grid: too many cells");
  g.count.assign(static_cast<size_t>(g.size()), 0);
  g.valid.assign(static_cast<size_t>(g.size()), false);
  g.mean_xyz = Points::Zero(g.size(), 3);
  g.mean_normal = Points::Zero(g.size(), 3);
  g.td_m = Eigen::VectorXd::Constant(g.size(), std::numeric_limits<double>::quiet_NaN());
  for (size_t i = 0; i < n; ++i) {
    const int cell = g.index(rows[i], cols[i]);
    g.valid[static_cast<size_t>(cell)] = true;
    g.count[static_cast<size_t>(cell)] = 1;
    g.td_m[cell] = td_before_m[i];
    const double th = g.theta_center(rows[i]);
    g.mean_xyz.row(cell) =
        axis.to_cartesian(profile.radius_at(th) + profile.radial_offset_m(td_before_m[i], th), th, g.d_center(cols[i])).transpose();
    g.mean_normal.row(cell) = -design_normal(axis, profile, th).transpose();
  }
  return g;
}

Comparison compare_cells(const Eigen::VectorXd& measured_m, const Eigen::VectorXd& predicted_m) {
  if (measured_m.size() != predicted_m.size()) throw std::invalid_argument("compare_cells: sizes differ");
  Comparison out;
  double sum = 0, sum2 = 0;
  for (Eigen::Index i = 0; i < measured_m.size(); ++i) {
    if (!std::isfinite(measured_m[i]) || !std::isfinite(predicted_m[i])) continue;
    const double e = measured_m[i] - predicted_m[i];
    sum += e;
    sum2 += e * e;
    out.max_abs_m = std::max(out.max_abs_m, std::abs(e));
    ++out.cells;
  }
  if (out.cells) {
    out.bias_m = sum / out.cells;
    out.rms_m = std::sqrt(sum2 / out.cells);
  }
  return out;
}

Calibration calibrate_flow(const Eigen::VectorXd& measured_m, const Eigen::VectorXd& predicted_m, const RescanConfig& c) {
  if (measured_m.size() != predicted_m.size()) throw std::invalid_argument("calibrate_flow: sizes differ");
  std::vector<Eigen::Index> use;
  for (Eigen::Index i = 0; i < measured_m.size(); ++i)
    if (std::isfinite(measured_m[i]) && std::isfinite(predicted_m[i]) && predicted_m[i] >= c.calibration_min_deposit_m)
      use.push_back(i);
  const int n0 = static_cast<int>(use.size());
  Calibration out;
  for (int pass = 0; pass < 6; ++pass) {
    if (use.size() < 10)
      throw std::invalid_argument("calibration: " + std::to_string(use.size()) +
                                  " cells with a measured thickness and a predicted deposit of at least "
                                  "rescan.calibration_min_deposit_m; at least 10 are needed");
    double mp = 0, pp = 0;
    for (auto i : use) {
      mp += measured_m[i] * predicted_m[i];
      pp += predicted_m[i] * predicted_m[i];
    }
    out.factor = mp / pp;
    std::vector<double> res;
    double s2 = 0;
    for (auto i : use) {
      res.push_back(measured_m[i] - out.factor * predicted_m[i]);
      s2 += res.back() * res.back();
    }
    out.residual_rms_m = std::sqrt(s2 / static_cast<double>(use.size()));
    out.std_error = std::sqrt(s2 / std::max<double>(1.0, static_cast<double>(use.size()) - 1.0) / pp);
    std::vector<double> absres(res.size());
    std::transform(res.begin(), res.end(), absres.begin(), [](double x) { return std::abs(x); });
    std::nth_element(absres.begin(), absres.begin() + static_cast<long>(absres.size() / 2), absres.end());
    const double limit = 3.0 * 1.4826 * absres[absres.size() / 2];
    std::vector<Eigen::Index> keep;
    for (size_t k = 0; k < use.size(); ++k)
      if (std::abs(res[k]) <= limit) keep.push_back(use[k]);
    if (keep.size() == use.size() || pass == 5 || !(limit > 0)) break;
    use = keep;
  }
  out.cells = static_cast<int>(use.size());
  out.rejected = n0 - out.cells;
  return out;
}

}  // namespace shotcrete
