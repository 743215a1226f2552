#pragma once
// Survey coordinates (docs/architecture.md §3, "Survey coordinates"). Scans arrive in survey
// coordinates (x = 500,000, y = 4,000,000): float32, which PCL's filters and normals use, keeps
// only ~0.25 m there. A job therefore runs in a local frame: the input (read in double precision)
// minus a local origin, the centre of its bounding box rounded to whole 100 m ((0, 0, 0) for any
// cloud within 50 m of its own origin, so such clouds run unchanged). The config's coordinates
// (axis origin, crop box, robot base) are in the input's frame too and move with it. The CLI
// (python/shotcrete/survey.py) and the ROS node both call these.
#include <Eigen/Core>

#include "shotcrete/config.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

/// The local origin is a multiple of this on every axis [m].
constexpr double kLocalOriginStepM = 100.0;
/// A config point (robot base, axis origin) farther than this from a shifted cloud was not given
/// in the cloud's frame [m].
constexpr double kFarFromCloudM = 1000.0;

/// The bounding-box centre of the finite rows of `xyz_m` (metres, scaled by `unit_scale` first),
/// rounded to whole kLocalOriginStepM; (0, 0, 0) for none.
Eigen::Vector3d local_origin(const Points& xyz, double unit_scale = 1.0);

/// The local origin [m] of a cloud in its input units (io.unit_scale); (0, 0, 0) for a cloud wider
/// than io.max_extent_m, which the surface stage refuses with a units hint.
Eigen::Vector3d local_frame_origin(const Points& xyz, const IoConfig& io);

/// Moves `cloud` (input units: by -origin_m / io.unit_scale) and the config's coordinates
/// (profile.axis_origin_m, preprocess.crop_min_m/crop_max_m, robot.base_position_m, by -origin_m)
/// into the local frame; normals unchanged; nothing moves for a zero origin. Throws
/// std::invalid_argument, naming the key, when the robot base (or the axis origin, when it is
/// used) lies more than kFarFromCloudM from the cloud: a config left in another frame.
void to_local_frame(const Eigen::Vector3d& origin_m, Cloud& cloud, Config& config);

}  // namespace shotcrete
