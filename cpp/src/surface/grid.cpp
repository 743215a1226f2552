#include "shotcrete/surface/grid.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <unordered_map>
#include <cstdint>

namespace shotcrete {

int Grid::cell_at(double theta_rad, double d_m) const {
  const int row = static_cast<int>(std::floor((theta_rad - theta0_rad) / dtheta_rad));
  const int col = static_cast<int>(std::floor((d_m - d0_m) / cell_size_m));
  if (row < 0 || row >= n_theta || col < 0 || col >= n_d) return -1;
  return index(row, col);
}

Eigen::Vector3d Grid::design_point(int cell) const {
  const double theta = theta_center(row_of(cell));
  return axis.to_cartesian(profile.radius_at(theta), theta, d_center(col_of(cell)));
}

int Grid::valid_count() const { return static_cast<int>(std::count(valid.begin(), valid.end(), true)); }

double missing_volume_m3(const Grid& g) {
  double v = 0.0;
  for (int c = 0; c < g.size(); ++c) {
    const double t = g.td_m[c];
    if (!g.valid[static_cast<std::size_t>(c)] || !(t > 0.0)) continue;
    // The polar wedge between the design line and the wall t along the line's normal: t / cos(phi)
    // along the ray (the ring sector on a circle).
    const double theta = g.theta_center(g.row_of(c));
    const double r = g.profile.radius_at(theta), dr = g.profile.radial_offset_m(t, theta);
    v += g.dtheta_rad * g.cell_size_m * (r * dr + 0.5 * dr * dr);
  }
  return v;
}

Eigen::VectorXd point_td(const Cloud& cloud, const TunnelAxis& axis, const DesignProfile& profile) {
  Eigen::VectorXd td(cloud.size());
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d c = axis.to_cylindrical(cloud.xyz.row(i).transpose());
    td[i] = profile.td_m(c[0], c[1]);
  }
  return td;
}

