#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/collision/transit.hpp"

#include <fcl/fcl.h>
#include <fcl/geometry/octree/octree.h>
#include <octomap/OcTree.h>
#ifdef _OPENMP
#include <omp.h>
#else
inline int omp_get_thread_num() { return 0; }
#endif

#include <algorithm>
#include <array>
#include <atomic>
#include <exception>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <map>
#include <stdexcept>
#include <tuple>

#include "shotcrete/timing/trajectory.hpp"

namespace shotcrete {

namespace {

std::shared_ptr<fcl::CollisionGeometryd> fcl_shape(const CollisionShape& s) {
  switch (s.kind) {
    case CollisionShape::Kind::cylinder:
      return std::make_shared<fcl::Cylinderd>(s.radius_m, s.length_m);
    case CollisionShape::Kind::box:
      return std::make_shared<fcl::Boxd>(s.size_m.x(), s.size_m.y(), s.size_m.z());
    case CollisionShape::Kind::sphere:
      return std::make_shared<fcl::Sphered>(s.radius_m);
  }
  throw std::logic_error("fcl_shape: unknown shape kind");
}

fcl::Transform3d to_fcl(const Eigen::Isometry3d& t) {
  fcl::Transform3d f = fcl::Transform3d::Identity();
  f.linear() = t.linear();
  f.translation() = t.translation();
  return f;
}

// Corners of the shape's bounding box in its link frame: every point of the shape is a convex
// combination of them, so no point moves farther than the farthest corner under a rigid motion.
std::array<Eigen::Vector3d, 8> box_corners(const CollisionShape& s) {
  Eigen::Vector3d half;
  if (s.kind == CollisionShape::Kind::cylinder) half = Eigen::Vector3d(s.radius_m, s.radius_m, 0.5 * s.length_m);
  else if (s.kind == CollisionShape::Kind::box) half = 0.5 * s.size_m;
  else half = Eigen::Vector3d::Constant(s.radius_m);
  std::array<Eigen::Vector3d, 8> out;
  for (int k = 0; k < 8; ++k)
    out[k] = s.origin * Eigen::Vector3d((k & 1 ? 1 : -1) * half.x(), (k & 2 ? 1 : -1) * half.y(), (k & 4 ? 1 : -1) * half.z());
  return out;
}

double max_displacement(const std::array<Eigen::Vector3d, 8>& corners, const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  double m = 0.0;
  for (const auto& c : corners) m = std::max(m, (a * c - b * c).norm());
  return m;
}

// How far any point of a cylinder moves between two link poses, the cylinder as a set: a point
// e(t) + w (e on the axis, w radial, |w| <= r) goes to e'(t) + R w (R the least rotation of the
// axis onto its new direction): at most the farther axis end's motion + r |axis' - axis|. Zero
// when the cylinder only turns about its own axis (the turret slewing). Other shapes: the
// bounding box's corners.
double shape_motion(const CollisionShape& s, const std::array<Eigen::Vector3d, 8>& corners, const Eigen::Isometry3d& a,
                    const Eigen::Isometry3d& b) {
  if (s.kind != CollisionShape::Kind::cylinder) return max_displacement(corners, a, b);
  const Eigen::Vector3d e0 = s.origin * Eigen::Vector3d(0, 0, -0.5 * s.length_m), e1 = s.origin * Eigen::Vector3d(0, 0, 0.5 * s.length_m);
  const Eigen::Vector3d axis = s.origin.linear().col(2);
  return std::max((a * e0 - b * e0).norm(), (a * e1 - b * e1).norm()) + s.radius_m * (a.linear() * axis - b.linear() * axis).norm();
}

// A shape's placement as shape_motion reads it: a cylinder's axis ends and direction in the
// world, other shapes' bounding-box corners. placement_motion(now, then) equals
// shape_motion(s, corners, pose now, pose then) to the last bit, from one placement per pose.
struct Placement {
  std::array<Eigen::Vector3d, 8> p;  // cylinder: p[0], p[1] the axis ends, p[2] the axis direction
};
Placement placement(const CollisionShape& s, const std::array<Eigen::Vector3d, 8>& corners, const Eigen::Isometry3d& a) {
  Placement out;
  if (s.kind != CollisionShape::Kind::cylinder) {
    for (int k = 0; k < 8; ++k) out.p[static_cast<std::size_t>(k)] = a * corners[static_cast<std::size_t>(k)];
    return out;
  }
  out.p[0] = a * (s.origin * Eigen::Vector3d(0, 0, -0.5 * s.length_m));
  out.p[1] = a * (s.origin * Eigen::Vector3d(0, 0, 0.5 * s.length_m));
  out.p[2] = a.linear() * s.origin.linear().col(2);
  return out;
}
double placement_motion(const CollisionShape& s, const Placement& a, const Placement& b) {
  if (s.kind != CollisionShape::Kind::cylinder) {
    double m = 0.0;
    for (std::size_t k = 0; k < 8; ++k) m = std::max(m, (a.p[k] - b.p[k]).norm());
    return m;
  }
  return std::max((a.p[0] - b.p[0]).norm(), (a.p[1] - b.p[1]).norm()) + s.radius_m * (a.p[2] - b.p[2]).norm();
}

// A sphere cover of a shape, in its link frame: every point of the shape lies within radius[j] of
// centre[j] for some j. A cylinder: centres along its axis, each ball covering a slice (radius
// hypot(r, slice/2) <= r + slack); a sphere: itself; a box: a grid of cubes of its least edge (at
// least 0.1 m), coarser than `slack` (the URDF's shapes are cylinders). Any cover keeps
// exact_distance() right; the slack only sets how tight its per-ball lower bounds are.
struct BallCover {
  std::vector<Eigen::Vector3d> centre;
  std::vector<double> radius;
  std::vector<double> inner;  // a ball of this radius about the centre lies inside the shape
};
BallCover ball_cover(const CollisionShape& s, double slack) {
  BallCover out;
  if (s.kind == CollisionShape::Kind::cylinder) {
    const double slice = 2.0 * std::sqrt(2.0 * s.radius_m * slack + slack * slack);
    const int m = std::max(1, static_cast<int>(std::ceil(s.length_m / slice)));
    const double h = s.length_m / m;
    for (int k = 0; k < m; ++k) {
      const double z = -0.5 * s.length_m + (k + 0.5) * h;
      out.centre.push_back(s.origin * Eigen::Vector3d(0, 0, z));
      out.radius.push_back(std::hypot(s.radius_m, 0.5 * h));
      out.inner.push_back(std::min(s.radius_m, 0.5 * s.length_m - std::abs(z)));
    }
  } else if (s.kind == CollisionShape::Kind::box) {
    const double cell = std::max(s.size_m.minCoeff(), 0.1);
    Eigen::Vector3i n;
    for (int i = 0; i < 3; ++i) n[i] = std::max(1, static_cast<int>(std::ceil(s.size_m[i] / cell)));
    const Eigen::Vector3d step = s.size_m.cwiseQuotient(n.cast<double>());
    for (int i = 0; i < n.x(); ++i)
      for (int j = 0; j < n.y(); ++j)
        for (int k = 0; k < n.z(); ++k) {
          out.centre.push_back(s.origin * (-0.5 * s.size_m + step.cwiseProduct(Eigen::Vector3d(i + 0.5, j + 0.5, k + 0.5))));
          out.radius.push_back(0.5 * step.norm());
          out.inner.push_back(0.5 * step.minCoeff());
        }
  } else {
    out.centre.push_back(s.origin.translation());
    out.radius.push_back(s.radius_m);
    out.inner.push_back(s.radius_m);
  }
  return out;
}

// The distance-field bounds' sphere cover: each ball a lookup, its slack adds to the bound's gap
// below the exact distance.
constexpr double kFieldCoverSlack_m = 0.01;

// The distance field's cells: half an octree leaf, coarser while the wall's bounding box would
// need more than this many (4 bytes each).
constexpr double kFieldCellsMax = 64e6;

// Felzenszwalb-Huttenlocher: d[q] = min over p of (q - p)^2 + f[p] along one line of n cells, exact
// (f holds squared distances in cells; infinite where no occupied cell is known yet, left out of
// the lower envelope). v, z: work arrays of n and n + 1.
void edt_line(const float* f, std::size_t stride, int n, float* d_out, std::vector<double>& fin, std::vector<int>& v,
              std::vector<double>& z) {
  const double inf = std::numeric_limits<double>::infinity();
  for (int q = 0; q < n; ++q) fin[static_cast<std::size_t>(q)] = f[static_cast<std::size_t>(q) * stride];
  int k = -1;
  for (int q = 0; q < n; ++q) {
    const double fq = fin[static_cast<std::size_t>(q)];
    if (!std::isfinite(fq)) continue;
    double s = -inf;
    while (k >= 0) {
      const int p = v[static_cast<std::size_t>(k)];
      s = ((fq + double(q) * q) - (fin[static_cast<std::size_t>(p)] + double(p) * p)) / (2.0 * (q - p));
      if (s > z[static_cast<std::size_t>(k)]) break;
      --k;
    }
    if (k < 0) s = -inf;
    ++k;
    v[static_cast<std::size_t>(k)] = q;
    z[static_cast<std::size_t>(k)] = s;
    z[static_cast<std::size_t>(k) + 1] = inf;
  }
  if (k < 0) return;  // no occupied cell on this line yet: stays infinite
  int j = 0;
  for (int q = 0; q < n; ++q) {
    while (z[static_cast<std::size_t>(j) + 1] < q) ++j;
    const int p = v[static_cast<std::size_t>(j)];
    d_out[static_cast<std::size_t>(q) * stride] = static_cast<float>(double(q - p) * (q - p) + fin[static_cast<std::size_t>(p)]);
  }
}

// exact_distance's groups of wall points: blocks of this edge, each of cells of kPointCell_m (a
// whole number of cells per block). A query bounds every block, then the cells of the blocks that
// can hold a nearer point, then the points of those cells.
constexpr double kPointBlock_m = 0.2, kPointCell_m = 0.05;
// A group's bound (its sphere's centre's distance less its radius) is lowered by this much for
// rounding, so that a point at the least distance is never left out.
constexpr double kRound_m = 1e-9;

// The distance [m] of a point given in the shape's own frame (that of link_pose * shape.origin) to
// the shape: point_shape_distance without the transform.
inline double local_shape_distance(const Eigen::Vector3d& p, const CollisionShape& shape) {
  switch (shape.kind) {
    case CollisionShape::Kind::cylinder: {
      const double radial = std::max(0.0, std::hypot(p.x(), p.y()) - shape.radius_m);
      const double axial = std::max(0.0, std::abs(p.z()) - 0.5 * shape.length_m);
      return std::hypot(radial, axial);
    }
    case CollisionShape::Kind::box:
      return (p.cwiseAbs() - 0.5 * shape.size_m).cwiseMax(0.0).norm();
    case CollisionShape::Kind::sphere:
      return std::max(0.0, p.norm() - shape.radius_m);
  }
  throw std::logic_error("point_shape_distance: unknown shape kind");
}

// local_shape_distance with sqrt for hypot (several times faster, within a few 1e-16 relative of
// it): the groups' bounds and the points' first screen, each allowed kRound_m for the difference.
inline double fast_local_distance(const Eigen::Vector3d& p, const CollisionShape& shape) {
  if (shape.kind != CollisionShape::Kind::cylinder) return local_shape_distance(p, shape);
  const double radial = std::max(0.0, std::sqrt(p.x() * p.x() + p.y() * p.y()) - shape.radius_m);
  const double axial = std::max(0.0, std::abs(p.z()) - 0.5 * shape.length_m);
  return std::sqrt(radial * radial + axial * axial);
}

// FCL reports -1 (or a depth) for shapes in contact: 0 here. `nearest`: both nearest points.
// `at_most`: an upper bound that prunes the octree traversal (FCL visits every node nearer than
// the best distance so far, in a fixed order, so a good first bound saves most of the work); when
// nothing is nearer, `at_most` itself comes back and `nearest` is left alone.
double fcl_distance(const fcl::CollisionObjectd& a, const fcl::CollisionObjectd& b, std::array<Eigen::Vector3d, 2>* nearest,
                    double at_most = std::numeric_limits<double>::max()) {
  fcl::DistanceRequestd request(nearest != nullptr);
  fcl::DistanceResultd result(at_most);
  fcl::distance(&a, &b, request, result);
  if (nearest && result.min_distance < at_most) *nearest = {result.nearest_points[0], result.nearest_points[1]};
  return std::max(0.0, result.min_distance);
}

// The least readings (octree, link pairs) may be this much above the every-sample ones (a sample
// is not checked when it could only lower a minimum by less); the counts below the margins are exact.
constexpr double kMinTolerance_m = 0.01;

// How far past the threshold an octree query looks: larger answers more samples per query, smaller
// makes each query cheaper (bench_clearance.py).
constexpr double kQuerySlack_m = 0.25;

// The trajectory is checked in stretches of at least this many samples (at most kMaxChunks),
// spread over kThreads threads: the machine's two cores.
constexpr std::size_t kChunkSamples = 2048, kMaxChunks = 2, kThreads = 2;

// Each link's least distance (check_clearance): a measurement asks for the distance up to the best
// so far plus this much (farther comes back as that bound). A larger ask bounds more of the
// samples around it by their motion but gathers more wall points: 2 cm takes the least time on the
// default bay (bench_clearance.py; 5 cm: 30 % fewer queries, 20 % more time).
constexpr double kMinAskSlack_m = 0.02;
// Distances within this much are ties (rounding: a cylinder turned about its own axis): the
// earliest sample is reported.
constexpr double kTie_m = 1e-12;

}  // namespace

// ------------------------------------------------------------------------------------------------
// WallOctree
// ------------------------------------------------------------------------------------------------
struct WallOctree::Impl {
  double resolution_m = 0.0;
  std::size_t leaves = 0;
  std::shared_ptr<fcl::OcTreed> geometry;
  std::unique_ptr<fcl::CollisionObjectd> object;
  Points points;  // the wall's points, for exact distances
  // The points for exact distances, grouped by cells of kPointCell_m inside blocks of
  // kPointBlock_m (both over the points' bounding box), each group with the tight bounding sphere
  // of its points (the centre and half the diagonal of their bounding box): no point of a group is
  // nearer to a shape than the shape's distance to the sphere's centre less its radius. Built on
  // first use.
  struct Group {
    Eigen::Vector3d centre;
    double radius;
    int begin, end;  // points (px.. order) of a cell; cells (cell order) of a block
  };
  std::once_flag groups_built;
  std::vector<double> px, py, pz;   // the points, ordered by block and cell (within a cell: by index)
  std::vector<int> p_index;         // their rows in `points`
  std::vector<Group> cells, blocks;
  void build_groups() {
    std::call_once(groups_built, [&] {
      const Eigen::Vector3d plo = points.colwise().minCoeff().transpose();
      const int per = static_cast<int>(std::lround(kPointBlock_m / kPointCell_m));  // cells per block edge
      Eigen::Vector3i nb;
      for (int a = 0; a < 3; ++a)
        nb[a] = static_cast<int>(std::floor((points.col(a).maxCoeff() - plo[a]) / kPointBlock_m)) + 1;
      const auto rows = static_cast<std::size_t>(points.rows());
      std::vector<std::pair<std::uint64_t, int>> key(rows);  // (block, cell in block), row
      for (std::size_t i = 0; i < rows; ++i) {
        std::uint64_t block = 0, cell = 0, bm = 1, cm = 1;
        for (int a = 0; a < 3; ++a) {
          const int c = std::max(0, static_cast<int>(std::floor((points(static_cast<Eigen::Index>(i), a) - plo[a]) / kPointCell_m)));
          const int b = std::min(c / per, nb[a] - 1);
          block += bm * static_cast<std::uint64_t>(b);
          cell += cm * static_cast<std::uint64_t>(std::min(c - b * per, per - 1));
          bm *= static_cast<std::uint64_t>(nb[a]);
          cm *= static_cast<std::uint64_t>(per);
        }
        key[i] = {block * cm + cell, static_cast<int>(i)};
      }
      std::sort(key.begin(), key.end());
      const std::uint64_t cells_per_block = static_cast<std::uint64_t>(per) * per * per;
      px.resize(rows), py.resize(rows), pz.resize(rows), p_index.resize(rows);
      const auto sphere = [](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int begin, int end) {
        return Group{0.5 * (lo + hi), 0.5 * (hi - lo).norm(), begin, end};
      };
      Eigen::Vector3d cell_lo = Eigen::Vector3d::Zero(), cell_hi = cell_lo, block_lo = cell_lo, block_hi = cell_lo;
      for (std::size_t k = 0; k < rows; ++k) {
        const Eigen::Vector3d p = points.row(key[k].second).transpose();
        px[k] = p.x(), py[k] = p.y(), pz[k] = p.z(), p_index[k] = key[k].second;
        const bool new_cell = k == 0 || key[k].first != key[k - 1].first;
        const bool new_block = k == 0 || key[k].first / cells_per_block != key[k - 1].first / cells_per_block;
        if (new_cell) {
          if (k > 0) cells.push_back(sphere(cell_lo, cell_hi, cells.empty() ? 0 : cells.back().end, static_cast<int>(k)));
          cell_lo = cell_hi = p;
        }
        if (new_block) {
          if (k > 0) blocks.push_back(sphere(block_lo, block_hi, blocks.empty() ? 0 : blocks.back().end, static_cast<int>(cells.size())));
          block_lo = block_hi = p;
        }
        cell_lo = cell_lo.cwiseMin(p), cell_hi = cell_hi.cwiseMax(p);
        block_lo = block_lo.cwiseMin(p), block_hi = block_hi.cwiseMax(p);
      }
      cells.push_back(sphere(cell_lo, cell_hi, cells.empty() ? 0 : cells.back().end, static_cast<int>(rows)));
      blocks.push_back(sphere(block_lo, block_hi, blocks.empty() ? 0 : blocks.back().end, static_cast<int>(cells.size())));
    });
  }
  // The Euclidean distance field: per cell of edge h (cell (i,j,k) spans lo + [i, i+1) h on x, ...),
  // the distance [m] between its centre and the nearest centre of a cell that holds a wall point,
  // exact (separable EDT, one pass per axis).
  std::once_flag field_built;
  Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();
  double h = 0.0;
  Eigen::Vector3i n = Eigen::Vector3i::Zero();
  std::vector<float> field_m;
  void build_field() {
    std::call_once(field_built, [&] {
      lo = points.colwise().minCoeff().transpose();
      hi = points.colwise().maxCoeff().transpose();
      h = 0.5 * resolution_m;
      for (;;) {
        for (int a = 0; a < 3; ++a) n[a] = static_cast<int>(std::floor((hi[a] - lo[a]) / h)) + 1;
        if (double(n.x()) * n.y() * n.z() <= kFieldCellsMax) break;
        h *= 1.25;
      }
      const std::size_t nx = static_cast<std::size_t>(n.x()), ny = static_cast<std::size_t>(n.y()),
                        nz = static_cast<std::size_t>(n.z());
      field_m.assign(nx * ny * nz, std::numeric_limits<float>::infinity());
      for (Eigen::Index i = 0; i < points.rows(); ++i) field_m[cell_index(points.row(i).transpose())] = 0.0f;
      // One pass per axis over every line along it; lines are independent.
      auto pass = [&](int axis) {
        const std::size_t len = static_cast<std::size_t>(n[axis]);
        const std::size_t stride = axis == 0 ? 1 : axis == 1 ? nx : nx * ny;
        const std::size_t a_n = axis == 0 ? ny : nx, b_n = axis == 2 ? ny : nz;
#pragma omp parallel num_threads(static_cast<int>(kThreads))
        {
          std::vector<double> fin(len), z(len + 1);
          std::vector<int> v(len);
#pragma omp for schedule(static)
          for (long ab = 0; ab < static_cast<long>(a_n * b_n); ++ab) {
            const std::size_t a = static_cast<std::size_t>(ab) % a_n, b = static_cast<std::size_t>(ab) / a_n;
            const std::size_t start = axis == 0 ? nx * (a + ny * b) : axis == 1 ? a + nx * ny * b : a + nx * b;
            edt_line(field_m.data() + start, stride, static_cast<int>(len), field_m.data() + start, fin, v, z);
          }
        }
      };
      for (int axis = 0; axis < 3; ++axis) pass(axis);
      for (float& f : field_m) f = static_cast<float>(std::sqrt(double(f)) * h);
    });
  }
  std::size_t cell_index(const Eigen::Vector3d& p) const {
    std::size_t idx = 0, mult = 1;
    for (int a = 0; a < 3; ++a) {
      const int i = std::clamp(static_cast<int>(std::floor((p[a] - lo[a]) / h)), 0, n[a] - 1);
      idx += mult * static_cast<std::size_t>(i);
      mult *= static_cast<std::size_t>(n[a]);
    }
    return idx;
  }
};

WallOctree::WallOctree(const Points& xyz_m, double resolution_m) : impl_(std::make_unique<Impl>()) {
  if (!(resolution_m > 0) || !std::isfinite(resolution_m))
    throw std::invalid_argument("WallOctree: resolution_m must be > 0, got " + std::to_string(resolution_m));
  if (xyz_m.rows() == 0) throw std::invalid_argument("WallOctree: no wall points");
  if (!xyz_m.allFinite()) throw std::invalid_argument("WallOctree: wall points contain NaN or inf");
  auto tree = std::make_shared<octomap::OcTree>(resolution_m);
  for (Eigen::Index i = 0; i < xyz_m.rows(); ++i)
    tree->updateNode(octomap::point3d(static_cast<float>(xyz_m(i, 0)), static_cast<float>(xyz_m(i, 1)),
                                      static_cast<float>(xyz_m(i, 2))),
                     true, true);  // lazy: inner nodes once below
  tree->updateInnerOccupancy();
  impl_->resolution_m = resolution_m;
  impl_->points = xyz_m;
  impl_->leaves = tree->getNumLeafNodes();
  impl_->geometry = std::make_shared<fcl::OcTreed>(tree);
  impl_->object = std::make_unique<fcl::CollisionObjectd>(impl_->geometry, fcl::Transform3d::Identity());
}

WallOctree::~WallOctree() = default;
WallOctree::WallOctree(WallOctree&&) noexcept = default;
WallOctree& WallOctree::operator=(WallOctree&&) noexcept = default;
double WallOctree::resolution_m() const { return impl_->resolution_m; }
double WallOctree::leaf_diagonal_m() const { return std::sqrt(3.0) * impl_->resolution_m; }
std::size_t WallOctree::occupied_leaves() const { return impl_->leaves; }

double WallOctree::distance(const CollisionShape& shape, const Eigen::Isometry3d& link_pose, Eigen::Vector3d* closest_m,
                            double at_most_m) const {
  const fcl::CollisionObjectd obj(fcl_shape(shape), to_fcl(link_pose * shape.origin));
  if (!closest_m) return fcl_distance(obj, *impl_->object, nullptr, at_most_m);
  std::array<Eigen::Vector3d, 2> nearest{closest_m ? *closest_m : Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  const double d = fcl_distance(obj, *impl_->object, &nearest, at_most_m);
  if (d >= at_most_m) return d;  // nothing nearer than the bound: no closest point
  // FCL 0.7 gives the shape-octree pair in either order: the wall's point is the one off the shape.
  const bool first_on_wall = point_shape_distance(nearest[0], shape, link_pose) >= point_shape_distance(nearest[1], shape, link_pose);
  *closest_m = nearest[first_on_wall ? 0 : 1];
  return d;
}

double WallOctree::exact_distance(const CollisionShape& shape, const Eigen::Isometry3d& link_pose,
                                  Eigen::Vector3d* closest_m, double at_most_m) const {
  impl_->build_groups();
  const Impl& w = *impl_;
  // Every point in the shape's own frame, as point_shape_distance measures it (the same
  // arithmetic: the same value to the last bit).
  const Eigen::Isometry3d to_shape = (link_pose * shape.origin).inverse();
  const auto group_bound = [&](const Impl::Group& g) {
    return fast_local_distance(to_shape * g.centre, shape) - g.radius - kRound_m;
  };
  // The blocks that can hold a point nearer than at_most_m, in the order of their bounds; in each,
  // the cells that can hold one nearer than the best so far, then their points: the least distance
  // over every point (a point nearer than the best lies in a group whose bound is below it).
  double best = at_most_m;
  int best_i = -1;
  thread_local std::vector<std::pair<double, int>> order;
  order.clear();
  for (std::size_t b = 0; b < w.blocks.size(); ++b) {
    const double lb = group_bound(w.blocks[b]);
    if (lb < best) order.emplace_back(lb, static_cast<int>(b));
  }
  std::sort(order.begin(), order.end());
  for (const auto& [lb, b] : order) {
    if (lb >= best) break;
    const Impl::Group& block = w.blocks[static_cast<std::size_t>(b)];
    for (int c = block.begin; c < block.end; ++c) {
      const Impl::Group& cell = w.cells[static_cast<std::size_t>(c)];
      if (group_bound(cell) >= best) continue;
      for (int k = cell.begin; k < cell.end; ++k) {
        const auto uk = static_cast<std::size_t>(k);
        const Eigen::Vector3d p = to_shape * Eigen::Vector3d(w.px[uk], w.py[uk], w.pz[uk]);
        if (fast_local_distance(p, shape) > best + kRound_m) continue;  // cannot reach best
        const double d = local_shape_distance(p, shape);
        const int i = w.p_index[uk];
        if (d < best || (d == best && best_i >= 0 && i < best_i)) best = d, best_i = i;  // ties: the first point
      }
    }
  }
  if (best_i < 0) return at_most_m;  // nothing nearer than the bound
  if (closest_m) *closest_m = w.points.row(best_i).transpose();
  return best;
}

WallOctree::FieldBounds WallOctree::field_bounds(const Eigen::Vector3d& centre_m, double radius_m) const {
  impl_->build_field();
  const Impl& f = *impl_;
  // Outside the points' bounding box, the field is read at the centre's projection c' onto it: for
  // every point p in the box (a convex set), |c - p|^2 >= |c - c'|^2 + |c' - p|^2.
  const Eigen::Vector3d inside = centre_m.cwiseMax(f.lo).cwiseMin(f.hi);
  const double out = (centre_m - inside).norm();
  Eigen::Vector3d cell_centre;
  std::size_t idx = 0, mult = 1;
  for (int a = 0; a < 3; ++a) {
    const int i = std::min(static_cast<int>((inside[a] - f.lo[a]) / f.h), f.n[a] - 1);  // inside: >= 0
    cell_centre[a] = f.lo[a] + f.h * (i + 0.5);
    idx += mult * static_cast<std::size_t>(i);
    mult *= static_cast<std::size_t>(f.n[a]);
  }
  // A wall point p in cell Q: |c' - p| >= |C - Q| - |c' - C| - |p - Q| with |p - Q| <= half a
  // cell's diagonal; float rounding of the field (relative 6e-8) covered by 10 micrometres.
  const double offset = (inside - cell_centre).norm() + 0.5 * std::sqrt(3.0) * f.h + 1e-5;
  const double field = f.field_m[idx];
  const double near = std::max(0.0, field - offset);
  return {std::sqrt(out * out + near * near) - radius_m, out + field + offset};
}

namespace {
// The field's bounds of a shape from its cover placed at link_pose: lower, the least ball bound;
// upper, the least ball upper bound less the ball's inner radius (a ball of that radius about
// the centre lies inside the shape).
WallOctree::FieldBounds shape_field_bounds(const WallOctree& wall, const BallCover& cover,
                                           const Eigen::Isometry3d& link_pose) {
  WallOctree::FieldBounds out{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  for (std::size_t j = 0; j < cover.centre.size(); ++j) {
    const auto b = wall.field_bounds(link_pose * cover.centre[j], cover.radius[j]);
    out.lower_m = std::min(out.lower_m, b.lower_m);
    out.upper_m = std::min(out.upper_m, b.upper_m - cover.inner[j]);
  }
  return out;
}
}  // namespace

double WallOctree::field_lower_bound(const CollisionShape& shape, const Eigen::Isometry3d& link_pose) const {
  return shape_field_bounds(*this, ball_cover(shape, kFieldCoverSlack_m), link_pose).lower_m;
}

double WallOctree::field_distance(const Eigen::Vector3d& p_m, Eigen::Vector3d* gradient, double step_m) const {
  impl_->build_field();
  const Impl& f = *impl_;
  const auto read = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3d inside = p.cwiseMax(f.lo).cwiseMin(f.hi);
    // Trilinear between the centres of the 8 cells around the point (clamped at the grid's edges).
    Eigen::Vector3i i0;
    Eigen::Vector3d w;
    for (int a = 0; a < 3; ++a) {
      const double u = std::clamp((inside[a] - f.lo[a]) / f.h - 0.5, 0.0, static_cast<double>(f.n[a] - 1));
      i0[a] = std::min(static_cast<int>(u), std::max(0, f.n[a] - 2));
      w[a] = std::min(1.0, u - i0[a]);
    }
    const auto at = [&](int dx, int dy, int dz) {
      const std::size_t x = static_cast<std::size_t>(std::min(i0.x() + dx, f.n.x() - 1));
      const std::size_t y = static_cast<std::size_t>(std::min(i0.y() + dy, f.n.y() - 1));
      const std::size_t z = static_cast<std::size_t>(std::min(i0.z() + dz, f.n.z() - 1));
      return static_cast<double>(f.field_m[x + static_cast<std::size_t>(f.n.x()) * (y + static_cast<std::size_t>(f.n.y()) * z)]);
    };
    double v = 0.0;
    for (int dz = 0; dz < 2; ++dz)
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx)
          v += (dx ? w.x() : 1 - w.x()) * (dy ? w.y() : 1 - w.y()) * (dz ? w.z() : 1 - w.z()) * at(dx, dy, dz);
    return v + (p - inside).norm();
  };
  if (gradient)
    for (int a = 0; a < 3; ++a) {
      const Eigen::Vector3d e = 0.5 * step_m * Eigen::Vector3d::Unit(a);
      (*gradient)[a] = (read(p_m + e) - read(p_m - e)) / step_m;
    }
  return read(p_m);
}

double WallOctree::field_voxel_m() const {
  impl_->build_field();
  return impl_->h;
}

double shape_distance(const CollisionShape& a, const Eigen::Isometry3d& pose_a, const CollisionShape& b,
                      const Eigen::Isometry3d& pose_b) {
  const fcl::CollisionObjectd oa(fcl_shape(a), to_fcl(pose_a * a.origin));
  const fcl::CollisionObjectd ob(fcl_shape(b), to_fcl(pose_b * b.origin));
  return fcl_distance(oa, ob, nullptr);
}

double point_shape_distance(const Eigen::Vector3d& p_world, const CollisionShape& shape, const Eigen::Isometry3d& link_pose) {
  const Eigen::Vector3d p = (link_pose * shape.origin).inverse() * p_world;  // in the shape's frame
  return local_shape_distance(p, shape);
}

bool nozzle_shape(const CollisionShape& shape) { return shape.link.rfind("nozzle", 0) == 0; }

double shape_margin_m(const CollisionShape& shape, const ClearanceConfig& config) {
  return nozzle_shape(shape) ? config.nozzle_margin_m : config.link_margin_m;
}

std::vector<char> fixed_shapes(const Robot& robot) {
  const auto& shapes = robot.collision_shapes();
  const Eigen::VectorXd q0 = robot.neutral(), lo = robot.lower_limits(), hi = robot.upper_limits();
  const auto at_neutral = robot.link_frames(q0);
  std::vector<char> fixed(shapes.size(), 1);
  for (int j = 0; j < robot.dof(); ++j)
    for (int k = 0; k <= 4; ++k) {  // each joint alone over its range, the others at neutral
      Eigen::VectorXd q = q0;
      q[j] = lo[j] + 0.25 * k * (hi[j] - lo[j]);
      const auto frames = robot.link_frames(q);
      for (std::size_t s = 0; s < shapes.size(); ++s) {
        const Eigen::Isometry3d& a = at_neutral[shapes[s].frame];
        const Eigen::Isometry3d& b = frames[shapes[s].frame];
        if (shape_motion(shapes[s], box_corners(shapes[s]), a, b) > 1e-9) fixed[s] = 0;
      }
    }
  return fixed;
}

std::vector<char> machine_points(const Points& xyz_m, const Robot& robot, double tolerance_m) {
  if (!(tolerance_m >= 0.0) || !std::isfinite(tolerance_m))
    throw std::invalid_argument("machine_points: the tolerance must be a distance >= 0 m");
  std::vector<char> out(static_cast<std::size_t>(xyz_m.rows()), 0);
  // Each carrier box in the tunnel frame (inverse pose; its z is base_link's, up) and its half edges.
  std::vector<std::pair<Eigen::Isometry3d, Eigen::Vector3d>> boxes;
  for (const auto& sh : robot.collision_shapes())
    if (sh.carrier)  // upright boxes on base_link's frame (Robot's loader)
      boxes.emplace_back((robot.base_pose() * sh.origin).inverse(), 0.5 * sh.size_m + Eigen::Vector3d::Constant(tolerance_m));
  if (boxes.empty()) return out;
  for (Eigen::Index i = 0; i < xyz_m.rows(); ++i) {
    const Eigen::Vector3d p = xyz_m.row(i).transpose();
    for (const auto& [to_box, half] : boxes) {
      const Eigen::Vector3d b = to_box * p;  // the column: within the footprint, no higher than the top
      if (std::abs(b.x()) <= half.x() && std::abs(b.y()) <= half.y() && b.z() <= half.z()) {
        out[static_cast<std::size_t>(i)] = 1;
        break;
      }
    }
  }
  return out;
}

double box_signed_distance(const CollisionShape& box, const Eigen::Isometry3d& link_pose, const Eigen::Vector3d& p,
                           Eigen::Vector3d* gradient) {
  const Eigen::Isometry3d pose = link_pose * box.origin;
  const Eigen::Vector3d local = pose.inverse() * p;
  const Eigen::Vector3d q = local.cwiseAbs() - 0.5 * box.size_m;
  const Eigen::Vector3d outside = q.cwiseMax(0.0);
  const double out_norm = outside.norm();
  Eigen::Index k = 0;
  const double inside = std::min(q.maxCoeff(&k), 0.0);
  if (gradient) {
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    if (out_norm > 0.0) {
      for (int a = 0; a < 3; ++a) g[a] = (local[a] < 0.0 ? -1.0 : 1.0) * outside[a] / out_norm;
    } else {
      g[k] = local[k] < 0.0 ? -1.0 : 1.0;  // toward the nearest face
    }
    *gradient = pose.linear() * g;
  }
  return out_norm + inside;
}

std::vector<std::pair<int, int>> self_check_pairs(const Robot& robot) {
  const auto& shapes = robot.collision_shapes();
  const auto frames = robot.link_frames(robot.neutral());
  std::vector<std::pair<int, int>> out;
  for (int i = 0; i < static_cast<int>(shapes.size()); ++i)
    for (int j = i + 1; j < static_cast<int>(shapes.size()); ++j) {
      if (std::abs(shapes[i].frame - shapes[j].frame) <= 1) continue;
      if (shape_distance(shapes[i], frames[shapes[i].frame], shapes[j], frames[shapes[j].frame]) <= 0.0) continue;
      out.emplace_back(i, j);
    }
  return out;
}

int ClearanceReport::samples_below_margin() const {
  int n = self.samples_below_margin;
  for (const auto& l : links) n += l.samples_below_margin;
  return n;
}

int ClearanceReport::moving_samples_below_margin() const {
  int n = self.samples_below_margin;
  for (const auto& l : links)
    if (!l.fixed) n += l.samples_below_margin;
  return n;
}

// ------------------------------------------------------------------------------------------------
// check_clearance, check_clearance_octree
// ------------------------------------------------------------------------------------------------
namespace {

// A sample and shape whose field bound leaves it a candidate for its link's least distance.
struct Candidate {
  double lower_m;
  std::size_t sample, shape;
  bool operator<(const Candidate& o) const { return std::tie(lower_m, sample, shape) < std::tie(o.lower_m, o.sample, o.shape); }
};

// One stretch of samples checked on its own (its first sample queries every shape and pair).
struct ChunkResult {
  std::vector<LinkClearance> links;
  SelfClearance self;
  long long wall_queries = 0, field_queries = 0, exact_queries = 0, self_queries = 0;
  std::vector<std::pair<std::size_t, std::size_t>> min_at;  // per link: the sample and shape of min_m
  // Exact check, per link: the least field upper bound and the candidates whose lower bound was
  // below the least upper bound at the time (only those can hold the link's least distance).
  std::vector<double> upper_m;
  std::vector<std::vector<Candidate>> candidates;
};

enum class Measure { exact, octree };

ClearanceReport run_check(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                          const ClearanceConfig& config, const ProgressFn& progress, Measure measure) {
  const auto t0 = std::chrono::steady_clock::now();
  const auto& shapes = robot.collision_shapes();
  const std::size_t n = trajectory.size();
  ClearanceReport rep;
  rep.octree_resolution_m = wall.resolution_m();
  rep.octree_leaves = wall.occupied_leaves();
  rep.samples = static_cast<int>(n);
  if (shapes.empty()) throw std::invalid_argument("check_clearance: the robot has no collision shapes");
  // One entry per link with geometry, in chain order; fixed when all its shapes are.
  const std::vector<char> fixed = fixed_shapes(robot);
  std::vector<int> link_of(shapes.size());
  for (std::size_t s = 0; s < shapes.size(); ++s) {
    auto it = std::find_if(rep.links.begin(), rep.links.end(), [&](const LinkClearance& l) { return l.link == shapes[s].link; });
    if (it == rep.links.end()) {
      LinkClearance l;
      l.link = shapes[s].link;
      l.margin_m = shape_margin_m(shapes[s], config);
      l.min_m = std::numeric_limits<double>::infinity();
      l.fixed = true;
      rep.links.push_back(l);
      it = rep.links.end() - 1;
    }
    it->fixed = it->fixed && fixed[s];
    link_of[s] = static_cast<int>(it - rep.links.begin());
  }
  // A link no joint moves needs no room for motion (path deviations, a posture's error), only for
  // the rig's placing and the scan's registration: clearance.base_margin_m. Its distance is the
  // base's place (the problem base_clearance).
  for (auto& l : rep.links)
    if (l.fixed) l.margin_m = config.base_margin_m;
  const auto pairs = self_check_pairs(robot);
  rep.self.min_m = std::numeric_limits<double>::infinity();
  if (n == 0) return rep;

  std::vector<std::array<Eigen::Vector3d, 8>> corners;
  std::vector<BallCover> covers;  // the field bounds' cover of each shape
  for (const auto& s : shapes) corners.push_back(box_corners(s)), covers.push_back(ball_cover(s, kFieldCoverSlack_m));
  wall.field_voxel_m();  // the field built here, once, inside the timing
  const double leaf_diagonal_m = wall.leaf_diagonal_m();
  // Fixed stretches of samples, whatever the number of threads: the result (minima, counts,
  // queries) depends on the trajectory only.
  const std::size_t n_chunks = std::clamp<std::size_t>(n / kChunkSamples, 1, kMaxChunks);
  std::vector<ChunkResult> results(n_chunks);
  std::atomic<std::size_t> done{0};
  const std::size_t report_every = std::max<std::size_t>(1, n / 100);
  std::exception_ptr failure;
  std::mutex failure_mutex;

  auto run_chunk = [&](std::size_t c, bool reports) {
    const std::size_t begin = n * c / n_chunks, end = n * (c + 1) / n_chunks;
    ChunkResult& out = results[c];
    out.links = rep.links;
    out.self = rep.self;
    // Per shape and per pair: a lower bound on the distance at the last query (the octree's
    // reading, which is never long; a pair's exact distance) and the pose then. The distance now is at least that less how far the
    // shape has moved since (the farthest corner of its bounding box from where it was: every
    // point of a rigid shape moves at most that far).
    const double inf = std::numeric_limits<double>::infinity();
    std::vector<double> wall_at(shapes.size(), -inf), pair_at(pairs.size(), -inf);  // field_at: wall_at
    std::vector<Eigen::Isometry3d> wall_pose(shapes.size());
    std::vector<Placement> wall_place(shapes.size());  // the exact check's: the placement at the last bound
    std::vector<Eigen::Isometry3d> pair_pose(pairs.size());  // b relative to a
    std::vector<char> below(out.links.size());
    std::vector<Eigen::Isometry3d> inverse(robot.link_names().size());  // frames' inverses at this sample
    std::vector<char> inverse_done(inverse.size());
    std::vector<signed char> last_below(shapes.size(), -1);  // the exact decision at wall_pose (-1: none)
    out.min_at.assign(out.links.size(), {0, 0});
    out.upper_m.assign(out.links.size(), inf);
    out.candidates.resize(out.links.size());
    for (std::size_t k = begin; k < end; ++k) {
      const std::size_t count = done.fetch_add(1, std::memory_order_relaxed);
      if (reports && progress && count % report_every == 0) progress("clearance", static_cast<double>(count) / static_cast<double>(n));
      const auto frames = robot.link_frames(trajectory.q[k]);
      std::fill(below.begin(), below.end(), 0);
      for (std::size_t s = 0; s < shapes.size(); ++s) {
        const std::size_t l = static_cast<std::size_t>(link_of[s]);
        LinkClearance& lc = out.links[l];
        const Eigen::Isometry3d& pose = frames[shapes[s].frame];
        if (measure == Measure::exact) {
          // The distance field bounds the exact distance from below (lower) and above (upper) in a
          // lookup per ball of the cover. Below the margin only if lower is: then the exact
          // distance decides. The link's least distance can only be at a sample whose lower bound
          // is below the least upper bound: those are kept for the exact pass after the stretches.
          // Skipped (as the octree readings) where the last lower bound less the shape's motion
          // since is past the margin and past the least upper bound.
          // Not moved at all (the same placement as at the last bound): the same distance, the
          // same decision, no new candidate (the earlier sample is one if this would be).
          const Placement now = placement(shapes[s], corners[s], pose);
          if (wall_at[s] > -inf) {
            const double motion = placement_motion(shapes[s], now, wall_place[s]);
            if (motion == 0.0 && last_below[s] >= 0) {
              below[l] = below[l] || last_below[s] == 1;
              continue;
            }
            const double moved = wall_at[s] - motion;
            if (moved >= lc.margin_m && moved > out.upper_m[l]) continue;
          }
          const auto [lower, upper] = shape_field_bounds(wall, covers[s], pose);
          ++out.field_queries;
          wall_at[s] = lower;
          wall_place[s] = now;
          last_below[s] = 0;
          if (lower < lc.margin_m) {
            if (below[l]) {
              last_below[s] = -1;  // not measured: the link is below by another shape
            } else {
              ++out.exact_queries;
              below[l] = wall.exact_distance(shapes[s], pose, nullptr, lc.margin_m) < lc.margin_m;
              last_below[s] = below[l] ? 1 : 0;
            }
          }
          out.upper_m[l] = std::min(out.upper_m[l], std::max(0.0, upper));
          if (lower <= out.upper_m[l]) out.candidates[l].push_back({lower, k, s});
          continue;
        }
        // Skipped where the last octree reading less the motion since is past the margin and past
        // the least reading so far less the tolerance: the octree never reads long, so such a
        // sample is provably not below the margin (nor, by the exact distance, which is at least
        // the reading) and cannot lower the least reading by more than the tolerance.
        const double threshold = std::max(lc.margin_m, lc.min_m - kMinTolerance_m);
        if (wall_at[s] > threshold && wall_at[s] - max_displacement(corners[s], pose, wall_pose[s]) >= threshold) continue;
        // Skipped, by the same argument, where the distance field's lower bound (never above the
        // exact distance, which the reading is at most a leaf diagonal short of) is past the
        // threshold by a diagonal: a lookup per ball instead of an FCL traversal.
        if (shape_field_bounds(wall, covers[s], pose).lower_m - leaf_diagonal_m >= threshold) continue;
        // Asked only up to the threshold plus a slack: "at least that far" is all the skipping
        // needs, and the bound makes FCL's traversal several times faster.
        Eigen::Vector3d closest;
        const double d = wall.distance(shapes[s], pose, &closest, std::isfinite(threshold) ? threshold + kQuerySlack_m : std::numeric_limits<double>::max());
        ++out.wall_queries;
        wall_pose[s] = pose;
        wall_at[s] = d;
        if (d < lc.min_m) lc.min_m = d, lc.at_time_s = trajectory.t_s[k], lc.closest_m = closest, out.min_at[l] = {k, s};
        if (d < lc.margin_m) {
          // Below by the octree (at most a leaf diagonal short): the exact distance decides.
          if (measure == Measure::octree) {
            below[l] = 1;
          } else {
            ++out.exact_queries;
            below[l] = below[l] || wall.exact_distance(shapes[s], pose) < lc.margin_m;
          }
        }
      }
      for (std::size_t l = 0; l < out.links.size(); ++l) out.links[l].samples_below_margin += below[l];
      bool self_below = false;
      std::fill(inverse_done.begin(), inverse_done.end(), 0);
      for (std::size_t p = 0; p < pairs.size(); ++p) {
        const auto [a, b] = pairs[p];
        const auto ua = static_cast<std::size_t>(a), ub = static_cast<std::size_t>(b);
        // Their distance depends on b's pose relative to a only: b's motion in a's frame bounds it
        // (skipped as the wall queries above; shape_motion's set bound for a cylinder gave more
        // queries here: 1,967 instead of 1,849 on the default bay).
        const auto fa = static_cast<std::size_t>(shapes[ua].frame);
        if (!inverse_done[fa]) inverse[fa] = frames[fa].inverse(), inverse_done[fa] = 1;
        const Eigen::Isometry3d relative = inverse[fa] * frames[shapes[ub].frame];
        const double threshold = std::max(config.self_margin_m, out.self.min_m - kMinTolerance_m);
        if (pair_at[p] > threshold && pair_at[p] - max_displacement(corners[ub], relative, pair_pose[p]) >= threshold) continue;
        const double d = shape_distance(shapes[ua], frames[shapes[ua].frame], shapes[ub], frames[shapes[ub].frame]);
        ++out.self_queries;
        pair_at[p] = d;
        pair_pose[p] = relative;
        if (d < out.self.min_m)
          out.self.min_m = d, out.self.at_time_s = trajectory.t_s[k], out.self.link_a = shapes[ua].link, out.self.link_b = shapes[ub].link;
        self_below = self_below || d < config.self_margin_m;
      }
      out.self.samples_below_margin += self_below ? 1 : 0;
    }
  };
  const int threads = static_cast<int>(std::min<std::size_t>(n_chunks, kThreads));
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads) if (threads > 1)
  for (long c = 0; c < static_cast<long>(n_chunks); ++c) {
    try {
      run_chunk(static_cast<std::size_t>(c), omp_get_thread_num() == 0);  // progress from the caller's thread only
    } catch (...) {
      const std::lock_guard<std::mutex> lock(failure_mutex);
      if (!failure) failure = std::current_exception();
    }
  }
  if (failure) std::rethrow_exception(failure);
  // Merged in sample order: the earliest of equal minima wins, as in one pass.
  std::vector<std::pair<std::size_t, std::size_t>> min_at(rep.links.size(), {0, 0});
  for (const ChunkResult& c : results) {
    for (std::size_t l = 0; l < rep.links.size(); ++l) {
      LinkClearance& to = rep.links[l];
      const LinkClearance& from = c.links[l];
      if (from.min_m < to.min_m)
        to.min_m = from.min_m, to.at_time_s = from.at_time_s, to.closest_m = from.closest_m, min_at[l] = c.min_at[l];
      to.samples_below_margin += from.samples_below_margin;
    }
    if (c.self.min_m < rep.self.min_m)
      rep.self.min_m = c.self.min_m, rep.self.at_time_s = c.self.at_time_s, rep.self.link_a = c.self.link_a, rep.self.link_b = c.self.link_b;
    rep.self.samples_below_margin += c.self.samples_below_margin;
    rep.wall_queries += c.wall_queries;
    rep.field_queries += c.field_queries;
    rep.exact_queries += c.exact_queries;
    rep.self_queries += c.self_queries;
  }
  if (measure == Measure::exact) {
    // Each link's least distance, exact over every sample, by branch and bound: its candidates in
    // the order of their field lower bounds, each measured exactly unless a bound already keeps it
    // from beating the best so far, until the next lower bound is past the best (every other
    // sample's bound was above the least upper bound, so above the least distance). Besides the
    // field bound, a measured sample bounds its shape at the others: the distance there is at
    // least the measured one less the shape's motion between them (shape_motion), read from the
    // measured samples on either side in time (on the default bay this leaves ~1 in 40 of the
    // samples whose field bound is below the least distance to measure). A measurement asks for
    // the distance only up to the best + kMinAskSlack_m: nearer ones come back exact, farther ones
    // as that bound, which is what the motion bound needs. Ties (within kTie_m, rounding): the
    // earliest sample.
    std::vector<long long> link_exact(rep.links.size(), 0);
#pragma omp parallel for schedule(dynamic, 1) num_threads(static_cast<int>(kThreads))
    for (long li = 0; li < static_cast<long>(rep.links.size()); ++li) {
      const auto l = static_cast<std::size_t>(li);
      double upper = std::numeric_limits<double>::infinity();
      for (const ChunkResult& c : results) upper = std::min(upper, c.upper_m[l]);
      std::vector<Candidate> cands;
      for (const ChunkResult& c : results)
        for (const Candidate& cd : c.candidates[l])
          if (cd.lower_m <= upper) cands.push_back(cd);
      std::sort(cands.begin(), cands.end());
      double best = std::numeric_limits<double>::infinity();
      std::size_t best_sample = std::numeric_limits<std::size_t>::max();
      Eigen::Vector3d best_closest = Eigen::Vector3d::Zero();
      // Per shape: sample -> (a lower bound on the distance there, exact or the bound asked; the link pose).
      std::map<std::size_t, std::map<std::size_t, std::pair<double, Eigen::Isometry3d>>> measured;
      for (const Candidate& cd : cands) {
        if (cd.lower_m > best + kTie_m) break;
        // A sample at least `bound` away can still win when nearer than the best, or as near and earlier.
        const auto can_win = [&](double bound) {
          return bound < best - kTie_m || (bound <= best + kTie_m && cd.sample < best_sample);
        };
        if (!can_win(cd.lower_m)) continue;
        const CollisionShape& shape = shapes[cd.shape];
        const Eigen::Isometry3d pose = robot.link_frames(trajectory.q[cd.sample])[shape.frame];
        auto& at = measured[cd.shape];
        const auto after = at.lower_bound(cd.sample);
        double bound = cd.lower_m;
        if (after != at.end())
          bound = std::max(bound, after->second.first - shape_motion(shape, corners[cd.shape], pose, after->second.second));
        if (after != at.begin()) {
          const auto before = std::prev(after);
          bound = std::max(bound, before->second.first - shape_motion(shape, corners[cd.shape], pose, before->second.second));
        }
        if (!can_win(bound)) continue;
        Eigen::Vector3d closest;
        const double d = wall.exact_distance(shape, pose, &closest, best + kMinAskSlack_m);
        ++link_exact[l];
        at[cd.sample] = {d, pose};
        if (d < best - kTie_m || (d <= best + kTie_m && cd.sample < best_sample))
          best = d, best_sample = cd.sample, best_closest = closest;
      }
      LinkClearance& lc = rep.links[l];
      lc.min_m = best;
      lc.closest_m = best_closest;
      lc.at_time_s = best_sample < n ? trajectory.t_s[best_sample] : 0.0;
    }
    for (long long e : link_exact) rep.exact_queries += e;
  }
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (progress) progress("clearance", 1.0);
  return rep;
}

}  // namespace

