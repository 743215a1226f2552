// Thickness along the wall normal, M3C2-style (docs/architecture.md §12; Lague et al. 2013).
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "shotcrete/rescan/rescan.hpp"
#include "shotcrete/surface/preprocess.hpp"

namespace shotcrete {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Running mean and variance (Welford).
struct Stats {
  long n = 0;
  double mean = 0.0, m2 = 0.0;
  void add(double x) {
    ++n;
    const double d = x - mean;
    mean += d / static_cast<double>(n);
    m2 += d * (x - mean);
  }
  double std() const { return n > 1 ? std::sqrt(m2 / static_cast<double>(n - 1)) : 0.0; }
};

// A point in a cylinder: along its axis, and across it (two coordinates in the cross-section).
struct InCyl {
  double t, u, v;
};

// The wall among the points of one cloud in a cylinder, without the points of other surfaces that
// cross it (the face or an arch where the wall ends, a rebound lump): a wall fills the cross-section
// in a short stretch along the axis, a crossing surface lies spread along it on one side. So: the
// window of `window_m` along the axis with the most points whose cross-section centroid lies
// within 0.6 radius of the axis (any window of fewer than 3 points), then the points
// within 3.5 robust std devs (1.4826 MAD, at least 1 mm) of its median; their mean and std dev.
Stats wall_stats(std::vector<InCyl>& x, double window_m, double radius_m) {
  Stats s;
  if (x.empty()) return s;
  std::sort(x.begin(), x.end(), [](const InCyl& a, const InCyl& b) { return a.t < b.t; });
  const size_t n = x.size();
  std::vector<double> cu(n + 1, 0.0), cv(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) {
    cu[i + 1] = cu[i] + x[i].u;
    cv[i + 1] = cv[i] + x[i].v;
  }
  const double lim_c2 = 0.36 * radius_m * radius_m;
  size_t best_lo = 0, best_n = 0;
  for (size_t lo = 0, hi = 0; lo < n; ++lo) {
    while (hi < n && x[hi].t - x[lo].t <= window_m) ++hi;
    const size_t k = hi - lo;
    if (k <= best_n) continue;
    const double mu = (cu[hi] - cu[lo]) / static_cast<double>(k), mv = (cv[hi] - cv[lo]) / static_cast<double>(k);
    if (k >= 3 && mu * mu + mv * mv > lim_c2) continue;  // one-sided: a surface crossing the cylinder
    best_n = k;
    best_lo = lo;
  }
  if (best_n == 0) return s;
  const double med = x[best_lo + best_n / 2].t;
  std::vector<double> dev(best_n);
  for (size_t i = 0; i < best_n; ++i) dev[i] = std::abs(x[best_lo + i].t - med);
  std::nth_element(dev.begin(), dev.begin() + static_cast<long>(best_n / 2), dev.end());
  const double lim = 3.5 * std::max(0.001, 1.4826 * dev[best_n / 2]);
  for (const InCyl& p : x)
    if (std::abs(p.t - med) <= lim) s.add(p.t);
  return s;
}

void check_cloud_finite(const Cloud& c, const char* what) {
  if (c.size() == 0) throw std::invalid_argument(std::string("rescan: the ") + what + "-scan is empty");
  if (!c.xyz.allFinite()) throw std::invalid_argument(std::string("rescan: the ") + what + "-scan has NaN or infinite coordinates");
}

}  // namespace

