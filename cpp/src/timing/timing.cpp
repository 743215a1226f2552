// Motion timing: speed profiles, turn-arounds, sampling, joint-space timing, AIWCPSO.
#include "shotcrete/timing/timing.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>

#include "shotcrete/robot/robot.hpp"

namespace shotcrete {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;

std::string num(double v) {
  std::ostringstream o;
  o << std::setprecision(6) << v;
  return o.str();
}

// Shape function g(tau) of a speed change, its derivatives and its integral.
double shape_g(SpeedShape s, double t) {
  if (s == SpeedShape::Cycloid) return t - std::sin(kTwoPi * t) / kTwoPi;
  return t * t * t * (10.0 + t * (-15.0 + 6.0 * t));
}
double shape_dg(SpeedShape s, double t) {
  if (s == SpeedShape::Cycloid) return 1.0 - std::cos(kTwoPi * t);
  return 30.0 * t * t * (1.0 - t) * (1.0 - t);
}
double shape_ddg(SpeedShape s, double t) {
  if (s == SpeedShape::Cycloid) return kTwoPi * std::sin(kTwoPi * t);
  return 60.0 * t - 180.0 * t * t + 120.0 * t * t * t;
}
double shape_G(SpeedShape s, double t) {
  if (s == SpeedShape::Cycloid) return 0.5 * t * t + (std::cos(kTwoPi * t) - 1.0) / (kTwoPi * kTwoPi);
  return t * t * t * t * (2.5 + t * (-3.0 + t));
}
double shape_peak_dg(SpeedShape s) { return s == SpeedShape::Cycloid ? 2.0 : 1.875; }

Eigen::Vector3d normalized_or(const Eigen::Vector3d& v, const Eigen::Vector3d& fallback) {
  const double n = v.norm();
  return n > 1e-12 ? Eigen::Vector3d(v / n) : fallback;
}

void check_pass(const Pass& p, std::size_t i) {
  if (p.waypoints.size() < 2)
    throw std::invalid_argument("pass " + std::to_string(i) + " has " + std::to_string(p.waypoints.size()) +
                                " waypoints; at least 2 are needed");
  if (!(p.speed_mps > 0.0) || !std::isfinite(p.speed_mps))
    throw std::invalid_argument("pass " + std::to_string(i) + " has speed_mps = " + num(p.speed_mps) +
                                "; it must be > 0");
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

Eigen::Vector3d start_direction(const Pass& p) {
  return normalized_or(p.waypoints[1].position_m - p.waypoints[0].position_m, Eigen::Vector3d::UnitX());
}
Eigen::Vector3d end_direction(const Pass& p) {
  const auto n = p.waypoints.size();
  return normalized_or(p.waypoints[n - 1].position_m - p.waypoints[n - 2].position_m, Eigen::Vector3d::UnitX());
}

// Speed on a turn arc of radius r between the pass speeds v_in and v_out: the turn speed (or the
// pass speeds when it is 0), capped so that the centripetal acceleration v^2 / r stays at accel;
// 0 = no own turn speed (the arc changes from one pass speed to the next).
double turn_arc_speed(double radius_m, double v_in, double v_out, double turn_speed_mps, double accel_mps2) {
  const double cap = std::sqrt(accel_mps2 * radius_m);
  if (turn_speed_mps > 0.0) return std::min(turn_speed_mps, cap);
  return std::max(v_in, v_out) > cap ? cap : 0.0;
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
  const int kSteps = std::max(8, static_cast<int>(std::ceil(3.0 * c / 0.005)));
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

// Piece data needed by the speed profile: kind, length and the planned speeds.
struct PieceSpec {
  SegmentKind kind;
  double length_m, v_in, v_out;
  std::vector<double> run_len_m, run_speed_mps;  // pass with a speed profile: constant-speed runs
  char motion;
  double accel_scale;  // turn arc: share of the params' turn acceleration
};

std::vector<PieceSpec> specs_of(const CartesianPath& path) {
  std::vector<PieceSpec> out;
  for (const auto& p : path.pieces())
    out.push_back(
        {p.kind, p.length_m(), p.speed_mps, p.speed_out_mps, p.run_len_m, p.run_speed_mps, p.motion, p.accel_scale});
  return out;
}

// Constant-speed runs of a pass with a per-waypoint speed profile, with the planner's dwell
// semantics: waypoint i owns half of each neighbouring interval at speed_at(i).
void speed_runs(const Pass& p, std::vector<double>& len, std::vector<double>& speed) {
  len.clear();
  speed.clear();
  const std::size_t n = p.waypoints.size();
  for (std::size_t i = 0; i < n; ++i) {
    double own = 0.0;
    if (i > 0) own += 0.5 * (p.waypoints[i].position_m - p.waypoints[i - 1].position_m).norm();
    if (i + 1 < n) own += 0.5 * (p.waypoints[i + 1].position_m - p.waypoints[i].position_m).norm();
    const double v = p.speed_at(i);
    if (!(v > 0.0) || !std::isfinite(v))
      throw std::invalid_argument("pass speed profile value " + num(v) + " m/s at waypoint " + std::to_string(i) +
                                  " must be > 0");
    if (!speed.empty() && std::abs(speed.back() - v) <= 1e-12 * v) {
      len.back() += own;
    } else {
      len.push_back(own);
      speed.push_back(v);
    }
  }
}

// Speed profile over the runs of a pass: cruise on each run, cycloidal change centred on each
// boundary over the length that keeps the peak acceleration at accel_mps2 (at most half of each
// neighbouring run).
void append_runs(SpeedProfile& prof, const std::vector<double>& len, const std::vector<double>& v, double accel_mps2) {
  const std::size_t n = len.size();
  std::vector<double> h(n + 1, 0.0);  // half transition length at boundary b (between run b-1 and b)
  for (std::size_t b = 1; b < n; ++b) {
    const double full = std::abs(v[b] - v[b - 1]) * (v[b] + v[b - 1]) / accel_mps2;  // peak = accel
    h[b] = std::min({0.5 * full, 0.5 * len[b - 1], 0.5 * len[b]});
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (i > 0 && h[i] > 0.0)
      prof.append(SpeedPiece{v[i - 1], v[i], 2.0 * h[i] / (0.5 * (v[i - 1] + v[i])), SpeedShape::Cycloid});
    const double cruise = len[i] - h[i] - h[i + 1];
    if (cruise > 0.0) prof.append(SpeedPiece{v[i], v[i], cruise / v[i], SpeedShape::Cycloid});
  }
}

SpeedProfile profile_from_specs(const std::vector<PieceSpec>& specs, const TimingParams& params) {
  if (specs.size() < 3 || specs.front().kind != SegmentKind::Lead || specs.back().kind != SegmentKind::Lead)
    throw std::invalid_argument("region_profile: the path must start with a lead-in and end with a lead-out");
  if (!(params.k1 > 0.0 && params.k1 <= 1.0)) throw std::invalid_argument("k1 = " + num(params.k1) + " must be in (0, 1]");
  if (!(params.k2 >= 0.0 && params.k2 < 1.0)) throw std::invalid_argument("k2 = " + num(params.k2) + " must be in [0, 1)");
  // Speed on turn arc j: the turn speed (or the pass speeds when it is 0), capped so that the
  // centripetal acceleration v^2 / r stays at speed_change_accel_mps2; 0 = no own turn speed (the
  // arc changes from one pass speed to the next).
  const double turn_accel = params.turn_accel_mps2 > 0.0 ? params.turn_accel_mps2 : params.speed_change_accel_mps2;
  auto turn_v = [&](std::size_t j) {
    const auto& t = specs[j];
    return turn_arc_speed(t.length_m / kPi, t.v_in, t.v_out, params.turn_speed_mps, t.accel_scale * turn_accel);
  };
  SpeedProfile prof;
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const auto& s = specs[i];
    if (i == 0) {
      prof.append(cycloid_start(s.length_m, s.v_in, params.k1));
    } else if (i + 1 == specs.size()) {
      prof.append(cycloid_end(s.length_m, s.v_in, params.k2));
    } else if (s.motion == 3 || s.motion == 1) {
      // Stop-and-go runs: plain cycloidal start / stop (no cruise). The spray is off and the arm
      // only leaves the pass line there, so a cruise (the paper's k1 / k2, which shape the lead-in
      // and lead-out) would take it up to 3x further out at the pass speed.
      prof.append(s.motion == 3 ? cycloid_start(s.length_m, s.v_in, 1.0) : cycloid_end(s.length_m, s.v_in, 0.0));
    } else if (s.motion == 4) {
      // Spray-off gap on the same line: change smoothly from one pass speed to the next.
      prof.append(SpeedPiece{s.v_in, s.v_out, s.length_m / (0.5 * (s.v_in + s.v_out)), SpeedShape::Cycloid});
    } else if (s.motion == 2) {
      const double v = params.turn_speed_mps > 0.0 ? params.turn_speed_mps : s.v_in;
      if (s.length_m > 0.0) prof.append(rest_to_rest(s.length_m, v, 2.0 * v / params.speed_change_accel_mps2, SpeedShape::Cycloid));
    } else if (s.kind == SegmentKind::Link && s.motion == 0 &&
               ((specs[i + 1].kind == SegmentKind::Turn && turn_v(i + 1) > 0.0) ||
                (specs[i - 1].kind == SegmentKind::Turn && turn_v(i - 1) > 0.0))) {
      // Run-out before / run-in after a turn: the speed changes to / from the turn speed here.
      const bool before = specs[i + 1].kind == SegmentKind::Turn && turn_v(i + 1) > 0.0;
      const double vt = before ? turn_v(i + 1) : turn_v(i - 1);
      const double va = before ? s.v_in : vt, vb = before ? vt : s.v_in;
      prof.append(SpeedPiece{va, vb, s.length_m / (0.5 * (va + vb)), SpeedShape::Cycloid});
    } else if (s.kind == SegmentKind::Turn) {
      const double vt = turn_v(i);
      const bool run_before = specs[i - 1].kind == SegmentKind::Link, run_after = specs[i + 1].kind == SegmentKind::Link;
      if (vt > 0.0) {
        // Entry / exit speeds: the turn speed where a run line already changed it, else the pass
        // speed; the rest of the change happens on the arc halves (constant when nothing is left).
        const double v0 = run_before ? vt : s.v_in, v1 = run_after ? vt : s.v_out;
        const double half = 0.5 * s.length_m;
        prof.append(SpeedPiece{v0, vt, half / (0.5 * (v0 + vt)), SpeedShape::Cycloid});
        prof.append(SpeedPiece{vt, v1, half / (0.5 * (vt + v1)), SpeedShape::Cycloid});
      } else {
        prof.append(SpeedPiece{s.v_in, s.v_out, s.length_m / (0.5 * (s.v_in + s.v_out)), SpeedShape::Cycloid});
      }
    } else if (!s.run_len_m.empty()) {
      append_runs(prof, s.run_len_m, s.run_speed_mps, params.speed_change_accel_mps2);
    } else {
      prof.append(SpeedPiece{s.v_in, s.v_in, s.length_m / s.v_in, SpeedShape::Cycloid});
    }
  }
  return prof;
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// SpeedPiece / SpeedProfile
// ------------------------------------------------------------------------------------------------

double SpeedPiece::speed_at(double t) const {
  if (duration_s <= 0.0) return v1_mps;
  return v0_mps + (v1_mps - v0_mps) * shape_g(shape, std::clamp(t / duration_s, 0.0, 1.0));
}
double SpeedPiece::accel_at(double t) const {
  if (duration_s <= 0.0) return 0.0;
  return (v1_mps - v0_mps) / duration_s * shape_dg(shape, std::clamp(t / duration_s, 0.0, 1.0));
}
double SpeedPiece::jerk_at(double t) const {
  if (duration_s <= 0.0) return 0.0;
  return (v1_mps - v0_mps) / (duration_s * duration_s) * shape_ddg(shape, std::clamp(t / duration_s, 0.0, 1.0));
}
double SpeedPiece::distance_at(double t) const {
  if (duration_s <= 0.0) return 0.0;
  const double tau = std::clamp(t / duration_s, 0.0, 1.0);
  return duration_s * (v0_mps * tau + (v1_mps - v0_mps) * shape_G(shape, tau));
}
double SpeedPiece::peak_accel_mps2() const {
  if (duration_s <= 0.0) return 0.0;
  return std::abs(v1_mps - v0_mps) / duration_s * shape_peak_dg(shape);
}

void SpeedProfile::append(const SpeedPiece& piece) {
  if (!(piece.duration_s >= 0.0) || !std::isfinite(piece.duration_s))
    throw std::invalid_argument("speed piece duration " + num(piece.duration_s) + " s must be finite and >= 0");
  if (piece.v0_mps < 0.0 || piece.v1_mps < 0.0)
    throw std::invalid_argument("speed piece speeds must be >= 0 (got " + num(piece.v0_mps) + ", " + num(piece.v1_mps) + ")");
  if (piece.duration_s == 0.0) return;
  pieces_.push_back(piece);
  t_.push_back(t_.back() + piece.duration_s);
  s_.push_back(s_.back() + piece.length_m());
}

void SpeedProfile::append(const SpeedProfile& other) {
  for (const auto& p : other.pieces_) append(p);
}

SpeedProfile::State SpeedProfile::at(double t) const {
  State st;
  if (pieces_.empty()) return st;
  t = std::clamp(t, 0.0, duration_s());
  std::size_t i = static_cast<std::size_t>(std::upper_bound(t_.begin(), t_.end(), t) - t_.begin());
  i = std::min(i == 0 ? 0 : i - 1, pieces_.size() - 1);
  const double lt = t - t_[i];
  const auto& p = pieces_[i];
  st.s_m = s_[i] + p.distance_at(lt);
  st.v_mps = p.speed_at(lt);
  st.a_mps2 = p.accel_at(lt);
  st.j_mps3 = p.jerk_at(lt);
  return st;
}

double SpeedProfile::time_at_distance(double s) const {
  if (pieces_.empty()) return 0.0;
  s = std::clamp(s, 0.0, length_m());
  std::size_t i = static_cast<std::size_t>(std::upper_bound(s_.begin(), s_.end(), s) - s_.begin());
  i = std::min(i == 0 ? 0 : i - 1, pieces_.size() - 1);
  const auto& p = pieces_[i];
  double lo = 0.0, hi = p.duration_s;
  for (int it = 0; it < 80; ++it) {
    const double mid = 0.5 * (lo + hi);
    (s_[i] + p.distance_at(mid) < s ? lo : hi) = mid;
  }
  return t_[i] + 0.5 * (lo + hi);
}

SpeedProfile cycloid_start(double s_start_m, double v_mps, double k1) {
  if (!(s_start_m > 0.0)) throw std::invalid_argument("start length " + num(s_start_m) + " m must be > 0 (the nozzle starts from rest)");
  if (!(v_mps > 0.0)) throw std::invalid_argument("cruise speed " + num(v_mps) + " m/s must be > 0");
  if (!(k1 > 0.0 && k1 <= 1.0)) throw std::invalid_argument("k1 = " + num(k1) + " must be in (0, 1]");
  const double ts = 2.0 * s_start_m / (v_mps * (2.0 - k1));
  SpeedProfile p;
  p.append(SpeedPiece{0.0, v_mps, k1 * ts, SpeedShape::Cycloid});
  p.append(SpeedPiece{v_mps, v_mps, (1.0 - k1) * ts, SpeedShape::Cycloid});
  return p;
}

SpeedProfile cycloid_end(double s_end_m, double v_mps, double k2) {
  if (!(s_end_m > 0.0)) throw std::invalid_argument("end length " + num(s_end_m) + " m must be > 0 (the nozzle stops at rest)");
  if (!(v_mps > 0.0)) throw std::invalid_argument("cruise speed " + num(v_mps) + " m/s must be > 0");
  if (!(k2 >= 0.0 && k2 < 1.0)) throw std::invalid_argument("k2 = " + num(k2) + " must be in [0, 1)");
  const double te = 2.0 * s_end_m / (v_mps * (1.0 + k2));
  SpeedProfile p;
  p.append(SpeedPiece{v_mps, v_mps, k2 * te, SpeedShape::Cycloid});
  p.append(SpeedPiece{v_mps, 0.0, (1.0 - k2) * te, SpeedShape::Cycloid});
  return p;
}

SpeedProfile rest_to_rest(double length_m, double v_mps, double accel_time_s, SpeedShape shape) {
  if (!(length_m >= 0.0)) throw std::invalid_argument("move length " + num(length_m) + " m must be >= 0");
  if (!(v_mps > 0.0)) throw std::invalid_argument("cruise speed " + num(v_mps) + " m/s must be > 0");
  if (!(accel_time_s > 0.0)) throw std::invalid_argument("acceleration time " + num(accel_time_s) + " s must be > 0");
  SpeedProfile p;
  if (length_m == 0.0) return p;
  if (length_m >= v_mps * accel_time_s) {
    p.append(SpeedPiece{0.0, v_mps, accel_time_s, shape});
    p.append(SpeedPiece{v_mps, v_mps, (length_m - v_mps * accel_time_s) / v_mps, shape});
    p.append(SpeedPiece{v_mps, 0.0, accel_time_s, shape});
  } else {
    const double vp = length_m / accel_time_s;
    p.append(SpeedPiece{0.0, vp, accel_time_s, shape});
    p.append(SpeedPiece{vp, 0.0, accel_time_s, shape});
  }
  return p;
}

// ------------------------------------------------------------------------------------------------
// Path geometry
// ------------------------------------------------------------------------------------------------

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
  out.position_m = (1.0 - f) * poses[k].position_m + f * poses[k + 1].position_m;
  out.axis = normalized_or((1.0 - f) * poses[k].axis + f * poses[k + 1].axis, poses[k].axis);
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
                                   double speed_a, double speed_b, bool spraying, double run_m, double run_in_m,
                                   const Eigen::Vector3d& dir_b) {
  if (run_in_m < 0.0) run_in_m = run_m;
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
  if (x_arc > 1e-9) out.push_back(polyline_piece(SegmentKind::Link, {end_a, pa}, speed_a, spraying, -1));
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
  arc.axis0 = end_a.axis;
  arc.axis1 = start_b.axis;
  out.push_back(arc);
  const double run_in = (pb.position_m - start_b.position_m).norm();
  if (run_in <= 1e-9) return out;
  // Run-in: the arc leaves along -d, the next pass starts along dir_b. Wall-following passes are
  // not exactly antiparallel, and a straight run-in would kink where it meets the pass (up to
  // 40 deg on real plans, a step in the joint velocities). A cubic Bezier tangent to both turns
  // the difference over the whole run instead.
  const Eigen::Vector3d db = dir_b.squaredNorm() > 0.0 ? normalized_or(dir_b, -d) : Eigen::Vector3d(-d);
  if ((db + d).norm() < 1e-4) {
    out.push_back(polyline_piece(SegmentKind::Link, {pb, start_b}, speed_b, spraying, -1));
    return out;
  }
  out.push_back(polyline_piece(SegmentKind::Link, tangent_curve(pb, -d, start_b, db), speed_b, spraying, -1));
  return out;
}

CartesianPath region_path(const std::vector<Pass>& passes, double lead_in_m, double lead_out_m, bool spray_on_turns,
                          int first_pass_index, double turn_run_m, double stop_accel_mps2, double turn_speed_mps,
                          double turn_accel_mps2, const std::vector<double>& gap_accel_scale) {
  if (passes.empty()) throw std::invalid_argument("region_path: the region has no passes");
  for (std::size_t i = 0; i < passes.size(); ++i) check_pass(passes[i], i);
  if (!gap_accel_scale.empty() && gap_accel_scale.size() + 1 != passes.size())
    throw std::invalid_argument("region_path: " + std::to_string(gap_accel_scale.size()) +
                                " gap acceleration scales for " + std::to_string(passes.size()) + " passes");
  for (double g : gap_accel_scale)
    if (!(g > 0.0 && g <= 1.0)) throw std::invalid_argument("region_path: gap acceleration scale " + num(g) + " must be in (0, 1]");
  if (!(lead_in_m > 0.0) || !(lead_out_m > 0.0))
    throw std::invalid_argument("region_path: lead-in " + num(lead_in_m) + " m and lead-out " + num(lead_out_m) +
                                " m must be > 0 (start and stop happen off the passes)");
  CartesianPath path;
  const Pass& first = passes.front();
  NozzlePose lead0 = first.waypoints.front();
  lead0.position_m -= lead_in_m * start_direction(first);
  auto v_first = [](const Pass& p) { return p.speed_at(0); };
  auto v_last = [](const Pass& p) { return p.speed_at(p.waypoints.size() - 1); };
  path.append(polyline_piece(SegmentKind::Lead, {lead0, first.waypoints.front()}, v_first(first), false, -1));
  for (std::size_t i = 0; i < passes.size(); ++i) {
    const Pass& p = passes[i];
    PathPiece piece = polyline_piece(SegmentKind::Pass, p.waypoints, v_first(p), true, first_pass_index + static_cast<int>(i));
    piece.speed_out_mps = v_last(p);
    if (!p.speed_profile_mps.empty()) {
      if (p.speed_profile_mps.size() != p.waypoints.size())
        throw std::invalid_argument("pass " + std::to_string(i) + " has " + std::to_string(p.speed_profile_mps.size()) +
                                    " speed profile values for " + std::to_string(p.waypoints.size()) + " waypoints");
      speed_runs(p, piece.run_len_m, piece.run_speed_mps);
      if (piece.run_len_m.size() == 1) piece.run_len_m.clear(), piece.run_speed_mps.clear();  // constant after all
    }
    path.append(std::move(piece));
    if (i + 1 < passes.size()) {
      const Pass& q = passes[i + 1];
      const double gap_scale = gap_accel_scale.empty() ? 1.0 : gap_accel_scale[i];
      const double turn_accel = gap_scale * turn_accel_mps2, stop_accel = gap_scale * stop_accel_mps2;
      const Eigen::Vector3d da = end_direction(p), db = start_direction(q);
      const Eigen::Vector3d gap = q.waypoints.front().position_m - p.waypoints.back().position_m;
      const bool serpentine = da.dot(db) < -0.5 && (gap - gap.dot(da) * da).norm() > 1e-3;
      // The next pass continues the same line further on (the optimal planner switches the spray
      // off over segments that would only overfill): carry on along the line, spray off, no stop.
      const bool continuation = da.dot(db) > 0.99 && gap.dot(da) >= 0.0 && (gap - gap.dot(da) * da).norm() < 1e-3;
      if (continuation) {
        // Tangent to both passes: their end directions may differ by a few degrees.
        PathPiece link = polyline_piece(SegmentKind::Link, tangent_curve(p.waypoints.back(), da, q.waypoints.front(), db),
                                        v_last(p), false, -1);
        link.speed_out_mps = v_first(q);
        link.motion = 4;
        if (link.length_m() > 0.0) path.append(std::move(link));
      } else if (serpentine) {
        // Runs long enough for the change between the pass speed and the arc speed at
        // turn_accel_mps2 (cycloid peak |v1^2 - v0^2| / length): fast passes need metres, not 0.1 m.
        double run_out = turn_run_m, run_in = turn_run_m;
        if (turn_run_m > 0.0 && turn_accel > 0.0) {
          const double vt = turn_arc_speed(0.5 * (gap - gap.dot(da) * da).norm(), v_last(p), v_first(q),
                                           turn_speed_mps, turn_accel);
          if (vt > 0.0) {
            run_out = std::max(run_out, std::abs(v_last(p) * v_last(p) - vt * vt) / turn_accel);
            run_in = std::max(run_in, std::abs(v_first(q) * v_first(q) - vt * vt) / turn_accel);
          }
        }
        for (auto& t : turn_around(p.waypoints.back(), da, q.waypoints.front(), v_last(p), v_first(q), spray_on_turns,
                                   run_out, run_in, db)) {
          if (t.kind == SegmentKind::Turn) t.accel_scale = gap_scale;  // the profile eases the arc speed alike
          path.append(std::move(t));
        }
      } else {
        // Stop and go: the direction changes only where the nozzle stands still.
        const double run = turn_run_m > 0.0 ? turn_run_m : 0.1;
        // Long enough to stop from / start to the pass speeds within the acceleration limit (plain
        // cycloidal stop / start, peak v^2 / s).
        double run_out = run, run_in = run;
        if (stop_accel > 0.0) {
          run_out = std::max(run, v_last(p) * v_last(p) / stop_accel);
          run_in = std::max(run, v_first(q) * v_first(q) / stop_accel);
        }
        NozzlePose a = p.waypoints.back(), b = q.waypoints.front();
        a.position_m += run_out * da;
        b.position_m -= run_in * db;
        PathPiece out = polyline_piece(SegmentKind::Link, {p.waypoints.back(), a}, v_last(p), false, -1);
        out.motion = 1;
        path.append(std::move(out));
        PathPiece mid = polyline_piece(SegmentKind::Link, {a, b}, std::max(v_last(p), v_first(q)), false, -1);
        mid.motion = 2;
        path.append(std::move(mid));
        PathPiece in = polyline_piece(SegmentKind::Link, {b, q.waypoints.front()}, v_first(q), false, -1);
        in.motion = 3;
        path.append(std::move(in));
      }
    }
  }
  const Pass& last = passes.back();
  NozzlePose lead1 = last.waypoints.back();
  lead1.position_m += lead_out_m * end_direction(last);
  path.append(polyline_piece(SegmentKind::Lead, {last.waypoints.back(), lead1}, v_last(last), false, -1));
  return path;
}

CartesianPath timing_region_path(const std::vector<Pass>& passes, double lead_in_m, double lead_out_m,
                                 const TimingConfig& timing, int first_pass_index,
                                 const std::vector<double>& gap_accel_scale) {
  return region_path(passes, lead_in_m, lead_out_m, timing.spray_on_turns, first_pass_index, timing.turn_run_m,
                     timing.nozzle_max_accel_mps2, timing.turn_speed_mps, timing.speed_change_accel_mps2,
                     gap_accel_scale);
}

TimingParams TimingParams::from_config(const TimingConfig& c) {
  TimingParams p;
  p.k1 = c.start_fraction_k1;
  p.k2 = c.end_fraction_k2;
  p.start_length_m = c.start_length_m;
  p.end_length_m = c.end_length_m;
  p.turn_speed_mps = c.turn_speed_mps;
  p.speed_change_accel_mps2 = c.speed_change_accel_mps2;
  return p;
}

SpeedProfile region_profile(const CartesianPath& path, const TimingParams& params) {
  return profile_from_specs(specs_of(path), params);
}

BaselinePath quintic_baseline(const std::vector<Pass>& passes, double max_accel_mps2, double stepover_speed_mps,
                              int first_pass_index) {
  if (passes.empty()) throw std::invalid_argument("quintic_baseline: the region has no passes");
  for (std::size_t i = 0; i < passes.size(); ++i) check_pass(passes[i], i);
  if (!(max_accel_mps2 > 0.0)) throw std::invalid_argument("quintic_baseline: max_accel_mps2 must be > 0");
  if (!(stepover_speed_mps > 0.0)) throw std::invalid_argument("quintic_baseline: stepover_speed_mps must be > 0");
  const double peak = shape_peak_dg(SpeedShape::Quintic);
  BaselinePath out;
  NozzlePose prev_end;
  for (std::size_t i = 0; i < passes.size(); ++i) {
    const Pass& p = passes[i];
    const double v = p.speed_mps, ta = peak * v / max_accel_mps2, ext = 0.5 * v * ta;
    NozzlePose a = p.waypoints.front(), b = p.waypoints.back();
    a.position_m -= ext * start_direction(p);
    b.position_m += ext * end_direction(p);
    if (i > 0) {  // straight step-over, from rest to rest
      out.path.append(polyline_piece(SegmentKind::Link, {prev_end, a}, stepover_speed_mps, false, -1));
      const double len = out.path.pieces().back().length_m();
      double vs = stepover_speed_mps, ts = peak * vs / max_accel_mps2;
      if (len < vs * ts) {  // too short to reach the step-over speed at the acceleration limit
        vs = std::sqrt(len * max_accel_mps2 / peak);
        ts = peak * vs / max_accel_mps2;
      }
      if (len > 0.0) out.profile.append(rest_to_rest(len, vs, ts, SpeedShape::Quintic));
    }
    out.path.append(polyline_piece(SegmentKind::Lead, {a, p.waypoints.front()}, v, false, -1));
    out.path.append(polyline_piece(SegmentKind::Pass, p.waypoints, v, true, first_pass_index + static_cast<int>(i)));
    out.path.append(polyline_piece(SegmentKind::Lead, {p.waypoints.back(), b}, v, false, -1));
    const double len = 2.0 * ext + out.path.pieces()[out.path.pieces().size() - 2].length_m();
    out.profile.append(rest_to_rest(len, v, ta, SpeedShape::Quintic));
    prev_end = b;
  }
  return out;
}

// ------------------------------------------------------------------------------------------------
// Sampling
// ------------------------------------------------------------------------------------------------

namespace {
void check_lengths(const CartesianPath& path, const SpeedProfile& profile) {
  const double lp = path.length_m(), ls = profile.length_m();
  if (std::abs(lp - ls) > 1e-6 * std::max(1.0, lp))
    throw std::invalid_argument("speed profile covers " + num(ls) + " m but the path is " + num(lp) + " m long");
}
// Uniform times over [0, T] with steps <= 1 / rate (no tiny last step).
std::vector<double> time_grid(double duration_s, double rate_hz) {
  if (!(rate_hz > 0.0)) throw std::invalid_argument("rate " + num(rate_hz) + " Hz must be > 0");
  const int n = std::max(1, static_cast<int>(std::ceil(duration_s * rate_hz - 1e-9)));
  std::vector<double> t(static_cast<std::size_t>(n) + 1);
  for (int k = 0; k <= n; ++k) t[static_cast<std::size_t>(k)] = duration_s * k / n;
  return t;
}
}  // namespace

namespace {
// Samples of the profile's time window [t0_s, t1_s] (uniform steps <= 1 / rate, both ends).
CartesianSamples sample_window(const CartesianPath& path, const SpeedProfile& profile, double rate_hz, double t0_s,
                               double t1_s) {
  CartesianSamples out;
  for (double dt : time_grid(std::max(0.0, t1_s - t0_s), rate_hz)) {
    const double t = t0_s + dt;
    const auto st = profile.at(t);
    double local = 0.0;
    const auto i = path.locate(st.s_m, local);
    const auto& piece = path.pieces()[i];
    out.t_s.push_back(t);
    out.s_m.push_back(st.s_m);
    out.nozzle.push_back(piece.pose_at(local));
    out.speed_mps.push_back(st.v_mps);
    out.tangential_accel_mps2.push_back(st.a_mps2);
    out.normal_accel_mps2.push_back(st.v_mps * st.v_mps * piece.curvature_at(local));
    out.spraying.push_back(piece.spraying ? 1 : 0);
    out.pass_index.push_back(piece.pass_index);
    out.kind.push_back(static_cast<char>(piece.kind));
  }
  return out;
}
}  // namespace

CartesianSamples sample_path(const CartesianPath& path, const SpeedProfile& profile, double rate_hz) {
  check_lengths(path, profile);
  return sample_window(path, profile, rate_hz, 0.0, profile.duration_s());
}

std::vector<double> spray_dwells(const std::vector<double>& t, const std::vector<char>& spraying) {
  if (t.size() != spraying.size()) throw std::invalid_argument("spray_dwells: t_s and spraying differ in size");
  std::vector<double> dwell(t.size(), 0.0);
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (!spraying[i]) continue;
    const double lo = i > 0 ? 0.5 * (t[i] - t[i - 1]) : 0.0;
    const double hi = i + 1 < t.size() ? 0.5 * (t[i + 1] - t[i]) : 0.0;
    dwell[i] = lo + hi;
  }
  return dwell;
}

NozzleCheck check_nozzle(const CartesianPath& path, const SpeedProfile& profile, const NozzleLimits& limits,
                         double rate_hz) {
  check_lengths(path, profile);
  NozzleCheck c;
  for (double t : time_grid(profile.duration_s(), rate_hz)) {
    const auto st = profile.at(t);
    const double an = st.v_mps * st.v_mps * path.curvature_at(st.s_m);
    c.max_speed_mps = std::max(c.max_speed_mps, st.v_mps);
    c.max_accel_mps2 = std::max(c.max_accel_mps2, std::hypot(st.a_mps2, an));
  }
  // The peaks of the speed pieces are exact, not sampled.
  for (const auto& p : profile.pieces()) c.max_accel_mps2 = std::max(c.max_accel_mps2, p.peak_accel_mps2());
  c.speed_ratio = c.max_speed_mps / limits.max_speed_mps;
  c.accel_ratio = c.max_accel_mps2 / limits.max_accel_mps2;
  return c;
}

// ------------------------------------------------------------------------------------------------
// Joint space
// ------------------------------------------------------------------------------------------------

double quintic_min_duration(const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, const Eigen::VectorXd& vel_limit,
                            const Eigen::VectorXd& acc_limit) {
  const Eigen::Index n = q0.size();
  if (q1.size() != n || vel_limit.size() != n || acc_limit.size() != n)
    throw std::invalid_argument("quintic_min_duration: q0, q1 and the limits must have the same size");
  const double kv = 1.875, ka = 10.0 / std::sqrt(3.0);  // peaks of s' and s'' of 10t^3-15t^4+6t^5
  double t = 0.0;
  for (Eigen::Index j = 0; j < n; ++j) {
    if (!(vel_limit[j] > 0.0) || !(acc_limit[j] > 0.0))
      throw std::invalid_argument("quintic_min_duration: joint " + std::to_string(j) + " has a non-positive limit");
    const double dq = std::abs(q1[j] - q0[j]);
    t = std::max({t, kv * dq / vel_limit[j], std::sqrt(ka * dq / acc_limit[j])});
  }
  return t;
}

void quintic_joint(const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, double T, double t, Eigen::VectorXd& q,
                   Eigen::VectorXd& qd, Eigen::VectorXd& qdd) {
  const Eigen::VectorXd dq = q1 - q0;
  if (T <= 0.0) {
    q = q1;
    qd = Eigen::VectorXd::Zero(q0.size());
    qdd = Eigen::VectorXd::Zero(q0.size());
    return;
  }
  const double x = std::clamp(t / T, 0.0, 1.0);
  q = q0 + dq * shape_g(SpeedShape::Quintic, x);
  qd = dq * (shape_dg(SpeedShape::Quintic, x) / T);
  qdd = dq * (shape_ddg(SpeedShape::Quintic, x) / (T * T));
}

Eigen::MatrixXd TimedTrajectory::joint_table() const {
  const Eigen::Index n = static_cast<Eigen::Index>(t_s.size());
  const Eigen::Index dof = q.empty() ? 0 : q.front().size();
  Eigen::MatrixXd m(n, 1 + 3 * dof);
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto k = static_cast<std::size_t>(i);
    m(i, 0) = t_s[k];
    m.block(i, 1, 1, dof) = q[k].transpose();
    m.block(i, 1 + dof, 1, dof) = qd[k].transpose();
    m.block(i, 1 + 2 * dof, 1, dof) = qdd[k].transpose();
  }
  return m;
}

