// Path geometry: polyline and half-circle pieces, the path made of them, and the turn-around.
#include "shotcrete/timing/cartesian_path.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <Eigen/Geometry>

#include "detail.hpp"

namespace shotcrete {
namespace timing_detail {

Eigen::Vector3d normalized_or(const Eigen::Vector3d& v, const Eigen::Vector3d& fallback) {
  const double n = v.norm();
  return n > 1e-12 ? Eigen::Vector3d(v / n) : fallback;
}

PathPiece polyline_piece(SegmentKind kind, std::vector<NozzlePose> poses, double speed, bool spraying, int pass_index) {
  PathPiece p;
  p.kind = kind;
  p.pass_index = pass_index;
  p.spraying = spraying;
  p.speed_mps = p.speed_out_mps = speed;
  // Drop repeated points: the arc-length table must increase strictly.
  std::vector<NozzlePose> kept;
  kept.reserve(poses.size());
  for (const auto& q : poses)
    if (kept.empty() || (q.position_m - kept.back().position_m).norm() > 1e-9) kept.push_back(q);
  if (kept.size() == 1) kept.push_back(kept.front());
  p.cum_m.assign(kept.size(), 0.0);
  for (std::size_t k = 1; k < kept.size(); ++k)
    p.cum_m[k] = p.cum_m[k - 1] + (kept[k].position_m - kept[k - 1].position_m).norm();
  p.poses = std::move(kept);
  return p;
}

namespace {
// Axis turns slower than this are left to the runs as before (held): the default bay's square
// passes turn at most 0.03 rad/m (a rough wall's knots); a lean fading over a 1.2 m bay, 0.5.
constexpr double kMinCarriedTurn_radpm = 0.1;
// The turn rate is read over at least this much of the pass's end (one 1 cm step's axis noise of
// 1 mrad would read as 0.1 rad/m), and carried down to 0 over at most this much of a run (eased
// runs are metres long; the turn carried on is at most rate x 5 cm, 1.4 deg at 0.5 rad/m).
constexpr double kRateChord_m = 0.02, kCarryFade_m = 0.1;
// Vertex spacing of the dense polylines built here (below a 50 Hz sample step at the top speed).
constexpr double kVertexStep_m = 0.005;
}  // namespace

Eigen::Vector3d axis_turn_rate(const std::vector<NozzlePose>& waypoints, bool at_end) {
  const std::size_t n = waypoints.size();
  if (n < 2) return Eigen::Vector3d::Zero();
  const NozzlePose& q = at_end ? waypoints[n - 1] : waypoints[0];
  // The waypoint at least kRateChord_m back along the pass (or its far end).
  std::size_t k = 1;
  double ds = 0.0;
  for (; k < n; ++k) {
    ds += (waypoints[at_end ? n - 1 - k : k].position_m - waypoints[at_end ? n - k : k - 1].position_m).norm();
    if (ds >= kRateChord_m) break;
  }
  const NozzlePose& p = waypoints[at_end ? n - 1 - std::min(k, n - 1) : std::min(k, n - 1)];
  // Turn from p to q (at_end: along the travel; at the start: q -> p is along it).
  const Eigen::Vector3d a = (at_end ? p : q).axis.normalized(), b = (at_end ? q : p).axis.normalized(), c = a.cross(b);
  if (!(ds > 1e-9) || !(c.norm() > 1e-15) || !c.allFinite()) return Eigen::Vector3d::Zero();
  return c.normalized() * std::atan2(c.norm(), a.dot(b)) / ds;
}

bool carry_axis_turn(std::vector<NozzlePose>& poses, const Eigen::Vector3d& rate, bool leaving) {
  const double w = rate.norm();
  if (poses.size() < 2 || !(w > kMinCarriedTurn_radpm)) return false;
  std::vector<double> cum(poses.size(), 0.0);
  for (std::size_t k = 1; k < poses.size(); ++k) cum[k] = cum[k - 1] + (poses[k].position_m - poses[k - 1].position_m).norm();
  const double L = cum.back(), F = std::min(L, kCarryFade_m);
  if (!(L > 0.0)) return false;
  // Turned by w (s - s^2 / 2F) at distance s <= F from the pass, held beyond: rate w at the pass,
  // 0 from F on (the same axes on a run of any length past F: the timing swarm's longer leads).
  const Eigen::Vector3d anchor = leaving ? poses.front().axis : poses.back().axis, dir = rate / w;
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const double s = std::min(leaving ? cum[k] : L - cum[k], F);
    const double angle = w * (s - 0.5 * s * s / F);
    poses[k].axis = Eigen::AngleAxisd(leaving ? angle : -angle, dir) * anchor;
  }
  return true;
}

std::vector<NozzlePose> run_carrying_axis_turn(const NozzlePose& a, const NozzlePose& b, const Eigen::Vector3d& rate,
                                               bool leaving) {
  const double length_m = (b.position_m - a.position_m).norm();
  if (!(rate.norm() > kMinCarriedTurn_radpm) || !std::isfinite(length_m)) return {a, b};
  const int n = std::max(2, static_cast<int>(std::ceil(length_m / kVertexStep_m)));
  std::vector<NozzlePose> poses(static_cast<std::size_t>(n) + 1, leaving ? a : b);
  for (int k = 0; k <= n; ++k) poses[static_cast<std::size_t>(k)].position_m = a.position_m + (b.position_m - a.position_m) * k / n;
  carry_axis_turn(poses, rate, leaving);
  return poses;
}

// Cubic Bezier from a (leaving along unit ta) to b (arriving along unit tb), control points a third
// of the chord out, as a dense polyline; the axis blends linearly. Joins two pieces whose
// directions differ without a corner.
std::vector<NozzlePose> tangent_curve(const NozzlePose& a, const Eigen::Vector3d& ta, const NozzlePose& b,
                                      const Eigen::Vector3d& tb) {
  const double c = (b.position_m - a.position_m).norm() / 3.0;
  const Eigen::Vector3d p0 = a.position_m, p1 = p0 + c * ta, p3 = b.position_m, p2 = p3 - c * tb;
  // Vertices every ~5 mm (less than a 50 Hz sample step at the top speed), so the polyline's small
  // corners do not show up in the finite-difference accelerations.
  const int kSteps = std::max(8, static_cast<int>(std::ceil(3.0 * c / kVertexStep_m)));
  std::vector<NozzlePose> poses;
  for (int k = 0; k <= kSteps; ++k) {
    const double t = static_cast<double>(k) / kSteps, r = 1.0 - t;
    NozzlePose q;
    q.position_m = r * r * r * p0 + 3.0 * r * r * t * p1 + 3.0 * r * t * t * p2 + t * t * t * p3;
    q.axis = normalized_or(r * a.axis + t * b.axis, b.axis);
    poses.push_back(q);
  }
  return poses;
}

}  // namespace timing_detail

