#include "shotcrete/surface/profile.hpp"

#include "shotcrete/surface/grid.hpp"
#include "shotcrete/surface/preprocess.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <unordered_map>
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

/// The quantile cylinder fit below with one radius per group of points (slab[i] in [0, slabs)).
void quantile_cylinder_in_slabs(const Points& pts, const std::vector<int>& slab, int slabs, bool fit_origin, double tau,
                                 Eigen::Vector3d& origin, Eigen::Vector3d& ex, Eigen::VectorXd& radii) {
  const int na = fit_origin ? 4 : 2;  // axis parameters (a, b[, cu, cv]); then one radius per slab
  const double eps_m = 1e-3;  // residuals below 1 mm weigh as 1 mm (IRLS for the L1-type loss)
  const Eigen::Index n = pts.rows();
  std::vector<long> per_slab(static_cast<std::size_t>(slabs), 0);
  for (const int k : slab) ++per_slab[static_cast<std::size_t>(k)];
  const int np = na + slabs;
  Eigen::VectorXd J(na);
  for (int it = 0; it < 100; ++it) {
    const TunnelAxis f = TunnelAxis::from_direction(origin, ex);
    Eigen::MatrixXd JtJ = Eigen::MatrixXd::Zero(np, np);
    Eigen::VectorXd Jtr = Eigen::VectorXd::Zero(np);
    for (Eigen::Index i = 0; i < n; ++i) {
      const int k = na + slab[static_cast<std::size_t>(i)];
      const Eigen::Vector3d q = pts.row(i).transpose() - origin;
      const double x = q.dot(f.ex), u = q.dot(f.ey), v = q.dot(f.ez), r = std::max(std::hypot(u, v), 1e-12);
      const double res = r - radii[k - na];
      const double w = (res > 0 ? tau : 1.0 - tau) / std::max(std::abs(res), eps_m);
      const double gu = -u / r, gv = -v / r;
      if (fit_origin) J << gu * x, gv * x, gu, gv;
      else J << gu * x, gv * x;
      JtJ.topLeftCorner(na, na).noalias() += w * J * J.transpose();
      JtJ.block(0, k, na, 1).noalias() -= w * J;  // d res / d radius_k = -1
      JtJ(k, k) += w;
      Jtr.head(na).noalias() += w * res * J;
      Jtr[k] -= w * res;
    }
    for (int k = 0; k < slabs; ++k)
      if (per_slab[static_cast<std::size_t>(k)] == 0) JtJ(na + k, na + k) = 1.0;  // an empty slab: its radius stays
    const Eigen::MatrixXd JtJ_full = JtJ.selfadjointView<Eigen::Upper>();
    const Eigen::VectorXd step = JtJ_full.ldlt().solve(-Jtr);
    if (!step.allFinite()) throw std::invalid_argument("axis fit: no cylinder fits the cloud");
    ex = (f.ex + step[0] * f.ey + step[1] * f.ez).normalized();
    if (fit_origin) origin += step[2] * f.ey + step[3] * f.ez;
    radii += step.tail(slabs);
    if (step.cwiseAbs().maxCoeff() < 1e-9) break;
  }
}