std::vector<std::string> TimedTrajectory::joint_table_header() const {
  const std::size_t dof = q.empty() ? 0 : static_cast<std::size_t>(q.front().size());
  std::vector<std::string> h{"t_s"};
  for (const char* p : {"q", "qd", "qdd"})
    for (std::size_t j = 0; j < dof; ++j) h.push_back(std::string(p) + std::to_string(j));
  return h;
}

std::string TimedTrajectory::to_csv() const {
  std::ostringstream o;
  o << std::setprecision(10);
  const auto h = joint_table_header();
  for (std::size_t k = 0; k < h.size(); ++k) o << (k ? "," : "") << h[k];
  o << ",x_m,y_m,z_m,ax,ay,az,spraying,pass_index,region_index,kind\n";
  const Eigen::MatrixXd m = joint_table();
  for (Eigen::Index i = 0; i < m.rows(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    for (Eigen::Index j = 0; j < m.cols(); ++j) o << (j ? "," : "") << m(i, j);
    const auto& p = nozzle[k];
    o << "," << p.position_m.x() << "," << p.position_m.y() << "," << p.position_m.z() << "," << p.axis.x() << ","
      << p.axis.y() << "," << p.axis.z() << "," << int(spraying[k]) << "," << pass_index[k] << "," << region_index[k]
      << "," << int(kind[k]) << "\n";
  }
  return o.str();
}

namespace {

// Velocities and accelerations by 3-point finite differences on a non-uniform grid; the ends are at
// rest (every timed trajectory starts and stops standing still).
// First and second derivatives of q sampled at t (time, or arc length): three-point differences on
// an uneven grid, exact for quadratics; qdd at the ends copies its neighbour's. qd at the ends is 0
// (a trajectory from rest to rest) or, with one_sided_ends, the one-sided difference (a path). At a
// repeated point (step under 1e-9) qd is the one-sided difference and qdd the previous value.
void finite_differences(const std::vector<double>& t, const std::vector<Eigen::VectorXd>& q,
                        std::vector<Eigen::VectorXd>& qd, std::vector<Eigen::VectorXd>& qdd,
                        bool one_sided_ends = false) {
  const std::size_t n = q.size();
  const Eigen::Index dof = n ? q[0].size() : 0;
  qd.assign(n, Eigen::VectorXd::Zero(dof));
  qdd.assign(n, Eigen::VectorXd::Zero(dof));
  for (std::size_t i = 1; i + 1 < n; ++i) {
    const double h1 = t[i] - t[i - 1], h2 = t[i + 1] - t[i];
    if (h1 < 1e-9 || h2 < 1e-9) {
      const std::size_t a = h1 < 1e-9 ? i : i - 1, b = h1 < 1e-9 ? i + 1 : i;
      if (t[b] - t[a] > 1e-9) qd[i] = (q[b] - q[a]) / (t[b] - t[a]);
      qdd[i] = qdd[i - 1];
      continue;
    }
    qd[i] = (-h2 / (h1 * (h1 + h2))) * q[i - 1] + ((h2 - h1) / (h1 * h2)) * q[i] + (h1 / (h2 * (h1 + h2))) * q[i + 1];
    qdd[i] = 2.0 * (q[i - 1] / (h1 * (h1 + h2)) - q[i] / (h1 * h2) + q[i + 1] / (h2 * (h1 + h2)));
  }
  if (one_sided_ends && n >= 2) {
    if (t[1] - t[0] > 1e-9) qd[0] = (q[1] - q[0]) / (t[1] - t[0]);
    if (t[n - 1] - t[n - 2] > 1e-9) qd[n - 1] = (q[n - 1] - q[n - 2]) / (t[n - 1] - t[n - 2]);
  }
  if (n >= 3) {
    qdd[0] = qdd[1];
    qdd[n - 1] = qdd[n - 2];
  }
}

// Task error of the 5-DOF spraying task at q: position (3) and the axis error expressed in the
// nozzle's x/y directions (2); A is the matching 5 x dof task Jacobian.
void task_error(const Robot& robot, const Eigen::VectorXd& q, const NozzlePose& target, Eigen::Matrix<double, 5, 1>& e,
                Eigen::MatrixXd* A) {
  const Eigen::Isometry3d T = robot.fk(q);
  const Eigen::Matrix3d R = T.linear();
  const Eigen::Vector3d zt = target.axis.normalized();
  const Eigen::Vector3d w = R.col(2).cross(zt);  // rotation (small angle) taking z onto the target
  e.head<3>() = target.position_m - T.translation();
  e(3) = R.col(0).dot(w);
  e(4) = R.col(1).dot(w);
  if (R.col(2).dot(zt) < 0.0) e(3) += 2.0;  // far side: push away from the antipodal fixed point
  if (A) {
    const Eigen::MatrixXd J = robot.jacobian(q);
    A->resize(5, q.size());
    A->topRows<3>() = J.topRows<3>();
    A->row(3) = R.col(0).transpose() * J.bottomRows<3>();
    A->row(4) = R.col(1).transpose() * J.bottomRows<3>();
  }
}

}  // namespace

std::vector<Eigen::VectorXd> track_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                              const Eigen::VectorXd& q0, double limit_gain, double* max_error_m,
                                              double* max_error_rad) {
  if (q0.size() != robot.dof()) throw std::invalid_argument("track_joint_path: q0 does not match the robot");
  const Eigen::VectorXd lo = robot.lower_limits(), hi = robot.upper_limits();
  const Eigen::VectorXd range = (hi - lo).cwiseMax(1e-9);
  const int n = robot.dof();
  std::vector<Eigen::VectorXd> out;
  out.reserve(poses.size());
  Eigen::VectorXd q = q0;
  Eigen::Matrix<double, 5, 1> e;
  Eigen::MatrixXd A;
  double emax = 0.0, amax = 0.0;
  // Null-space step away from the limits for a path step ds: the projection of -grad H
  // (H = sum 1 / (4 x (1 - x)), x = normalised joint position) onto the null space of the task, a
  // descent direction of H, times limit_gain * ds, scaled down as a whole (direction kept) so no
  // joint drifts faster than kMaxDrift of its range per metre of path.
  constexpr double kMaxDrift = 0.05, kNearDrift = 0.5, kNearBand = 0.1;
  auto null_step = [&](const NozzlePose& at, double ds) {
    task_error(robot, q, at, e, &A);
    Eigen::VectorXd g(n);
    for (int i = 0; i < n; ++i) {
      const double x = std::clamp((q(i) - lo(i)) / range(i), 1e-4, 1.0 - 1e-4);
      g(i) = (1.0 - 2.0 * x) / (4.0 * x * x * (1.0 - x) * (1.0 - x)) / range(i);
    }
    const Eigen::Matrix<double, 5, 5> M = A * A.transpose() + 1e-12 * Eigen::Matrix<double, 5, 5>::Identity();
    Eigen::VectorXd dq = limit_gain * ds * (g - A.transpose() * M.ldlt().solve(A * g));
    // Near a limit the task itself may push the joint outwards faster than kMaxDrift can pull it
    // back (e.g. the arm telescope at the edge of the reach): the allowed drift grows smoothly up
    // to kNearDrift as the closest joint comes within kNearBand of its range.
    double margin = 1.0;
    for (int i = 0; i < n; ++i) margin = std::min({margin, (q(i) - lo(i)) / range(i), (hi(i) - q(i)) / range(i)});
    const double near = std::clamp(1.0 - margin / kNearBand, 0.0, 1.0);
    const double cap = kMaxDrift + (kNearDrift - kMaxDrift) * near * near;
    const double worst = dq.cwiseQuotient(range).cwiseAbs().maxCoeff() / (cap * ds);
    if (worst > 1.0) dq /= worst;
    q += dq;
    return dq.cwiseQuotient(range).cwiseAbs().maxCoeff();
  };
  auto correct = [&](const NozzlePose& target) {
    for (int it = 0; it < 30; ++it) {
      task_error(robot, q, target, e, &A);
      if (e.head<3>().norm() < 1e-10 && e.tail<2>().norm() < 1e-10) break;
      const Eigen::Matrix<double, 5, 5> M = A * A.transpose() + 1e-10 * Eigen::Matrix<double, 5, 5>::Identity();
      Eigen::VectorXd dq = A.transpose() * M.ldlt().solve(e);
      const double big = dq.cwiseAbs().maxCoeff();
      if (big > 0.2) dq *= 0.2 / big;
      q += dq;
    }
  };
  // Settle the start configuration at rest (free: the transit brings the arm there anyway), so the
  // drift along the path stays small.
  if (!poses.empty() && limit_gain > 0.0) {
    correct(poses.front());
    for (int it = 0; it < 2000; ++it) {
      const double step = null_step(poses.front(), 0.05);
      correct(poses.front());
      if (step < 1e-6) break;
    }
  }
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const double ds = k == 0 ? 0.0 : (poses[k].position_m - poses[k - 1].position_m).norm();
    // Drift proportional to the path step: q(s) depends on the path only, as smooth as the path.
    if (ds > 0.0 && limit_gain > 0.0) null_step(poses[k - 1], ds);
    correct(poses[k]);  // minimal-norm Gauss-Newton onto the exact target
    task_error(robot, q, poses[k], e, nullptr);
    emax = std::max(emax, e.head<3>().norm());
    amax = std::max(amax, std::asin(std::min(1.0, e.tail<2>().norm())));
    out.push_back(q);
  }
  if (max_error_m) *max_error_m = emax;
  if (max_error_rad) *max_error_rad = amax;
  return out;
}