std::vector<ClearanceKeyPoint> clearance_key_points(const Robot& robot) {
  std::vector<ClearanceKeyPoint> keys;
  for (const CollisionShape& s : robot.collision_shapes()) {
    if (nozzle_shape(s)) continue;  // placed by the task: the null space cannot move them
    if (s.kind == CollisionShape::Kind::cylinder) {
      const int m = std::max(1, static_cast<int>(std::ceil(s.length_m / 0.25)));
      for (int k = 0; k < m; ++k)
        keys.push_back({s.frame, s.origin * Eigen::Vector3d(0, 0, -0.5 * s.length_m + (k + 0.5) * s.length_m / m), s.radius_m});
    } else {
      keys.push_back({s.frame, s.origin.translation(), s.kind == CollisionShape::Kind::sphere ? s.radius_m : 0.5 * s.size_m.minCoeff()});
    }
  }
  return keys;
}

NullSpaceObjective clearance_objective(const Robot& robot, const WallOctree& wall, const ClearanceConfig& config) {
  NullSpaceObjective out;
  out.gain = config.null_space_gain;
  if (!(out.gain > 0.0)) return out;
  const Robot* rb = &robot;
  const WallOctree* w = &wall;
  // The room a posture leaves: the shapes the spare degrees of freedom move (not the base, not
  // the nozzle links, which the task places), read up to 1 m past their margins. Only with the
  // drift: without it the tracking's settling toward mid-range (the slew's 0 points the boom
  // ahead) takes a roomier start back where it came from.
  std::vector<char> skip = fixed_shapes(robot);
  const auto& shapes = robot.collision_shapes();
  for (std::size_t k = 0; k < shapes.size(); ++k)
    if (nozzle_shape(shapes[k])) skip[k] = 1;
  const auto pairs = self_check_pairs(robot);
  const ClearanceConfig cc = config;
  out.room = [rb, w, skip, pairs, cc](const Eigen::VectorXd& q) { return posture_allowance(*rb, q, *w, cc, pairs, 1.0, &skip); };
  const std::vector<ClearanceKeyPoint> keys = clearance_key_points(robot);
  const double d0 = config.null_space_influence_m;
  // The robot's carrier boxes (on base_link): the wall's field holds no link of the robot, so the
  // carrier pushes by its own signed distance (exact, inside too), within link_margin_m only:
  // postures clear of it are not moved.
  std::vector<CollisionShape> carriers;
  for (const auto& sh : robot.collision_shapes())
    if (sh.carrier) carriers.push_back(sh);  // boxes on base_link's frame (Robot's loader)
  const double d0_carrier = config.link_margin_m;
  out.gradient = [rb, w, keys, d0, carriers, d0_carrier](const Eigen::VectorXd& q, Eigen::VectorXd& grad) {
    grad.setZero(q.size());
    std::vector<JointAxis> joints;
    const auto frames = rb->link_frames(q, joints);
    // dU/dx at each key point x inside the influence distance: -(d0 - d) / d0 times the field's gradient.
    struct Active {
      int frame;
      Eigen::Vector3d x, dudx;
    };
    std::vector<Active> active;
    for (const ClearanceKeyPoint& key : keys) {
      if (key.frame == 0) continue;  // on base_link: no joint moves it
      const Eigen::Vector3d x = frames[static_cast<std::size_t>(key.frame)] * key.point_m;
      const double d = w->field_distance(x) - key.radius_m;
      if (d < d0) {
        Eigen::Vector3d g;  // the field's gradient only where the key is within the influence
        w->field_distance(x, &g);
        active.push_back({key.frame, x, -(d0 - d) / d0 * g});
      }
      for (const CollisionShape& box : carriers) {
        Eigen::Vector3d g;
        const double dc = box_signed_distance(box, frames[0], x, &g) - key.radius_m;
        if (dc < d0_carrier) active.push_back({key.frame, x, -(d0_carrier - dc) / d0_carrier * g});
      }
    }
    if (active.empty()) return;
    // dU/dq_j = sum of dU/dx . dx/dq_j over the key points the joint moves (the point Jacobians
    // from the joints' axes at q).
    for (std::size_t j = 0; j < joints.size(); ++j) {
      const JointAxis& ja = joints[j];
      double sum = 0.0;
      for (const Active& a : active) {
        if (a.frame < ja.first_frame) continue;
        sum += a.dudx.dot(ja.rotational ? Eigen::Vector3d(ja.axis.cross(a.x - ja.point_m)) : ja.axis);
      }
      grad[static_cast<Eigen::Index>(j)] = sum;
    }
  };
  return out;
}

ClearanceReport check_clearance(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                                const ClearanceConfig& config, const ProgressFn& progress) {
  return run_check(robot, trajectory, wall, config, progress, Measure::exact);
}

ClearanceReport check_clearance_octree(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                                       const ClearanceConfig& config, const ProgressFn& progress) {
  return run_check(robot, trajectory, wall, config, progress, Measure::octree);
}

}  // namespace shotcrete
