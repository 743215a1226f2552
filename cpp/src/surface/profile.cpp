#include "shotcrete/surface/profile.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
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

AxisFit fit_axis(const Cloud& cloud, const Eigen::Vector3d& direction_hint) {
  const Eigen::Index n = cloud.size();
  if (n < 10) throw std::invalid_argument("axis fit: need at least 10 points, got " + std::to_string(n));
  if (!cloud.has_normals()) throw std::invalid_argument("axis fit: the cloud needs normals");
  // Wall normals of a cylinder are all perpendicular to its axis: smallest eigenvector of N^T N.
  const Eigen::Matrix3d scatter = cloud.normals.transpose() * cloud.normals;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter);
  Eigen::Vector3d dir = eig.eigenvectors().col(0);
  if (dir.dot(direction_hint) < 0) dir = -dir;
  const double spread = eig.eigenvalues()(1) / std::max(eig.eigenvalues()(2), 1e-12);
  if (spread < 1e-3)
    throw std::invalid_argument("axis fit: the normals are (nearly) parallel; the cloud looks planar, not like a tunnel wall");
  TunnelAxis frame = TunnelAxis::from_direction(Eigen::Vector3d::Zero(), dir);

  // Circle fit in the (y', z') plane: Kasa algebraic fit, then Gauss-Newton on geometric distance.
  Eigen::MatrixXd A(n, 3);
  Eigen::VectorXd b(n);
  Eigen::VectorXd u(n), v(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d p = cloud.xyz.row(i).transpose();
    u[i] = p.dot(frame.ey);
    v[i] = p.dot(frame.ez);
    A(i, 0) = u[i];
    A(i, 1) = v[i];
    A(i, 2) = 1.0;
    b[i] = u[i] * u[i] + v[i] * v[i];
  }
  const Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
  double cu = c[0] / 2, cv = c[1] / 2;
  double r = std::sqrt(std::max(c[2] + cu * cu + cv * cv, 0.0));
  for (int it = 0; it < 20; ++it) {
    Eigen::MatrixXd J(n, 3);
    Eigen::VectorXd res(n);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double du = u[i] - cu, dv = v[i] - cv, di = std::max(std::hypot(du, dv), 1e-12);
      res[i] = di - r;
      J(i, 0) = -du / di;
      J(i, 1) = -dv / di;
      J(i, 2) = -1.0;
    }
    const Eigen::Vector3d step = (J.transpose() * J).ldlt().solve(-J.transpose() * res);
    cu += step[0];
    cv += step[1];
    r += step[2];
    if (step.norm() < 1e-10) break;
  }
  if (!std::isfinite(r) || r <= 0) throw std::invalid_argument("axis fit: no circle fits the cloud");
  double sq = 0;
  for (Eigen::Index i = 0; i < n; ++i) sq += std::pow(std::hypot(u[i] - cu, v[i] - cv) - r, 2);
  AxisFit fit;
  // Keep the axis origin at the projection of the cloud centroid's axial coordinate at 0.
  fit.axis = TunnelAxis::from_direction(cu * frame.ey + cv * frame.ez, dir);
  fit.radius_m = r;
  fit.rms_m = std::sqrt(sq / static_cast<double>(n));
  return fit;
}

}  // namespace shotcrete
