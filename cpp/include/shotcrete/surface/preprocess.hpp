#pragma once
#include <vector>
// Cloud checks and PCL preprocessing: crop box, voxel downsampling, statistical outlier removal,
// and k-NN normals oriented toward the tunnel axis.
#include "shotcrete/config.hpp"
#include "shotcrete/surface/profile.hpp"
#include "shotcrete/types.hpp"

#include <string>

namespace shotcrete {

/// Throws std::invalid_argument for an empty cloud, NaN/inf coordinates, a normals array of the
/// wrong size, or an extent beyond io.max_extent_m (which usually means millimetres).
void check_cloud(const Cloud& cloud, const IoConfig& io);

/// The message for a cloud spanning `span` units (> max_extent_m): the unit (cm or mm) that makes
/// it bay-sized, e.g. "coordinates span 12,000 units, ...: looks like millimetres (12 m); pass --units mm".
std::string unit_hint(double span, double max_extent_m);

/// Applies io.unit_scale to the coordinates (normals unchanged).
Cloud scale_cloud(const Cloud& cloud, double unit_scale);

/// The points at `indices`, in that order (with their normals when the cloud has them).
Cloud select_points(const Cloud& cloud, const std::vector<Eigen::Index>& indices);
Cloud crop_box(const Cloud& cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m);
Cloud voxel_downsample(const Cloud& cloud, double voxel_size_m);
Cloud remove_statistical_outliers(const Cloud& cloud, int neighbors, double std_ratio);
/// crop (if enabled) -> voxel (if > 0) -> outliers (if neighbors > 0). Normals are dropped.
Cloud preprocess(const Cloud& cloud, const PreprocessConfig& config);

/// Flips each normal to point from the wall toward the tunnel axis (zero/NaN normals get the radial one).
void orient_normals_toward_axis(Cloud& cloud, const TunnelAxis& axis);

/// PCL k-NN normals, each flipped to point from the wall toward the tunnel axis.
Cloud estimate_normals(const Cloud& cloud, int k_neighbors, const TunnelAxis& axis);

}  // namespace shotcrete
