// Speed profile of a region path: the paper's start and end on the leads, the planned pass speeds,
// cycloidal speed changes on the turns and their runs, stop-and-go from rest to rest.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "detail.hpp"
#include "shotcrete/timing/region_path.hpp"

namespace shotcrete {
namespace timing_detail {

double turn_arc_speed(double radius_m, double v_in, double v_out, double turn_speed_mps, double accel_mps2) {
  const double cap = std::sqrt(accel_mps2 * radius_m);
  if (turn_speed_mps > 0.0) return std::min(turn_speed_mps, cap);
  return std::max(v_in, v_out) > cap ? cap : 0.0;
}

std::vector<PieceSpec> specs_of(const CartesianPath& path) {
  std::vector<PieceSpec> out;
  for (const auto& p : path.pieces())
    out.push_back(
        {p.kind, p.length_m(), p.speed_mps, p.speed_out_mps, p.run_len_m, p.run_speed_mps, p.motion, p.accel_scale});
  return out;
}

}  // namespace timing_detail

using namespace timing_detail;

namespace {

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

// Cycloidal change v0 -> v1 over a piece of length_m.
SpeedPiece change_over(double v0, double v1, double length_m) {
  return SpeedPiece{v0, v1, length_m / (0.5 * (v0 + v1)), SpeedShape::Cycloid};
}

// Duration [s] of turn j (its runs, if any, and the arc) at arc speed u, as append_turn_run and
// append_turn_arc profile it: every change is a cycloid over its piece at the mean speed.
double turn_duration_s(const std::vector<PieceSpec>& specs, std::size_t j, double u) {
  const auto& t = specs[j];
  const bool run_before = specs[j - 1].kind == SegmentKind::Link, run_after = specs[j + 1].kind == SegmentKind::Link;
  const double v0 = run_before ? u : t.v_in, v1 = run_after ? u : t.v_out, half = 0.5 * t.length_m;
  double d = half / (0.5 * (v0 + u)) + half / (0.5 * (u + v1));
  if (run_before) d += specs[j - 1].length_m / (0.5 * (specs[j - 1].v_in + u));
  if (run_after) d += specs[j + 1].length_m / (0.5 * (u + specs[j + 1].v_in));
  return d;
}

// Arc speed of turn j lowered from v so that the turn lasts min_s (the pump's shortest off spell:
// a shorter turn is sprayed through), no lower than its speed changes at accel_mps2 allow
// (|v_pass^2 - u^2| / length of the piece they change over). A turn that cannot last min_s within
// that keeps v: slowing it would cost time and still be sprayed through.
double turn_speed_for_duration(const std::vector<PieceSpec>& specs, std::size_t j, double v, double min_s,
                               double accel_mps2) {
  if (turn_duration_s(specs, j, v) >= min_s) return v;
  const auto& t = specs[j];
  const bool run_before = specs[j - 1].kind == SegmentKind::Link, run_after = specs[j + 1].kind == SegmentKind::Link;
  auto floor_of = [&](double v_pass, double length_m) {
    return std::sqrt(std::max(0.0, v_pass * v_pass - accel_mps2 * length_m));
  };
  double lo = 1e-3;
  lo = std::max(lo, run_before ? floor_of(specs[j - 1].v_in, specs[j - 1].length_m) : floor_of(t.v_in, 0.5 * t.length_m));
  lo = std::max(lo, run_after ? floor_of(specs[j + 1].v_in, specs[j + 1].length_m) : floor_of(t.v_out, 0.5 * t.length_m));
  if (lo >= v || turn_duration_s(specs, j, lo) < min_s) return v;
  return speed_lasting([&](double u) { return turn_duration_s(specs, j, u); }, lo, v, min_s);
}

// Speed on turn arc j: the turn speed (or the pass speeds when it is 0), capped so that the
// centripetal acceleration v^2 / r stays at the params' turn acceleration (scaled by the arc's
// accel_scale); 0 = no own turn speed (the arc changes from one pass speed to the next).
double turn_speed_of(const std::vector<PieceSpec>& specs, std::size_t j, const TimingParams& params) {
  const double turn_accel = params.turn_accel_mps2 > 0.0 ? params.turn_accel_mps2 : params.speed_change_accel_mps2;
  const auto& t = specs[j];
  const double v = turn_arc_speed(t.length_m / kPi, t.v_in, t.v_out, params.turn_speed_mps, t.accel_scale * turn_accel);
  // An eased gap (accel_scale < 1, time_region_within_limits) whose arc would run at the pass
  // speeds under the cap: slow the arc too, so its centripetal part eases with the scale.
  if (!(v > 0.0) && t.accel_scale < 1.0) return std::sqrt(t.accel_scale) * std::max(t.v_in, t.v_out);
  // Slowed to last the pump's off spell; an eased turn (accel_scale < 1) sqrt(scale) slower than
  // that still (pinned at min_s, its easing would not ease it), never faster than its eased cap.
  const double v1 = turn_arc_speed(t.length_m / kPi, t.v_in, t.v_out, params.turn_speed_mps, turn_accel);
  if (v > 0.0 && v1 > 0.0 && params.min_turn_s > 0.0) {
    const double u = turn_speed_for_duration(specs, j, v1, params.min_turn_s, turn_accel);
    if (u < v1) return std::min(v, std::sqrt(t.accel_scale) * u);
  }
  return v;
}
bool turn_with_own_speed(const std::vector<PieceSpec>& specs, std::size_t j, const TimingParams& params) {
  return specs[j].kind == SegmentKind::Turn && turn_speed_of(specs, j, params) > 0.0;
}

// A piece with its own motion (stop-and-go runs and middles, spray-off gaps).
void append_motion_piece(SpeedProfile& prof, const PieceSpec& s, const TimingParams& params) {
  switch (s.motion) {
    case PieceMotion::StartFromRest:
    case PieceMotion::StopAtEnd:
      // Stop-and-go runs: plain cycloidal start / stop (no cruise). The spray is off and the arm
      // only leaves the pass line there, so a cruise (the paper's k1 / k2, which shape the lead-in
      // and lead-out) would take it up to 3x further out at the pass speed.
      prof.append(s.motion == PieceMotion::StartFromRest ? cycloid_start(s.length_m, s.v_in, 1.0)
                                                         : cycloid_end(s.length_m, s.v_in, 0.0));
      break;
    case PieceMotion::SprayOffGap:  // on the same line: change smoothly from one pass speed to the next
      prof.append(change_over(s.v_in, s.v_out, s.length_m));
      break;
    case PieceMotion::RestToRest: {
      const double v = params.turn_speed_mps > 0.0 ? params.turn_speed_mps : s.v_in;
      if (s.length_m > 0.0) prof.append(rest_to_rest(s.length_m, v, 2.0 * v / params.speed_change_accel_mps2, SpeedShape::Cycloid));
      break;
    }
    case PieceMotion::ByKind:
      break;
    case PieceMotion::Creep:
      throw std::logic_error("append_motion_piece: a creep is timed with its neighbours (append_creep)");
  }
}

// Tight turn middle i (region_path): rest to rest along its line, lasting what the stop before
// and the start after leave of the pump's off spell (min_turn_s), and no shorter than its peak
// acceleration allows at the turn acceleration (eased by its scale): rest_to_rest's short move is
// two cycloidal halves of T / 2, 0 -> 2 length / T and back, peaking at 8 length / T^2.
void append_creep(SpeedProfile& prof, const std::vector<PieceSpec>& specs, std::size_t i, const TimingParams& params) {
  const auto& s = specs[i];
  if (!(s.length_m > 0.0)) return;
  auto rest_time = [&](const PieceSpec& r) {  // a cycloidal stop or start over r: 2 length / v
    return (r.motion == PieceMotion::StopAtEnd || r.motion == PieceMotion::StartFromRest) && r.v_in > 0.0
               ? 2.0 * r.length_m / r.v_in
               : 0.0;
  };
  const double accel = s.accel_scale * (params.turn_accel_mps2 > 0.0 ? params.turn_accel_mps2 : params.speed_change_accel_mps2);
  double T = std::sqrt(8.0 * s.length_m / accel);
  T = std::max(T, params.min_turn_s - rest_time(specs[i - 1]) - rest_time(specs[i + 1]));
  // Short-move branch of rest_to_rest: peak speed 2 length / T, accelerating over T / 2.
  prof.append(rest_to_rest(s.length_m, 4.0 * s.length_m / T, 0.5 * T, SpeedShape::Cycloid));
}

// Run-out before / run-in after turn arc i +- 1: the speed changes to / from the turn speed here.
void append_turn_run(SpeedProfile& prof, const std::vector<PieceSpec>& specs, std::size_t i, const TimingParams& params) {
  const auto& s = specs[i];
  const bool before = turn_with_own_speed(specs, i + 1, params);
  const double vt = before ? turn_speed_of(specs, i + 1, params) : turn_speed_of(specs, i - 1, params);
  const double va = before ? s.v_in : vt, vb = before ? vt : s.v_in;
  prof.append(change_over(va, vb, s.length_m));
}

void append_turn_arc(SpeedProfile& prof, const std::vector<PieceSpec>& specs, std::size_t i, const TimingParams& params) {
  const auto& s = specs[i];
  const double vt = turn_speed_of(specs, i, params);
  const bool run_before = specs[i - 1].kind == SegmentKind::Link, run_after = specs[i + 1].kind == SegmentKind::Link;
  if (!(vt > 0.0)) {
    prof.append(change_over(s.v_in, s.v_out, s.length_m));
    return;
  }
  // Entry / exit speeds: the turn speed where a run line already changed it, else the pass
  // speed; the rest of the change happens on the arc halves (constant when nothing is left).
  const double v0 = run_before ? vt : s.v_in, v1 = run_after ? vt : s.v_out;
  const double half = 0.5 * s.length_m;
  prof.append(change_over(v0, vt, half));
  prof.append(change_over(vt, v1, half));
}

void check_profile_input(const std::vector<PieceSpec>& specs, const TimingParams& params) {
  if (specs.size() < 3 || specs.front().kind != SegmentKind::Lead || specs.back().kind != SegmentKind::Lead)
    throw std::invalid_argument("region_profile: the path must start with a lead-in and end with a lead-out");
  if (!(params.k1 > 0.0 && params.k1 <= 1.0)) throw std::invalid_argument("k1 = " + num(params.k1) + " must be in (0, 1]");
  if (!(params.k2 >= 0.0 && params.k2 < 1.0)) throw std::invalid_argument("k2 = " + num(params.k2) + " must be in [0, 1)");
}

}  // namespace

namespace timing_detail {

SpeedProfile profile_from_specs(const std::vector<PieceSpec>& specs, const TimingParams& params) {
  check_profile_input(specs, params);
  SpeedProfile prof;
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const auto& s = specs[i];
    if (i == 0) {
      prof.append(cycloid_start(s.length_m, s.v_in, params.k1));
    } else if (i + 1 == specs.size()) {
      prof.append(cycloid_end(s.length_m, s.v_in, params.k2));
    } else if (s.motion == PieceMotion::Creep) {
      append_creep(prof, specs, i, params);
    } else if (s.motion != PieceMotion::ByKind) {
      append_motion_piece(prof, s, params);
    } else if (s.kind == SegmentKind::Link &&
               (turn_with_own_speed(specs, i + 1, params) || turn_with_own_speed(specs, i - 1, params))) {
      append_turn_run(prof, specs, i, params);
    } else if (s.kind == SegmentKind::Turn) {
      append_turn_arc(prof, specs, i, params);
    } else if (!s.run_len_m.empty()) {
      append_runs(prof, s.run_len_m, s.run_speed_mps, params.speed_change_accel_mps2);
    } else {
      prof.append(SpeedPiece{s.v_in, s.v_in, s.length_m / s.v_in, SpeedShape::Cycloid});
    }
  }
  return prof;
}

}  // namespace timing_detail