using namespace timing_detail;

double PathPiece::length_m() const {
  if (is_arc) return kPi * radius_m;
  return cum_m.empty() ? 0.0 : cum_m.back();
}

namespace {
// Segment k of a polyline containing local arc length s, and the fraction inside it.
std::size_t poly_segment(const std::vector<double>& cum, double s, double& frac) {
  const std::size_t n = cum.size();
  std::size_t k = static_cast<std::size_t>(std::upper_bound(cum.begin(), cum.end(), s) - cum.begin());
  k = std::clamp<std::size_t>(k == 0 ? 0 : k - 1, 0, n - 2);
  const double len = cum[k + 1] - cum[k];
  frac = len > 0.0 ? std::clamp((s - cum[k]) / len, 0.0, 1.0) : 0.0;
  return k;
}
}  // namespace

NozzlePose PathPiece::pose_at(double s) const {
  NozzlePose out;
  if (is_arc) {
    const double phi = std::clamp(s / radius_m, 0.0, kPi);
    out.position_m = center + radius_m * (-std::cos(phi) * u + std::sin(phi) * d);
    // The axis turns with the position across the passes ((1 - cos phi) / 2 along u): no angular
    // rate at the ends, so the joint velocities stay continuous where the arc meets a pass.
    const double w = 0.5 * (1.0 - std::cos(phi));
    out.axis = normalized_or((1.0 - w) * axis0 + w * axis1, axis0);
    return out;
  }
  double f = 0.0;
  const std::size_t k = poly_segment(cum_m, s, f);
  // A cubic Hermite curve through the vertices (tangents by central differences, Catmull-Rom with
  // chord lengths) instead of straight segments: a curved pass is a dense polyline (vertices 1 cm
  // apart, turning a few degrees each), and samples 5 mm apart meet its corners every other step,
  // so the finite-difference joint accelerations read twice the path's curvature in spikes (a
  // horseshoe slice's pass: 1.17x a limit at 0.26 m/s). A vertex where the polyline turns more
  // than 30 deg or whose segments differ more than twice in length stays a corner (both sides
  // straight): a deliberate corner is not rounded, and a long segment does not bulge.
  const auto& P = poses;
  const auto smooth = [&](std::size_t j) {
    if (j == 0 || j + 1 >= P.size()) return false;
    const double la = cum_m[j] - cum_m[j - 1], lb = cum_m[j + 1] - cum_m[j];
    if (!(la > 0.0 && lb > 0.0) || la > 2.0 * lb || lb > 2.0 * la) return false;
    const Eigen::Vector3d a = P[j].position_m - P[j - 1].position_m, b = P[j + 1].position_m - P[j].position_m;
    return a.dot(b) >= std::cos(kPi / 6.0) * la * lb;
  };
  const double len = cum_m[k + 1] - cum_m[k];
  if (len <= 0.0 || P.size() < 3) {
    out.position_m = (1.0 - f) * P[k].position_m + f * P[k + 1].position_m;
    out.axis = normalized_or((1.0 - f) * P[k].axis + f * P[k + 1].axis, P[k].axis);
    return out;
  }
  // Derivatives per metre at the segment's ends: central at a smooth vertex, the segment's own at
  // a corner or an end (there the curve leaves as the straight segment did).
  const Eigen::Vector3d dp = (P[k + 1].position_m - P[k].position_m) / len, da = (P[k + 1].axis - P[k].axis) / len;
  Eigen::Vector3d p0 = dp, p1 = dp, a0 = da, a1 = da;
  if (smooth(k)) {
    const double w = cum_m[k + 1] - cum_m[k - 1];
    p0 = (P[k + 1].position_m - P[k - 1].position_m) / w, a0 = (P[k + 1].axis - P[k - 1].axis) / w;
  }
  if (smooth(k + 1)) {
    const double w = cum_m[k + 2] - cum_m[k];
    p1 = (P[k + 2].position_m - P[k].position_m) / w, a1 = (P[k + 2].axis - P[k].axis) / w;
  }
  const double f2 = f * f, f3 = f2 * f;
  const double h00 = 2.0 * f3 - 3.0 * f2 + 1.0, h10 = (f3 - 2.0 * f2 + f) * len, h01 = 1.0 - h00, h11 = (f3 - f2) * len;
  out.position_m = h00 * P[k].position_m + h10 * p0 + h01 * P[k + 1].position_m + h11 * p1;
  out.axis = normalized_or(h00 * P[k].axis + h10 * a0 + h01 * P[k + 1].axis + h11 * a1, P[k].axis);
  return out;
}

