#include "shotcrete/surface/preprocess.hpp"

#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>

#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

namespace shotcrete {
namespace {

pcl::PointCloud<pcl::PointXYZ>::Ptr to_pcl(const Cloud& cloud) {
  auto pc = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  pc->resize(cloud.size());
  for (Eigen::Index i = 0; i < cloud.size(); ++i)
    (*pc)[i] = pcl::PointXYZ(cloud.xyz(i, 0), cloud.xyz(i, 1), cloud.xyz(i, 2));
  return pc;
}

Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZ>& pc) {
  Cloud out;
  out.xyz.resize(pc.size(), 3);
  for (std::size_t i = 0; i < pc.size(); ++i) out.xyz.row(i) << pc[i].x, pc[i].y, pc[i].z;
  return out;
}

/// 12345.6 -> "12,346"
std::string thousands(double value) {
  // llround is undefined past 2^63 (a hostile cloud's span can be 1e38): such spans in %g.
  if (!(std::abs(value) < 1e15)) {
    char text[32];
    std::snprintf(text, sizeof text, "%.3g", value);
    return text;
  }
  std::string digits = std::to_string(static_cast<long long>(std::llround(value)));
  for (int i = static_cast<int>(digits.size()) - 3; i > 0; i -= 3) digits.insert(static_cast<std::size_t>(i), ",");
  return digits;
}

}  // namespace

std::string unit_hint(double span, double max_extent_m) {
  // The unit that makes the span closest (in ratio) to a bay's ~10 m; a scene may be larger.
  struct Unit {
    const char* name;
    const char* option;
    double scale;
  };
  const Unit units[] = {{"centimetres", "cm", 0.01}, {"millimetres", "mm", 0.001}};
  const Unit* best = nullptr;
  for (const auto& u : units)
    if (span * u.scale <= max_extent_m &&
        (!best || std::abs(std::log10(span * u.scale / 10.0)) < std::abs(std::log10(span * best->scale / 10.0))))
      best = &u;
  std::ostringstream msg;
  msg << "coordinates span " << thousands(span) << " units, more than io.max_extent_m = " << max_extent_m << " m";
  if (!best) {
    msg << ", even read as millimetres; crop the scan to the bay";
  } else {
    msg.precision(3);
    msg << ": looks like " << best->name << " (" << span * best->scale << " m); pass --units " << best->option
        << " (io.unit_scale: " << best->scale << ")";
  }
  return msg.str();
}

void check_cloud(const Cloud& cloud, const IoConfig& io) {
  if (cloud.size() == 0) throw std::invalid_argument("cloud is empty");
  if (cloud.normals.rows() != 0 && cloud.normals.rows() != cloud.size())
    throw std::invalid_argument("cloud has " + std::to_string(cloud.normals.rows()) + " normals for " +
                                std::to_string(cloud.size()) + " points");
  for (Eigen::Index i = 0; i < cloud.size(); ++i)
    if (!cloud.xyz.row(i).allFinite()) {
      std::ostringstream msg;
      msg << "cloud point " << i << " has a non-finite coordinate (" << cloud.xyz(i, 0) << ", " << cloud.xyz(i, 1)
          << ", " << cloud.xyz(i, 2) << "); remove NaN/inf points first";
      throw std::invalid_argument(msg.str());
    }
  const Eigen::Vector3d extent = cloud.xyz.colwise().maxCoeff() - cloud.xyz.colwise().minCoeff();
  if (extent.maxCoeff() > io.max_extent_m) throw std::invalid_argument(unit_hint(extent.maxCoeff(), io.max_extent_m));
}

Cloud scale_cloud(const Cloud& cloud, double unit_scale) {
  if (!(unit_scale > 0) || !std::isfinite(unit_scale)) throw std::invalid_argument("unit_scale must be > 0");
  Cloud out = cloud;
  out.xyz *= unit_scale;
  return out;
}

Cloud select_points(const Cloud& cloud, const std::vector<Eigen::Index>& indices) {
  const bool normals = cloud.has_normals();
  Cloud out;
  out.xyz.resize(static_cast<Eigen::Index>(indices.size()), 3);
  if (normals) out.normals.resize(static_cast<Eigen::Index>(indices.size()), 3);
  for (std::size_t j = 0; j < indices.size(); ++j) {
    out.xyz.row(static_cast<Eigen::Index>(j)) = cloud.xyz.row(indices[j]);
    if (normals) out.normals.row(static_cast<Eigen::Index>(j)) = cloud.normals.row(indices[j]);
  }
  return out;
}

