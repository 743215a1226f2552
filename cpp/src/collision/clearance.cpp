#include "shotcrete/collision/clearance.hpp"

#include <fcl/fcl.h>
#include <fcl/geometry/octree/octree.h>
#include <octomap/OcTree.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>

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

// The reported minima may be this much above the exact ones (a sample is not checked when it
// could only lower a minimum by less); the counts below the margins are exact.
constexpr double kMinTolerance_m = 0.01;

// How far past the threshold a wall query looks: larger answers more samples per query, smaller
// makes each query cheaper (bench_clearance.py).
constexpr double kQuerySlack_m = 0.25;

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
  std::once_flag kd_built;
  pcl::KdTreeFLANN<pcl::PointXYZ> kd;
  const pcl::KdTreeFLANN<pcl::PointXYZ>& kdtree() {
    std::call_once(kd_built, [&] {
      auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
      cloud->resize(static_cast<std::size_t>(points.rows()));
      for (Eigen::Index i = 0; i < points.rows(); ++i)
        (*cloud)[static_cast<std::size_t>(i)] = pcl::PointXYZ(static_cast<float>(points(i, 0)), static_cast<float>(points(i, 1)),
                                                              static_cast<float>(points(i, 2)));
      kd.setInputCloud(cloud);
    });
    return kd;
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
                                  Eigen::Vector3d* closest_m) const {
  // Every point of the nearest leaf lies within a leaf diagonal of the shape's distance to it.
  const double upper = distance(shape, link_pose) + std::sqrt(3.0) * impl_->resolution_m;
  // Spheres that cover every point within `upper` of the shape: along a cylinder's axis, spaced at
  // most the tube's radius apart; one about a box's or a sphere's centre.
  const Eigen::Isometry3d T = link_pose * shape.origin;
  std::vector<std::pair<Eigen::Vector3d, double>> balls;
  if (shape.kind == CollisionShape::Kind::cylinder) {
    const double tube = shape.radius_m + upper;
    const int m = std::max(1, static_cast<int>(std::ceil(shape.length_m / tube)));
    const double h = shape.length_m / m;
    for (int k = 0; k <= m; ++k)
      balls.emplace_back(T * Eigen::Vector3d(0, 0, -0.5 * shape.length_m + k * h), std::hypot(0.5 * h, tube));
  } else {
    const double r = shape.kind == CollisionShape::Kind::box ? 0.5 * shape.size_m.norm() : shape.radius_m;
    balls.emplace_back(T.translation(), r + upper);
  }
  const auto& kd = impl_->kdtree();
  double best = std::numeric_limits<double>::infinity();
  Eigen::Index best_i = -1;
  std::vector<int> idx;
  std::vector<float> d2;
  for (const auto& [c, r] : balls) {
    kd.radiusSearch(pcl::PointXYZ(static_cast<float>(c.x()), static_cast<float>(c.y()), static_cast<float>(c.z())),
                    r + 1e-4, idx, d2);  // (float coordinates: a hair wider)
    for (int i : idx) {
      const double d = point_shape_distance(impl_->points.row(i).transpose(), shape, link_pose);
      if (d < best) best = d, best_i = i;
    }
  }
  if (best_i < 0) throw std::logic_error("WallOctree::exact_distance: no point within the octree's bound");
  if (closest_m) *closest_m = impl_->points.row(best_i).transpose();
  return best;
}

double shape_distance(const CollisionShape& a, const Eigen::Isometry3d& pose_a, const CollisionShape& b,
                      const Eigen::Isometry3d& pose_b) {
  const fcl::CollisionObjectd oa(fcl_shape(a), to_fcl(pose_a * a.origin));
  const fcl::CollisionObjectd ob(fcl_shape(b), to_fcl(pose_b * b.origin));
  return fcl_distance(oa, ob, nullptr);
}

