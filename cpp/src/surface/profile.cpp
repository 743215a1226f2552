#include "shotcrete/surface/profile.hpp"

#include "shotcrete/surface/preprocess.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>
#include <stdexcept>

namespace shotcrete {

TunnelAxis TunnelAxis::from_direction(const Eigen::Vector3d& origin_m, const Eigen::Vector3d& direction) {
  if (!origin_m.allFinite() || !direction.allFinite() || direction.norm() < 1e-12)
    throw std::invalid_argument("tunnel axis: origin and direction must be finite and the direction non-zero");
  TunnelAxis a;
  a.origin_m = origin_m;
  a.ex = direction.normalized();
  Eigen::Vector3d up(0, 0, 1);
  if (std::abs(a.ex.dot(up)) > 0.99)
    throw std::invalid_argument("tunnel axis: direction is (nearly) vertical; a tunnel axis must be mostly horizontal");
  a.ey = up.cross(a.ex).normalized();
  a.ez = a.ex.cross(a.ey);
  return a;
}

Eigen::Vector3d TunnelAxis::to_cylindrical(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d q = p - origin_m;
  const double y = q.dot(ey), z = q.dot(ez);
  double theta = std::atan2(z, y);
  if (theta < -0.5 * M_PI) theta += 2.0 * M_PI;  // cut at the invert, so a wall arch never wraps
  return {std::hypot(y, z), theta, q.dot(ex)};
}

Eigen::Vector3d TunnelAxis::to_cartesian(double r_m, double theta_rad, double d_m) const {
  return origin_m + d_m * ex + r_m * radial(theta_rad);
}

Eigen::Vector3d TunnelAxis::radial(double theta_rad) const {
  return std::cos(theta_rad) * ey + std::sin(theta_rad) * ez;
}

TunnelAxis axis_from_config(const ProfileConfig& config) {
  return TunnelAxis::from_direction(config.axis_origin_m, config.axis_direction);
}

namespace {

std::string fmt(double v, int decimals) {
  std::ostringstream o;
  o << std::fixed << std::setprecision(decimals) << v;
  return o.str();
}

/// Axis direction from the normals: the eigenvector of N^T N with the smallest eigenvalue (wall
/// normals of a cylinder are perpendicular to its axis), refitted twice without the normals tilted
/// most along it (pit flanks, edges), which otherwise bias it by a degree or two.
Eigen::Vector3d direction_from_normals(const Points& normals) {
  const Eigen::Index n = normals.rows();
  std::vector<char> keep(static_cast<std::size_t>(n), 1);
  Eigen::Vector3d dir = Eigen::Vector3d::UnitX();
  for (int pass = 0; pass < 3; ++pass) {
    Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
    for (Eigen::Index i = 0; i < n; ++i)
      if (keep[static_cast<std::size_t>(i)]) scatter += normals.row(i).transpose() * normals.row(i);
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter);
    dir = eig.eigenvectors().col(0);
    if (pass == 0 && eig.eigenvalues()(1) / std::max(eig.eigenvalues()(2), 1e-12) < 1e-3)
      throw std::invalid_argument(
          "axis fit: the normals are (nearly) parallel; the cloud looks like a plane, not a tunnel wall");
    std::vector<double> tilt(static_cast<std::size_t>(n));
    for (Eigen::Index i = 0; i < n; ++i) tilt[static_cast<std::size_t>(i)] = std::abs(normals.row(i).dot(dir));
    std::vector<double> sorted = tilt;
    std::nth_element(sorted.begin(), sorted.begin() + n / 2, sorted.end());
    const double limit = std::max(2.5 * 1.4826 * sorted[static_cast<std::size_t>(n / 2)], 1e-3);
    for (Eigen::Index i = 0; i < n; ++i) keep[static_cast<std::size_t>(i)] = tilt[static_cast<std::size_t>(i)] < limit;
  }
  return dir;
}

/// Quantile cylinder fit by iteratively reweighted Gauss-Newton: the cylinder with a fraction tau
/// of the points inside it. Dig pits only ever add over-break, so the lower envelope follows the
/// intact contour, which is concentric with the design line; a least-squares fit follows the pits
/// instead (TD 40 mm low on the synthetic bay). Small-angle parameters, re-framed every step:
/// centre line origin + x ex + (cu + a x) ey + (cv + b x) ez; (cu, cv) only when fit_origin.
void quantile_cylinder(const Points& pts, bool fit_origin, double tau, Eigen::Vector3d& origin, Eigen::Vector3d& ex,
                       double& radius) {
  const int np = fit_origin ? 5 : 3;
  const double eps_m = 1e-3;  // residuals below 1 mm weigh as 1 mm (IRLS for the L1-type loss)
  Eigen::VectorXd J(np);
  for (int it = 0; it < 100; ++it) {
    const TunnelAxis f = TunnelAxis::from_direction(origin, ex);
    Eigen::MatrixXd JtJ = Eigen::MatrixXd::Zero(np, np);
    Eigen::VectorXd Jtr = Eigen::VectorXd::Zero(np);
    for (Eigen::Index i = 0; i < pts.rows(); ++i) {
      const Eigen::Vector3d q = pts.row(i).transpose() - origin;
      const double x = q.dot(f.ex), u = q.dot(f.ey), v = q.dot(f.ez), r = std::max(std::hypot(u, v), 1e-12);
      const double res = r - radius;
      const double w = (res > 0 ? tau : 1.0 - tau) / std::max(std::abs(res), eps_m);
      const double gu = -u / r, gv = -v / r;
      if (fit_origin) J << gu * x, gv * x, -1.0, gu, gv;
      else J << gu * x, gv * x, -1.0;
      JtJ.noalias() += w * J * J.transpose();
      Jtr.noalias() += w * res * J;
    }
    const Eigen::VectorXd step = JtJ.ldlt().solve(-Jtr);
    if (!step.allFinite()) throw std::invalid_argument("axis fit: no cylinder fits the cloud");
    ex = (f.ex + step[0] * f.ey + step[1] * f.ez).normalized();
    radius += step[2];
    if (fit_origin) origin += step[3] * f.ey + step[4] * f.ez;
    if (step.cwiseAbs().maxCoeff() < 1e-9) break;
  }
}

/// Means of the points in 7.5 cm x 7.5 cm patches of the wall around `axis` (patches with >= 3 points).
Points patch_means(const Points& pts, const TunnelAxis& axis, double radius_m) {
  constexpr double kPatch_m = 0.075;
  std::map<std::int64_t, std::pair<Eigen::Vector3d, int>> sums;  // ordered: sums independent of hashing
  for (Eigen::Index i = 0; i < pts.rows(); ++i) {
    const Eigen::Vector3d c = axis.to_cylindrical(pts.row(i).transpose());
    const auto row = static_cast<std::int64_t>(std::floor(c[1] * radius_m / kPatch_m));
    const auto col = static_cast<std::int64_t>(std::floor(c[2] / kPatch_m));
    auto& e = sums.try_emplace(row * 4000037 + col, Eigen::Vector3d::Zero(), 0).first->second;
    e.first += pts.row(i).transpose();
    e.second += 1;
  }
  Points out(static_cast<Eigen::Index>(sums.size()), 3);
  Eigen::Index k = 0;
  for (const auto& kv : sums)
    if (kv.second.second >= 3) out.row(k++) = (kv.second.first / kv.second.second).transpose();
  out.conservativeResize(k, 3);
  return out;
}

/// Indices of the points that can be wall around the axis along `dir`: a scene (floor, face,
/// lining's end) holds more than the wall, and a cylinder fitted to it all is wrong. Each point
/// whose normal lies across the axis votes for the centre one design radius along its normal; the
/// densest 10 cm bin of votes is the centre, and the wall is the points within max_deviation_m of
/// the design radius around it whose normals point at it within kWallNormalTilt_rad.
std::vector<Eigen::Index> wall_candidates(const Cloud& cloud, const Eigen::Vector3d& dir, const ProfileConfig& profile) {
  constexpr double kBin_m = 0.1, kWallNormalTilt_rad = 1.0472;
  const TunnelAxis f = TunnelAxis::from_direction(Eigen::Vector3d::Zero(), dir);
  const double R = profile.design_radius_m;
  std::map<std::pair<std::int64_t, std::int64_t>, int> votes;
  std::vector<Eigen::Vector2d> centre(static_cast<std::size_t>(cloud.size()), Eigen::Vector2d::Constant(NAN));
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d p = cloud.xyz.row(i).transpose(), n = cloud.normals.row(i).transpose();
    const Eigen::Vector2d n2(n.dot(f.ey), n.dot(f.ez));
    if (n2.norm() < 0.5) continue;  // the face: normal along the axis
    const Eigen::Vector2d c = Eigen::Vector2d(p.dot(f.ey), p.dot(f.ez)) + R * n2.normalized();
    centre[static_cast<std::size_t>(i)] = c;
    ++votes[{static_cast<std::int64_t>(std::floor(c.x() / kBin_m)), static_cast<std::int64_t>(std::floor(c.y() / kBin_m))}];
  }
  std::vector<Eigen::Index> out;
  if (votes.empty()) return out;
  const auto best = std::max_element(votes.begin(), votes.end(), [](const auto& a, const auto& b) { return a.second < b.second; });
  const Eigen::Vector2d bin_c((best->first.first + 0.5) * kBin_m, (best->first.second + 0.5) * kBin_m);
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  int count = 0;
  for (const auto& c : centre)
    if (c.allFinite() && (c - bin_c).norm() < 3 * kBin_m) sum += c, ++count;
  const Eigen::Vector2d c0 = sum / std::max(count, 1);
  const double cos_tilt = std::cos(kWallNormalTilt_rad);
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d p = cloud.xyz.row(i).transpose(), n = cloud.normals.row(i).transpose();
    const Eigen::Vector2d q = Eigen::Vector2d(p.dot(f.ey), p.dot(f.ez)) - c0;
    const double r = q.norm();
    if (r < 1e-9 || std::abs(r - R) > profile.max_deviation_m) continue;
    const Eigen::Vector3d radial = (q.x() * f.ey + q.y() * f.ez) / r;
    if (std::abs(n.dot(radial)) >= cos_tilt * std::max(n.norm(), 1e-12)) out.push_back(i);
  }
  return out;
}