Grid build_grid(const Cloud& cloud, const TunnelAxis& axis, const DesignProfile& profile,
                const GridConfig& config, double max_deviation_m, const std::optional<BayRange>& bay,
                std::vector<char>* kept_points) {
  if (!(profile.radius_m > 0) || !std::isfinite(profile.radius_m))
    throw std::invalid_argument("grid: design radius must be > 0, got " + std::to_string(profile.radius_m));
  if (!(config.cell_size_m > 0)) throw std::invalid_argument("grid: cell_size_m must be > 0");
  if (cloud.size() == 0) throw std::invalid_argument("grid: the cloud is empty");
  if (!cloud.has_normals()) throw std::invalid_argument("grid: the cloud needs normals (run estimate_normals)");
  if (bay && !(bay->start_m < bay->end_m))
    throw std::invalid_argument("grid: the bay's start chainage " + std::to_string(bay->start_m) +
                                " m is not below its end " + std::to_string(bay->end_m) + " m");

  Grid g;
  g.axis = axis;
  g.profile = profile;
  g.cell_size_m = config.cell_size_m;
  g.dtheta_rad = config.cell_size_m / profile.radius_m;
  // Bay ends on the nearest cell edges, so the end columns are whole cells of the bay.
  const double bay_d0 = bay ? std::round(bay->start_m / g.cell_size_m) * g.cell_size_m : 0.0;
  const int bay_cols = bay ? std::max(1, static_cast<int>(std::lround((bay->end_m - bay_d0) / g.cell_size_m))) : 0;
  const double cos_tilt = std::cos(config.max_normal_tilt_rad);

  std::vector<Eigen::Vector3d> cyl(cloud.size());
  // 0: not near the line; 1: near it but facing away (not wall); 2: wall-like. A floor's noisy
  // normals tip a few of its points under the tilt limit, and one point makes a cell: a cell of the
  // fixed lattice whose wall-like points are both a minority of its points near the line and under
  // half a typical cell's drops them. (Where the face meets the wall, the face's points
  // outnumber the wall's in the last column, but the wall's are as many as anywhere.)
  // 3: wall-like but obstacle_gap_m or more inside the outermost surface of its lattice cell (the
  // same rays from the axis): something hangs in front of the wall there (a duct's top). The
  // outermost surface is the third-largest TD of the cell's wall-like points, so two outliers
  // beyond the wall do not move it.
  std::vector<char> kind(cloud.size(), 0);
  std::vector<float> td(cloud.size(), 0.0f);
  struct Votes {
    int wall = 0, not_wall = 0;
    float top[3] = {-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
                    -std::numeric_limits<float>::infinity()};  // largest wall-like TDs, descending
    float low = std::numeric_limits<float>::infinity();  // smallest wall-like TD
  };
  std::unordered_map<std::int64_t, Votes> votes;  // lattice cell -> votes
  auto lattice_key = [&](const Eigen::Vector3d& c) {
    return static_cast<std::int64_t>(std::floor(c[1] / g.dtheta_rad)) * 4000037 +
           static_cast<std::int64_t>(std::floor(c[2] / g.cell_size_m));
  };
  std::size_t near_line = 0;
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    cyl[i] = axis.to_cylindrical(cloud.xyz.row(i).transpose());
    const double t = profile.td_m(cyl[i][0], cyl[i][1]);
    if (!(std::abs(t) <= max_deviation_m)) continue;  // NaN: off a section's span
    ++near_line;
    td[i] = static_cast<float>(t);
    // A zero normal (none estimated) counts as wall: only a known tilt leaves a point out.
    const Eigen::Vector3d n = cloud.normals.row(i).transpose();
    const bool facing_away = n.squaredNorm() > 0.25 && std::abs(n.dot(design_normal(axis, profile, cyl[i][1]))) < cos_tilt * n.norm();
    kind[i] = facing_away ? 1 : 2;
    auto& v = votes[lattice_key(cyl[i])];
    if (facing_away) {
      v.not_wall += 1;
      continue;
    }
    v.wall += 1;
    v.low = std::min(v.low, td[i]);
    float x = td[i];
    for (float& slot : v.top)
      if (x > slot) std::swap(x, slot);
  }
  if (config.obstacle_gap_m > 0) {
    // A cell whose outer surface (third-largest TD; the smallest of its TDs when it has under
    // three) lies obstacle_gap_m or more beyond some of its points holds either something in
    // front of the wall or a step across the cell (the lining's end, a ledge): only the first has
    // wall behind the point on the same rays. So the candidates are checked on rays: a point is an
    // obstacle when one of the 3 x 3 fine bins (a quarter of a cell) around it holds a point that
    // far beyond it; a step then moves at most a fine bin and a half of its cell. (A stray point
    // beyond the wall makes no candidate: the cell's third-largest TD ignores two.)
    const float gap = static_cast<float>(config.obstacle_gap_m);
    auto outer_of = [](const Votes& v) { return std::isfinite(v.top[2]) ? v.top[2] : std::isfinite(v.top[1]) ? v.top[1] : v.top[0]; };
    const double fine_th = g.dtheta_rad / 4.0, fine_d = g.cell_size_m / 4.0;
    auto fine_key = [&](std::int64_t row, std::int64_t col) { return row * 40000003 + col; };
    std::unordered_map<std::int64_t, float> fine;  // fine bin of a candidate cell -> largest wall-like TD
    std::vector<Eigen::Index> candidates;
    for (Eigen::Index i = 0; i < cloud.size(); ++i) {
      if (kind[i] != 2) continue;
      const Votes& v = votes[lattice_key(cyl[i])];
      const float outer = outer_of(v);
      if (!(v.low <= outer - gap)) continue;
      const std::int64_t key = fine_key(static_cast<std::int64_t>(std::floor(cyl[i][1] / fine_th)),
                                        static_cast<std::int64_t>(std::floor(cyl[i][2] / fine_d)));
      auto it = fine.emplace(key, td[i]).first;
      it->second = std::max(it->second, td[i]);
      if (td[i] <= outer - gap) candidates.push_back(i);
    }
    for (const Eigen::Index i : candidates) {
      const auto row = static_cast<std::int64_t>(std::floor(cyl[i][1] / fine_th));
      const auto col = static_cast<std::int64_t>(std::floor(cyl[i][2] / fine_d));
      int behind = 0;
      for (int dr = -1; dr <= 1; ++dr)
        for (int dc = -1; dc <= 1; ++dc) {
          const auto it = fine.find(fine_key(row + dr, col + dc));
          behind += it != fine.end() && it->second >= td[i] + gap;
        }
      if (behind >= 1) {
        kind[i] = 3;
        votes[lattice_key(cyl[i])].wall -= 1;  // not a wall vote: the cell's wall is what lies behind it
      }
    }
  }
  std::vector<int> wall_counts;
  for (const auto& kv : votes)
    if (kv.second.wall > 0) wall_counts.push_back(kv.second.wall);
  int typical = 0;
  if (!wall_counts.empty()) {
    std::nth_element(wall_counts.begin(), wall_counts.begin() + wall_counts.size() / 2, wall_counts.end());
    typical = wall_counts[wall_counts.size() / 2];
  }
  std::vector<char> keep(cloud.size(), 0);
  double tmin = std::numeric_limits<double>::infinity(), tmax = -tmin, dmin = tmin, dmax = -tmin;
  std::size_t kept = 0;
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    if (kind[i] == 0) continue;
    if (kind[i] == 3) {
      ++g.points_obstacle;
      continue;
    }
    const auto& v = votes[lattice_key(cyl[i])];
    if (kind[i] == 1 || (v.wall < v.not_wall && 2 * v.wall < typical)) {
      ++g.points_not_wall;
      continue;
    }
    if (bay && (cyl[i][2] < bay_d0 || cyl[i][2] >= bay_d0 + bay_cols * g.cell_size_m)) {
      ++g.points_outside_bay;
      continue;
    }
    keep[i] = 1;
    ++kept;
    tmin = std::min(tmin, cyl[i][1]);
    tmax = std::max(tmax, cyl[i][1]);
    dmin = std::min(dmin, cyl[i][2]);
    dmax = std::max(dmax, cyl[i][2]);
  }
  if (kept == 0) {
    std::ostringstream msg;
    if (near_line == 0) {
      msg << "grid: no point lies within " << max_deviation_m << " m of the design ";
      if (profile.is_circle())
        msg << "radius " << profile.radius_m << " m";
      else
        msg << "section (profile.section_path)";
      msg << " around the axis; check the design profile, the axis, and that coordinates are metres";
    }
    else if (g.points_outside_bay == 0)
      msg << "grid: none of the " << near_line << " points near the design line faces the axis (normals tilted more than grid.max_normal_tilt_rad = "
          << config.max_normal_tilt_rad << " rad from radial): the cloud is no tunnel wall around this axis";
    else
      msg << "grid: no wall point lies in the bay's chainage range [" << bay->start_m << ", " << bay->end_m
          << ") m along the axis; check grid.bay_start_m/bay_end_m against the scan";
    throw std::invalid_argument(msg.str());
  }
  if (kept_points) *kept_points = keep;
  // Cell edges on fixed multiples of the cell size, so cells do not depend on the point sample.
  g.theta0_rad = std::floor(tmin / g.dtheta_rad) * g.dtheta_rad;
  g.n_theta = std::max(1, static_cast<int>(std::floor((tmax - g.theta0_rad) / g.dtheta_rad)) + 1);
  if (bay) {
    g.d0_m = bay_d0;
    g.n_d = bay_cols;
  } else {
    g.d0_m = std::floor(dmin / g.cell_size_m) * g.cell_size_m;
    g.n_d = std::max(1, static_cast<int>(std::floor((dmax - g.d0_m) / g.cell_size_m)) + 1);
  }
  if (static_cast<double>(g.n_theta) * g.n_d > 5e7)
    throw std::invalid_argument("grid: more than 50 million cells; increase grid.cell_size_m");

  const int n = g.size();
  g.count.assign(n, 0);
  g.valid.assign(n, false);
  g.mean_xyz = Points::Zero(n, 3);
  g.mean_normal = Points::Zero(n, 3);
  Eigen::VectorXd r_sum = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    if (!keep[i]) continue;
    const int c = g.cell_at(cyl[i][1], cyl[i][2]);
    if (c < 0) continue;
    g.count[c] += 1;
    g.mean_xyz.row(c) += cloud.xyz.row(i);
    g.mean_normal.row(c) += cloud.normals.row(i);
    r_sum[c] += profile.td_m(cyl[i][0], cyl[i][1]);  // double, not the float copy
  }
  g.td_m = Eigen::VectorXd::Constant(n, std::numeric_limits<double>::quiet_NaN());
  for (int c = 0; c < n; ++c) {
    if (g.count[c] < config.min_points_per_cell || g.count[c] == 0) {
      g.mean_xyz.row(c).setZero();
      g.mean_normal.row(c).setZero();
      continue;
    }
    g.valid[c] = true;
    g.mean_xyz.row(c) /= g.count[c];
    const double len = g.mean_normal.row(c).norm();
    if (len > 1e-12) g.mean_normal.row(c) /= len;
    g.td_m[c] = r_sum[c] / g.count[c];
  }
  return g;
}

