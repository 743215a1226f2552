#include "shotcrete/surface/profile.hpp"

#include "shotcrete/surface/preprocess.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
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

double cross2(const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return a.x() * b.y() - a.y() * b.x(); }

// theta of a section-plane point in the frame's convention: [-pi/2, 3pi/2), the cut at the invert.
double section_theta(const Eigen::Vector2d& p) {
  double t = std::atan2(p.y(), p.x());
  if (t < -0.5 * M_PI) t += 2.0 * M_PI;
  return t;
}

std::string point_str(const Eigen::Vector2d& p) {
  std::ostringstream o;
  o << std::fixed << std::setprecision(3) << "(" << p.x() << ", " << p.y() << ")";
  return o.str();
}

}  // namespace

DesignProfile DesignProfile::circle(double radius_m) {
  DesignProfile p;
  p.radius_m = radius_m;
  return p;
}

DesignProfile DesignProfile::from_section(const std::vector<SectionVertex>& vertices) {
  if (vertices.size() < 2)
    throw std::invalid_argument("design section: needs at least 2 vertices, got " + std::to_string(vertices.size()));
  for (std::size_t i = 0; i < vertices.size(); ++i)
    if (!std::isfinite(vertices[i].y_m) || !std::isfinite(vertices[i].z_m) || !std::isfinite(vertices[i].bulge))
      throw std::invalid_argument("design section: vertex " + std::to_string(i + 1) + " is not finite");
  // Arcs flattened to chords whose sagitta stays within 0.2 mm: TD on them is exact to that.
  constexpr double kMaxSagittaM = 2e-4;
  std::vector<Eigen::Vector2d> pts{{vertices[0].y_m, vertices[0].z_m}};
  for (std::size_t i = 0; i + 1 < vertices.size(); ++i) {
    const Eigen::Vector2d a(vertices[i].y_m, vertices[i].z_m), b(vertices[i + 1].y_m, vertices[i + 1].z_m);
    const double chord = (b - a).norm();
    if (chord < 1e-6) throw std::invalid_argument("design section: vertices " + std::to_string(i + 1) + " and " +
                                                  std::to_string(i + 2) + " coincide at " + point_str(a));
    const double bulge = vertices[i].bulge;
    if (bulge == 0.0) {
      pts.push_back(b);
      continue;
    }
    if (std::abs(bulge) > 1e3) throw std::invalid_argument("design section: bulge of vertex " + std::to_string(i + 1) + " out of range");
    const double angle = 4.0 * std::atan(bulge);  // included angle, signed (counter-clockwise > 0)
    const double rho = chord / (2.0 * std::sin(std::abs(angle) / 2.0));
    // Centre: from the chord's midpoint along its left normal (ccw arcs) by rho cos(angle/2).
    const Eigen::Vector2d mid = 0.5 * (a + b), dir = (b - a) / chord, left(-dir.y(), dir.x());
    const double h = rho * std::cos(std::abs(angle) / 2.0);
    const Eigen::Vector2d centre = mid + (angle > 0 ? 1.0 : -1.0) * h * left;
    const double step = 2.0 * std::acos(std::max(-1.0, 1.0 - kMaxSagittaM / rho));
    const int pieces = std::max(1, static_cast<int>(std::ceil(std::abs(angle) / step)));
    const double a0 = std::atan2(a.y() - centre.y(), a.x() - centre.x());
    for (int k = 1; k < pieces; ++k) {
      const double t = a0 + angle * k / pieces;
      pts.emplace_back(centre.x() + rho * std::cos(t), centre.y() + rho * std::sin(t));
    }
    pts.push_back(b);
  }
  std::vector<double> th(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) {
    if (pts[i].norm() < 1e-3) throw std::invalid_argument("design section: the profile passes through the axis at " + point_str(pts[i]));
    th[i] = section_theta(pts[i]);
  }
  if (th.back() < th.front()) {
    std::reverse(pts.begin(), pts.end());
    std::reverse(th.begin(), th.end());
  }
  for (std::size_t i = 0; i + 1 < pts.size(); ++i) {
    // Every ray from the axis must meet the line once: theta strictly increases along it (an edge
    // along a ray does not; the cut at the invert shows as a jump of almost 2 pi).
    const double dth = th[i + 1] - th[i];
    if (!(dth > 1e-9) || dth > M_PI)
      throw std::invalid_argument("design section: not star-shaped about the tunnel axis near " + point_str(pts[i]) +
                                  " (a ray from the axis meets it twice, or it crosses the invert below the axis); "
                                  "give the sprayed part, from one foot over the crown to the other, around the axis");
  }
  DesignProfile p;
  double length = 0.0;
  for (std::size_t i = 0; i + 1 < pts.size(); ++i) length += (pts[i + 1] - pts[i]).norm();
  p.radius_m = length / (th.back() - th.front());
  p.polyline_m = std::move(pts);
  p.vertex_theta_rad = std::move(th);
  return p;
}