double point_shape_distance(const Eigen::Vector3d& p_world, const CollisionShape& shape, const Eigen::Isometry3d& link_pose) {
  const Eigen::Vector3d p = (link_pose * shape.origin).inverse() * p_world;  // in the shape's frame
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

double shape_margin_m(const CollisionShape& shape, const ClearanceConfig& config) {
  return shape.link.rfind("nozzle", 0) == 0 ? config.nozzle_margin_m : config.link_margin_m;
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

// ------------------------------------------------------------------------------------------------
// check_clearance
// ------------------------------------------------------------------------------------------------
ClearanceReport check_clearance(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                                const ClearanceConfig& config, const ProgressFn& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  const auto& shapes = robot.collision_shapes();
  const std::size_t n = trajectory.size();
  ClearanceReport rep;
  rep.octree_resolution_m = wall.resolution_m();
  rep.octree_leaves = wall.occupied_leaves();
  rep.samples = static_cast<int>(n);
  if (shapes.empty()) throw std::invalid_argument("check_clearance: the robot has no collision shapes");
  // One entry per link with geometry, in chain order.
  std::vector<int> link_of(shapes.size());
  for (std::size_t s = 0; s < shapes.size(); ++s) {
    auto it = std::find_if(rep.links.begin(), rep.links.end(), [&](const LinkClearance& l) { return l.link == shapes[s].link; });
    if (it == rep.links.end()) {
      LinkClearance l;
      l.link = shapes[s].link;
      l.margin_m = shape_margin_m(shapes[s], config);
      l.min_m = std::numeric_limits<double>::infinity();
      rep.links.push_back(l);
      it = rep.links.end() - 1;
    }
    link_of[s] = static_cast<int>(it - rep.links.begin());
  }
  const auto pairs = self_check_pairs(robot);
  rep.self.min_m = std::numeric_limits<double>::infinity();
  if (n == 0) return rep;

  std::vector<std::array<Eigen::Vector3d, 8>> corners;
  for (const auto& s : shapes) corners.push_back(box_corners(s));
  // Per shape and per pair: the distance at the last query less the motion since (a lower bound).
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> wall_lower(shapes.size(), -inf), pair_lower(pairs.size(), -inf);
  std::vector<Eigen::Isometry3d> prev;
  std::vector<char> below(rep.links.size());
  const std::size_t report_every = std::max<std::size_t>(1, n / 100);
  for (std::size_t k = 0; k < n; ++k) {
    if (progress && k % report_every == 0) progress("clearance", static_cast<double>(k) / static_cast<double>(n));
    const auto frames = robot.link_frames(trajectory.q[k]);
    std::vector<double> step(shapes.size(), 0.0);
    if (!prev.empty())
      for (std::size_t s = 0; s < shapes.size(); ++s)
        step[s] = max_displacement(corners[s], frames[shapes[s].frame], prev[shapes[s].frame]);
    std::fill(below.begin(), below.end(), 0);
    for (std::size_t s = 0; s < shapes.size(); ++s) {
      LinkClearance& lc = rep.links[static_cast<std::size_t>(link_of[s])];
      const double lower = wall_lower[s] -= step[s];
      // Skipped when it can be neither below the margin nor more than the tolerance below the
      // least distance so far: counts exact, minima within kMinTolerance_m.
      if (lower >= lc.margin_m && lower >= lc.min_m - kMinTolerance_m) continue;
      // Asked only up to the threshold plus a slack: "at least that far" is all the skipping
      // needs, and the bound makes FCL's traversal several times faster.
      const double threshold = std::max(lc.min_m, lc.margin_m);
      const double at_most = std::isfinite(threshold) ? threshold + kQuerySlack_m : std::numeric_limits<double>::max();
      Eigen::Vector3d closest;
      const double d = wall.distance(shapes[s], frames[shapes[s].frame], &closest, at_most);
      ++rep.wall_queries;
      wall_lower[s] = d;
      if (d < lc.min_m) lc.min_m = d, lc.at_time_s = trajectory.t_s[k], lc.closest_m = closest;
      if (d < lc.margin_m) below[static_cast<std::size_t>(link_of[s])] = 1;
    }
    for (std::size_t l = 0; l < rep.links.size(); ++l) rep.links[l].samples_below_margin += below[l];
    bool self_below = false;
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      const auto [a, b] = pairs[p];
      const double lower = pair_lower[p] -= step[static_cast<std::size_t>(a)] + step[static_cast<std::size_t>(b)];
      if (lower >= config.self_margin_m && lower >= rep.self.min_m - kMinTolerance_m) continue;
      const double d = shape_distance(shapes[a], frames[shapes[a].frame], shapes[b], frames[shapes[b].frame]);
      ++rep.self_queries;
      pair_lower[p] = d;
      if (d < rep.self.min_m)
        rep.self.min_m = d, rep.self.at_time_s = trajectory.t_s[k], rep.self.link_a = shapes[a].link, rep.self.link_b = shapes[b].link;
      self_below = self_below || d < config.self_margin_m;
    }
    rep.self.samples_below_margin += self_below ? 1 : 0;
    prev = frames;
  }
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (progress) progress("clearance", 1.0);
  return rep;
}

}  // namespace shotcrete
