#pragma once
// The unrolled wall grid: cells of cell_size_m along the axis (d) and of cell_size_m of arc at the
// design radius (theta step = cell_size_m / r_design; on a section, its mean radius, so cells
// span cell_size_m of arc on average). Cell index = row * n_d + col with
// row along theta (up the wall) and col along d (along the tunnel).
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/profile.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

/// Level of an empty cell (no data); never a real level.
constexpr int kNoDataLevel = -100;

struct Grid {
  TunnelAxis axis;
  DesignProfile profile;
  double cell_size_m = 0.05;
  double dtheta_rad = 0.0;  // cell_size_m / design radius
  double theta0_rad = 0.0;  // lower edge of row 0
  double d0_m = 0.0;        // lower edge of column 0
  int n_theta = 0, n_d = 0;

  std::vector<int> count;      // points per cell
  std::vector<bool> valid;     // count >= min_points_per_cell
  Points mean_xyz;             // per cell, m (zero where invalid)
  Points mean_normal;          // per cell, unit, toward the axis (zero where invalid)
  Eigen::VectorXd td_m;        // per cell mean TD (distance from the design line along its normal), m (NaN where invalid)
  long points_not_wall = 0;     // points near the design line left out: normal tilted beyond grid.max_normal_tilt_rad
  long points_outside_bay = 0;  // points near the design line left out: outside the bay's chainage range
  long points_obstacle = 0;     // wall-like points left out: grid.obstacle_gap_m inside their cell's outermost surface

  int size() const { return n_theta * n_d; }
  int index(int row, int col) const { return row * n_d + col; }
  int row_of(int cell) const { return cell / n_d; }
  int col_of(int cell) const { return cell % n_d; }
  double theta_center(int row) const { return theta0_rad + (row + 0.5) * dtheta_rad; }
  double d_center(int col) const { return d0_m + (col + 0.5) * cell_size_m; }
  /// Cell containing (theta, d), or -1 outside the grid.
  int cell_at(double theta_rad, double d_m) const;
  /// Design-line point at the centre of a cell (where the wall should end up).
  Eigen::Vector3d design_point(int cell) const;
  int valid_count() const;
};

/// Chainage range of the bay along the axis [start_m, end_m), m from the axis origin.
struct BayRange {
  double start_m = 0.0, end_m = 0.0;
};

/// Grids a cloud with normals. Points farther than max_deviation_m from the design line, points
/// whose normal tilts more than config.max_normal_tilt_rad from the radial direction (face,
/// floor) and, with `bay`, points outside its chainage range are left out; throws
/// std::invalid_argument if none is left (wrong radius, axis or units). With `bay`, the grid's
/// columns span exactly the range, its ends snapped to the nearest cell edges. A lattice cell whose
/// wall-like points are both a minority of its points near the design line and under half
/// a typical cell's drops them (a floor's noisy normals tip a few of its points under the limit).
/// A wall-like point config.obstacle_gap_m or more inside the outermost surface of its lattice
/// cell (the cell's third-largest wall-like TD) lies on an obstacle in front of the wall (a
/// ventilation duct's top) and is left out too (points_obstacle). kept_points, when given, gets
/// 1 for every point gridded.
Grid build_grid(const Cloud& cloud, const TunnelAxis& axis, const DesignProfile& profile,
                const GridConfig& config, double max_deviation_m, const std::optional<BayRange>& bay = std::nullopt,
                std::vector<char>* kept_points = nullptr);

/// How the bay was chosen (report.json `bay`).
struct BaySelectionResult {
  std::string mode;            // grid.bay: whole | range | detect
  BayRange range;              // the grid's chainage span, m
  double scan_start_m = 0.0, scan_end_m = 0.0;  // chainage span of the wall points of the scan, m
  int lined_columns = 0;       // detect: cross-sections that look lined
  int scan_columns = 0;        // cross-sections of the whole scan's grid
  std::string warning;         // detect found only lining: the whole scan is gridded
};

/// The bay of a grid of the whole scan (docs/architecture.md §3, "Bay selection"). detect: a
/// column (cross-section) is lining when at least config.lined_fraction of its valid cells lie
/// within config.lined_td_m of the design line; the bay is the longest run of columns that are
/// not lining (the farther one along the axis on a tie), less end columns holding under a third
/// of the points of its median cross-section (the face's rim); when every column is lining, the
/// whole scan with a warning. Throws std::invalid_argument when a range misses the scan.
BaySelectionResult select_bay(const Grid& whole_scan, const GridConfig& config);

/// Concrete missing behind the design line [m^3]: a valid cell with TD t > 0 holds the polar wedge
/// of its dtheta between the design line (R at its theta) and R + dr, dr = t / cos(phi) the
/// radial offset of TD t: dtheta * dd * (R dr + dr^2 / 2). On a circle dr = t: the ring sector
/// (the flat cell volume t * dd * R dtheta times 1 + t / (2 R)). Cells with t <= 0 or invalid hold none.
double missing_volume_m3(const Grid& grid);

/// Per-point TD (DesignProfile::td_m: r - r_design on a circle) in metres.
Eigen::VectorXd point_td(const Cloud& cloud, const TunnelAxis& axis, const DesignProfile& profile);

/// Priority level of a TD in millimetres (docs/architecture.md §3).
int level_of_td_mm(double td_mm);
/// Level per cell (kNoDataLevel where invalid).
std::vector<int> cell_levels(const Grid& grid);
/// Count of valid cells per level.
std::map<int, int> level_counts(const std::vector<int>& levels);

struct Region {
  std::vector<int> cells;  // grid cell indices
  int level = 0;
  double td_min_m = 0, td_max_m = 0, td_mean_m = 0;
  int row_min = 0, row_max = 0, col_min = 0, col_max = 0;  // bounding box in grid indices
};

/// 4-connected regions of the cells at `level`; regions smaller than min_cells merge into the
/// nearest region (closest pair of cell centres on the unrolled wall) until large enough.
std::vector<Region> find_regions(const Grid& grid, const std::vector<int>& levels, int level, int min_cells);

}  // namespace shotcrete