Eigen::Vector3d PathPiece::tangent_at(double s) const {
  if (is_arc) {
    const double phi = std::clamp(s / radius_m, 0.0, kPi);
    return std::sin(phi) * u + std::cos(phi) * d;
  }
  double f = 0.0;
  const std::size_t k = poly_segment(cum_m, s, f);
  return normalized_or(poses[k + 1].position_m - poses[k].position_m, Eigen::Vector3d::UnitX());
}

double PathPiece::curvature_at(double s) const {
  if (is_arc) return 1.0 / radius_m;
  if (poses.size() < 3) return 0.0;
  double f = 0.0;
  std::size_t k = poly_segment(cum_m, s, f);
  // Turning angle at the nearer interior vertex over the mean length of its two segments.
  std::size_t v = f < 0.5 ? k : k + 1;
  v = std::clamp<std::size_t>(v, 1, poses.size() - 2);
  const Eigen::Vector3d a = poses[v].position_m - poses[v - 1].position_m;
  const Eigen::Vector3d b = poses[v + 1].position_m - poses[v].position_m;
  const double la = a.norm(), lb = b.norm();
  if (la <= 0.0 || lb <= 0.0) return 0.0;
  const double ang = std::atan2(a.cross(b).norm(), a.dot(b));
  return ang / (0.5 * (la + lb));
}

void CartesianPath::append(PathPiece piece) {
  const double len = piece.length_m();
  pieces_.push_back(std::move(piece));
  cum_.push_back(cum_.back() + len);
}