BaySelectionResult select_bay(const Grid& whole, const GridConfig& config) {
  BaySelectionResult r;
  r.mode = enum_name(config.bay);
  r.scan_columns = whole.n_d;
  r.scan_start_m = whole.d0_m;
  r.scan_end_m = whole.d0_m + whole.n_d * whole.cell_size_m;
  r.range = {r.scan_start_m, r.scan_end_m};
  if (config.bay == BaySelection::whole) return r;
  if (config.bay == BaySelection::range) {
    if (config.bay_end_m <= r.scan_start_m || config.bay_start_m >= r.scan_end_m) {
      std::ostringstream msg;
      msg << "grid: the bay [" << config.bay_start_m << ", " << config.bay_end_m << ") m (grid.bay_start_m, bay_end_m) misses the scan's wall, which spans ["
          << r.scan_start_m << ", " << r.scan_end_m << ") m along the axis";
      throw std::invalid_argument(msg.str());
    }
    r.range = {config.bay_start_m, config.bay_end_m};
    return r;
  }
  // detect: lining is smooth and on the design line; a fresh bay lies outside it (over-break).
  std::vector<char> lining(whole.n_d, 0);
  std::vector<int> valid(whole.n_d, 0);
  std::vector<long> points(whole.n_d, 0);
  for (int col = 0; col < whole.n_d; ++col) {
    int lined = 0;
    for (int row = 0; row < whole.n_theta; ++row) {
      const int c = whole.index(row, col);
      points[col] += whole.count[c];
      if (!whole.valid[c]) continue;
      ++valid[col];
      if (std::abs(whole.td_m[c]) <= config.lined_td_m) ++lined;
    }
    lining[col] = valid[col] > 0 && lined >= config.lined_fraction * valid[col];
    r.lined_columns += lining[col];
  }
  int best_start = -1, best_len = 0;
  for (int col = 0; col < whole.n_d;) {
    if (lining[col]) {
      ++col;
      continue;
    }
    int end = col;
    while (end < whole.n_d && !lining[end]) ++end;
    if (end - col >= best_len) best_start = col, best_len = end - col;  // >=: the farther run on a tie
    col = end;
  }
  if (best_len == 0) {  // nothing but lining (or a bay already on its design line): grid it all, say so
    std::ostringstream msg;
    msg << "every cross-section of the scan looks lined (" << config.lined_fraction * 100.0
        << " % of its cells within grid.lined_td_m = " << config.lined_td_m * 1000.0
        << " mm of the design line): no unlined bay was found, the whole scan is gridded; set grid.bay to range "
           "(bay_start_m, bay_end_m) if the bay is a part of it";
    r.warning = msg.str();
    return r;
  }
  // End columns of the run holding under a third of the points of its median cross-section are
  // no bay wall: the rim of the face, where the wall's neighbours tilt a few normals toward it.
  std::vector<long> counts(points.begin() + best_start, points.begin() + best_start + best_len);
  std::nth_element(counts.begin(), counts.begin() + counts.size() / 2, counts.end());
  const double typical = static_cast<double>(counts[counts.size() / 2]);
  while (best_len > 1 && points[best_start] < typical / 3.0) ++best_start, --best_len;
  while (best_len > 1 && points[best_start + best_len - 1] < typical / 3.0) --best_len;
  r.range = {whole.d0_m + best_start * whole.cell_size_m, whole.d0_m + (best_start + best_len) * whole.cell_size_m};
  return r;
}