double DesignProfile::theta_min_rad() const { return is_circle() ? -0.5 * M_PI : vertex_theta_rad.front(); }
double DesignProfile::theta_max_rad() const { return is_circle() ? 1.5 * M_PI : vertex_theta_rad.back(); }
bool DesignProfile::covers(double theta_rad) const {
  return is_circle() || (theta_rad >= vertex_theta_rad.front() && theta_rad <= vertex_theta_rad.back());
}

int DesignProfile::segment_at(double theta_rad) const {
  if (!std::isfinite(theta_rad)) return -1;
  const auto it = std::upper_bound(vertex_theta_rad.begin(), vertex_theta_rad.end(), theta_rad);
  const int k = static_cast<int>(it - vertex_theta_rad.begin()) - 1;
  return std::clamp(k, 0, static_cast<int>(polyline_m.size()) - 2);
}

double DesignProfile::radius_at(double theta_rad) const {
  if (is_circle()) return radius_m;
  const int k = segment_at(theta_rad);
  if (k < 0) return std::numeric_limits<double>::quiet_NaN();
  // Ray t u meets the edge p + s e where cross(p + s e - t u, ...) vanishes: t = cross(p, e) / cross(u, e).
  const Eigen::Vector2d u(std::cos(theta_rad), std::sin(theta_rad));
  const Eigen::Vector2d p = polyline_m[k], e = polyline_m[k + 1] - polyline_m[k];
  const double t = cross2(p, e) / cross2(u, e);
  return t > 0.0 && std::isfinite(t) ? t : std::numeric_limits<double>::quiet_NaN();
}

Eigen::Vector2d DesignProfile::normal_at(double theta_rad) const {
  const Eigen::Vector2d u(std::cos(theta_rad), std::sin(theta_rad));
  if (is_circle()) return u;
  const int k = segment_at(theta_rad);
  if (k < 0) return {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::quiet_NaN()};
  const Eigen::Vector2d e = (polyline_m[k + 1] - polyline_m[k]).normalized();
  Eigen::Vector2d n(e.y(), -e.x());
  return n.dot(u) < 0 ? Eigen::Vector2d(-n) : n;
}

double DesignProfile::normal_cos_at(double theta_rad) const {
  if (is_circle()) return 1.0;
  return normal_at(theta_rad).dot(Eigen::Vector2d(std::cos(theta_rad), std::sin(theta_rad)));
}

double DesignProfile::td_m(double r_m, double theta_rad) const {
  if (is_circle()) return r_m - radius_m;
  if (!covers(theta_rad)) return std::numeric_limits<double>::quiet_NaN();
  return (r_m - radius_at(theta_rad)) * normal_cos_at(theta_rad);
}

double DesignProfile::radial_offset_m(double td_m, double theta_rad) const {
  if (is_circle()) return td_m;
  return td_m / normal_cos_at(theta_rad);
}

Eigen::Vector3d design_normal(const TunnelAxis& axis, const DesignProfile& profile, double theta_rad) {
  if (profile.is_circle()) return axis.radial(theta_rad);
  const Eigen::Vector2d n = profile.normal_at(theta_rad);
  return n.x() * axis.ey + n.y() * axis.ez;
}

