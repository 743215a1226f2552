// Registration of the after-scan on the reference areas (docs/architecture.md §12).
#include <pcl/filters/random_sample.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/search/kdtree.h>

#include <Eigen/Eigenvalues>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <unordered_set>

#include "shotcrete/rescan/rescan.hpp"
#include "gicp_parts.hpp"

namespace shotcrete {

namespace detail {

namespace {

// The covariance of the points of `cloud` at nn[0, k), about their mean (centred: no cancellation).
Eigen::Matrix3d neighbour_covariance(const PclCloud& cloud, const std::vector<int>& nn, int k, Eigen::Vector3d* mean_out = nullptr) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int j = 0; j < k; ++j) mean += cloud[static_cast<size_t>(nn[static_cast<size_t>(j)])].getVector3fMap().cast<double>();
  mean /= static_cast<double>(k);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (int j = 0; j < k; ++j) {
    const Eigen::Vector3d v = cloud[static_cast<size_t>(nn[static_cast<size_t>(j)])].getVector3fMap().cast<double>() - mean;
    cov += v * v.transpose();
  }
  if (mean_out) *mean_out = mean;
  return cov / static_cast<double>(k);
}

}  // namespace

// PCL computes the covariances on one thread (they were a third of the fine stage), squaring the
// coordinates in float; here on every thread, in double, about the neighbours' mean.
GicpBase::MatricesVectorPtr gicp_covariances(const PclCloud& cloud, const Tree& tree, int k, double epsilon) {
  auto out = std::make_shared<GicpBase::MatricesVector>(cloud.size());
  const long n = static_cast<long>(cloud.size());
#pragma omp parallel
  {
    std::vector<int> nn(static_cast<size_t>(k));
    std::vector<float> d2(static_cast<size_t>(k));
#pragma omp for schedule(static)
    for (long i = 0; i < n; ++i) {
      const int found = tree.nearestKSearch(cloud[static_cast<size_t>(i)], k, nn, d2);
      const Eigen::JacobiSVD<Eigen::Matrix3d> svd(neighbour_covariance(cloud, nn, found), Eigen::ComputeFullU);
      const Eigen::Matrix3d& U = svd.matrixU();
      (*out)[static_cast<size_t>(i)] = U * Eigen::Vector3d(1.0, 1.0, epsilon).asDiagonal() * U.transpose();
    }
  }
  return out;
}

size_t occupied_voxels(const PclCloud& pc, double voxel_m) {
  struct Key {
    std::int64_t i, j, k;
    bool operator==(const Key& o) const { return i == o.i && j == o.j && k == o.k; }
  };
  struct Hash {
    size_t operator()(const Key& a) const {
      return static_cast<size_t>(a.i * 73856093LL ^ a.j * 19349663LL ^ a.k * 83492791LL);
    }
  };
  const float inv = 1.0f / static_cast<float>(voxel_m);
  std::unordered_set<Key, Hash> keys;
  keys.reserve(pc.size() / 4);
  const auto key = [inv](float x) { return static_cast<std::int64_t>(std::floor(x * inv)); };
  for (const auto& p : pc.points) keys.insert(Key{key(p.x), key(p.y), key(p.z)});
  return keys.size();
}

}  // namespace detail