/// Quantile cylinder fit by iteratively reweighted Gauss-Newton: the cylinder with a fraction tau
/// of the points inside it. Dig pits only ever add over-break, so the lower envelope follows the
/// intact contour, which is concentric with the design line; a least-squares fit follows the pits
/// instead (TD 40 mm low on the synthetic bay). A scan's wall may step out along the axis, from a
/// lined bay (on the design line) to the over-broken new one: one radius for both let the envelope
/// tilt 2 deg to reach into the new bay. So with `runs` given, the radius is one per run of the wall
/// along the axis: when `runs` is empty, first one per kAxisFitSlab_m slab, then one per run of
/// slabs whose radii lie within kAxisFitStep_m of the run's first (slabs with under 2 % of the
/// points join the run they sit in), and `runs` gets the runs' starts along the axis (a single
/// surface: one radius, as slabs alone hold the tilt loosely: 0.4 deg on a bay); when not empty,
/// those runs. Small-angle parameters, re-framed every step: centre line origin + x ex + (cu + a
/// x) ey + (cv + b x) ez; (cu, cv) only when fit_origin. radius: the points' mean of their radius.
void quantile_cylinder(const Points& pts, bool fit_origin, double tau, std::vector<double>* runs, Eigen::Vector3d& origin,
                       Eigen::Vector3d& ex, double& radius) {
  const Eigen::Index n = pts.rows();
  std::vector<double> x(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) x[static_cast<std::size_t>(i)] = (pts.row(i).transpose() - origin).dot(ex);
  // Group of each point: its run (from the run starts), its slab, or one for all.
  auto groups_from = [&](const std::vector<double>& starts, std::vector<int>& group) {
    for (std::size_t i = 0; i < group.size(); ++i)
      group[i] = std::max(0, static_cast<int>(std::upper_bound(starts.begin(), starts.end(), x[i]) - starts.begin()) - 1);
    return std::max<int>(1, static_cast<int>(starts.size()));
  };
  std::vector<int> group(static_cast<std::size_t>(n), 0);
  int groups = 1;
  if (runs && !runs->empty()) {
    groups = groups_from(*runs, group);
  } else if (runs) {
    const double xmin = n > 0 ? *std::min_element(x.begin(), x.end()) : 0.0;
    for (std::size_t i = 0; i < group.size(); ++i) {
      group[i] = static_cast<int>(std::floor((x[i] - xmin) / kAxisFitSlab_m));
      groups = std::max(groups, group[i] + 1);
    }
  }
  Eigen::VectorXd radii = Eigen::VectorXd::Constant(groups, radius);
  quantile_cylinder_in_slabs(pts, group, groups, fit_origin, tau, origin, ex, radii);
  if (runs && runs->empty()) {  // slabs -> runs, and the fit again with them
    std::vector<long> per_slab(static_cast<std::size_t>(groups), 0);
    for (const int k : group) ++per_slab[static_cast<std::size_t>(k)];
    const double xmin = n > 0 ? *std::min_element(x.begin(), x.end()) : 0.0;
    double run_radius = NAN;
    for (int k = 0; k < groups; ++k) {
      if (per_slab[static_cast<std::size_t>(k)] < std::max<long>(50, n / 50)) continue;  // sparse: joins its run
      if (std::isnan(run_radius) || std::abs(radii[k] - run_radius) > kAxisFitStep_m) {
        runs->push_back(runs->empty() ? -std::numeric_limits<double>::infinity() : xmin + k * kAxisFitSlab_m);
        run_radius = radii[k];
      }
    }
    if (runs->empty()) runs->push_back(-std::numeric_limits<double>::infinity());
    groups = groups_from(*runs, group);
    radii = Eigen::VectorXd::Constant(groups, radius);
    quantile_cylinder_in_slabs(pts, group, groups, fit_origin, tau, origin, ex, radii);
  }
  double sum = 0.0;
  for (const int k : group) sum += radii[k];
  radius = sum / static_cast<double>(std::max<Eigen::Index>(n, 1));
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

/// A first axis for a cloud that holds more than the wall (a scene: face, floor, duct, rig), whose
/// normals alone point nowhere near the axis (the face's and the floor's outnumber the wall's).
/// RANSAC on pairs of points with normals: two normals of a cylinder are perpendicular to its axis
/// (direction n1 x n2) and their lines meet on it in the section plane (centre; the radii are the
/// distances to it). A candidate whose two radii lie within max_deviation_m of the design radius
/// scores the points of a sample within kSeedBand_m of its radius whose normals face its axis. Rough
/// (two noisy normals: a few degrees, a few decimetres); fit_axis refines it on the wall it finds.
/// nullopt when no candidate has a design-like radius and support (a plane, a gentle sheet).
std::optional<TunnelAxis> seed_axis(const Cloud& cloud, const ProfileConfig& profile) {
  constexpr std::size_t kSample = 5000;
  constexpr int kCandidates = 2000;
  constexpr double kSeedBand_m = 0.3, kMinCross = 0.2, kFacingCos = 0.866;  // normals >= 11.5 deg apart; facing within 30 deg
  const Eigen::Index n = cloud.size();
  std::mt19937_64 rng(16);  // fixed: the same cloud gives the same axis
  std::uniform_int_distribution<Eigen::Index> pick(0, n - 1);
  std::vector<Eigen::Index> sample;
  for (std::size_t k = 0; k < 4 * kSample && sample.size() < kSample; ++k) {
    const Eigen::Index i = pick(rng);
    if (cloud.normals.row(i).squaredNorm() > 0.25 && cloud.xyz.row(i).allFinite()) sample.push_back(i);
  }
  if (sample.size() < 2) return std::nullopt;
  const auto m = static_cast<Eigen::Index>(sample.size());
  Points P(m, 3), N(m, 3);
  for (Eigen::Index k = 0; k < m; ++k) {
    P.row(k) = cloud.xyz.row(sample[static_cast<std::size_t>(k)]);
    N.row(k) = cloud.normals.row(sample[static_cast<std::size_t>(k)]).normalized();
  }
  const Eigen::RowVector3d c0 = P.colwise().mean();
  P.rowwise() -= c0;
  const double R = profile.design_radius_m;
  std::uniform_int_distribution<Eigen::Index> pick_sample(0, m - 1);
  long best_score = 0;
  Eigen::Vector3d best_dir = Eigen::Vector3d::UnitX(), best_centre = Eigen::Vector3d::Zero();
  for (int k = 0; k < kCandidates; ++k) {
    const Eigen::Index a = pick_sample(rng), b = pick_sample(rng);
    const Eigen::Vector3d n1 = N.row(a).transpose(), n2 = N.row(b).transpose();
    Eigen::Vector3d d = n1.cross(n2);
    if (d.norm() < kMinCross) continue;
    d.normalize();
    if (std::abs(d.z()) > 0.9) continue;  // a tunnel axis is mostly horizontal
    const Eigen::Vector3d u = d.unitOrthogonal(), v = d.cross(u);
    const Eigen::Vector2d a1(P.row(a).dot(u), P.row(a).dot(v)), a2(P.row(b).dot(u), P.row(b).dot(v));
    const Eigen::Vector2d m1 = Eigen::Vector2d(n1.dot(u), n1.dot(v)).normalized(), m2 = Eigen::Vector2d(n2.dot(u), n2.dot(v)).normalized();
    const double det = -m1.x() * m2.y() + m2.x() * m1.y();  // [m1, -m2] t = a2 - a1
    if (std::abs(det) < 1e-9) continue;
    const Eigen::Vector2d rhs = a2 - a1;
    const double t1 = (-rhs.x() * m2.y() + m2.x() * rhs.y()) / det;
    const Eigen::Vector2d c = a1 + t1 * m1;
    const double r1 = (a1 - c).norm(), r2 = (a2 - c).norm();
    if (!(std::abs(r1 - R) <= profile.max_deviation_m && std::abs(r2 - R) <= profile.max_deviation_m)) continue;
    const double rc = 0.5 * (r1 + r2);
    long score = 0;
    for (Eigen::Index i = 0; i < m; ++i) {
      const double qu = P.row(i).dot(u) - c.x(), qv = P.row(i).dot(v) - c.y(), r = std::hypot(qu, qv);
      if (std::abs(r - rc) < kSeedBand_m && std::abs(N.row(i).dot(qu * u + qv * v)) > kFacingCos * r) ++score;
    }
    if (score > best_score) {
      best_score = score;
      best_dir = d;
      best_centre = c0.transpose() + c.x() * u + c.y() * v;
    }
  }
  if (best_score < std::max<long>(10, m / 20)) return std::nullopt;  // under 5 % of the sample: no wall
  if (best_dir.dot(profile.axis_direction) < 0) best_dir = -best_dir;
  return TunnelAxis::from_direction(best_centre, best_dir);
}

/// Indices of the points build_grid grids around `axis` (the whole scan): within max_deviation_m of
/// the design radius, facing the axis, not in front of the wall (a duct's top: grid.obstacle_gap_m)
/// and not a floor's stray normals. Empty when none is.
/// Of `wall`, the points no more than grid.obstacle_gap_m inside the median distance from `axis`
/// of their bin (kAxisFitSlab_m along the axis, 15 deg around it): what the grid's obstacle rule
/// leaves of a duct's top where the scan is sparse (its fine bins hold a point or none; at 8 points
/// per cell it left enough for a lower envelope to follow at the scan's end). Over-break is
/// outward, so the wall lies at or beyond the median.
std::vector<Eigen::Index> without_inward_clutter(const Cloud& cloud, const std::vector<Eigen::Index>& wall,
                                                 const TunnelAxis& axis, const GridConfig& grid) {
  constexpr double kSector_rad = 15.0 * M_PI / 180.0;
  std::vector<std::pair<std::int64_t, double>> keyed(wall.size());  // (bin, r)
  for (std::size_t k = 0; k < wall.size(); ++k) {
    const Eigen::Vector3d c = axis.to_cylindrical(cloud.xyz.row(wall[k]).transpose());
    keyed[k] = {static_cast<std::int64_t>(std::floor(c[2] / kAxisFitSlab_m)) * 1000 +
                    static_cast<std::int64_t>(std::floor((c[1] + M_PI) / kSector_rad)),
                c[0]};
  }
  std::unordered_map<std::int64_t, std::vector<double>> bins;
  for (const auto& kr : keyed) bins[kr.first].push_back(kr.second);
  std::unordered_map<std::int64_t, double> median;
  for (auto& kv : bins) {
    auto& v = kv.second;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    median[kv.first] = v[v.size() / 2];
  }
  std::vector<Eigen::Index> out;
  for (std::size_t k = 0; k < wall.size(); ++k)
    if (keyed[k].second >= median[keyed[k].first] - grid.obstacle_gap_m) out.push_back(wall[k]);
  return out;
}

std::vector<Eigen::Index> wall_points(const Cloud& cloud, const TunnelAxis& axis, const ProfileConfig& profile,
                                      const GridConfig& grid) {
  std::vector<char> kept;
  try {
    build_grid(cloud, axis, DesignProfile::circle(profile.design_radius_m), grid, profile.max_deviation_m, std::nullopt, &kept);
  } catch (const std::invalid_argument&) {
    return {};  // nothing near the design line around this axis
  }
  std::vector<Eigen::Index> out;
  for (Eigen::Index i = 0; i < cloud.size(); ++i)
    if (kept[static_cast<std::size_t>(i)]) out.push_back(i);
  return out;
}

AxisFit fit_cylinder(const Cloud& cloud, const ProfileConfig& profile, bool slab_radii) {
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
  std::vector<double> runs;  // the wall's runs along the axis (kept for the patches)
  quantile_cylinder(cloud.xyz, fit_origin, kAxisFitQuantile, slab_radii ? &runs : nullptr, origin, ex, radius);
  // Again on the means of 7.5 cm patches: the scanner noise averages out, so the envelope is the
  // contour's, not that of the noise's extremes (which biases the centre by a few mm).
  const Points patches = patch_means(cloud.xyz, TunnelAxis::from_direction(origin, ex), radius);
  if (patches.rows() >= 50) quantile_cylinder(patches, fit_origin, kAxisFitPatchQuantile, slab_radii ? &runs : nullptr, origin, ex, radius);
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

AxisFit fit_axis(const Cloud& cloud, const ProfileConfig& profile, const GridConfig& grid) {
  const Eigen::Index n = cloud.size();
  if (n < kMinAxisFitPoints)
    throw std::invalid_argument("axis fit: need at least " + std::to_string(kMinAxisFitPoints) + " points, got " +
                                std::to_string(n));
  if (!cloud.has_normals()) throw std::invalid_argument("axis fit: the cloud needs normals");
  // The wall first: from a RANSAC seed, the points the grid would take as wall (no face, floor,
  // duct or rig), fitted, and the wall taken again around the fitted axis until it settles.
  if (std::optional<TunnelAxis> axis = seed_axis(cloud, profile)) {
    try {
      std::optional<AxisFit> fit;
      for (int round = 0; round < kAxisFitRounds; ++round) {
        std::vector<Eigen::Index> wall = wall_points(cloud, *axis, profile, grid);
        if (round > 0 && grid.obstacle_gap_m > 0) wall = without_inward_clutter(cloud, wall, *axis, grid);  // the seed is too rough for bins
        if (static_cast<long>(wall.size()) < kMinAxisFitPoints) break;
        fit = fit_cylinder(select_points(cloud, wall), profile, true);
        const Eigen::Vector3d q = fit->axis.origin_m - axis->origin_m;
        const bool settled = fit->axis.ex.dot(axis->ex) > std::cos(1e-5) && (q - q.dot(axis->ex) * axis->ex).norm() < 1e-4;
        axis = fit->axis;
        if (settled) break;
      }
      if (fit) {
        fit->inlier_share = static_cast<double>(fit->points) / static_cast<double>(n);
        return *fit;
      }
    } catch (const std::invalid_argument&) {
      // Refused on the wall found: the whole cloud's fit, or its reason (a scatter's RMS, a plane).
    }
  }
  // No wall found around a seed (a plane, a gentle sheet): the whole cloud, whose refusal names the reason.
  return fit_cylinder(cloud, profile, false);
}

}  // namespace shotcrete
