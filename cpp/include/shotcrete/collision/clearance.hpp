#pragma once
// Space allowance of the arm (seed method: key points and optimal space allowance): the distance of
// every link's collision shape to the wall and to the other links, at every trajectory sample.
// The wall is an octomap octree queried through FCL; shapes are the URDF's <collision> geometry.
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "shotcrete/config.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

struct TimedTrajectory;

/// The wall as an obstacle: an octree of points (leaf edge `resolution_m`). Each occupied leaf is a
/// box, so a distance reads at most a leaf diagonal (sqrt(3) x resolution) short of the
/// distance to the points themselves, never long.
class WallOctree {
 public:
  WallOctree(const Points& xyz_m, double resolution_m);
  ~WallOctree();
  WallOctree(WallOctree&&) noexcept;
  WallOctree& operator=(WallOctree&&) noexcept;
  /// Distance [m] of `shape` placed at `link_pose` (world pose of its link) to the wall; 0 when it
  /// touches or enters an occupied leaf. `closest_m`: the wall's closest point (leaf surface).
  /// With `at_most_m`, a distance of at least at_most_m comes back as at_most_m (closest_m unset):
  /// the bound prunes the search.
  double distance(const CollisionShape& shape, const Eigen::Isometry3d& link_pose, Eigen::Vector3d* closest_m = nullptr,
                  double at_most_m = std::numeric_limits<double>::max()) const;
  /// Exact distance [m] of `shape` to the wall's points (the minimum over every point, 0 inside):
  /// the octree's answer L is at most a leaf diagonal short, so every point that can be nearest
  /// lies within L + sqrt(3) x resolution of the shape; those are gathered from a KD-tree of the
  /// points (built on first use) and measured exactly (point_shape_distance). `closest_m`: the point.
  double exact_distance(const CollisionShape& shape, const Eigen::Isometry3d& link_pose,
                        Eigen::Vector3d* closest_m = nullptr) const;
  double resolution_m() const;
  std::size_t occupied_leaves() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Distance [m] between two shapes at their links' world poses (0 when they touch or overlap).
double shape_distance(const CollisionShape& a, const Eigen::Isometry3d& pose_a, const CollisionShape& b,
                      const Eigen::Isometry3d& pose_b);

/// Distance [m] of a point to a shape at its link's world pose (0 inside): the exact reference
/// the octree query is checked against.
double point_shape_distance(const Eigen::Vector3d& p, const CollisionShape& shape, const Eigen::Isometry3d& link_pose);

/// The wall margin of a shape: nozzle_margin_m for links named nozzle*, else link_margin_m.
double shape_margin_m(const CollisionShape& shape, const ClearanceConfig& config);

/// Shape pairs checked against each other: every pair on links that are not neighbours on the
/// chain (frames more than one apart) and do not already touch at the neutral posture (a
/// telescope inside its boom; such pairs are allowed contact, as in a MoveIt allowed-collision matrix).
std::vector<std::pair<int, int>> self_check_pairs(const Robot& robot);

struct LinkClearance {
  std::string link;
  double margin_m = 0.0;             // clearance.link_margin_m or nozzle_margin_m
  double min_m = 0.0;                // least distance to the wall over every sample
  double at_time_s = 0.0;            // when
  Eigen::Vector3d closest_m = Eigen::Vector3d::Zero();  // the wall's closest point then
  int samples_below_margin = 0;
};
struct SelfClearance {
  std::string link_a, link_b;        // the closest pair of non-neighbouring links
  double min_m = 0.0;
  double at_time_s = 0.0;
  int samples_below_margin = 0;      // samples where any checked pair is closer than self_margin_m
};
struct ClearanceReport {
  std::vector<LinkClearance> links;  // links with collision geometry, base first
  SelfClearance self;
  double octree_resolution_m = 0.0;
  std::size_t octree_leaves = 0, wall_points = 0;
  int samples = 0;
  long long wall_queries = 0, self_queries = 0;  // exact distance queries run (the rest were bounded)
  double seconds = 0.0;
  int samples_below_margin() const;  // over the links and the self check
};

/// The space allowance along `trajectory`. A sample is checked unless a lower bound proves it
/// cannot set a new minimum or fall below the margin: the distance at the last query less how far
/// the shape has moved since (every point of a rigid shape moves at most as far as the farthest
/// corner of its bounding box; a link pair's distance changes by at most b's motion relative to
/// a). The counts below the margins are therefore those of a check of every sample, and the
/// minima lie within 10 mm above its minima. Two fixed stretches of the trajectory run on two
/// threads: the result does not depend on their timing.
ClearanceReport check_clearance(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                                const ClearanceConfig& config, const ProgressFn& progress = {});

}  // namespace shotcrete
