#pragma once
// Space allowance of the arm (seed method: key points and optimal space allowance): the distance of
// every link's collision shape to the wall and to the other links, at every trajectory sample.
// The wall is an octomap octree queried through FCL (the transit router's screen), a Euclidean
// distance field (check_clearance's bounds) and its points grouped in blocks (exact distances); shapes
// are the URDF's <collision> geometry.
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "shotcrete/config.hpp"
#include "shotcrete/robot/joint_tracking.hpp"  // NullSpaceObjective
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

struct TimedTrajectory;

/// The wall as an obstacle: an octree of points (leaf edge `resolution_m`). Each occupied leaf is a
/// box, so a distance reads at most a leaf diagonal (sqrt(3) x resolution) short of the
/// distance to the points themselves, never long. The distance field and the point groups are
/// built on first use (thread-safe).
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
  /// Exact distance [m] of `shape` to the wall's points (the minimum over every point, 0 inside).
  /// The points are grouped in blocks of 0.2 m and cells of 5 cm (built on first use), each with
  /// the bounding sphere of its points; the blocks that can hold a nearer point than the best so
  /// far (the shape's distance to the sphere's centre less its radius is below it), in the order of
  /// those bounds, then their cells likewise, then every point of those cells, measured as
  /// point_shape_distance does (the same value to the last bit). `closest_m`: the point (the first
  /// row of equal ones). With `at_most_m`: a distance of at least at_most_m comes back as at_most_m
  /// (closest_m unset); only groups that can hold a point nearer than it are visited.
  double exact_distance(const CollisionShape& shape, const Eigen::Isometry3d& link_pose,
                        Eigen::Vector3d* closest_m = nullptr,
                        double at_most_m = std::numeric_limits<double>::infinity()) const;
  /// Bounds [m] from the wall's Euclidean distance field (an exact EDT of the cells of edge
  /// field_voxel_m() that hold a wall point, built on first use): no point within `radius_m` of
  /// `centre_m` is nearer than `lower` to a wall point, and some wall point is at most `upper` from
  /// `centre_m`. lower = field value at the centre's cell - the centre's offset from the cell's
  /// centre - half a cell diagonal (a point's offset in its cell) - radius_m; upper adds the same
  /// offsets instead (outside the points' bounding box: read at the centre's projection onto it,
  /// combined with the distance to it). O(1): a lookup.
  struct FieldBounds {
    double lower_m, upper_m;
  };
  FieldBounds field_bounds(const Eigen::Vector3d& centre_m, double radius_m) const;
  /// A lower bound [m] on exact_distance(shape, link_pose), never above it: the least
  /// field_bounds().lower_m over a sphere cover of the shape (balls at most 1 cm past it).
  double field_lower_bound(const CollisionShape& shape, const Eigen::Isometry3d& link_pose) const;
  /// A smooth reading [m] of the distance field at p (trilinear between cell centres; outside the
  /// points' bounding box, at p's projection onto it plus the distance to it) and its gradient by
  /// central differences `step_m` apart (smoothed over that span): the clearance term's guide, not
  /// a bound (it reads up to about a cell diagonal off the distance to the points).
  double field_distance(const Eigen::Vector3d& p_m, Eigen::Vector3d* gradient = nullptr, double step_m = 0.1) const;
  /// Edge [m] of the distance field's cells: half the octree's leaf, coarser only if the wall's
  /// bounding box would need more than 64 M cells.
  double field_voxel_m() const;
  double resolution_m() const;
  /// Diagonal [m] of an octree leaf: how far the octree's readings may fall short of the exact
  /// distance to the points (a point anywhere in an occupied leaf).
  double leaf_diagonal_m() const;
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

/// A shape of the nozzle links (named nozzle*): the task places them, the null space cannot move them.
bool nozzle_shape(const CollisionShape& shape);

/// The wall margin of a shape: nozzle_margin_m for the nozzle links (nozzle_shape), else link_margin_m.
double shape_margin_m(const CollisionShape& shape, const ClearanceConfig& config);

/// Shape pairs checked against each other: every pair on links that are not neighbours on the
/// chain (frames more than one apart) and do not already touch at the neutral posture (a
/// telescope inside its boom; such pairs are allowed contact, as in a MoveIt allowed-collision matrix).
std::vector<std::pair<int, int>> self_check_pairs(const Robot& robot);

/// Per collision shape (Robot::collision_shapes order): 1 when no joint moves it (each joint alone
/// over its range from the neutral posture leaves it in place, as shape_motion reads it): the base,
/// a turret cylinder slewing about its own axis. No posture changes its distance to the wall; where
/// that is below its margin the base stands too close (robot.base_position_m).
std::vector<char> fixed_shapes(const Robot& robot);

/// Per point of `xyz_m` (tunnel frame): 1 when it is the machine's own, where the robot stands (its
/// base_pose): in the column of one of its carrier boxes (CollisionShape::carrier, the rig's
/// carrier), within the box across (x, y in the box's frame, its z up) widened by `tolerance_m`,
/// and no higher than its top + tolerance_m, down to the ground (wheels, tracks and the invert
/// under it: the box stops above the ground). A scan holds the carrier where the rig
/// stood when it was taken: those points are not obstacles (the carrier shape stands for them and
/// moves with the base). Throws std::invalid_argument for a negative or non-finite tolerance.
std::vector<char> machine_points(const Points& xyz_m, const Robot& robot, double tolerance_m);

