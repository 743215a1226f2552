// Parts of the registration that replace PCL steps for speed, declared here so the tests can
// compare them with the PCL steps they replace (tests/cpp/test_rescan.cpp).
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/search/kdtree.h>

#include <cstddef>

namespace shotcrete::detail {

using PclCloud = pcl::PointCloud<pcl::PointXYZ>;
using GicpBase = pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ>;
using Tree = pcl::search::KdTree<pcl::PointXYZ>;

// GICP's per-point covariances by PCL 1.13's formula, in double precision (GeneralizedIterativeClosestPoint::
// computeCovariances: the covariance of the k nearest points with its two largest singular values
// set to 1 and the smallest to epsilon), on every thread; `tree` is built on `cloud`.
GicpBase::MatricesVectorPtr gicp_covariances(const PclCloud& cloud, const Tree& tree, int k, double epsilon);

// The number of voxels of edge voxel_m that `cloud` occupies: the size of PCL's VoxelGrid output
// (the same float floor(x / edge) keys) without its sort and centroids.
std::size_t occupied_voxels(const PclCloud& cloud, double voxel_m);

}  // namespace shotcrete::detail