int level_of_td_mm(double td_mm) {
  if (!std::isfinite(td_mm)) return kNoDataLevel;
  if (td_mm < -50.0) return -1;
  if (td_mm < 50.0) return 0;
  if (td_mm < 140.0) return 1;
  return static_cast<int>(std::floor(td_mm / 70.0));
}

std::vector<int> cell_levels(const Grid& grid) {
  std::vector<int> levels(grid.size(), kNoDataLevel);
  for (int c = 0; c < grid.size(); ++c)
    if (grid.valid[c]) levels[c] = level_of_td_mm(grid.td_m[c] * 1000.0);
  return levels;
}

std::map<int, int> level_counts(const std::vector<int>& levels) {
  std::map<int, int> counts;
  for (int l : levels)
    if (l != kNoDataLevel) counts[l] += 1;
  return counts;
}

namespace {

void summarise(const Grid& grid, Region& r) {
  r.td_min_m = std::numeric_limits<double>::infinity();
  r.td_max_m = -r.td_min_m;
  r.row_min = r.col_min = std::numeric_limits<int>::max();
  r.row_max = r.col_max = -1;
  double sum = 0;
  std::sort(r.cells.begin(), r.cells.end());
  for (int c : r.cells) {
    r.td_min_m = std::min(r.td_min_m, grid.td_m[c]);
    r.td_max_m = std::max(r.td_max_m, grid.td_m[c]);
    sum += grid.td_m[c];
    r.row_min = std::min(r.row_min, grid.row_of(c));
    r.row_max = std::max(r.row_max, grid.row_of(c));
    r.col_min = std::min(r.col_min, grid.col_of(c));
    r.col_max = std::max(r.col_max, grid.col_of(c));
  }
  r.td_mean_m = r.cells.empty() ? 0.0 : sum / r.cells.size();
}

// Squared distance (in cells) between the closest cells of two regions.
double region_gap2(const Grid& grid, const Region& a, const Region& b) {
  double best = std::numeric_limits<double>::infinity();
  for (int ca : a.cells)
    for (int cb : b.cells) {
      const double dr = grid.row_of(ca) - grid.row_of(cb), dc = grid.col_of(ca) - grid.col_of(cb);
      best = std::min(best, dr * dr + dc * dc);
    }
  return best;
}

}  // namespace

