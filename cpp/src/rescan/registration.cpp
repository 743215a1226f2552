// Registration of the after-scan on the reference areas (docs/architecture.md §12).
#include <pcl/filters/random_sample.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>

#include <Eigen/Eigenvalues>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "shotcrete/rescan/rescan.hpp"

namespace shotcrete {

namespace {

using PclCloud = pcl::PointCloud<pcl::PointXYZ>;

// PCL's GICP with its iteration count readable (nr_iterations_ is protected).
class Gicp : public pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> {
 public:
  int iterations() const { return nr_iterations_; }
};

// Points (already in the before frame) shifted by -centre into float (float keeps 0.1 mm within a
// few hundred metres of the centre, so survey coordinates never reach PCL), then thinned to as
// many points as voxel_m would leave, drawn at random: voxel centroids depend on where the voxel
// edges cut a surface, which moved the pose by ~3 mm along the axis (the face straddling them).
PclCloud::Ptr to_pcl_voxel(const std::vector<Eigen::Vector3d>& pts, const Eigen::Vector3d& centre, double voxel_m) {
  PclCloud::Ptr pc(new PclCloud);
  pc->reserve(pts.size());
  for (const auto& p : pts) {
    const Eigen::Vector3f q = (p - centre).cast<float>();
    pc->push_back(pcl::PointXYZ(q.x(), q.y(), q.z()));
  }
  if (!(voxel_m > 0) || pc->empty()) return pc;
  pcl::VoxelGrid<pcl::PointXYZ> grid;
  grid.setInputCloud(pc);
  grid.setLeafSize(static_cast<float>(voxel_m), static_cast<float>(voxel_m), static_cast<float>(voxel_m));
  PclCloud voxels;
  grid.filter(voxels);
  pcl::RandomSample<pcl::PointXYZ> sample;
  sample.setInputCloud(pc);
  sample.setSample(static_cast<unsigned int>(voxels.size()));
  sample.setSeed(1);
  PclCloud::Ptr out(new PclCloud);
  sample.filter(*out);
  return out;
}

std::string pct(double x) {
  std::ostringstream s;
  s.precision(3);
  s << 100.0 * x << " %";
  return s.str();
}

Eigen::Vector3d apply(const Eigen::Matrix4d& T, const Eigen::Vector3d& p) {
  return T.topLeftCorner<3, 3>() * p + T.topRightCorner<3, 1>();
}

}  // namespace

Cloud transform_cloud(const Cloud& cloud, const Eigen::Matrix4d& T) {
  Cloud out = cloud;
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const Eigen::RowVector3d t = T.topRightCorner<3, 1>().transpose();
  out.xyz = (cloud.xyz * R.transpose()).rowwise() + t;
  if (cloud.has_normals()) out.normals = cloud.normals * R.transpose();
  return out;
}

ReferenceTest box_reference(const RescanConfig& c) {
  const Eigen::Vector3d lo = c.reference_box_min_m, hi = c.reference_box_max_m;
  if (!(lo.array() < hi.array()).all())
    throw std::invalid_argument("rescan.reference_box_min_m must be below reference_box_max_m on every axis");
  return [lo, hi](const Eigen::Vector3d& p) { return (p.array() >= lo.array()).all() && (p.array() <= hi.array()).all(); };
}

ReferenceTest mask_reference(const Cloud& mask, const RescanConfig& c) {
  if (mask.size() == 0) throw std::invalid_argument("rescan: the reference mask cloud is empty");
  if (!mask.xyz.allFinite()) throw std::invalid_argument("rescan: the reference mask cloud has NaN or infinite coordinates");
  const Eigen::Vector3d centre = mask.xyz.colwise().mean().transpose();
  std::vector<Eigen::Vector3d> pts(static_cast<size_t>(mask.size()));
  for (Eigen::Index i = 0; i < mask.size(); ++i) pts[static_cast<size_t>(i)] = mask.xyz.row(i).transpose();
  auto pc = to_pcl_voxel(pts, centre, 0.0);
  auto tree = std::make_shared<pcl::KdTreeFLANN<pcl::PointXYZ>>();
  tree->setInputCloud(pc);
  const float r2 = static_cast<float>(c.mask_radius_m * c.mask_radius_m);
  return [tree, centre, r2](const Eigen::Vector3d& p) {
    const Eigen::Vector3f q = (p - centre).cast<float>();
    std::vector<int> idx(1);
    std::vector<float> d2(1);
    return tree->nearestKSearch(pcl::PointXYZ(q.x(), q.y(), q.z()), 1, idx, d2) > 0 && d2[0] <= r2;
  };
}

ReferenceTest dry_reference(const Grid& grid, const Eigen::VectorXd& predicted_deposit_m, const RescanConfig& c,
                            double max_deviation_m) {
  if (predicted_deposit_m.size() != grid.size())
    throw std::invalid_argument("rescan: " + std::to_string(predicted_deposit_m.size()) +
                                " predicted deposits for a grid of " + std::to_string(grid.size()) + " cells");
  // The sprayed cells grown by the margin, on a lattice extended by the margin on every side.
  const int m = static_cast<int>(std::ceil(c.reference_margin_m / grid.cell_size_m));
  const int nt = grid.n_theta + 2 * m, nd = grid.n_d + 2 * m;
  std::vector<char> wet(static_cast<size_t>(nt) * static_cast<size_t>(nd), 0);
  for (int cell = 0; cell < grid.size(); ++cell) {
    const double p = predicted_deposit_m[cell];
    const bool sprayed = grid.valid[static_cast<size_t>(cell)] && !(p < c.dry_threshold_m);  // NaN: sprayed
    if (!sprayed) continue;
    const int row = grid.row_of(cell) + m, col = grid.col_of(cell) + m;
    for (int i = row - m; i <= row + m; ++i)
      for (int j = col - m; j <= col + m; ++j)
        if ((i - row) * (i - row) + (j - col) * (j - col) <= m * m) wet[static_cast<size_t>(i) * nd + j] = 1;
  }
  const Grid g = grid;  // copied: the test outlives the caller's grid
  return [g, wet = std::move(wet), m, nt, nd, max_deviation_m](const Eigen::Vector3d& p) {
    const Eigen::Vector3d cyl = g.axis.to_cylindrical(p);
    if (!(std::abs(g.profile.td_m(cyl.x(), cyl.y())) <= max_deviation_m)) return true;  // off the wall band
    const int row = static_cast<int>(std::floor((cyl.y() - g.theta0_rad) / g.dtheta_rad)) + m;
    const int col = static_cast<int>(std::floor((cyl.z() - g.d0_m) / g.cell_size_m)) + m;
    if (row < 0 || row >= nt || col < 0 || col >= nd) return true;
    return wet[static_cast<size_t>(row) * nd + col] == 0;
  };
}

Registration register_scans(const Cloud& before, const Cloud& after, const ReferenceTest& reference,
                            const RescanConfig& c, const Eigen::Matrix4d& initial) {
  const auto t0 = std::chrono::steady_clock::now();
  for (const Cloud* cl : {&before, &after}) {
    if (cl->size() == 0) throw std::invalid_argument(std::string("rescan: the ") + (cl == &before ? "before" : "after") + "-scan is empty");
    if (!cl->xyz.allFinite())
      throw std::invalid_argument(std::string("rescan: the ") + (cl == &before ? "before" : "after") +
                                  "-scan has NaN or infinite coordinates");
  }
  if (!initial.allFinite()) throw std::invalid_argument("rescan: the initial pose is not finite");
  std::vector<Eigen::Vector3d> target_pts;
  for (Eigen::Index i = 0; i < before.size(); ++i) {
    const Eigen::Vector3d p = before.xyz.row(i).transpose();
    if (reference(p)) target_pts.push_back(p);
  }
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const auto& p : target_pts) centre += p;
  if (!target_pts.empty()) centre /= static_cast<double>(target_pts.size());
  auto target = to_pcl_voxel(target_pts, centre, c.voxel_size_m);
  // The coarse stage on half as dense clouds (twice the voxel edge): it moves the pose most of the
  // way in fewer, cheaper iterations; the fine stage refines on the full thinning.
  auto coarse_target = to_pcl_voxel(target_pts, centre, 2.0 * c.voxel_size_m);
  if (static_cast<long>(target->size()) < c.min_reference_points)
    throw std::invalid_argument("rescan: no reference area: " + std::to_string(target->size()) +
                                " before-scan reference points after voxelling, fewer than rescan.min_reference_points " +
                                std::to_string(c.min_reference_points) + " (rescan.reference " +
                                enum_name(c.reference) + ")");
  Registration out;
  out.target_points = static_cast<long>(target->size());
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(target);
  std::vector<int> idx(1);
  std::vector<float> d2(1);
  // The share of `pts` whose nearest target point lies within `dist`, and (rms) the RMS distance
  // of those points to the plane of their 8 nearest target points: the thinned clouds' spacing
  // would dominate a point-to-point distance.
  auto matched_share = [&](const PclCloud& pts, double dist, double* rms) {
    long matched = 0;
    double sum2 = 0.0;
    std::vector<int> nn(8);
    std::vector<float> nd2(8);
    for (const auto& q : pts.points) {
      if (tree.nearestKSearch(q, 1, idx, d2) <= 0 || d2[0] > dist * dist) continue;
      ++matched;
      if (!rms) continue;
      const int k = tree.nearestKSearch(q, 8, nn, nd2);
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (int j = 0; j < k; ++j) mean += target->points[static_cast<size_t>(nn[j])].getVector3fMap().cast<double>();
      mean /= k;
      Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
      for (int j = 0; j < k; ++j) {
        const Eigen::Vector3d v = target->points[static_cast<size_t>(nn[j])].getVector3fMap().cast<double>() - mean;
        cov += v * v.transpose();
      }
      const Eigen::Vector3d normal = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors().col(0);
      const double e = (q.getVector3fMap().cast<double>() - mean).dot(normal);
      sum2 += e * e;
    }
    if (rms) *rms = matched ? std::sqrt(sum2 / static_cast<double>(matched)) : std::numeric_limits<double>::quiet_NaN();
    return pts.empty() ? 0.0 : static_cast<double>(matched) / static_cast<double>(pts.size());
  };
  Eigen::Matrix4d T = initial;
  PclCloud::Ptr source;
  Eigen::Matrix4d S = Eigen::Matrix4d::Identity(), Sinv = Eigen::Matrix4d::Identity();  // centring
  S.topRightCorner<3, 1>() = centre;
  Sinv.topRightCorner<3, 1>() = -centre;
  for (const bool coarse : {true, false}) {
    const double dist = coarse ? c.coarse_correspondence_m : c.fine_correspondence_m;
    std::vector<Eigen::Vector3d> src;
    for (Eigen::Index i = 0; i < after.size(); ++i) {
      const Eigen::Vector3d p = apply(T, after.xyz.row(i).transpose());
      if (reference(p)) src.push_back(p);
    }
    source = to_pcl_voxel(src, centre, coarse ? 2.0 * c.voxel_size_m : c.voxel_size_m);
    if (static_cast<long>(source->size()) < c.min_reference_points)
      throw std::invalid_argument("rescan: no reference area in the after-scan: " + std::to_string(source->size()) +
                                  " points fall in the reference areas (fewer than rescan.min_reference_points " +
                                  std::to_string(c.min_reference_points) + "): another bay, or a wrong initial pose");
    if (coarse) {
      const double start = matched_share(*source, dist, nullptr);
      if (start < c.min_overlap)
        throw std::runtime_error("rescan: at the start pose only " + pct(start) + " of the after-scan's reference points lie within "
                                 "rescan.coarse_correspondence_m of the before-scan's (below rescan.min_overlap " +
                                 pct(c.min_overlap) + "): another bay, or give the initial pose");
    }
    Gicp gicp;
    gicp.setInputSource(source);
    gicp.setInputTarget(coarse ? coarse_target : target);
    gicp.setMaxCorrespondenceDistance(dist);
    gicp.setMaximumIterations(c.max_iterations);
    gicp.setTransformationEpsilon(1e-6);  // m: stop when the translation changes by less
    gicp.setRotationEpsilon(1e-7);        // rotation matrix entries
    gicp.setCorrespondenceRandomness(20);
    PclCloud aligned;
    gicp.align(aligned);
    out.iterations += gicp.iterations();
    if (!gicp.hasConverged() || gicp.iterations() >= c.max_iterations)
      throw std::runtime_error("rescan: registration did not converge in rescan.max_iterations " +
                               std::to_string(c.max_iterations) + " GICP iterations (correspondence distance " +
                               std::to_string(dist) + " m)");
    const Eigen::Matrix4d dT = gicp.getFinalTransformation().cast<double>();
    if (!dT.allFinite()) throw std::runtime_error("rescan: registration diverged (non-finite transform)");
    T = S * dT * Sinv * T;
    pcl::transformPointCloud(*source, *source, gicp.getFinalTransformation());
  }
  // Overlap and RMS of the final source against the target.
  out.source_points = static_cast<long>(source->size());
  out.overlap = matched_share(*source, c.fine_correspondence_m, &out.rms_m);
  out.transform = T;
  out.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (out.overlap < c.min_overlap)
    throw std::runtime_error("rescan: registration overlap " + pct(out.overlap) + " is below rescan.min_overlap " +
                             pct(c.min_overlap) + " (the after-scan does not show the same reference areas)");
  return out;
}

}  // namespace shotcrete