std::vector<double> joint_speed_limits(const Robot& robot, const std::vector<NozzlePose>& poses,
                                       const Eigen::VectorXd& seed, double tangential_accel_mps2, double limit_share) {
  if (!(limit_share > 0.0 && limit_share <= 1.0))
    throw std::invalid_argument("joint_speed_limits: limit_share " + num(limit_share) + " must be in (0, 1]");
  if (!(tangential_accel_mps2 >= 0.0))
    throw std::invalid_argument("joint_speed_limits: tangential_accel_mps2 " + num(tangential_accel_mps2) +
                                " must be >= 0");
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> cap(poses.size(), inf);
  if (poses.size() < 2) return cap;
  const auto q = track_joint_path(robot, poses, seed);
  std::vector<double> s(poses.size(), 0.0);
  for (std::size_t k = 1; k < poses.size(); ++k)
    s[k] = s[k - 1] + (poses[k].position_m - poses[k - 1].position_m).norm();
  std::vector<Eigen::VectorXd> dq, ddq;
  finite_differences(s, q, dq, ddq, true);
  const Eigen::VectorXd vmax = limit_share * robot.velocity_limits(), amax = limit_share * robot.acceleration_limits();
  for (std::size_t k = 0; k < poses.size(); ++k)
    for (int i = 0; i < robot.dof(); ++i) {
      const double d1 = std::abs(dq[k][i]), d2 = std::abs(ddq[k][i]);
      if (d1 > 0.0) cap[k] = std::min(cap[k], vmax[i] / d1);
      const double budget = amax[i] - d1 * tangential_accel_mps2;
      if (budget <= 0.0) cap[k] = 0.0;
      else if (d2 > 0.0) cap[k] = std::min(cap[k], std::sqrt(budget / d2));
    }
  return cap;
}

