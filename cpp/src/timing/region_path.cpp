// The nozzle path of a region: lead-in, passes, the joins between them (turn-around, spray-off gap
// or stop-and-go), lead-out; and the quintic baseline path.
#include "shotcrete/timing/region_path.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "detail.hpp"

namespace shotcrete {

using namespace timing_detail;

namespace {

// The least run past a tight pass end before the nozzle stands (a tight turn's stop) [m].
constexpr double kTightRunM = 0.005;
// A tight turn creeps across at most this far (serpentine neighbours); farther joins at a tight
// end are stop-and-go with the tight runs [m].
constexpr double kTightTurnMostM = 0.5;
// Two runs of one planner line at most this far apart are joined along it though the line is not
// straight (append_join) [m].
constexpr double kSameLineGapMostM = 0.5;

void check_pass(const Pass& p, std::size_t i) {
  if (p.waypoints.size() < 2)
    throw std::invalid_argument("pass " + std::to_string(i) + " has " + std::to_string(p.waypoints.size()) +
                                " waypoints; at least 2 are needed");
  if (!(p.speed_mps > 0.0) || !std::isfinite(p.speed_mps))
    throw std::invalid_argument("pass " + std::to_string(i) + " has speed_mps = " + num(p.speed_mps) +
                                "; it must be > 0");
}

Eigen::Vector3d start_direction(const Pass& p) {
  return normalized_or(p.waypoints[1].position_m - p.waypoints[0].position_m, Eigen::Vector3d::UnitX());
}
Eigen::Vector3d end_direction(const Pass& p) {
  const auto n = p.waypoints.size();
  return normalized_or(p.waypoints[n - 1].position_m - p.waypoints[n - 2].position_m, Eigen::Vector3d::UnitX());
}
double first_speed(const Pass& p) { return p.speed_at(0); }
double last_speed(const Pass& p) { return p.speed_at(p.waypoints.size() - 1); }

// A run off pass p's end to `to`, and one from `from` onto pass q's start, carrying the axis's
// turn on the pass down to 0 (run_carrying_axis_turn).
std::vector<NozzlePose> run_off(const Pass& p, const NozzlePose& to) {
  return run_carrying_axis_turn(p.waypoints.back(), to, axis_turn_rate(p.waypoints, true), true);
}
std::vector<NozzlePose> run_onto(const NozzlePose& from, const Pass& q) {
  return run_carrying_axis_turn(from, q.waypoints.front(), axis_turn_rate(q.waypoints, false), false);
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

void check_region(const std::vector<Pass>& passes, const RegionPathOptions& o) {
  if (passes.empty()) throw std::invalid_argument("region_path: the region has no passes");
  for (std::size_t i = 0; i < passes.size(); ++i) check_pass(passes[i], i);
  if (!o.gap_accel_scale.empty() && o.gap_accel_scale.size() + 1 != passes.size())
    throw std::invalid_argument("region_path: " + std::to_string(o.gap_accel_scale.size()) +
                                " gap acceleration scales for " + std::to_string(passes.size()) + " passes");
  for (double g : o.gap_accel_scale)
    if (!(g > 0.0 && g <= 1.0)) throw std::invalid_argument("region_path: gap acceleration scale " + num(g) + " must be in (0, 1]");
  if (!(o.lead_in_m > 0.0) || !(o.lead_out_m > 0.0))
    throw std::invalid_argument("region_path: lead-in " + num(o.lead_in_m) + " m and lead-out " + num(o.lead_out_m) +
                                " m must be > 0 (start and stop happen off the passes)");
}

// Pass i of the region as a path piece, with its constant-speed runs when it has a speed profile.
PathPiece pass_piece(const Pass& p, std::size_t i, int pass_index) {
  PathPiece piece = polyline_piece(SegmentKind::Pass, p.waypoints, first_speed(p), true, pass_index);
  piece.speed_out_mps = last_speed(p);
  if (!p.speed_profile_mps.empty()) {
    if (p.speed_profile_mps.size() != p.waypoints.size())
      throw std::invalid_argument("pass " + std::to_string(i) + " has " + std::to_string(p.speed_profile_mps.size()) +
                                  " speed profile values for " + std::to_string(p.waypoints.size()) + " waypoints");
    speed_runs(p, piece.run_len_m, piece.run_speed_mps);
    if (piece.run_len_m.size() == 1) piece.run_len_m.clear(), piece.run_speed_mps.clear();  // constant after all
  }
  return piece;
}

// The join from pass p to the next pass q: directions at the ends and the gap between them.
struct Join {
  const Pass& p;
  const Pass& q;
  Eigen::Vector3d da, db, gap;
  double gap_scale;  // the gap's share of the options' accelerations
  // Distance across the pass direction (the pass spacing of a serpentine).
  double across_m() const { return (gap - gap.dot(da) * da).norm(); }
};

// The next pass continues the same line further on (the optimal planner switches the spray off
// over segments that would only overfill): carry on along the line, spray off, no stop.
void append_spray_off_gap(CartesianPath& path, const Join& j) {
  // Tangent to both passes: their end directions may differ by a few degrees.
  PathPiece link = polyline_piece(SegmentKind::Link, tangent_curve(j.p.waypoints.back(), j.da, j.q.waypoints.front(), j.db),
                                  last_speed(j.p), false, -1);
  link.speed_out_mps = first_speed(j.q);
  link.motion = PieceMotion::SprayOffGap;
  if (link.length_m() > 0.0) path.append(std::move(link));
}

// Serpentine neighbours: a turn-around.
void append_turn(CartesianPath& path, const Join& j, const RegionPathOptions& o) {
  const double turn_accel = j.gap_scale * o.turn_accel_mps2;
  const double v_out = last_speed(j.p), v_in = first_speed(j.q);
  // Runs long enough for the change between the pass speed and the arc speed at
  // turn_accel_mps2 (cycloid peak |v1^2 - v0^2| / length): fast passes need metres, not 0.1 m.
  double run_out = o.turn_run_m, run_in = o.turn_run_m;
  if (o.turn_run_m > 0.0 && turn_accel > 0.0) {
    double vt = turn_arc_speed(0.5 * j.across_m(), v_out, v_in, o.turn_speed_mps, turn_accel);
    auto run_for = [&](double v_pass, double u, double accel) {
      return std::max(o.turn_run_m, std::abs(v_pass * v_pass - u * u) / accel);
    };
    // A turn too short for the pump to switch off over it: runs with room for the slower arc that
    // region_profile then gives it (between passes about as fast as the turn there is none). The
    // uneased turn's arc speed, sized so; an eased one is sqrt(scale) slower still.
    const double a1 = o.turn_accel_mps2, v1 = turn_arc_speed(0.5 * j.across_m(), v_out, v_in, o.turn_speed_mps, a1);
    auto duration = [&](double u) {  // runs + arc at arc speed u, the runs sized for u
      return run_for(v_out, u, a1) / (0.5 * (v_out + u)) + kPi * 0.5 * j.across_m() / u +
             run_for(v_in, u, a1) / (0.5 * (u + v_in));
    };
    if (vt > 0.0 && v1 > 0.0 && o.min_turn_s > 0.0 && duration(v1) < o.min_turn_s)
      vt = std::min(vt, std::sqrt(j.gap_scale) * speed_lasting(duration, 1e-3, v1, o.min_turn_s));
    if (vt > 0.0) {
      run_out = run_for(v_out, vt, turn_accel);
      run_in = run_for(v_in, vt, turn_accel);
    }
  }
  TurnAroundOptions turn;
  turn.speed_in_mps = v_out;
  turn.speed_out_mps = v_in;
  turn.spraying = o.spray_on_turns;
  turn.run_out_m = run_out;
  turn.run_in_m = run_in;
  turn.dir_b_start = j.db;
  turn.axis_rate_a = axis_turn_rate(j.p.waypoints, true);
  turn.axis_rate_b = axis_turn_rate(j.q.waypoints, false);
  for (auto& t : turn_around(j.p.waypoints.back(), j.da, j.q.waypoints.front(), turn)) {
    if (t.kind == SegmentKind::Turn) t.accel_scale = j.gap_scale;  // the profile eases the arc speed alike
    path.append(std::move(t));
  }
}

// Stop and go: the direction changes only where the nozzle stands still; at a tight end
// (tight_out: pass p's end, tight_in: pass q's start) within v^2 / a (kTightRunM at least).
// `middle`: RestToRest (a joint move in time_plan, the pump off) or Creep, a tight turn: a
// turn-around runs on 0.2 m and more past the pass ends (its runs and half its arc), into the room
// the nozzle's lean kept clear (the face scene: 0.23 m from the face at its 0.4 m margin); the
// tight turn stops, creeps across to the next pass along the path (tracked like a turn: the pump
// may run on it) and starts from rest.
void append_stop_and_go(CartesianPath& path, const Join& j, const RegionPathOptions& o, bool tight_out, bool tight_in,
                        PieceMotion middle = PieceMotion::RestToRest) {
  const double stop_accel = j.gap_scale * o.stop_accel_mps2;
  const double v_out = last_speed(j.p), v_in = first_speed(j.q);
  // An eased join (gap_scale < 1) runs 1 / scale as long: where the minimum run binds (a stop from
  // 0.34 m/s over 0.1 m), a lower acceleration alone left the stop as it was (the default bay: a
  // slew at 1.006x its limit through six easings, then two re-plans of the whole bay).
  const double run = (o.turn_run_m > 0.0 ? o.turn_run_m : 0.1) / std::max(j.gap_scale, 1e-3);
  // Long enough to stop from / start to the pass speeds within the acceleration limit (plain
  // cycloidal stop / start, peak v^2 / s).
  double run_out = tight_out ? kTightRunM : run, run_in = tight_in ? kTightRunM : run;
  if (stop_accel > 0.0) {
    run_out = std::max(run_out, v_out * v_out / stop_accel);
    run_in = std::max(run_in, v_in * v_in / stop_accel);
  }
  NozzlePose a = j.p.waypoints.back(), b = j.q.waypoints.front();
  a.position_m += run_out * j.da;
  b.position_m -= run_in * j.db;
  // The runs carry the axis's turn on the passes down to 0 at the stop.
  const auto stop = run_off(j.p, a);
  const auto start = run_onto(b, j.q);
  a.axis = stop.back().axis;
  b.axis = start.front().axis;
  PathPiece out = polyline_piece(SegmentKind::Link, stop, v_out, false, -1);
  out.motion = PieceMotion::StopAtEnd;
  path.append(std::move(out));
  PathPiece mid = polyline_piece(SegmentKind::Link, {a, b}, std::max(v_out, v_in), false, -1);
  mid.motion = middle;
  mid.accel_scale = j.gap_scale;
  path.append(std::move(mid));
  PathPiece in = polyline_piece(SegmentKind::Link, start, v_in, false, -1);
  in.motion = PieceMotion::StartFromRest;
  path.append(std::move(in));
}

void append_join(CartesianPath& path, const Join& j, const RegionPathOptions& o) {
  const double cos_turn = j.da.dot(j.db);
  const double along = j.gap.dot(j.da), across = j.across_m();
  const bool turn = cos_turn < -0.5 && across > 1e-3, tight = j.p.tight_end || j.q.tight_start;
  // The same planner line further on (Pass::line), though a leaning nozzle's line is no straight
  // one: its standoff point drifts across as the lean fades (the face scene: 2-4 cm over a 0.14 m
  // gap, ends 10-30 deg apart), which a stop-and-go crossed in 10-13 s at the slow passes' speeds.
  // Not over longer gaps (a graded line's pieces 0.3 m and more apart, an arc's): crossed at the
  // passes' speeds they can take longer than a stop-and-go.
  const bool same_line_on = j.p.line >= 0 && j.p.line == j.q.line && cos_turn > 0.0 && along > 0.0 &&
                            across < along && j.gap.norm() <= kSameLineGapMostM;
  if ((cos_turn > 0.99 && along >= 0.0 && across < 1e-3) || same_line_on) append_spray_off_gap(path, j);
  else if (turn && tight && j.gap.norm() <= kTightTurnMostM)
    append_stop_and_go(path, j, o, j.p.tight_end, j.q.tight_start, PieceMotion::Creep);
  else if (turn && !tight) append_turn(path, j, o);
  else append_stop_and_go(path, j, o, j.p.tight_end, j.q.tight_start);
}

}  // namespace

CartesianPath region_path(const std::vector<Pass>& passes, const RegionPathOptions& o) {
  check_region(passes, o);
  CartesianPath path;
  const Pass& first = passes.front();
  NozzlePose lead0 = first.waypoints.front();
  lead0.position_m -= o.lead_in_m * start_direction(first);
  // The leads carry the axis's turn at the pass ends down to 0 at rest (as the joins' runs).
  path.append(polyline_piece(SegmentKind::Lead, run_onto(lead0, first), first_speed(first), false, -1));
  for (std::size_t i = 0; i < passes.size(); ++i) {
    const Pass& p = passes[i];
    path.append(pass_piece(p, i, o.first_pass_index + static_cast<int>(i)));
    if (i + 1 == passes.size()) break;
    const Pass& q = passes[i + 1];
    const Join join{p, q, end_direction(p), start_direction(q),
                    q.waypoints.front().position_m - p.waypoints.back().position_m,
                    o.gap_accel_scale.empty() ? 1.0 : o.gap_accel_scale[i]};
    append_join(path, join, o);
  }
  const Pass& last = passes.back();
  NozzlePose lead1 = last.waypoints.back();
  lead1.position_m += o.lead_out_m * end_direction(last);
  path.append(polyline_piece(SegmentKind::Lead, run_off(last, lead1), last_speed(last), false, -1));
  return path;
}

CartesianPath timing_region_path(const std::vector<Pass>& passes, double lead_in_m, double lead_out_m,
                                 const TimingConfig& timing, int first_pass_index,
                                 const std::vector<double>& gap_accel_scale) {
  RegionPathOptions o;
  o.lead_in_m = lead_in_m;
  o.lead_out_m = lead_out_m;
  o.spray_on_turns = timing.spray_on_turns;
  o.first_pass_index = first_pass_index;
  o.turn_run_m = timing.turn_run_m;
  o.stop_accel_mps2 = timing.nozzle_max_accel_mps2;
  o.turn_speed_mps = timing.turn_speed_mps;
  o.turn_accel_mps2 = timing.turn_accel_mps2 > 0.0 ? timing.turn_accel_mps2 : timing.speed_change_accel_mps2;
  o.min_turn_s = timing.spray_on_turns ? 0.0 : timing.min_turn_s;
  o.gap_accel_scale = gap_accel_scale;
  return region_path(passes, o);
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

}  // namespace shotcrete