AxisFit fit_cylinder(const Cloud& cloud, const ProfileConfig& profile) {
  const Eigen::Index n = cloud.size();
  if (n < kMinAxisFitPoints)
    throw std::invalid_argument("axis fit: need at least " + std::to_string(kMinAxisFitPoints) + " points, got " +
                                std::to_string(n));
  if (!cloud.has_normals()) throw std::invalid_argument("axis fit: the cloud needs normals");
  const bool fit_origin = profile.estimate_axis_origin;
  Eigen::Vector3d dir = direction_from_normals(cloud.normals);
  if (dir.dot(profile.axis_direction) < 0) dir = -dir;
  const TunnelAxis start = TunnelAxis::from_direction(Eigen::Vector3d::Zero(), dir);

  // Work relative to the centroid (or the given origin): well conditioned, and p stays small.
  const Eigen::Vector3d centroid = cloud.xyz.colwise().mean().transpose();
  Eigen::Vector3d origin = fit_origin ? centroid : Eigen::Vector3d(profile.axis_origin_m);
  if (fit_origin) {  // Kasa algebraic circle across the start direction: the centre to start from
    Eigen::MatrixXd A(n, 3);
    Eigen::VectorXd b(n);
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Vector3d q = cloud.xyz.row(i).transpose() - centroid;
      const double u = q.dot(start.ey), v = q.dot(start.ez);
      A.row(i) << u, v, 1.0;
      b[i] = u * u + v * v;
    }
    const Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
    if (c.allFinite()) origin = centroid + 0.5 * c[0] * start.ey + 0.5 * c[1] * start.ez;
  }

  Eigen::Vector3d ex = dir;
  double radius = 0.0;
  {
    const TunnelAxis f = TunnelAxis::from_direction(origin, ex);
    for (Eigen::Index i = 0; i < n; ++i) radius += f.to_cylindrical(cloud.xyz.row(i).transpose())[0];
    radius /= static_cast<double>(n);
  }
  quantile_cylinder(cloud.xyz, fit_origin, kAxisFitQuantile, origin, ex, radius);
  // Again on the means of 7.5 cm patches: the scanner noise averages out, so the envelope is the
  // contour's, not that of the noise's extremes (which biases the centre by a few mm).
  const Points patches = patch_means(cloud.xyz, TunnelAxis::from_direction(origin, ex), radius);
  if (patches.rows() >= 50) quantile_cylinder(patches, fit_origin, kAxisFitPatchQuantile, origin, ex, radius);
  if (!ex.allFinite() || !origin.allFinite() || !std::isfinite(radius))
    throw std::invalid_argument("axis fit: no cylinder fits the cloud");
  if (fit_origin) {  // on the axis where the scan starts (its 0.5 % quantile along the axis, not one
                     // stray point): the grid's columns begin at the scan's edge
    std::vector<double> d(static_cast<std::size_t>(n));
    for (Eigen::Index i = 0; i < n; ++i) d[static_cast<std::size_t>(i)] = (cloud.xyz.row(i).transpose() - origin).dot(ex);
    const auto k = static_cast<std::ptrdiff_t>(0.005 * static_cast<double>(n));
    std::nth_element(d.begin(), d.begin() + k, d.end());
    origin += d[static_cast<std::size_t>(k)] * ex;
  }

  AxisFit fit;
  fit.axis = TunnelAxis::from_direction(origin, ex);
  fit.points = static_cast<long>(n);
  fit.origin_fitted = fit_origin;
  constexpr int kBins = 720;  // half-degree bins for the arc covered
  std::vector<char> occupied(kBins, 0);
  Eigen::VectorXd r(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d c = fit.axis.to_cylindrical(cloud.xyz.row(i).transpose());
    r[i] = c[0];
    const int bin = static_cast<int>(std::floor((c[1] + 0.5 * M_PI) / (2.0 * M_PI) * kBins));
    occupied[static_cast<std::size_t>(std::clamp(bin, 0, kBins - 1))] = 1;
  }
  fit.radius_m = r.mean();
  fit.rms_m = std::sqrt((r.array() - fit.radius_m).square().mean());
  int gap = 0, run = 0;  // longest circular run of empty bins
  for (int k = 0; k < 2 * kBins; ++k) {
    run = occupied[static_cast<std::size_t>(k % kBins)] ? 0 : run + 1;
    gap = std::max(gap, std::min(run, kBins));
  }
  fit.arc_rad = 2.0 * M_PI * (kBins - gap) / kBins;

  const double R = profile.design_radius_m;
  if (!(std::abs(fit.radius_m - R) <= profile.max_deviation_m))
    throw std::invalid_argument("axis fit: the fitted radius " + fmt(fit.radius_m, 2) + " m is more than profile.max_deviation_m = " +
                                fmt(profile.max_deviation_m, 2) + " m from the design radius " + fmt(R, 2) +
                                " m; the cloud is not this tunnel's wall (a plane fits as a huge radius)");
  if (fit.arc_rad < profile.min_fit_arc_rad)
    throw std::invalid_argument("axis fit: the wall covers " + fmt(fit.arc_rad * 180.0 / M_PI, 1) +
                                " deg around the fitted axis, less than profile.min_fit_arc_rad = " +
                                fmt(profile.min_fit_arc_rad * 180.0 / M_PI, 1) + " deg; give the axis instead (profile.axis_origin_m, axis_direction)");
  if (fit.rms_m > kMaxAxisFitRmsFraction * fit.radius_m)
    throw std::invalid_argument("axis fit: RMS " + fmt(fit.rms_m * 1000.0, 0) + " mm of the points about the fitted cylinder exceeds " +
                                fmt(kMaxAxisFitRmsFraction * 100.0, 0) + " % of its radius " + fmt(fit.radius_m, 2) +
                                " m; the cloud is not a tunnel wall");
  return fit;
}

}  // namespace

AxisFit fit_axis(const Cloud& cloud, const ProfileConfig& profile) {
  if (cloud.size() < kMinAxisFitPoints)
    throw std::invalid_argument("axis fit: need at least " + std::to_string(kMinAxisFitPoints) + " points, got " +
                                std::to_string(cloud.size()));
  if (!cloud.has_normals()) throw std::invalid_argument("axis fit: the cloud needs normals");
  try {
    return fit_cylinder(cloud, profile);
  } catch (const std::invalid_argument& whole_cloud) {
    // A scene (floor, face) around the wall: fit the points that can be wall, and when that does
    // not fit either, the whole cloud's reason stands.
    const std::vector<Eigen::Index> wall = wall_candidates(cloud, direction_from_normals(cloud.normals), profile);
    if (static_cast<long>(wall.size()) < kMinAxisFitPoints || wall.size() == static_cast<std::size_t>(cloud.size())) throw;
    try {
      return fit_cylinder(select_points(cloud, wall), profile);
    } catch (const std::invalid_argument&) {
      throw whole_cloud;
    }
  }
}

}  // namespace shotcrete