namespace {

using detail::gicp_covariances;
using detail::occupied_voxels;
using detail::PclCloud;
using detail::Tree;

// One kd-tree per cloud, shared by the covariances, GICP and the overlap (each built its own).
Tree::Ptr make_tree(const PclCloud::Ptr& cloud) {
  auto tree = std::make_shared<Tree>();
  tree->setInputCloud(cloud);
  return tree;
}

// PCL's GICP with its iteration count readable (nr_iterations_ is protected).
class Gicp : public detail::GicpBase {
 public:
  int iterations() const { return nr_iterations_; }
  double epsilon() const { return gicp_epsilon_; }
};

constexpr int kCovarianceNeighbours = 20;  // points per GICP covariance (PCL's default)

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
  pcl::RandomSample<pcl::PointXYZ> sample;
  sample.setInputCloud(pc);
  sample.setSample(static_cast<unsigned int>(occupied_voxels(*pc, voxel_m)));
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

// The points of `cloud` (moved by T) that pass the reference test, in the cloud's order; the
// test runs on every thread (it is read-only) over a million-point scan.
std::vector<Eigen::Vector3d> reference_points(const Cloud& cloud, const Eigen::Matrix4d& T, const ReferenceTest& reference) {
  const Eigen::Index n = cloud.size();
  std::vector<char> keep(static_cast<size_t>(n), 0);
  std::exception_ptr error;  // an exception may not leave an OpenMP region: the first is rethrown after it
#pragma omp parallel for schedule(static)
  for (Eigen::Index i = 0; i < n; ++i) {
    try {
      keep[static_cast<size_t>(i)] = reference(apply(T, cloud.xyz.row(i).transpose())) ? 1 : 0;
    } catch (...) {
#pragma omp critical(shotcrete_reference_error)
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);
  std::vector<Eigen::Vector3d> out;
  for (Eigen::Index i = 0; i < n; ++i)
    if (keep[static_cast<size_t>(i)]) out.push_back(apply(T, cloud.xyz.row(i).transpose()));
  return out;
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
  const std::vector<Eigen::Vector3d> target_pts = reference_points(before, Eigen::Matrix4d::Identity(), reference);
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
  const Tree::Ptr target_tree = make_tree(target), coarse_tree = make_tree(coarse_target);
  // The share of `pts` whose nearest target point lies within `dist`, and (rms) the RMS distance
  // of those points to the plane of their 8 nearest target points: the thinned clouds' spacing
  // would dominate a point-to-point distance. Per point on every thread, summed in order.
  auto matched_share = [&](const PclCloud& pts, double dist, double* rms) {
    const long n = static_cast<long>(pts.size());
    std::vector<double> e2(static_cast<size_t>(n), -1.0);  // squared plane distance; -1: unmatched
#pragma omp parallel
    {
      std::vector<int> nn(8);
      std::vector<float> nd2(8);
#pragma omp for schedule(static)
      for (long i = 0; i < n; ++i) {
        const auto& q = pts[static_cast<size_t>(i)];
        const int k = target_tree->nearestKSearch(q, rms ? 8 : 1, nn, nd2);  // nearest first
        if (k <= 0 || nd2[0] > dist * dist) continue;
        if (!rms) {
          e2[static_cast<size_t>(i)] = 0.0;
          continue;
        }
        Eigen::Vector3d mean;
        const Eigen::Matrix3d cov = detail::neighbour_covariance(*target, nn, k, &mean);
        const Eigen::Vector3d normal = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors().col(0);
        const double e = (q.getVector3fMap().cast<double>() - mean).dot(normal);
        e2[static_cast<size_t>(i)] = e * e;
      }
    }
    long matched = 0;
    double sum2 = 0.0;
    for (const double v : e2)
      if (v >= 0.0) {
        ++matched;
        sum2 += v;
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
    const std::vector<Eigen::Vector3d> src = reference_points(after, T, reference);
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
    const Tree::Ptr source_tree = make_tree(source);
    gicp.setSearchMethodSource(source_tree, true);
    gicp.setSearchMethodTarget(coarse ? coarse_tree : target_tree, true);
    gicp.setSourceCovariances(gicp_covariances(*source, *source_tree, kCovarianceNeighbours, gicp.epsilon()));
    gicp.setTargetCovariances(
        gicp_covariances(coarse ? *coarse_target : *target, coarse ? *coarse_tree : *target_tree, kCovarianceNeighbours, gicp.epsilon()));
    gicp.setMaxCorrespondenceDistance(dist);
    gicp.setMaximumIterations(c.max_iterations);
    gicp.setTransformationEpsilon(1e-6);  // m: stop when the translation changes by less
    gicp.setRotationEpsilon(1e-7);        // rotation matrix entries
    gicp.setCorrespondenceRandomness(kCovarianceNeighbours);
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