namespace {
// Splits a CSV data line into trimmed cells (empty for blank and '#' lines).
std::vector<std::string> csv_cells(const std::string& line) {
  std::vector<std::string> cols;
  const auto first = line.find_first_not_of(" \t\r");
  if (first == std::string::npos || line[first] == '#') return cols;
  std::stringstream ss(line);
  std::string c;
  while (std::getline(ss, c, ',')) {
    const auto b = c.find_first_not_of(" \t\r"), e = c.find_last_not_of(" \t\r");
    cols.push_back(b == std::string::npos ? std::string() : c.substr(b, e - b + 1));
  }
  return cols;
}
double csv_number(const std::string& cell, const std::string& where) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(cell, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != cell.size() || !std::isfinite(v))
    throw std::invalid_argument(where + ": '" + cell + "' is not a number");
  return v;
}
}  // namespace

std::vector<SectionVertex> read_section_csv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("design section: cannot open " + path);
  std::vector<SectionVertex> out;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const std::vector<std::string> cols = csv_cells(line);
    if (cols.empty() || (out.empty() && cols[0] == "y_m")) continue;  // blank, comment, header
    const std::string where = "design section " + path + ", line " + std::to_string(number);
    if (cols.size() < 2 || cols.size() > 3) throw std::invalid_argument(where + ": expected y_m,z_m[,bulge]");
    out.push_back({csv_number(cols[0], where), csv_number(cols[1], where), cols.size() == 3 ? csv_number(cols[2], where) : 0.0});
  }
  if (out.empty()) throw std::invalid_argument("design section " + path + ": no vertices");
  return out;
}


std::vector<AlignmentPoint> read_alignment_csv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("alignment: cannot open " + path);
  std::vector<AlignmentPoint> out;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const std::vector<std::string> cols = csv_cells(line);
    if (cols.empty() || (out.empty() && cols[0] == "chainage_m")) continue;
    const std::string where = "alignment " + path + ", line " + std::to_string(number);
    if (cols.size() != 4) throw std::invalid_argument(where + ": expected chainage_m,x_m,y_m,z_m");
    AlignmentPoint p;
    p.chainage_m = csv_number(cols[0], where);
    p.xyz_m = {csv_number(cols[1], where), csv_number(cols[2], where), csv_number(cols[3], where)};
    if (!out.empty() && !(p.chainage_m > out.back().chainage_m))
      throw std::invalid_argument(where + ": chainage " + cols[0] + " does not increase");
    out.push_back(p);
  }
  if (out.size() < 2) throw std::invalid_argument("alignment " + path + ": needs at least 2 points");
  return out;
}

namespace {
// Alignment point at chainage c (linear between the points; clamped to the ends).
Eigen::Vector3d alignment_at(const std::vector<AlignmentPoint>& a, double c) {
  if (c <= a.front().chainage_m) return a.front().xyz_m;
  if (c >= a.back().chainage_m) return a.back().xyz_m;
  const auto it = std::upper_bound(a.begin(), a.end(), c, [](double v, const AlignmentPoint& p) { return v < p.chainage_m; });
  const AlignmentPoint &q = *it, &p = *(it - 1);
  const double f = (c - p.chainage_m) / (q.chainage_m - p.chainage_m);
  return p.xyz_m + f * (q.xyz_m - p.xyz_m);
}
}  // namespace