Cloud crop_box(const Cloud& cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m) {
  std::vector<Eigen::Index> keep;
  keep.reserve(cloud.size());
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d p = cloud.xyz.row(i).transpose();
    if ((p.array() >= min_m.array()).all() && (p.array() <= max_m.array()).all()) keep.push_back(i);
  }
  return select_points(cloud, keep);
}

Cloud voxel_downsample(const Cloud& cloud, double voxel_size_m) {
  if (!(voxel_size_m > 0)) throw std::invalid_argument("voxel_size_m must be > 0");
  const Eigen::Vector3d extent = cloud.xyz.colwise().maxCoeff() - cloud.xyz.colwise().minCoeff();
  const double cells = ((extent / voxel_size_m).array() + 1.0).prod();
  if (cells > 9.0e18) throw std::invalid_argument("voxel_size_m is too small for the cloud extent");
  auto pc = to_pcl(cloud);
  pcl::VoxelGrid<pcl::PointXYZ> grid;
  grid.setInputCloud(pc);
  grid.setLeafSize(voxel_size_m, voxel_size_m, voxel_size_m);
  pcl::PointCloud<pcl::PointXYZ> out;
  grid.filter(out);
  return from_pcl(out);
}

Cloud remove_statistical_outliers(const Cloud& cloud, int neighbors, double std_ratio) {
  if (neighbors < 1) throw std::invalid_argument("outlier neighbors must be >= 1");
  if (cloud.size() <= neighbors) return cloud;
  auto pc = to_pcl(cloud);
  pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
  sor.setInputCloud(pc);
  sor.setMeanK(neighbors);
  sor.setStddevMulThresh(std_ratio);
  pcl::PointCloud<pcl::PointXYZ> out;
  sor.filter(out);
  return from_pcl(out);
}

Cloud preprocess(const Cloud& cloud, const PreprocessConfig& config) {
  Cloud out = cloud;
  out.normals.resize(0, 3);
  if (config.crop_enabled) out = crop_box(out, config.crop_min_m, config.crop_max_m);
  if (out.size() == 0) throw std::invalid_argument("preprocess: the crop box removed every point");
  if (config.voxel_size_m > 0) out = voxel_downsample(out, config.voxel_size_m);
  if (config.outlier_neighbors > 0)
    out = remove_statistical_outliers(out, config.outlier_neighbors, config.outlier_std_ratio);
  if (out.size() == 0) throw std::invalid_argument("preprocess: no points left after filtering");
  return out;
}

void orient_normals_toward_axis(Cloud& cloud, const TunnelAxis& axis) {
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    Eigen::Vector3d n = cloud.normals.row(i).transpose();
    const Eigen::Vector3d q = cloud.xyz.row(i).transpose() - axis.origin_m;
    const Eigen::Vector3d to_axis = -(q - q.dot(axis.ex) * axis.ex);  // from the point to the axis
    if (!n.allFinite() || n.norm() < 0.5) n = to_axis.normalized();   // degenerate neighbourhood
    if (n.dot(to_axis) < 0) n = -n;
    cloud.normals.row(i) = n.normalized().transpose();
  }
}

Cloud estimate_normals(const Cloud& cloud, int k_neighbors, const TunnelAxis& axis) {
  if (k_neighbors < 3) throw std::invalid_argument("normals: k_neighbors must be >= 3");
  if (cloud.size() <= k_neighbors)
    throw std::invalid_argument("normals: need more than k = " + std::to_string(k_neighbors) + " points, got " +
                                std::to_string(cloud.size()));
  auto pc = to_pcl(cloud);
  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> ne;
  ne.setInputCloud(pc);
  ne.setSearchMethod(std::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  ne.setKSearch(k_neighbors);
  pcl::PointCloud<pcl::Normal> normals;
  ne.compute(normals);
  Cloud out;
  out.xyz = cloud.xyz;
  out.normals.resize(cloud.size(), 3);
  for (Eigen::Index i = 0; i < cloud.size(); ++i)
    out.normals.row(i) << normals[i].normal_x, normals[i].normal_y, normals[i].normal_z;
  orient_normals_toward_axis(out, axis);
  return out;
}

}  // namespace shotcrete