M3C2Result m3c2(const Points& core, const Points& normals, const Cloud& before, const Cloud& after,
                const RescanConfig& c) {
  if (normals.rows() != core.rows()) throw std::invalid_argument("m3c2: one normal per core point is needed");
  check_cloud_finite(before, "before");
  check_cloud_finite(after, "after");
  const Eigen::Index n = core.rows();
  M3C2Result out;
  out.distance_m = out.lod95_m = out.before_std_m = out.after_std_m = Eigen::VectorXd::Constant(n, kNaN);
  out.before_count = out.after_count = Eigen::VectorXi::Zero(n);
  if (n == 0) return out;
  const Eigen::Vector3d centre = core.colwise().mean().transpose();
  const double radius = c.cylinder_radius_m, half = c.cylinder_half_length_m;
  // The cylinder is covered by spheres every `step` along its axis; a candidate is taken from the
  // sphere whose slab holds its projection, so no point counts twice.
  const double step = radius;
  const float sphere = static_cast<float>(std::sqrt(radius * radius + 0.25 * step * step) * 1.0001);
  const int slabs = static_cast<int>(std::ceil(2.0 * half / step));
  auto stats = [&](const Cloud& cloud, std::vector<Stats>& st) {
    pcl::PointCloud<pcl::PointXYZ>::Ptr pc(new pcl::PointCloud<pcl::PointXYZ>);
    pc->reserve(static_cast<size_t>(cloud.size()));
    for (Eigen::Index i = 0; i < cloud.size(); ++i) {
      const Eigen::Vector3f q = (cloud.xyz.row(i).transpose() - centre).cast<float>();
      pc->push_back(pcl::PointXYZ(q.x(), q.y(), q.z()));
    }
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    tree.setInputCloud(pc);
    st.assign(static_cast<size_t>(n), Stats{});
#pragma omp parallel for schedule(dynamic, 64)
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Vector3d p0 = core.row(i).transpose();
      Eigen::Vector3d nrm = normals.row(i).transpose();
      if (!p0.allFinite() || !nrm.allFinite() || nrm.norm() < 1e-9) continue;
      nrm.normalize();
      const Eigen::Vector3d e1 = nrm.unitOrthogonal(), e2 = nrm.cross(e1);
      std::vector<int> idx;
      std::vector<float> d2;
      std::vector<InCyl> proj;
      for (int k = 0; k < slabs; ++k) {
        const double t_lo = -half + k * step, t_hi = std::min(half, t_lo + step);
        const Eigen::Vector3f q = (p0 + nrm * (0.5 * (t_lo + t_hi)) - centre).cast<float>();
        if (tree.radiusSearch(pcl::PointXYZ(q.x(), q.y(), q.z()), sphere, idx, d2) <= 0) continue;
        for (int j : idx) {
          const Eigen::Vector3d v = cloud.xyz.row(j).transpose() - p0;
          const double t = v.dot(nrm);
          if (t < t_lo || t >= t_hi) continue;
          const Eigen::Vector3d across = v - t * nrm;
          if (across.squaredNorm() > radius * radius) continue;
          proj.push_back({t, across.dot(e1), across.dot(e2)});
        }
      }
      st[static_cast<size_t>(i)] = wall_stats(proj, radius, radius);
    }
  };
  std::vector<Stats> sb, sa;
  stats(before, sb);
  stats(after, sa);
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto &b = sb[static_cast<size_t>(i)], &a = sa[static_cast<size_t>(i)];
    out.before_count[i] = static_cast<int>(b.n);
    out.after_count[i] = static_cast<int>(a.n);
    if (b.n < c.min_cylinder_points || a.n < c.min_cylinder_points) continue;
    out.distance_m[i] = a.mean - b.mean;
    out.before_std_m[i] = b.std();
    out.after_std_m[i] = a.std();
    out.lod95_m[i] = 1.96 * std::sqrt(b.std() * b.std() / b.n + a.std() * a.std() / a.n);
  }
  return out;
}

M3C2Result measure_points(const TunnelAxis& axis, const Points& core, const Cloud& before, const Cloud& after,
                          const RescanConfig& c, const DesignProfile& profile) {
  Points normals(core.rows(), 3);
  for (Eigen::Index i = 0; i < core.rows(); ++i)
    normals.row(i) = -design_normal(axis, profile, axis.to_cylindrical(core.row(i).transpose()).y()).transpose();
  return m3c2(core, normals, before, after, c);  // inward normal: the after wall lies ahead, the layer reads positive
}