SpeedCapFn arm_speed_caps(const Robot& robot, const Config& config) {
  const double accel = config.timing.speed_change_accel_mps2, share = 1.0 - config.timing.joint_limit_margin;
  return [&robot, accel, share](const std::vector<NozzlePose>& poses) {
    return joint_speed_limits(robot, poses, robot.neutral(), accel, share);
  };
}

namespace {

// Joint path for timing: solve_path (limits, restarts, no flips) gives the branch and the start
// configuration; the config's tolerances (1 mm) are coarse next to the motion between two samples,
// and a warm-started solver that stops inside them returns a staircase whose finite differences are
// meaningless. So the samples are tracked exactly (minimal-norm steps + smooth null-space limit
// avoidance) from the first solution; if that leaves the limits or misses a target, the
// solve_path result is kept.
std::vector<Eigen::VectorXd> timing_joint_path(const Robot& robot, const std::vector<NozzlePose>& poses,
                                               const Eigen::VectorXd& seed, const RobotConfig& rc, bool* tracked) {
  const JointPath jp = solve_path(robot, poses, seed, rc);
  double em = 0.0, ea = 0.0;
  auto q = track_joint_path(robot, poses, jp.q.front(), 0.02, &em, &ea);
  bool ok = em <= rc.ik_position_tolerance_m && ea <= rc.ik_angle_tolerance_rad;
  for (const auto& x : q) ok = ok && robot.within_limits(x);
  if (tracked) *tracked = ok;
  return ok ? q : jp.q;
}

NozzlePose pose_of(const Eigen::Isometry3d& T) {
  NozzlePose p;
  p.position_m = T.translation();
  p.axis = T.linear().col(2);
  return p;
}

}  // namespace