TimingParams TimingParams::from_config(const TimingConfig& c) {
  TimingParams p;
  p.k1 = c.start_fraction_k1;
  p.k2 = c.end_fraction_k2;
  p.start_length_m = c.start_length_m;
  p.end_length_m = c.end_length_m;
  // One sample interval more: a region's first sample is the transit's last (flow_schedule's
  // ends_blocked), so the ramp has the lead less half a sample before the pass.
  p.min_lead_s = c.min_lead_s > 0.0 ? c.min_lead_s + 1.0 / c.trajectory_rate_hz : 0.0;
  p.turn_speed_mps = c.turn_speed_mps;
  p.speed_change_accel_mps2 = c.speed_change_accel_mps2;
  p.turn_accel_mps2 = c.turn_accel_mps2;
  p.min_turn_s = c.spray_on_turns ? 0.0 : c.min_turn_s;  // sprayed through anyway
  return p;
}

std::pair<double, double> lead_lengths(const std::vector<Pass>& passes, const TimingParams& params,
                                       double start_accel_mps2, double end_accel_mps2) {
  double lead_in = params.start_length_m, lead_out = params.end_length_m;
  if (!passes.empty() && passes.front().waypoints.size() >= 2) {
    const Pass& f = passes.front();
    const Pass& l = passes.back();
    const double v0 = f.speed_at(0), v1 = l.speed_at(l.waypoints.size() - 1);
    const double k1 = params.k1, k2 = params.k2;
    lead_in = std::max(lead_in, v0 * v0 * (2.0 - k1) / (k1 * start_accel_mps2));
    lead_out = std::max(lead_out, v1 * v1 * (1.0 + k2) / ((1.0 - k2) * end_accel_mps2));
    lead_in = std::max(lead_in, 0.5 * v0 * params.min_lead_s * (2.0 - k1));
    lead_out = std::max(lead_out, 0.5 * v1 * params.min_lead_s * (1.0 + k2));
  }
  return {lead_in, lead_out};
}

SpeedProfile region_profile(const CartesianPath& path, const TimingParams& params) {
  return profile_from_specs(specs_of(path), params);
}

}  // namespace shotcrete