CellThickness measure_cells(const Grid& grid, const Cloud& before, const Cloud& after, const RescanConfig& c) {
  check_cloud_finite(before, "before");
  check_cloud_finite(after, "after");
  const int ncell = grid.size();
  const DesignProfile& prof = grid.profile;
  const double radius = c.cylinder_radius_m, half = c.cylinder_half_length_m;
  double R = prof.radius_m;  // the design line's least distance from the axis
  for (const auto& v : prof.polyline_m) R = std::min(R, v.norm());
  // Points closer to the axis than r_lo cannot reach a cylinder (centred within max TD of the design line).
  const double r_lo = std::max(0.25 * R, R - half - 1.0);
  const int kd = static_cast<int>(std::ceil(radius / grid.cell_size_m));
  const int kt = static_cast<int>(std::ceil(radius / (grid.dtheta_rad * r_lo)));
  const int nt = grid.n_theta + 2 * kt, nd = grid.n_d + 2 * kd;
  struct Cyl { double r, theta, d; };
  auto bin = [&](const Cloud& cloud, std::vector<std::vector<Cyl>>& buckets) {
    buckets.assign(static_cast<size_t>(nt) * static_cast<size_t>(nd), {});
    for (Eigen::Index i = 0; i < cloud.size(); ++i) {
      const Eigen::Vector3d cyl = grid.axis.to_cylindrical(cloud.xyz.row(i).transpose());
      if (cyl.x() < r_lo) continue;
      const int row = static_cast<int>(std::floor((cyl.y() - grid.theta0_rad) / grid.dtheta_rad)) + kt;
      const int col = static_cast<int>(std::floor((cyl.z() - grid.d0_m) / grid.cell_size_m)) + kd;
      if (row < 0 || row >= nt || col < 0 || col >= nd) continue;
      buckets[static_cast<size_t>(row) * nd + col].push_back({cyl.x(), cyl.y(), cyl.z()});
    }
  };
  std::vector<std::vector<Cyl>> bb, ba;
  bin(before, bb);
  bin(after, ba);
  CellThickness out;
  out.thickness_m = out.lod95_m = out.residual_td_m = out.before_std_m = out.after_std_m = out.before_td_m =
      Eigen::VectorXd::Constant(ncell, kNaN);
  out.before_count = out.after_count = Eigen::VectorXi::Zero(ncell);
#pragma omp parallel for schedule(dynamic, 64)
  for (int cell = 0; cell < ncell; ++cell) {
    if (!grid.valid[static_cast<size_t>(cell)]) continue;
    const int row = grid.row_of(cell), col = grid.col_of(cell);
    const double th_c = grid.theta_center(row), d_c = grid.d_center(col);
    const double td = grid.td_m[cell];
    // The cylinder runs along the design line's normal n through its point at the cell's centre;
    // positions along it are TDs. Its centre: the wall as scanned.
    const double a0 = std::isfinite(td) ? td : 0.0;
    const Eigen::Vector2d n = prof.normal_at(th_c), t(-n.y(), n.x());
    const Eigen::Vector2d p0 = prof.radius_at(th_c) * Eigen::Vector2d(std::cos(th_c), std::sin(th_c));
    auto gather = [&](const std::vector<std::vector<Cyl>>& buckets) {
      std::vector<InCyl> proj;
      for (int i = row; i <= row + 2 * kt; ++i)
        for (int j = col; j <= col + 2 * kd; ++j)
          for (const Cyl& p : buckets[static_cast<size_t>(i) * nd + j]) {
            // Along the cell's normal and across it.
            const Eigen::Vector2d q = p.r * Eigen::Vector2d(std::cos(p.theta), std::sin(p.theta)) - p0;
            const double along = q.dot(n), across_arc = q.dot(t), across_d = p.d - d_c;
            if (across_arc * across_arc + across_d * across_d > radius * radius) continue;
            if (std::abs(along - a0) > half) continue;
            proj.push_back({along, across_d, across_arc});
          }
      return wall_stats(proj, radius, radius);
    };
    const Stats b = gather(bb), a = gather(ba);
    out.before_count[cell] = static_cast<int>(b.n);
    out.after_count[cell] = static_cast<int>(a.n);
    if (b.n >= c.min_cylinder_points) out.before_td_m[cell] = b.mean;
    if (b.n < c.min_cylinder_points || a.n < c.min_cylinder_points) continue;
    out.thickness_m[cell] = b.mean - a.mean;  // before lies farther from the axis
    out.before_std_m[cell] = b.std();
    out.after_std_m[cell] = a.std();
    out.lod95_m[cell] = 1.96 * std::sqrt(b.std() * b.std() / b.n + a.std() * a.std() / a.n);
    if (std::isfinite(td)) out.residual_td_m[cell] = td - out.thickness_m[cell];
  }
  for (int cell = 0; cell < ncell; ++cell) out.measured += std::isfinite(out.thickness_m[cell]) ? 1 : 0;
  return out;
}

Cloud wall_points(const Grid& grid, const Cloud& cloud, const Eigen::VectorXd& wall_td_m, double band_m) {
  if (wall_td_m.size() != grid.size())
    throw std::invalid_argument("wall_points: " + std::to_string(wall_td_m.size()) + " TD values for a grid of " +
                                std::to_string(grid.size()) + " cells");
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d cyl = grid.axis.to_cylindrical(cloud.xyz.row(i).transpose());
    const int cell = grid.cell_at(cyl.y(), cyl.z());
    if (cell < 0 || !grid.valid[static_cast<size_t>(cell)] || !std::isfinite(wall_td_m[cell])) continue;
    if (std::abs(grid.profile.td_m(cyl.x(), cyl.y()) - wall_td_m[cell]) <= band_m) keep.push_back(i);
  }
  return select_points(cloud, keep);
}

}  // namespace shotcrete