namespace {
void finish_trajectory(const Robot& robot, TimedTrajectory& tr);

// Arc-length spans [start, end] of a region path tracked in Cartesian space: everything but its
// rest-to-rest pieces (stop-and-go middles, motion 2), where the arm moves in joint space. Shared
// by time_region and RegionJointModel so both track the same stretches.
std::vector<std::pair<double, double>> cartesian_stretches(const CartesianPath& path) {
  std::vector<std::pair<double, double>> out;
  double open = 0.0;
  for (std::size_t i = 0; i < path.pieces().size(); ++i)
    if (path.pieces()[i].motion == 2) {
      out.emplace_back(open, path.piece_start_m(i));
      open = path.piece_start_m(i) + path.pieces()[i].length_m();
    }
  out.emplace_back(open, path.length_m());
  return out;
}

// Exact time spent on spraying pieces (from the profile, not from the samples).
double spraying_time(const CartesianPath& path, const SpeedProfile& prof) {
  double t = 0.0;
  for (std::size_t i = 0; i < path.pieces().size(); ++i)
    if (path.pieces()[i].spraying)
      t += prof.time_at_distance(path.piece_start_m(i) + path.pieces()[i].length_m()) -
           prof.time_at_distance(path.piece_start_m(i));
  return t;
}
}  // namespace