/// Signed distance [m] of p to a box shape at its link's world pose: the distance outside, minus
/// the depth inside (to the nearest face); `gradient`: its direction of steepest rise (the
/// outward normal of the nearest face inside). The clearance term's carrier field.
double box_signed_distance(const CollisionShape& box, const Eigen::Isometry3d& link_pose, const Eigen::Vector3d& p,
                           Eigen::Vector3d* gradient = nullptr);

struct LinkClearance {
  std::string link;
  bool fixed = false;                // every shape of the link is fixed (fixed_shapes)
  double margin_m = 0.0;             // clearance.link_margin_m or nozzle_margin_m; clearance.base_margin_m for a fixed link
  double min_m = 0.0;                // least distance to the wall over every sample (see check_clearance)
  double at_time_s = 0.0;            // when (the earliest sample at that distance)
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
  int carrier_points = 0;  // scan points left out as the machine's own (the rig's carrier where it stood; plan_for_arm)
  int samples = 0;
  // Queries run: wall_queries octree readings (FCL; check_clearance_octree, the other samples
  // bounded by the shape's motion), field_queries distance-field bounds of a shape at a sample
  // (check_clearance: every sample and shape), exact_queries exact distances to the wall's points
  // (check_clearance only), self_queries FCL shape-shape distances (motion-bounded as the octree's).
  long long wall_queries = 0, field_queries = 0, exact_queries = 0, self_queries = 0;
  double seconds = 0.0;
  int samples_below_margin() const;  // over the links and the self check
  int moving_samples_below_margin() const;  // the same without the fixed links (no posture changes those)
};

/// The space allowance along `trajectory`, by exact distances to the wall's points. Every sample
/// and shape is bounded on the wall's distance field (WallOctree::field_bounds over a sphere cover
/// of the shape: a lower and an upper bound on the exact distance, a lookup per ball). A sample is
/// below a link's margin when the exact distance (WallOctree::exact_distance) of one of the link's
/// shapes is; it is measured only where the lower bound is below the margin, so the counts are
/// those of a check of every sample by exact distances. A shape is not bounded again while its
/// last bound less its motion since is past the margin and the least upper bound (a cylinder that
/// only turns about its own axis does not move). Each link's least distance (min_m, closest_m,
/// at_time_s) is exact over every sample, by branch and bound: the samples whose lower bound is
/// below the least upper bound, in the order of their bounds, each measured exactly unless its
/// bound (the field's, or a measured sample's distance less the shape's motion since) keeps it
/// from beating the least found, until the next bound is past the least found; ties within 1e-12 m
/// go to the earliest sample. Link pairs: FCL's distance, a sample skipped where
/// the pair's distance at its last query less b's motion relative to a since (the farthest corner
/// of its bounding box) is past the margin and past the least so far less 10 mm. Two fixed
/// stretches of the trajectory run on two threads: the result does not depend on their timing.
ClearanceReport check_clearance(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                                const ClearanceConfig& config, const ProgressFn& progress = {});

/// A key point of the clearance term: fixed on link frame `frame` (Robot::link_frames), with the
/// radius its shape reaches past it.
struct ClearanceKeyPoint {
  int frame = 0;
  Eigen::Vector3d point_m = Eigen::Vector3d::Zero();  // in the link's frame
  double radius_m = 0.0;
};
/// The term's key points: along each cylinder's axis at most 0.25 m apart, a sphere's or box's
/// centre (half the box's shortest edge), on every link but the nozzle* ones (the task sets where
/// the nozzle is).
std::vector<ClearanceKeyPoint> clearance_key_points(const Robot& robot);

/// The tracking's clearance term (clearance.null_space_gain, null_space_influence_m d0): the
/// gradient in joint space of U(q) = sum over the key points of 0.5 (d0 - d)^2 / d0 where d < d0,
/// d the field's smooth reading at the point less its radius. Point Jacobians from the joints' axes
/// (Robot::link_frames(q, joints)). `wall` must outlive the objective. It also gives `room`
/// (posture_allowance without the base and the nozzle links, read up to 1 m past the margins).
/// gain 0: an inactive objective, no room either (without the drift the tracking's settling
/// toward mid-range takes a roomier start back).
/// The robot's carrier boxes (CollisionShape::carrier) push too, by their signed distance
/// (box_signed_distance less the key's radius) with link_margin_m for d0: the wall's field holds
/// no link of the robot, and the boom folded back over the top was steered onto the carrier.
NullSpaceObjective clearance_objective(const Robot& robot, const WallOctree& wall, const ClearanceConfig& config);

/// The transit router's screen (transit.cpp): the same check on the octree's reading alone (no
/// exact distances): a sample is below the margin when its reading is, and the minima are the
/// least readings (within 10 mm above those of every sample), so it keeps every sample at least
/// its reading's shortfall (up to a leaf diagonal) farther than the margins.
ClearanceReport check_clearance_octree(const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall,
                                       const ClearanceConfig& config, const ProgressFn& progress = {});

}  // namespace shotcrete
