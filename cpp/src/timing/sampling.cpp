// Sampling of a timed path: uniform time grids, samples with their piece data, spray dwells and
// the nozzle limit check.
#include "shotcrete/timing/sampling.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "detail.hpp"

namespace shotcrete {
namespace timing_detail {

// Uniform times over [0, T] with steps <= 1 / rate (no tiny last step).
std::vector<double> time_grid(double duration_s, double rate_hz) {
  if (!(rate_hz > 0.0)) throw std::invalid_argument("rate " + num(rate_hz) + " Hz must be > 0");
  const int n = std::max(1, static_cast<int>(std::ceil(duration_s * rate_hz - 1e-9)));
  std::vector<double> t(static_cast<std::size_t>(n) + 1);
  for (int k = 0; k <= n; ++k) t[static_cast<std::size_t>(k)] = duration_s * k / n;
  return t;
}

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

}  // namespace timing_detail

using namespace timing_detail;

namespace {
void check_lengths(const CartesianPath& path, const SpeedProfile& profile) {
  const double lp = path.length_m(), ls = profile.length_m();
  if (std::abs(lp - ls) > 1e-6 * std::max(1.0, lp))
    throw std::invalid_argument("speed profile covers " + num(ls) + " m but the path is " + num(lp) + " m long");
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

}  // namespace shotcrete