namespace {

void push_sample(TimedTrajectory& tr, double t, const Eigen::VectorXd& q, const NozzlePose& pose, char spray, int pass,
                 int region, char kind) {
  tr.t_s.push_back(t);
  tr.q.push_back(q);
  tr.nozzle.push_back(pose);
  tr.spraying.push_back(spray);
  tr.pass_index.push_back(pass);
  tr.region_index.push_back(region);
  tr.kind.push_back(kind);
}

// Longest lead the swarm considers for a region (and the lead time_plan tracks the region's first
// stretch from, so both see the same joint path): the config's bound, or more where fast end passes
// need it: room for k1, k2 down to 0.5 at the nozzle acceleration limit (start peak
// v^2 (2 - k1) / (k1 s)).
double swarm_max_lead(const std::vector<Pass>& passes, const TimingConfig& timing) {
  double v_end = 0.0;
  if (!passes.empty() && !passes.front().waypoints.empty() && !passes.back().waypoints.empty())
    v_end = std::max(passes.front().speed_at(0), passes.back().speed_at(passes.back().waypoints.size() - 1));
  return std::max(timing.max_lead_length_m, 3.0 * v_end * v_end / timing.nozzle_max_accel_mps2);
}

// One region timed from rest at q_prev: the transit to it, then its Cartesian stretches joined by
// joint-space rest-to-rest moves. Times start at 0 at q_prev (which is not included).
// slot_scale (passes + 1 values in (0, 1]: the lead-in, the gap after each pass but the last, the
// lead-out) scales the accelerations that size that slot's non-spraying motion (lead length,
// stop-and-go runs, the runs and arc of a turn); the passes keep their planned speeds. slot gives
// each sample's slot (-1 on joint moves).
struct RegionTiming {
  TimedTrajectory part;
  std::vector<int> slot;
  bool tracked = true;
};
RegionTiming time_region(const Robot& robot, const std::vector<Pass>& passes, int r, int pass_offset,
                         const Eigen::VectorXd& q_prev_in, const TimingConfig& timing, const RobotConfig& robot_config,
                         const TimingParams& params, const std::vector<double>& slot_scale) {
  const double rate = timing.trajectory_rate_hz;
  const double max_lead = std::max({swarm_max_lead(passes, timing), params.start_length_m, params.end_length_m});
  const double stop_accel = timing.nozzle_max_accel_mps2;  // sizes the leads, as in timing_region_path
  RegionTiming out;
  TimedTrajectory& tr = out.part;
  const std::size_t n = passes.size();
  if (slot_scale.size() != n + 1) throw std::logic_error("time_region: one acceleration scale per lead and gap");
  const std::vector<double> gap_scale(slot_scale.begin() + 1, slot_scale.end() - 1);
  // Leads at least as long as the nozzle acceleration limit needs at this region's end speeds
  // (start peak v^2 (2 - k1) / (k1 s), end peak v^2 (1 + k2) / ((1 - k2) s)): fast passes get
  // longer run-ups than the config's default. The swarm's parameters already satisfy this.
  TimingParams rp = params;
  if (!passes.empty() && passes.front().waypoints.size() >= 2) {
    const Pass& f = passes.front();
    const Pass& l = passes.back();
    const double v0 = f.speed_at(0), v1 = l.speed_at(l.waypoints.size() - 1);
    rp.start_length_m = std::max(rp.start_length_m, v0 * v0 * (2.0 - rp.k1) / (rp.k1 * slot_scale.front() * stop_accel));
    rp.end_length_m =
        std::max(rp.end_length_m, v1 * v1 * (1.0 + rp.k2) / ((1.0 - rp.k2) * slot_scale.back() * stop_accel));
  }
  auto make_path = [&](double lead_in, double lead_out, int first) {
    return timing_region_path(passes, lead_in, lead_out, timing, first, gap_scale);
  };
  const CartesianPath path = make_path(rp.start_length_m, rp.end_length_m, pass_offset);
  const SpeedProfile prof = region_profile(path, rp);
  // Slot of each piece: the number of passes before it.
  std::vector<int> piece_slot;
  int passes_before = 0;
  for (const auto& piece : path.pieces()) {
    piece_slot.push_back(passes_before);
    if (piece.kind == SegmentKind::Pass) ++passes_before;
  }
  // The region is tracked in stretches between its rest-to-rest moves (stop-and-go middles):
  // the nozzle stands still at both ends and sprays nothing there, so a joint quintic at the
  // limits replaces the straight Cartesian move, whose joint accelerations near the slew axis
  // can be many times the limits.
  const auto stretches = cartesian_stretches(path);
  std::vector<std::pair<double, double>> windows;  // their profile time spans, from 0 to the end
  for (std::size_t c = 0; c < stretches.size(); ++c)
    windows.emplace_back(c == 0 ? 0.0 : prof.time_at_distance(stretches[c].first),
                         c + 1 == stretches.size() ? prof.duration_s() : prof.time_at_distance(stretches[c].second));
  Eigen::VectorXd q_prev = q_prev_in;
  double t0 = 0.0;
  for (std::size_t c = 0; c < windows.size(); ++c) {
    const auto [wa, wb] = windows[c];
    const CartesianSamples cs = sample_window(path, prof, rate, wa, wb);
    std::vector<Eigen::VectorXd> jq;
    bool tracked = false;
    if (c == 0) {
      // The joint path starts where the swarm's RegionJointModel starts it (at the longest
      // lead-in) so that both see the same q(s): the unused part of that lead-in is prepended,
      // then dropped. If that longer lead-in leaves the reach, the bound is halved as in
      // tune_timing.
      std::size_t prefix = 0;
      for (double lead = std::max(max_lead, rp.start_length_m);; lead = std::max(0.5 * lead, rp.start_length_m)) {
        std::vector<NozzlePose> poses;
        const double unused = std::max(0.0, lead - rp.start_length_m);
        if (unused > 0.0) {
          const CartesianPath long_path = make_path(lead, lead, 0);
          const int m = static_cast<int>(std::ceil(unused / 0.005));
          for (int k = 0; k < m; ++k) poses.push_back(long_path.pose_at(unused * k / m));
        }
        prefix = poses.size();
        poses.insert(poses.end(), cs.nozzle.begin(), cs.nozzle.end());
        try {
          jq = timing_joint_path(robot, poses, q_prev, robot_config, &tracked);
          break;
        } catch (const std::exception& e) {
          if (unused <= 0.0) throw std::runtime_error("time_plan: region " + std::to_string(r) + ": " + e.what());
        }
      }
      jq.erase(jq.begin(), jq.begin() + static_cast<std::ptrdiff_t>(prefix));
    } else {
      try {
        jq = timing_joint_path(robot, cs.nozzle, q_prev, robot_config, &tracked);
      } catch (const std::exception& e) {
        throw std::runtime_error("time_plan: region " + std::to_string(r) + ", stretch " + std::to_string(c) +
                                 " (after a stop-and-go move): " + e.what());
      }
    }
    out.tracked = out.tracked && tracked;
    // Joint quintic from the previous rest configuration: the transit between regions (c == 0)
    // or the stop-and-go move inside the region.
    const Eigen::VectorXd q_first = jq.front();
    const double T = quintic_min_duration(q_prev, q_first, robot.velocity_limits(), robot.acceleration_limits());
    if (T > 0.0) {
      for (double t : time_grid(T, rate)) {
        if (t == 0.0) continue;
        Eigen::VectorXd q, qd, qdd;
        quintic_joint(q_prev, q_first, T, t, q, qd, qdd);
        push_sample(tr, t0 + t, q, pose_of(robot.fk(q)), 0, -1, c == 0 ? -1 : r, static_cast<char>(SegmentKind::Transit));
        out.slot.push_back(-1);
      }
      t0 += T;
      tr.transit_time_s += T;
    }
    for (std::size_t k = 1; k < cs.t_s.size(); ++k) {
      push_sample(tr, t0 + cs.t_s[k] - wa, jq[k], cs.nozzle[k], cs.spraying[k], cs.pass_index[k], r, cs.kind[k]);
      double local = 0.0;
      out.slot.push_back(piece_slot[path.locate(cs.s_m[k], local)]);
    }
    t0 += wb - wa;
    q_prev = jq.back();
  }
  tr.duration_s = t0;
  tr.spray_time_s = spraying_time(path, prof);
  return out;
}

// Worst |qdd| / limit per slot on the non-spraying Cartesian samples (turns, links, leads) of a
// region timed from rest at q_prev; passes keep their speeds and joint moves are within the limits
// by design. A non-finite value counts as the worst possible.
std::vector<double> off_pass_accel_ratios(const Robot& robot, const RegionTiming& rt, const Eigen::VectorXd& q_prev,
                                          std::size_t slots) {
  const TimedTrajectory& part = rt.part;
  std::vector<double> t{0.0};
  std::vector<Eigen::VectorXd> q{q_prev}, qd, qdd;
  t.insert(t.end(), part.t_s.begin(), part.t_s.end());
  q.insert(q.end(), part.q.begin(), part.q.end());
  finite_differences(t, q, qd, qdd);
  std::vector<double> worst(slots, 0.0);
  for (std::size_t i = 0; i < part.size(); ++i) {
    const auto kind = static_cast<SegmentKind>(part.kind[i]);
    if (kind == SegmentKind::Pass || kind == SegmentKind::Transit || rt.slot[i] < 0) continue;
    double ratio = qdd[i + 1].cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff();
    if (!std::isfinite(ratio)) ratio = std::numeric_limits<double>::max();
    double& w = worst[static_cast<std::size_t>(rt.slot[i])];
    w = std::max(w, ratio);
  }
  return worst;
}

}  // namespace

TimedTrajectory time_plan(const Robot& robot, const std::vector<std::vector<Pass>>& regions, const Eigen::VectorXd& q_start,
                          const TimingConfig& timing, const RobotConfig& robot_config,
                          const std::vector<TimingParams>& params_in) {
  const int dof = robot.dof();
  if (q_start.size() != dof)
    throw std::invalid_argument("time_plan: q_start has " + std::to_string(q_start.size()) + " entries, the robot has " +
                                std::to_string(dof) + " joints");
  for (std::size_t r = 0; r < regions.size(); ++r)
    if (regions[r].empty()) throw std::invalid_argument("time_plan: region " + std::to_string(r) + " has no passes");
  if (params_in.size() > 1 && params_in.size() != regions.size())
    throw std::invalid_argument("time_plan: " + std::to_string(params_in.size()) + " timing parameter sets for " +
                                std::to_string(regions.size()) + " regions (give none, one, or one per region)");
  auto params_of_region = [&](std::size_t r) {
    return params_in.empty() ? TimingParams::from_config(timing) : params_in[params_in.size() == 1 ? 0 : r];
  };
  TimedTrajectory tr;
  push_sample(tr, 0.0, q_start, pose_of(robot.fk(q_start)), 0, -1, -1, static_cast<char>(SegmentKind::Transit));
  double t0 = 0.0;
  Eigen::VectorXd q_prev = q_start;
  int pass_offset = 0;
  for (std::size_t r = 0; r < regions.size(); ++r) {
    // Where the arm's geometry makes the turns, runs or leads break a joint acceleration limit (e.g.
    // near the slew axis, where a nozzle acceleration is a large slew acceleration), the region is
    // re-timed with gentler accelerations there: the joint acceleration scales about linearly with
    // them. Each lead and gap has its own scale, so one awkward stop does not lengthen every run
    // (long leads can leave the reach or swing the arm out). A slot that got worse when eased, or
    // a timing that leaves the reach, goes halfway back to its best scale. At most kAttempts
    // timings; the one with the smallest excess is kept.
    constexpr int kAttempts = 6;
    const std::size_t slots = regions[r].size() + 1;
    std::vector<double> scale(slots, 1.0), best_scale(slots, 1.0),
        best_slot_ratio(slots, std::numeric_limits<double>::infinity());
    double best_ratio = std::numeric_limits<double>::infinity();
    RegionTiming best;
    for (int attempt = 0; attempt < kAttempts; ++attempt) {
      RegionTiming rt;
      try {
        rt = time_region(robot, regions[r], static_cast<int>(r), pass_offset, q_prev, timing, robot_config,
                         params_of_region(r), scale);
      } catch (const std::exception&) {
        if (attempt == 0) throw;
        for (std::size_t k = 0; k < slots; ++k) scale[k] = std::sqrt(scale[k] * best_scale[k]);
        continue;
      }
      const std::vector<double> ratios = off_pass_accel_ratios(robot, rt, q_prev, slots);
      const double ratio = *std::max_element(ratios.begin(), ratios.end());
      if (attempt == 0 || ratio < best_ratio) best_ratio = ratio, best = std::move(rt);
      if (ratio <= 1.0) break;
      for (std::size_t k = 0; k < slots; ++k) {
        const bool improved = ratios[k] < best_slot_ratio[k];
        if (improved) best_slot_ratio[k] = ratios[k], best_scale[k] = scale[k];
        if (ratios[k] <= 1.0 && improved) continue;
        scale[k] = improved ? scale[k] * std::max(0.25, 0.9 / ratios[k]) : std::sqrt(scale[k] * best_scale[k]);
      }
    }
    const TimedTrajectory& part = best.part;
    for (std::size_t k = 0; k < part.size(); ++k)
      push_sample(tr, t0 + part.t_s[k], part.q[k], part.nozzle[k], part.spraying[k], part.pass_index[k],
                  part.region_index[k], part.kind[k]);
    t0 += part.duration_s;
    tr.transit_time_s += part.transit_time_s;
    tr.spray_time_s += part.spray_time_s;
    if (!best.tracked) ++tr.untracked_regions;
    if (!part.q.empty()) q_prev = part.q.back();
    pass_offset += static_cast<int>(regions[r].size());
  }
  tr.duration_s = t0;
  finish_trajectory(robot, tr);
  return tr;
}