AxisOnAlignment axis_on_alignment(const std::vector<AlignmentPoint>& a, const Eigen::Vector3d& centre_m,
                                  double half_span_m, double max_offset_m) {
  if (a.size() < 2) throw std::invalid_argument("alignment: needs at least 2 points");
  if (!centre_m.allFinite() || !(half_span_m > 0) || !std::isfinite(half_span_m))
    throw std::invalid_argument("alignment: the scan's centre and half span must be finite (and the span > 0)");
  // Nearest point of the polyline to the scan's centre: the section through the centre, which is
  // square to the (graded) alignment.
  double best = std::numeric_limits<double>::infinity(), c = a.front().chainage_m;
  for (std::size_t i = 0; i + 1 < a.size(); ++i) {
    const Eigen::Vector3d e = a[i + 1].xyz_m - a[i].xyz_m;
    const double f = e.squaredNorm() > 0 ? std::clamp((centre_m - a[i].xyz_m).dot(e) / e.squaredNorm(), 0.0, 1.0) : 0.0;
    const double dist = (a[i].xyz_m + f * e - centre_m).norm();
    if (dist < best) best = dist, c = a[i].chainage_m + f * (a[i + 1].chainage_m - a[i].chainage_m);
  }
  std::ostringstream where;
  where << std::fixed << std::setprecision(1) << "(" << centre_m.x() << ", " << centre_m.y() << ", " << centre_m.z() << ")";
  if (best > max_offset_m)
    throw std::invalid_argument("alignment: the scan's centre " + where.str() + " lies " + fmt(best, 1) +
                                " m from the alignment (more than " + fmt(max_offset_m, 1) +
                                " m): another tunnel, or the alignment is not in the scan's coordinates");
  if (c <= a.front().chainage_m || c >= a.back().chainage_m)
    throw std::invalid_argument("alignment: the scan lies beyond the alignment's end (chainage " +
                                fmt(a.front().chainage_m, 2) + ".." + fmt(a.back().chainage_m, 2) + " m)");
  AxisOnAlignment out;
  out.chainage_m = c;
  out.scan_offset_m = best;
  out.start_m = std::max(a.front().chainage_m, c - half_span_m);
  out.end_m = std::min(a.back().chainage_m, c + half_span_m);
  const Eigen::Vector3d dir = alignment_at(a, out.end_m) - alignment_at(a, out.start_m);
  if (!(dir.norm() > 1e-6)) throw std::invalid_argument("alignment: the alignment does not move over the scan");
  // Through the mean of the alignment over the span (samples every 0.1 m), so the straight axis
  // splits the curve's deviation both ways rather than cutting its chord.
  const int n = std::max(2, static_cast<int>(std::ceil((out.end_m - out.start_m) / 0.1)) + 1);
  std::vector<Eigen::Vector3d> samples(static_cast<std::size_t>(n));
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int k = 0; k < n; ++k) {
    samples[static_cast<std::size_t>(k)] = alignment_at(a, out.start_m + (out.end_m - out.start_m) * k / (n - 1));
    mean += samples[static_cast<std::size_t>(k)];
  }
  mean /= n;
  const Eigen::Vector3d u = dir.normalized();
  const Eigen::Vector3d at_c = alignment_at(a, c);
  const Eigen::Vector3d origin = mean + (at_c - mean).dot(u) * u;  // on the line, abreast of chainage c
  out.axis = TunnelAxis::from_direction(origin, u);
  for (const auto& p : samples) {
    const Eigen::Vector3d r = p - origin;
    out.deviation_m = std::max(out.deviation_m, (r - r.dot(u) * u).norm());
  }
  return out;
}

Config with_alignment_axis(const Config& config, const Points& xyz_m, AxisOnAlignment* where) {
  if (config.profile.alignment_path.empty()) return config;
  const std::vector<AlignmentPoint> alignment = read_alignment_csv(config.profile.alignment_path);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  long n = 0;
  for (Eigen::Index i = 0; i < xyz_m.rows(); ++i)
    if (xyz_m.row(i).allFinite()) sum += xyz_m.row(i).transpose(), ++n;
  if (n == 0) throw std::invalid_argument("alignment: the scan has no finite points");
  const Eigen::Vector3d centre = sum / static_cast<double>(n);
  // The span: first along the alignment at the centre, then the scan's extent along that axis.
  AxisOnAlignment at = axis_on_alignment(alignment, centre, 1.0);
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (Eigen::Index i = 0; i < xyz_m.rows(); ++i) {
    if (!xyz_m.row(i).allFinite()) continue;
    const double d = (xyz_m.row(i).transpose() - centre).dot(at.axis.ex);
    lo = std::min(lo, d), hi = std::max(hi, d);
  }
  at = axis_on_alignment(alignment, centre, std::max(0.5, 0.5 * (hi - lo)));
  Config out = config;
  out.profile.axis_origin_m = at.axis.origin_m;
  out.profile.axis_direction = at.axis.ex;
  if (out.grid.bay == BaySelection::range) {
    out.grid.bay_start_m -= at.chainage_m;
    out.grid.bay_end_m -= at.chainage_m;
  }
  if (where) *where = at;
  return out;
}

DesignProfile design_profile_from_config(const ProfileConfig& config) {
  if (config.section_path.empty()) return DesignProfile::circle(config.design_radius_m);
  try {
    return DesignProfile::from_section(read_section_csv(config.section_path));
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    if (what.find(config.section_path) != std::string::npos) throw;
    throw std::invalid_argument(what + " (" + config.section_path + ")");
  }
}

namespace {


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