std::vector<Region> find_regions(const Grid& grid, const std::vector<int>& levels, int level, int min_cells) {
  if (static_cast<int>(levels.size()) != grid.size())
    throw std::invalid_argument("find_regions: levels has " + std::to_string(levels.size()) + " entries for " +
                                std::to_string(grid.size()) + " cells");
  if (min_cells < 1) throw std::invalid_argument("find_regions: min_cells must be >= 1");
  std::vector<Region> regions;
  std::vector<char> seen(grid.size(), 0);
  const int dr[4] = {1, -1, 0, 0}, dc[4] = {0, 0, 1, -1};
  for (int start = 0; start < grid.size(); ++start) {
    if (seen[start] || levels[start] != level) continue;
    Region r;
    r.level = level;
    std::deque<int> queue{start};
    seen[start] = 1;
    while (!queue.empty()) {
      const int c = queue.front();
      queue.pop_front();
      r.cells.push_back(c);
      for (int k = 0; k < 4; ++k) {
        const int row = grid.row_of(c) + dr[k], col = grid.col_of(c) + dc[k];
        if (row < 0 || row >= grid.n_theta || col < 0 || col >= grid.n_d) continue;
        const int nb = grid.index(row, col);
        if (!seen[nb] && levels[nb] == level) {
          seen[nb] = 1;
          queue.push_back(nb);
        }
      }
    }
    regions.push_back(std::move(r));
  }
  // Merge the smallest undersized region into its nearest neighbour until none is left (or one region).
  while (regions.size() > 1) {
    auto small = std::min_element(regions.begin(), regions.end(),
                                  [](const Region& a, const Region& b) { return a.cells.size() < b.cells.size(); });
    if (static_cast<int>(small->cells.size()) >= min_cells) break;
    std::size_t best = 0;
    double best_gap = std::numeric_limits<double>::infinity();
    const std::size_t s = small - regions.begin();
    for (std::size_t j = 0; j < regions.size(); ++j) {
      if (j == s) continue;
      const double gap = region_gap2(grid, regions[s], regions[j]);
      if (gap < best_gap) {
        best_gap = gap;
        best = j;
      }
    }
    regions[best].cells.insert(regions[best].cells.end(), regions[s].cells.begin(), regions[s].cells.end());
    regions.erase(regions.begin() + s);
  }
  for (auto& r : regions) summarise(grid, r);
  return regions;
}

}  // namespace shotcrete