namespace {
void finish_trajectory(const Robot& robot, TimedTrajectory& tr) {
  const int dof = robot.dof();
  finite_differences(tr.t_s, tr.q, tr.qd, tr.qdd);
  const Eigen::VectorXd& vl = robot.velocity_limits();
  const Eigen::VectorXd& al = robot.acceleration_limits();
  for (std::size_t i = 0; i < tr.size(); ++i)
    for (int j = 0; j < dof; ++j) {
      const double rv = std::abs(tr.qd[i][j]) / vl[j], ra = std::abs(tr.qdd[i][j]) / al[j];
      if (rv > tr.max_velocity_ratio) { tr.max_velocity_ratio = rv; tr.worst_velocity_joint = j; }
      if (ra > tr.max_acceleration_ratio) { tr.max_acceleration_ratio = ra; tr.worst_acceleration_joint = j; }
      tr.max_position_violation_rad = std::max({tr.max_position_violation_rad, robot.lower_limits()[j] - tr.q[i][j],
                                                tr.q[i][j] - robot.upper_limits()[j]});
    }
}
}  // namespace

TimedTrajectory time_path(const Robot& robot, const CartesianPath& path, const SpeedProfile& profile,
                          const Eigen::VectorXd& seed, double rate_hz, const RobotConfig& robot_config) {
  const CartesianSamples cs = sample_path(path, profile, rate_hz);
  bool tracked = false;
  const auto jq = timing_joint_path(robot, cs.nozzle, seed, robot_config, &tracked);
  TimedTrajectory tr;
  tr.t_s = cs.t_s;
  tr.q = jq;
  tr.nozzle = cs.nozzle;
  tr.spraying = cs.spraying;
  tr.pass_index = cs.pass_index;
  tr.region_index.assign(cs.t_s.size(), 0);
  tr.kind = cs.kind;
  tr.duration_s = profile.duration_s();
  tr.untracked_regions = tracked ? 0 : 1;
  tr.spray_time_s = spraying_time(path, profile);
  finish_trajectory(robot, tr);
  return tr;
}

// ------------------------------------------------------------------------------------------------
// RegionJointModel
// ------------------------------------------------------------------------------------------------

RegionJointModel::RegionJointModel(const Robot& robot, const std::vector<Pass>& passes, double max_lead_m,
                                   const TimingConfig& timing, const Eigen::VectorXd& seed,
                                   const RobotConfig& robot_config, double step_m)
    : path_(timing_region_path(passes, max_lead_m, max_lead_m, timing)),
      max_lead_m_(max_lead_m),
      vel_limit_(robot.velocity_limits()),
      acc_limit_(robot.acceleration_limits()) {
  if (!(step_m > 0.0)) throw std::invalid_argument("RegionJointModel: step_m must be > 0");
  const auto spans = cartesian_stretches(path_);  // time_region's windows, in arc length
  Eigen::VectorXd q_prev = seed;
  for (std::size_t c = 0; c < spans.size(); ++c) {
    const auto [s0, s1] = spans[c];
    const int n = std::max(2, static_cast<int>(std::ceil((s1 - s0) / step_m)));
    Stretch st;
    std::vector<NozzlePose> poses;
    for (int k = 0; k <= n; ++k) {
      st.s.push_back(s0 + (s1 - s0) * k / n);
      poses.push_back(path_.pose_at(st.s.back()));
    }
    bool tracked = false;
    st.q = timing_joint_path(robot, poses, q_prev, robot_config, &tracked);
    tracked_ = tracked_ && tracked;
    finite_differences(st.s, st.q, st.dq, st.ddq, true);
    if (c > 0) move_s_.push_back(quintic_min_duration(q_prev, st.q.front(), vel_limit_, acc_limit_));
    q_prev = st.q.back();
    stretches_.push_back(std::move(st));
  }
}

int RegionJointModel::stretch_at(double s) const {
  // Last stretch starting at or before s (the swarm calls this for every sample of every particle).
  const auto it = std::upper_bound(stretches_.begin(), stretches_.end(), s,
                                   [](double x, const Stretch& st) { return x < st.s.front(); });
  const std::size_t k = it == stretches_.begin() ? 0 : static_cast<std::size_t>(it - stretches_.begin()) - 1;
  return s > stretches_[k].s.back() && k + 1 < stretches_.size() ? -1 : static_cast<int>(k);
}

void RegionJointModel::interpolate(const Stretch& st, double s, Eigen::VectorXd& q, Eigen::VectorXd& dq,
                                   Eigen::VectorXd& ddq) const {
  const double s0 = st.s.front(), s1 = st.s.back();
  const double x = std::clamp((s - s0) / (s1 - s0), 0.0, 1.0) * (static_cast<double>(st.s.size()) - 1.0);
  const std::size_t k = std::min(static_cast<std::size_t>(x), st.s.size() - 2);
  const double f = x - static_cast<double>(k);
  q = (1.0 - f) * st.q[k] + f * st.q[k + 1];
  dq = (1.0 - f) * st.dq[k] + f * st.dq[k + 1];
  ddq = (1.0 - f) * st.ddq[k] + f * st.ddq[k + 1];
}

RegionJointModel::Evaluation RegionJointModel::evaluate(const TimingParams& params, const NozzleLimits& limits,
                                                        double rate_hz) const {
  if (params.start_length_m > max_lead_m_ + 1e-12 || params.end_length_m > max_lead_m_ + 1e-12)
    throw std::invalid_argument("RegionJointModel: lead lengths above the modelled " + num(max_lead_m_) + " m");
  auto specs = specs_of(path_);
  specs.front().length_m = params.start_length_m;
  specs.back().length_m = params.end_length_m;
  const SpeedProfile prof = profile_from_specs(specs, params);
  const double offset = max_lead_m_ - params.start_length_m;
  Evaluation ev;
  // The joint moves replace the profile's straight rest-to-rest pieces.
  ev.duration_s = prof.duration_s();
  for (std::size_t k = 0; k + 1 < stretches_.size(); ++k)
    ev.duration_s += move_s_[k] - (prof.time_at_distance(stretches_[k + 1].s.front() - offset) -
                                   prof.time_at_distance(stretches_[k].s.back() - offset));
  // Pieces the parameters shape: the leads, and the turn arcs with their runs.
  auto tuned_at = [&](double s) {
    double local = 0.0;
    const PathPiece& piece = path_.pieces()[path_.locate(s, local)];
    return piece.kind == SegmentKind::Lead || piece.kind == SegmentKind::Turn ||
           (piece.kind == SegmentKind::Link && piece.motion == 0);
  };
  auto update = [](NozzleCheck& c, double v, double a) {
    c.max_speed_mps = std::max(c.max_speed_mps, v);
    c.max_accel_mps2 = std::max(c.max_accel_mps2, a);
  };
  Eigen::VectorXd q, dq, ddq;
  for (double t : time_grid(prof.duration_s(), rate_hz)) {
    const auto st = prof.at(t);
    const double s = offset + st.s_m;
    const int k = stretch_at(s);
    if (k < 0) continue;  // joint move: within the limits by construction
    interpolate(stretches_[static_cast<std::size_t>(k)], s, q, dq, ddq);
    const Eigen::VectorXd qd = dq * st.v_mps;
    const Eigen::VectorXd qdd = ddq * (st.v_mps * st.v_mps) + dq * st.a_mps2;
    const double rv = qd.cwiseAbs().cwiseQuotient(vel_limit_).maxCoeff();
    const double ra = qdd.cwiseAbs().cwiseQuotient(acc_limit_).maxCoeff();
    const double accel = std::hypot(st.a_mps2, st.v_mps * st.v_mps * path_.curvature_at(s));
    ev.velocity_ratio = std::max(ev.velocity_ratio, rv);
    ev.acceleration_ratio = std::max(ev.acceleration_ratio, ra);
    update(ev.nozzle, st.v_mps, accel);
    if (tuned_at(s)) {
      ev.tuned_velocity_ratio = std::max(ev.tuned_velocity_ratio, rv);
      ev.tuned_acceleration_ratio = std::max(ev.tuned_acceleration_ratio, ra);
      update(ev.tuned_nozzle, st.v_mps, accel);
    }
  }
  // Exact peaks of the profile's speed changes (the sampling may step over them).
  double t0 = 0.0;
  for (const auto& p : prof.pieces()) {
    update(ev.nozzle, 0.0, p.peak_accel_mps2());
    if (tuned_at(offset + prof.at(t0 + 0.5 * p.duration_s).s_m)) update(ev.tuned_nozzle, 0.0, p.peak_accel_mps2());
    t0 += p.duration_s;
  }
  for (NozzleCheck* c : {&ev.nozzle, &ev.tuned_nozzle}) {
    c->speed_ratio = c->max_speed_mps / limits.max_speed_mps;
    c->accel_ratio = c->max_accel_mps2 / limits.max_accel_mps2;
  }
  interpolate(stretches_.front(), offset, q, dq, ddq);
  ev.q_first = q;
  interpolate(stretches_.back(), offset + prof.length_m(), q, dq, ddq);
  ev.q_last = q;
  return ev;
}

