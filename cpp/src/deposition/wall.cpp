#include "shotcrete/deposition/wall.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace shotcrete {

namespace {

// Cell means and TD of the moved points on their fixed cells, then the levels.
void refresh(SprayedWall& wall) {
  Surface& s = wall.surface;
  Grid& grid = s.grid;
  const int n = grid.size();
  std::vector<int> count(n, 0);
  Points sum = Points::Zero(n, 3);
  Eigen::VectorXd td = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 0; i < s.cloud.size(); ++i) {
    const int c = wall.cell_of_point[i];
    if (c < 0) continue;
    const Eigen::Vector3d p = s.cloud.xyz.row(i).transpose();
    const Eigen::Vector3d cyl = grid.axis.to_cylindrical(p);
    sum.row(c) += s.cloud.xyz.row(i);
    td[c] += s.profile.td_m(cyl[0], cyl[1]);
    count[c] += 1;
  }
  for (int c = 0; c < n; ++c) {
    if (!grid.valid[c] || count[c] == 0) continue;
    grid.mean_xyz.row(c) = sum.row(c) / count[c];
    grid.td_m[c] = td[c] / count[c];
  }
  s.levels = cell_levels(grid);
}

// Normal of the sprayed wall at a cell from the slope of its TD map (central differences):
// after a thick layer the scan's normals no longer describe the surface.
Eigen::Vector3d cell_normal_from_td(const Grid& grid, int c, const DesignProfile& profile) {
  const int row = grid.row_of(c), col = grid.col_of(c);
  auto slope = [&](int r0, int c0, int r1, int c1, double step) {
    const bool ok0 = r0 >= 0 && r0 < grid.n_theta && c0 >= 0 && c0 < grid.n_d && grid.valid[grid.index(r0, c0)];
    const bool ok1 = r1 >= 0 && r1 < grid.n_theta && c1 >= 0 && c1 < grid.n_d && grid.valid[grid.index(r1, c1)];
    const double mid = grid.td_m[c];
    if (ok0 && ok1) return (grid.td_m[grid.index(r1, c1)] - grid.td_m[grid.index(r0, c0)]) / (2 * step);
    if (ok1) return (grid.td_m[grid.index(r1, c1)] - mid) / step;
    if (ok0) return (mid - grid.td_m[grid.index(r0, c0)]) / step;
    return 0.0;
  };
  const double theta = grid.theta_center(row);
  const double r = profile.radius_at(theta) + profile.radial_offset_m(grid.td_m[c], theta);
  const double dr_dd = slope(row, col - 1, row, col + 1, grid.cell_size_m);
  // d/ds along the wall arc at radius r: the theta step of a cell spans r * dtheta of arc (over
  // cos(phi) where the design line is slanted against the ray).
  const double dr_ds = slope(row - 1, col, row + 1, col, r * grid.dtheta_rad / profile.normal_cos_at(theta));
  // TD is measured along the design line's normal n; t is the line's tangent in the section.
  const Eigen::Vector3d radial = design_normal(grid.axis, profile, theta);
  const Eigen::Vector3d tangent = grid.axis.ex.cross(radial);
  // Surface TD(d, s) over the design line: outward normal ~ n - dTD/dd ex - dTD/ds t; the stored
  // normals face the axis.
  return -(radial - dr_dd * grid.axis.ex - dr_ds * tangent).normalized();
}

}  // namespace

SprayedWall unsprayed_wall(const Surface& surface, double max_deviation_m) {
  if (!surface.cloud.has_normals()) throw std::invalid_argument("unsprayed_wall: the surface cloud has no normals");
  SprayedWall wall;
  wall.surface = surface;
  wall.cell_of_point.assign(surface.cloud.size(), -1);
  const Eigen::VectorXd td = point_td(surface.cloud, surface.axis, surface.profile);
  // The points the grid was built from (not the face's rim or a floor's edge in a wall cell), or,
  // for a surface assembled by hand, every point near the design line.
  const bool known = surface.in_grid.size() == static_cast<std::size_t>(surface.cloud.size());
  for (Eigen::Index i = 0; i < surface.cloud.size(); ++i) {
    if (known ? !surface.in_grid[static_cast<std::size_t>(i)] : std::abs(td[i]) > max_deviation_m) continue;
    const Eigen::Vector3d cyl = surface.axis.to_cylindrical(surface.cloud.xyz.row(i).transpose());
    const int c = surface.grid.cell_at(cyl[1], cyl[2]);
    if (c >= 0 && surface.grid.valid[c]) wall.cell_of_point[i] = c;
  }
  refresh(wall);
  return wall;
}

void deposit_layer(SprayedWall& wall, const Eigen::VectorXd& thickness_m) {
  Cloud& cloud = wall.surface.cloud;
  Grid& grid = wall.surface.grid;
  if (thickness_m.size() != cloud.size())
    throw std::invalid_argument("deposit_layer: " + std::to_string(thickness_m.size()) + " thicknesses for " +
                                std::to_string(cloud.size()) + " points");
  if (static_cast<Eigen::Index>(wall.cell_of_point.size()) != cloud.size() || !cloud.has_normals())
    throw std::invalid_argument("deposit_layer: the wall does not come from unsprayed_wall (cells or normals missing)");
  std::vector<char> touched(grid.size(), 0);
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    // Points of no cell (face, floor, lining, a duct) stay as scanned: obstacles and references.
    // A nozzle passing a duct within centimetres would give it metres of "layer" and move it
    // across the axis into the arm's way.
    if (thickness_m[i] <= 0 || wall.cell_of_point[static_cast<std::size_t>(i)] < 0) continue;
    const Eigen::Vector3d p = cloud.xyz.row(i).transpose();
    const Eigen::Vector3d q = p - grid.axis.origin_m;
    const Eigen::Vector3d inward = -(q - q.dot(grid.axis.ex) * grid.axis.ex).normalized();
    const double cos_tilt = std::max(0.5, std::abs(cloud.normals.row(i).dot(inward.transpose())));
    cloud.xyz.row(i) += (thickness_m[i] / cos_tilt) * inward.transpose();
    if (wall.cell_of_point[i] >= 0 && thickness_m[i] > 0.002) touched[wall.cell_of_point[i]] = 1;
  }
  refresh(wall);
  std::vector<Eigen::Vector3d> normal(grid.size());
  for (int c = 0; c < grid.size(); ++c)
    if (touched[c]) {
      normal[c] = cell_normal_from_td(grid, c, wall.surface.profile);
      grid.mean_normal.row(c) = normal[c].transpose();
    }
  for (Eigen::Index i = 0; i < cloud.size(); ++i)
    if (wall.cell_of_point[i] >= 0 && touched[wall.cell_of_point[i]])
      cloud.normals.row(i) = normal[wall.cell_of_point[i]].transpose();
}

}  // namespace shotcrete