std::size_t CartesianPath::locate(double s, double& local) const {
  if (pieces_.empty()) throw std::invalid_argument("empty Cartesian path");
  s = std::clamp(s, 0.0, length_m());
  std::size_t i = static_cast<std::size_t>(std::upper_bound(cum_.begin(), cum_.end(), s) - cum_.begin());
  i = std::min(i == 0 ? 0 : i - 1, pieces_.size() - 1);
  local = s - cum_[i];
  return i;
}
NozzlePose CartesianPath::pose_at(double s) const {
  double l = 0.0;
  const auto i = locate(s, l);
  return pieces_[i].pose_at(l);
}
Eigen::Vector3d CartesianPath::tangent_at(double s) const {
  double l = 0.0;
  const auto i = locate(s, l);
  return pieces_[i].tangent_at(l);
}
double CartesianPath::curvature_at(double s) const {
  double l = 0.0;
  const auto i = locate(s, l);
  return pieces_[i].curvature_at(l);
}

std::vector<PathPiece> turn_around(const NozzlePose& end_a, const Eigen::Vector3d& dir_a, const NozzlePose& start_b,
                                   const TurnAroundOptions& o) {
  const double speed_a = o.speed_in_mps, speed_b = o.speed_out_mps, run_m = o.run_out_m;
  const double run_in_m = o.run_in_m < 0.0 ? run_m : o.run_in_m;
  const bool spraying = o.spraying;
  const Eigen::Vector3d& dir_b = o.dir_b_start;
  if (!(run_m >= 0.0) || !(run_in_m >= 0.0))
    throw std::invalid_argument("turn_around: run lengths " + num(run_m) + " m / " + num(run_in_m) + " m must be >= 0");
  const Eigen::Vector3d d = normalized_or(dir_a, Eigen::Vector3d::UnitX());
  const double e = (start_b.position_m - end_a.position_m).dot(d);
  // Align the two ends along d: the arc starts where both have run on by at least their run length
  // (room for a speed change before and after the arc); the shorter side is extended to it.
  const double x_arc = std::max(run_m, e + run_in_m);  // arc ends, along d from end_a
  NozzlePose pa = end_a, pb = start_b;
  pa.position_m += x_arc * d;
  pb.position_m += (x_arc - e) * d;
  const Eigen::Vector3d w = pb.position_m - pa.position_m;  // orthogonal to d by construction
  const double diameter = w.norm();
  if (diameter < 1e-6)
    throw std::invalid_argument("turn-around: the end of one pass and the start of the next coincide across the pass "
                                "direction (spacing " + num(diameter) + " m)");
  std::vector<PathPiece> out;
  if (x_arc > 1e-9) {
    const auto run = run_carrying_axis_turn(end_a, pa, o.axis_rate_a, true);
    pa.axis = run.back().axis;
    out.push_back(polyline_piece(SegmentKind::Link, run, speed_a, spraying, -1));
  }
  // Run-in: the arc leaves along -d, the next pass starts along dir_b. Wall-following passes are
  // not exactly antiparallel, and a straight run-in would kink where it meets the pass (up to
  // 40 deg on real plans, a step in the joint velocities). A cubic Bezier tangent to both turns
  // the difference over the whole run instead.
  const double run_in = (pb.position_m - start_b.position_m).norm();
  std::vector<NozzlePose> run_in_poses;
  if (run_in > 1e-9) {
    const Eigen::Vector3d db = dir_b.squaredNorm() > 0.0 ? normalized_or(dir_b, -d) : Eigen::Vector3d(-d);
    // (A held curve's first axis is start_b's normalised: the arc keeps start_b's own, to the bit.)
    bool carried = true;
    if ((db + d).norm() < 1e-4) {
      run_in_poses = run_carrying_axis_turn(pb, start_b, o.axis_rate_b, false);
    } else {
      run_in_poses = tangent_curve(pb, -d, start_b, db);
      carried = carry_axis_turn(run_in_poses, o.axis_rate_b, false);
    }
    if (carried) pb.axis = run_in_poses.front().axis;
  }
  PathPiece arc;
  arc.kind = SegmentKind::Turn;
  arc.spraying = spraying;
  arc.speed_mps = speed_a;
  arc.speed_out_mps = speed_b;
  arc.is_arc = true;
  arc.radius_m = 0.5 * diameter;
  arc.center = 0.5 * (pa.position_m + pb.position_m);
  arc.u = w / diameter;
  arc.d = d;
  arc.axis0 = pa.axis;
  arc.axis1 = pb.axis;
  out.push_back(arc);
  if (!run_in_poses.empty()) out.push_back(polyline_piece(SegmentKind::Link, run_in_poses, speed_b, spraying, -1));
  return out;
}

}  // namespace shotcrete