// ------------------------------------------------------------------------------------------------
// AIWCPSO
// ------------------------------------------------------------------------------------------------

PsoOptions PsoOptions::from_config(const TimingConfig& c) {
  PsoOptions o;
  o.particles = c.pso_particles;
  o.iterations = c.pso_iterations;
  o.seed = c.pso_seed;
  o.a = c.pso_a;
  o.b = c.pso_b;
  o.w_min = c.pso_w_min;
  o.w_max = c.pso_w_max;
  return o;
}

PsoResult pso_minimize(const std::function<double(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& lower,
                       const Eigen::VectorXd& upper, const PsoOptions& o, const std::vector<Eigen::VectorXd>& initial) {
  const Eigen::Index D = lower.size();
  if (D == 0 || upper.size() != D) throw std::invalid_argument("pso_minimize: lower and upper must be non-empty and of equal size");
  if ((upper.array() < lower.array()).any()) throw std::invalid_argument("pso_minimize: upper bound below lower bound");
  if (o.particles < 1 || o.iterations < 0) throw std::invalid_argument("pso_minimize: particles must be >= 1, iterations >= 0");
  const int N = o.particles;
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const Eigen::VectorXd range = upper - lower;
  const Eigen::VectorXd vmax = 0.5 * range;  // velocity clamp: half the box per step
  std::vector<Eigen::VectorXd> x(N), v(N), pb(N);
  std::vector<double> pf(N);
  PsoResult res;
  auto eval = [&](const Eigen::VectorXd& p) {
    ++res.evaluations;
    const double y = f(p);
    return std::isnan(y) ? std::numeric_limits<double>::infinity() : y;
  };
  for (int i = 0; i < N; ++i) {
    x[i].resize(D);
    v[i].resize(D);
    for (Eigen::Index d = 0; d < D; ++d) x[i][d] = lower[d] + U(rng) * range[d];
    for (Eigen::Index d = 0; d < D; ++d) v[i][d] = (2.0 * U(rng) - 1.0) * 0.1 * range[d];
    if (static_cast<std::size_t>(i) < initial.size()) {
      if (initial[i].size() != D) throw std::invalid_argument("pso_minimize: initial particle of the wrong size");
      x[i] = initial[i].cwiseMax(lower).cwiseMin(upper);
    }
    pb[i] = x[i];
    pf[i] = eval(x[i]);
  }
  int g = static_cast<int>(std::min_element(pf.begin(), pf.end()) - pf.begin());
  res.best_history.push_back(pf[g]);
  double bs = 1.0;  // every personal best is new after the initial evaluation
  for (int it = 0; it < o.iterations; ++it) {
    const double w = (o.w_max - o.w_min) * bs + o.w_min;
    const double c1 = o.a * bs + o.b, c2 = o.a * (1.0 - bs) + o.b;
    int improved = 0;
    for (int i = 0; i < N; ++i) {
      for (Eigen::Index d = 0; d < D; ++d) {
        const double r1 = U(rng), r2 = U(rng);
        double vd = w * v[i][d] + c1 * r1 * (pb[i][d] - x[i][d]) + c2 * r2 * (pb[g][d] - x[i][d]);
        vd = std::clamp(vd, -vmax[d], vmax[d]);
        double xd = x[i][d] + vd;
        if (xd < lower[d] || xd > upper[d]) {  // stop at the wall
          xd = std::clamp(xd, lower[d], upper[d]);
          vd = 0.0;
        }
        v[i][d] = vd;
        x[i][d] = xd;
      }
    }
    for (int i = 0; i < N; ++i) {
      const double y = eval(x[i]);
      if (y < pf[i]) {
        pf[i] = y;
        pb[i] = x[i];
        ++improved;
      }
    }
    g = static_cast<int>(std::min_element(pf.begin(), pf.end()) - pf.begin());
    bs = static_cast<double>(improved) / N;
    res.best_history.push_back(pf[g]);
    res.success_history.push_back(bs);
  }
  res.best_x = pb[g];
  res.best_f = pf[g];
  return res;
}

// ------------------------------------------------------------------------------------------------
// Tuning
// ------------------------------------------------------------------------------------------------

namespace {

TimingParams params_of(const Eigen::VectorXd& x, const TimingConfig& c) {
  TimingParams p = TimingParams::from_config(c);
  p.k1 = x[0];
  p.k2 = x[1];
  p.start_length_m = x[2];
  p.end_length_m = x[3];
  p.turn_speed_mps = x[4];
  p.turn_accel_mps2 = x[5];
  return p;
}

}  // namespace

TimingTuning tune_timing(const Robot* robot, const std::vector<std::vector<Pass>>& regions, const Eigen::VectorXd& q_start,
                         const TimingConfig& timing, const RobotConfig& robot_config) {
  if (regions.empty()) throw std::invalid_argument("tune_timing: no regions");
  if (robot && q_start.size() != robot->dof()) throw std::invalid_argument("tune_timing: q_start does not match the robot");
  const NozzleLimits limits{timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2};
  // The swarm keeps a margin on the joint limits: its arc-length model and the final sampled
  // trajectory differ slightly (start configuration, discretisation).
  const double jm = 1.0 - timing.joint_limit_margin;
  const TimingParams p0 = TimingParams::from_config(timing);
  TimingTuning out;
  out.initial_feasible = true;
  double initial = 0.0;
  Eigen::VectorXd q_prev = q_start;
  // Regions one after the other: a region's timing changes the next one only through the
  // configuration it ends in (the transit), so each gets its own particle.
  for (std::size_t r = 0; r < regions.size(); ++r) {
    if (regions[r].empty()) throw std::invalid_argument("tune_timing: region " + std::to_string(r) + " has no passes");
    double max_lead = swarm_max_lead(regions[r], timing);
    std::optional<RegionJointModel> model;
    if (robot) {
      // The longest lead-ins / lead-outs may leave the reach: halve the bound until the region's
      // joint path exists (time_plan does the same).
      for (;;) {
        try {
          model.emplace(*robot, regions[r], max_lead, timing, q_prev, robot_config);
          break;
        } catch (const std::exception& e) {
          if (max_lead <= 0.05)
            throw std::runtime_error("tune_timing: region " + std::to_string(r) + " (with " + num(max_lead) +
                                     " m leads): " + e.what());
          max_lead = std::max(0.05, 0.5 * max_lead);
        }
      }
    }
    const double min_lead = std::min(0.02, max_lead);
    // Execution time of the region plus the transit to it; infeasible -> penalty above any time.
    auto cost = [&](const TimingParams& p, Eigen::VectorXd* q_last) {
      double time = 0.0, worst = 0.0;
      if (model) {
        const auto ev = model->evaluate(p, limits);
        time = ev.duration_s + quintic_min_duration(q_prev, ev.q_first, robot->velocity_limits(),
                                                    robot->acceleration_limits());
        // Only what the parameters shape (see Evaluation): an excess elsewhere would make every
        // particle infeasible alike; plan_for_arm and time_plan deal with it.
        worst = std::max({ev.tuned_velocity_ratio / jm, ev.tuned_acceleration_ratio / jm,
                          ev.tuned_nozzle.speed_ratio, ev.tuned_nozzle.accel_ratio});
        if (q_last) *q_last = ev.q_last;
      } else {
        const CartesianPath path = timing_region_path(regions[r], p.start_length_m, p.end_length_m, timing);
        const SpeedProfile prof = region_profile(path, p);
        const auto c = check_nozzle(path, prof, limits, 100.0);
        time = prof.duration_s();
        worst = std::max(c.speed_ratio, c.accel_ratio);
      }
      return worst <= 1.0 ? time : 1e6 * worst;
    };
    TimingParams p0_region = p0;
    p0_region.start_length_m = std::clamp(p0.start_length_m, min_lead, max_lead);
    p0_region.end_length_m = std::clamp(p0.end_length_m, min_lead, max_lead);
    const double initial_region = cost(p0_region, nullptr);
    out.initial_feasible = out.initial_feasible && initial_region < 1e6;
    initial += initial_region;
    double vmin_pass = std::numeric_limits<double>::infinity(), vsum = 0.0;
    for (const auto& p : regions[r]) {
      vmin_pass = std::min(vmin_pass, p.speed_mps);
      vsum += p.speed_mps;
    }
    const double turn_accel0 = p0.turn_accel_mps2 > 0.0 ? p0.turn_accel_mps2 : p0.speed_change_accel_mps2;
    Eigen::VectorXd lo(6), hi(6), x0(6);
    lo << 0.05, 0.0, min_lead, min_lead, std::min(0.02, vmin_pass), std::min(0.1, turn_accel0);
    hi << 1.0, 0.95, max_lead, max_lead, timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2;
    x0 << p0.k1, p0.k2, p0.start_length_m, p0.end_length_m,
        p0.turn_speed_mps > 0.0 ? p0.turn_speed_mps : vsum / static_cast<double>(regions[r].size()), turn_accel0;
    PsoOptions opt = PsoOptions::from_config(timing);
    opt.seed += r;
    out.pso.push_back(pso_minimize([&](const Eigen::VectorXd& x) { return cost(params_of(x, timing), nullptr); },
                                   lo, hi, opt, {x0}));
    // No feasible particle: the config's parameters, which time_plan eases where the arm needs it.
    out.feasible.push_back(out.pso.back().best_f < 1e6);
    out.params.push_back(out.feasible.back() ? params_of(out.pso.back().best_x, timing) : p0);
    out.duration_s += out.feasible.back() ? out.pso.back().best_f : initial_region;
    if (model) cost(out.feasible.back() ? out.params.back() : p0_region, &q_prev);
  }
  out.initial_duration_s = out.initial_feasible ? initial : std::numeric_limits<double>::infinity();
  return out;
}

}  // namespace shotcrete
