// Speed pieces and profiles: the shape functions of a speed change, the paper's start / end
// profiles and rest-to-rest moves.
#include "shotcrete/timing/speed_profile.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <stdexcept>

#include "detail.hpp"

namespace shotcrete {
namespace timing_detail {

std::string num(double v) {
  std::ostringstream o;
  o << std::setprecision(6) << v;
  return o.str();
}

// Shape function g(tau) of a speed change and its derivatives.
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
double shape_peak_dg(SpeedShape s) { return s == SpeedShape::Cycloid ? 2.0 : 1.875; }

}  // namespace timing_detail

using namespace timing_detail;

namespace {
// Integral of g: the distance covered, as a share of (v1 - v0) T.
double shape_G(SpeedShape s, double t) {
  if (s == SpeedShape::Cycloid) return 0.5 * t * t + (std::cos(kTwoPi * t) - 1.0) / (kTwoPi * kTwoPi);
  return t * t * t * t * (2.5 + t * (-3.0 + t));
}
}  // namespace

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

}  // namespace shotcrete
