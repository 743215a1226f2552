// Joint-space timing: joint quintics, the timed trajectory of regions in spraying order (with the
// re-timing of awkward joins) and of a single path.
#include "shotcrete/timing/trajectory.hpp"

#include <algorithm>
#include <cmath>
#include <deque>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "detail.hpp"
#include "shotcrete/robot/joint_tracking.hpp"
#include "shotcrete/robot/robot.hpp"

namespace shotcrete {

using namespace timing_detail;

// ------------------------------------------------------------------------------------------------
// Joint quintics and the trajectory table
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

double quintic_nozzle_duration(const Robot& robot, const Eigen::VectorXd& q0, const Eigen::VectorXd& q1,
                               double max_speed_mps, double max_accel_mps2) {
  if (!(max_speed_mps > 0.0) || !(max_accel_mps2 > 0.0))
    throw std::invalid_argument("quintic_nozzle_duration: the nozzle limits must be > 0 (speed " + num(max_speed_mps) +
                                " m/s, acceleration " + num(max_accel_mps2) + " m/s^2)");
  const double t_joint = quintic_min_duration(q0, q1, robot.velocity_limits(), robot.acceleration_limits());
  if (!(t_joint > 0.0)) return t_joint;
  // Nozzle positions of the quintic at T = 1 s; central differences give its speed and acceleration.
  constexpr int n = kQuinticNozzleSteps;
  const double h = 1.0 / n;
  std::vector<Eigen::Vector3d> p(n + 1);
  Eigen::VectorXd q, qd, qdd;
  for (int k = 0; k <= n; ++k) {
    quintic_joint(q0, q1, 1.0, k * h, q, qd, qdd);
    p[static_cast<std::size_t>(k)] = robot.fk(q).translation();
  }
  double v1 = 0.0, a1 = 0.0;
  for (std::size_t k = 1; k < p.size() - 1; ++k) {
    v1 = std::max(v1, (p[k + 1] - p[k - 1]).norm() / (2.0 * h));
    a1 = std::max(a1, (p[k + 1] - 2.0 * p[k] + p[k - 1]).norm() / (h * h));
  }
  return std::max({t_joint, kQuinticNozzleMargin * v1 / max_speed_mps,
                   std::sqrt(kQuinticNozzleMargin * a1 / max_accel_mps2)});
}

CycleTimeBreakdown& CycleTimeBreakdown::operator+=(const CycleTimeBreakdown& o) {
  spraying_s += o.spraying_s;
  turn_arounds_s += o.turn_arounds_s;
  leads_s += o.leads_s;
  transits_s += o.transits_s;
  stop_and_go_s += o.stop_and_go_s;
  other_s += o.other_s;
  return *this;
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

std::vector<std::pair<double, double>> timing_detail::cartesian_stretches(const CartesianPath& path) {
  std::vector<std::pair<double, double>> out;
  double open = 0.0;
  for (std::size_t i = 0; i < path.pieces().size(); ++i)
    if (path.pieces()[i].motion == PieceMotion::RestToRest) {
      out.emplace_back(open, path.piece_start_m(i));
      open = path.piece_start_m(i) + path.pieces()[i].length_m();
    }
  out.emplace_back(open, path.length_m());
  return out;
}

namespace {

NozzlePose pose_of(const Eigen::Isometry3d& T) {
  NozzlePose p;
  p.position_m = T.translation();
  p.axis = T.linear().col(2);
  return p;
}

// The bucket of a path piece's time (CycleTimeBreakdown).
double& bucket_of(const PathPiece& piece, CycleTimeBreakdown& b) {
  if (piece.spraying) return b.spraying_s;
  switch (piece.kind) {
    case SegmentKind::Turn: return b.turn_arounds_s;
    case SegmentKind::Lead: return b.leads_s;
    case SegmentKind::Link:
      return piece.motion == PieceMotion::StopAtEnd || piece.motion == PieceMotion::RestToRest ||
                     piece.motion == PieceMotion::StartFromRest
                 ? b.stop_and_go_s
                 : b.turn_arounds_s;
    default: return b.other_s;
  }
}

// Exact time of the path's pieces by bucket (from the profile, not from the samples); without
// the rest-to-rest pieces when time_plan replaces them by joint moves. The path ends at the
// profile's duration (as stretch_windows), so the parts add up to the timed windows.
CycleTimeBreakdown piece_times(const CartesianPath& path, const SpeedProfile& prof, bool rest_to_rest_in_joint_space) {
  CycleTimeBreakdown b;
  const std::size_t n = path.pieces().size();
  for (std::size_t i = 0; i < n; ++i) {
    const PathPiece& piece = path.pieces()[i];
    if (rest_to_rest_in_joint_space && piece.motion == PieceMotion::RestToRest) continue;
    const double end_s = i + 1 == n ? prof.duration_s() : prof.time_at_distance(path.piece_start_m(i + 1));
    // A tight turn (its stop, creep and start: region_path) is a turn-around.
    const auto creep = [&](std::size_t k) { return k < n && path.pieces()[k].motion == PieceMotion::Creep; };
    const bool tight_turn = !piece.spraying && (piece.motion == PieceMotion::Creep ||
                                                (piece.motion == PieceMotion::StopAtEnd && creep(i + 1)) ||
                                                (piece.motion == PieceMotion::StartFromRest && i > 0 && creep(i - 1)));
    (tight_turn ? b.turn_arounds_s : bucket_of(piece, b)) += end_s - (i == 0 ? 0.0 : prof.time_at_distance(path.piece_start_m(i)));
  }
  return b;
}

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

// Every sample of part appended to tr, its times shifted by t0.
void append_samples(TimedTrajectory& tr, const TimedTrajectory& part, double t0) {
  for (std::size_t k = 0; k < part.size(); ++k)
    push_sample(tr, t0 + part.t_s[k], part.q[k], part.nozzle[k], part.spraying[k], part.pass_index[k],
                part.region_index[k], part.kind[k]);
}

// Rest-to-rest joint quintic q0 -> q1 within the joint and nozzle limits, appended to tr from time
// t0 (not included) as samples of kind Transit with region index `region`. Returns its duration;
// `pushed` gets the number of samples appended.
double push_joint_leg(const Robot& robot, const TimingConfig& timing, const Eigen::VectorXd& q0, const Eigen::VectorXd& q1,
                      double t0, int region, TimedTrajectory& tr, std::size_t& pushed) {
  pushed = 0;
  const double T = quintic_nozzle_duration(robot, q0, q1, timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2);
  if (!(T > 0.0)) return T;
  for (double t : time_grid(T, timing.trajectory_rate_hz)) {
    if (t == 0.0) continue;
    Eigen::VectorXd q, qd, qdd;
    quintic_joint(q0, q1, T, t, q, qd, qdd);
    push_sample(tr, t0 + t, q, pose_of(robot.fk(q)), 0, -1, region, static_cast<char>(SegmentKind::Transit));
    ++pushed;
  }
  return T;
}

// Velocities / accelerations by finite differences and the limit check.
void finish_trajectory(const Robot& robot, TimedTrajectory& tr) {
  const int dof = robot.dof();
  tr.max_velocity_ratio = tr.max_acceleration_ratio = 0.0;
  tr.worst_velocity_joint = tr.worst_acceleration_joint = -1;
  tr.max_position_violation_rad = tr.max_position_violation_m = 0.0;
  finite_differences(tr.t_s, tr.q, tr.qd, tr.qdd);
  const Eigen::VectorXd& vl = robot.velocity_limits();
  const Eigen::VectorXd& al = robot.acceleration_limits();
  const std::vector<bool>& prismatic = robot.joint_is_prismatic();
  for (std::size_t i = 0; i < tr.size(); ++i)
    for (int j = 0; j < dof; ++j) {
      const double rv = std::abs(tr.qd[i][j]) / vl[j], ra = std::abs(tr.qdd[i][j]) / al[j];
      if (rv > tr.max_velocity_ratio) { tr.max_velocity_ratio = rv; tr.worst_velocity_joint = j; }
      if (ra > tr.max_acceleration_ratio) { tr.max_acceleration_ratio = ra; tr.worst_acceleration_joint = j; }
      double& violation = prismatic[static_cast<std::size_t>(j)] ? tr.max_position_violation_m
                                                                 : tr.max_position_violation_rad;
      violation = std::max({violation, robot.lower_limits()[j] - tr.q[i][j], tr.q[i][j] - robot.upper_limits()[j]});
    }
}

// ------------------------------------------------------------------------------------------------
// One region
// ------------------------------------------------------------------------------------------------

// What timing a region needs besides the region itself.
struct TimingContext {
  const Robot& robot;
  const TimingConfig& timing;
  const RobotConfig& robot_config;
  const NullSpaceObjective& objective;  // the tracking's second null-space objective (clearance)
};

// A region to time: its passes, its place in the spraying order and the number of passes before it,
// its parameters. slot_scale (passes + 1 values in (0, 1]: the lead-in, the gap after each pass but
// the last, the lead-out) scales the accelerations that size that slot's non-spraying motion (lead
// length, stop-and-go runs, the runs and arc of a turn); the passes keep their planned speeds.
struct RegionJob {
  const std::vector<Pass>& passes;
  int region = 0;
  int pass_offset = 0;
  TimingParams params;
  std::vector<double> slot_scale;
};

// A region timed from rest at q_prev: slot gives each sample's slot (-1 on joint moves).
struct RegionTiming {
  TimedTrajectory part;
  std::vector<int> slot;
  bool tracked = true;
};

// The region's path and profile with leads at least as long as the nozzle acceleration limit needs
// at its end speeds (start peak v^2 (2 - k1) / (k1 s), end peak v^2 (1 + k2) / ((1 - k2) s)): fast
// passes get longer run-ups than the config's default. The swarm's parameters already satisfy this.
struct RegionSetup {
  TimingParams params;  // the job's, with the leads lengthened
  std::vector<double> gap_scale;
  double max_lead_m = 0.0;  // the lead the first stretch is tracked from (as the swarm's model)
  CartesianPath path;
  SpeedProfile profile;
};

RegionSetup set_up_region(const TimingContext& ctx, const RegionJob& job) {
  const std::vector<Pass>& passes = job.passes;
  const std::vector<double>& slot_scale = job.slot_scale;
  const double stop_accel = ctx.timing.nozzle_max_accel_mps2;  // sizes the leads, as in timing_region_path
  if (slot_scale.size() != passes.size() + 1)
    throw std::logic_error("time_region: one acceleration scale per lead and gap");
  RegionSetup rs;
  rs.max_lead_m = std::max({swarm_max_lead(passes, ctx.timing), job.params.start_length_m, job.params.end_length_m});
  rs.gap_scale.assign(slot_scale.begin() + 1, slot_scale.end() - 1);
  TimingParams& rp = rs.params;
  rp = job.params;
  // An eased lead is 1 / scale as long, so its accelerations scale with it also where the config's
  // lead length, not the nozzle limit, sizes it (slow passes).
  const auto [lead_in_m, lead_out_m] = lead_lengths(passes, rp, stop_accel, stop_accel);
  rp.start_length_m = lead_in_m / slot_scale.front();
  rp.end_length_m = lead_out_m / slot_scale.back();
  rs.path = timing_region_path(passes, rp.start_length_m, rp.end_length_m, ctx.timing, job.pass_offset, rs.gap_scale);
  rs.profile = region_profile(rs.path, rp);
  return rs;
}

// Slot of each piece: the number of passes before it.
std::vector<int> piece_slots(const CartesianPath& path) {
  std::vector<int> piece_slot;
  int passes_before = 0;
  for (const auto& piece : path.pieces()) {
    piece_slot.push_back(passes_before);
    if (piece.kind == SegmentKind::Pass) ++passes_before;
  }
  return piece_slot;
}

// Profile time spans of the Cartesian stretches, from 0 to the end.
std::vector<std::pair<double, double>> stretch_windows(const CartesianPath& path, const SpeedProfile& prof) {
  const auto stretches = cartesian_stretches(path);
  std::vector<std::pair<double, double>> windows;
  for (std::size_t c = 0; c < stretches.size(); ++c)
    windows.emplace_back(c == 0 ? 0.0 : prof.time_at_distance(stretches[c].first),
                         c + 1 == stretches.size() ? prof.duration_s() : prof.time_at_distance(stretches[c].second));
  return windows;
}

// Joints along the region's first stretch (samples `poses`). The joint path starts where the
// swarm's RegionJointModel starts it (at the longest lead-in) so that both see the same q(s): the
// unused part of that lead-in is prepended, then dropped. If that longer lead-in leaves the reach,
// the bound is halved as in tune_timing.
std::vector<Eigen::VectorXd> first_stretch_joints(const TimingContext& ctx, const RegionJob& job,
                                                  const RegionSetup& rs, const std::vector<NozzlePose>& samples,
                                                  const Eigen::VectorXd& q_prev, bool& tracked) {
  const double start_length = rs.params.start_length_m;
  std::vector<Eigen::VectorXd> jq;
  std::size_t prefix = 0;
  for (double lead = std::max(rs.max_lead_m, start_length);; lead = std::max(0.5 * lead, start_length)) {
    std::vector<NozzlePose> poses;
    const double unused = std::max(0.0, lead - start_length);
    if (unused > 0.0) {
      const CartesianPath long_path = timing_region_path(job.passes, lead, lead, ctx.timing, 0, rs.gap_scale);
      const int m = static_cast<int>(std::ceil(unused / 0.005));
      for (int k = 0; k < m; ++k) poses.push_back(long_path.pose_at(unused * k / m));
    }
    prefix = poses.size();
    poses.insert(poses.end(), samples.begin(), samples.end());
    try {
      jq = timing_joint_path(ctx.robot, poses, q_prev, ctx.robot_config, &tracked, ctx.objective);
      break;
    } catch (const std::exception& e) {
      if (unused <= 0.0) throw std::runtime_error("time_plan: region " + std::to_string(job.region) + ": " + e.what());
    }
  }
  jq.erase(jq.begin(), jq.begin() + static_cast<std::ptrdiff_t>(prefix));
  return jq;
}

// Joint quintic from rest at q0 to rest at q1 within the joint and nozzle limits, appended from
// time t0 (not included) as samples of kind Transit (region index `region`, slot -1). Returns its
// duration.
double append_joint_move(const TimingContext& ctx, const Eigen::VectorXd& q0, const Eigen::VectorXd& q1, double t0,
                         int region, RegionTiming& out) {
  std::size_t pushed = 0;
  const double T = push_joint_leg(ctx.robot, ctx.timing, q0, q1, t0, region, out.part, pushed);
  out.slot.insert(out.slot.end(), pushed, -1);
  return T;
}

// One region timed from rest at q_prev: the transit to it, then its Cartesian stretches joined by
// joint-space rest-to-rest moves. Times start at 0 at q_prev (which is not included).
RegionTiming time_region(const TimingContext& ctx, const RegionJob& job, const Eigen::VectorXd& q_prev_in) {
  const double rate = ctx.timing.trajectory_rate_hz;
  const RegionSetup rs = set_up_region(ctx, job);
  const CartesianPath& path = rs.path;
  const std::vector<int> piece_slot = piece_slots(path);
  const int r = job.region;
  RegionTiming out;
  TimedTrajectory& tr = out.part;
  // The region is tracked in stretches between its rest-to-rest moves (stop-and-go middles):
  // the nozzle stands still at both ends and sprays nothing there, so a joint quintic at the
  // limits replaces the straight Cartesian move, whose joint accelerations near the slew axis
  // can be many times the limits.
  const auto windows = stretch_windows(path, rs.profile);
  Eigen::VectorXd q_prev = q_prev_in;
  double t0 = 0.0;
  for (std::size_t c = 0; c < windows.size(); ++c) {
    const auto [wa, wb] = windows[c];
    const CartesianSamples cs = sample_window(path, rs.profile, rate, wa, wb);
    std::vector<Eigen::VectorXd> jq;
    bool tracked = false;
    if (c == 0) {
      jq = first_stretch_joints(ctx, job, rs, cs.nozzle, q_prev, tracked);
    } else {
      try {
        jq = timing_joint_path(ctx.robot, cs.nozzle, q_prev, ctx.robot_config, &tracked, ctx.objective);
      } catch (const std::exception& e) {
        throw std::runtime_error("time_plan: region " + std::to_string(r) + ", stretch " + std::to_string(c) +
                                 " (after a stop-and-go move): " + e.what());
      }
    }
    out.tracked = out.tracked && tracked;
    // Joint quintic from the previous rest configuration: the transit between regions (c == 0)
    // or the stop-and-go move inside the region.
    const double T = append_joint_move(ctx, q_prev, jq.front(), t0, c == 0 ? -1 : r, out);
    if (T > 0.0) {
      t0 += T;
      tr.transit_time_s += T;
      (c == 0 ? tr.cycle_time.transits_s : tr.cycle_time.stop_and_go_s) += T;
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
  tr.cycle_time += piece_times(path, rs.profile, true);
  tr.spray_time_s = tr.cycle_time.spraying_s;
  return out;
}

// Worst |qd| / limit and |qdd| / limit per slot on the non-spraying Cartesian samples (turns,
// links, leads) of a region timed from rest at q_prev; passes keep their speeds and joint moves
// are within the limits by design. A non-finite value counts as the worst possible.
struct SlotRatios {
  std::vector<double> velocity, acceleration;
};

SlotRatios off_pass_ratios(const Robot& robot, const RegionTiming& rt, const Eigen::VectorXd& q_prev, std::size_t slots) {
  const TimedTrajectory& part = rt.part;
  std::vector<double> t{0.0};
  std::vector<Eigen::VectorXd> q{q_prev}, qd, qdd;
  t.insert(t.end(), part.t_s.begin(), part.t_s.end());
  q.insert(q.end(), part.q.begin(), part.q.end());
  finite_differences(t, q, qd, qdd);
  SlotRatios worst{std::vector<double>(slots, 0.0), std::vector<double>(slots, 0.0)};
  const auto raise = [](double& w, double ratio) {
    w = std::max(w, std::isfinite(ratio) ? ratio : std::numeric_limits<double>::max());
  };
  for (std::size_t i = 0; i < part.size(); ++i) {
    const auto kind = static_cast<SegmentKind>(part.kind[i]);
    if (kind == SegmentKind::Pass || kind == SegmentKind::Transit || rt.slot[i] < 0) continue;
    const auto k = static_cast<std::size_t>(rt.slot[i]);
    raise(worst.velocity[k], qd[i + 1].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff());
    raise(worst.acceleration[k], qdd[i + 1].cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff());
  }
  return worst;
}

// The region timed from rest at q_prev, re-timed where its turns, runs or leads break a joint
// limit (e.g. near the slew axis, where a nozzle acceleration is a large slew acceleration).
// - Accelerations: gentler accelerations there; the joint acceleration scales about linearly with
//   them. Each lead and gap has its own scale, so one awkward stop does not lengthen every run
//   (long leads can leave the reach or swing the arm out).
// - Velocities: a lead runs at its pass's speed whatever its scale, and a longer lead only takes
//   the arm further out, so a lead over a limit first drops its cruise (the paper's k1 -> 1 on the
//   lead-in, k2 -> 0 on the lead-out: all of it speeding up or slowing down, a third as long as at
//   the default 0.5). A join's velocities are the passes' speeds; easing its arc's speed with the
//   scale made the speed changes on its short runs break acceleration limits 4.5x, so a join over
//   a velocity limit is left to the re-plan's bounds on its passes (SpeedCapMap::learn).
// A slot that got worse when eased, or a timing that leaves the reach, goes halfway back to its
// best scale. At most kAttempts timings; the one with the smallest excess is kept.
RegionTiming eased_region(const TimingContext& ctx, RegionJob job, const Eigen::VectorXd& q_prev, double& best_ratio) {
  constexpr int kAttempts = 6;
  const std::size_t slots = job.passes.size() + 1;
  std::vector<double>& scale = job.slot_scale;
  scale.assign(slots, 1.0);
  std::vector<double> best_scale(slots, 1.0), best_slot_ratio(slots, std::numeric_limits<double>::infinity());
  best_ratio = std::numeric_limits<double>::infinity();
  RegionTiming best;
  for (int attempt = 0; attempt < kAttempts; ++attempt) {
    RegionTiming rt;
    try {
      rt = time_region(ctx, job, q_prev);
    } catch (const std::exception&) {
      if (attempt == 0) throw;
      for (std::size_t k = 0; k < slots; ++k) scale[k] = std::sqrt(scale[k] * best_scale[k]);
      continue;
    }
    const SlotRatios r = off_pass_ratios(ctx.robot, rt, q_prev, slots);
    std::vector<double> ratios(slots);  // what easing a slot's scale acts on: its accelerations
    double ratio = 0.0;
    for (std::size_t k = 0; k < slots; ++k) {
      ratios[k] = r.acceleration[k];
      ratio = std::max({ratio, r.acceleration[k], r.velocity[k]});
    }
    if (attempt == 0 || ratio < best_ratio) best_ratio = ratio, best = std::move(rt);
    if (ratio <= 1.0) break;
    bool cruise_dropped = false;
    if (std::max(r.velocity.front(), r.acceleration.front()) > 1.0 && job.params.k1 < 1.0)
      job.params.k1 = 1.0, cruise_dropped = true;
    if (std::max(r.velocity.back(), r.acceleration.back()) > 1.0 && job.params.k2 > 0.0)
      job.params.k2 = 0.0, cruise_dropped = true;
    if (!cruise_dropped && *std::max_element(ratios.begin(), ratios.end()) <= 1.0) break;  // nothing to ease
    for (std::size_t k = 0; k < slots; ++k) {
      const bool improved = ratios[k] < best_slot_ratio[k];
      if (improved) best_slot_ratio[k] = ratios[k], best_scale[k] = scale[k];
      if (ratios[k] <= 1.0 && improved) continue;
      const bool lead = k == 0 || k + 1 == slots;
      if (lead && cruise_dropped) continue;  // see what the shorter leads do first
      scale[k] = improved ? scale[k] * std::max(0.25, 0.9 / ratios[k]) : std::sqrt(scale[k] * best_scale[k]);
    }
  }
  return best;
}

// A region's timing as slow_to_joint_limits leaves it (the plan's last word on the limits): its
// duration from rest at q_prev, and whether it then ends within the limits.
std::pair<double, bool> slowed_duration(const Robot& robot, const RegionTiming& rt, const Eigen::VectorXd& q_prev) {
  const TimedTrajectory& part = rt.part;
  TimedTrajectory tr;
  push_sample(tr, 0.0, q_prev, pose_of(robot.fk(q_prev)), 0, -1, -1, static_cast<char>(SegmentKind::Transit));
  append_samples(tr, part, 0.0);
  tr.duration_s = part.duration_s;
  const bool within = slow_to_joint_limits(robot, tr);
  return {tr.duration_s, within};
}

// The region eased within the limits (eased_region). Turn-arounds at their own speed
// (timing.turn_speed_mps, turn_accel_mps2) that no easing brings within a joint limit (an arc at
// 0.3-0.5 m/s where the slew turns fast: 1.06x on a graded region of the default bay) are timed
// again at the passes' speeds (turn_speed_mps and turn_accel_mps2 0, as the slow turns are
// everywhere). Each is then slowed where it still breaks a limit (slow_to_joint_limits, as the
// plan will be), and the one that ends within the limits sooner is kept (the smaller excess if
// neither does): the face scene's left wall kept its own-speed turns at 1.04x in one join
// instead of 42 turns at the passes' 0.04 m/s, 6-17 s each (+197 s), which slowing that join
// within the limit costs a fraction of a second. Likewise when the own-speed timing fails outright.
RegionTiming time_region_within_limits(const TimingContext& ctx, const RegionJob& job, const Eigen::VectorXd& q_prev) {
  const bool own_turns = job.passes.size() >= 2 &&  // one pass: no turn
                         (ctx.timing.turn_speed_mps > 0.0 || ctx.timing.turn_accel_mps2 > 0.0 ||
                          job.params.turn_speed_mps > 0.0 || job.params.turn_accel_mps2 > 0.0);
  TimingConfig slow = ctx.timing;
  slow.turn_speed_mps = 0.0;
  slow.turn_accel_mps2 = 0.0;
  const TimingContext slow_ctx{ctx.robot, slow, ctx.robot_config, ctx.objective};
  RegionJob slow_job = job;
  slow_job.params.turn_speed_mps = 0.0;
  slow_job.params.turn_accel_mps2 = 0.0;
  double ratio = 0.0, slow_ratio = 0.0;
  RegionTiming best;
  try {
    best = eased_region(ctx, job, q_prev, ratio);
  } catch (const std::exception&) {
    // The own-speed turns' longer runs may leave the reach: the turns at the passes' speeds then,
    // and the first error if those fail as well.
    if (!own_turns) throw;
    try {
      return eased_region(slow_ctx, slow_job, q_prev, slow_ratio);
    } catch (const std::exception&) {
    }
    throw;
  }
  if (ratio <= 1.0 || !own_turns) return best;
  try {
    RegionTiming at_pass_speeds = eased_region(slow_ctx, slow_job, q_prev, slow_ratio);
    // Kept when it tracks the nozzle path where the own-speed one does not, or as well and,
    // slowed to the limits, ends within them sooner (or within them where the own-speed turns do
    // not; by the excess when neither does).
    bool slower_turns = at_pass_speeds.tracked && !best.tracked;  // the tracked one outright
    if (!slower_turns && (at_pass_speeds.tracked || !best.tracked)) {
      try {
        const auto [own_s, own_within] = slowed_duration(ctx.robot, best, q_prev);
        const auto [slow_s, slow_within] = slowed_duration(ctx.robot, at_pass_speeds, q_prev);
        slower_turns = slow_within != own_within ? slow_within : own_within ? slow_s < own_s : slow_ratio < ratio;
      } catch (const std::invalid_argument&) {  // a posture not finite: by the excess, as before
        slower_turns = slow_ratio < ratio;
      }
    }
    if (slower_turns) best = std::move(at_pass_speeds);
  } catch (const std::exception&) {
    // The own-speed turns' timing stands; the limit check reports its excess.
  }
  return best;
}

void check_plan_input(const Robot& robot, const std::vector<std::vector<Pass>>& regions, const Eigen::VectorXd& q_start,
                      const std::vector<TimingParams>& params) {
  if (q_start.size() != robot.dof())
    throw std::invalid_argument("time_plan: q_start has " + std::to_string(q_start.size()) + " entries, the robot has " +
                                std::to_string(robot.dof()) + " joints");
  for (std::size_t r = 0; r < regions.size(); ++r)
    if (regions[r].empty()) throw std::invalid_argument("time_plan: region " + std::to_string(r) + " has no passes");
  if (params.size() > 1 && params.size() != regions.size())
    throw std::invalid_argument("time_plan: " + std::to_string(params.size()) + " timing parameter sets for " +
                                std::to_string(regions.size()) + " regions (give none, one, or one per region)");
}

}  // namespace

// ------------------------------------------------------------------------------------------------
// Plans and paths
// ------------------------------------------------------------------------------------------------

TimedTrajectory time_plan(const Robot& robot, const std::vector<std::vector<Pass>>& regions, const Eigen::VectorXd& q_start,
                          const TimingConfig& timing, const RobotConfig& robot_config,
                          const std::vector<TimingParams>& params_in, const NullSpaceObjective& objective) {
  check_plan_input(robot, regions, q_start, params_in);
  const TimingContext ctx{robot, timing, robot_config, objective};
  TimedTrajectory tr;
  push_sample(tr, 0.0, q_start, pose_of(robot.fk(q_start)), 0, -1, -1, static_cast<char>(SegmentKind::Transit));
  double t0 = 0.0;
  Eigen::VectorXd q_prev = q_start;
  int pass_offset = 0;
  for (std::size_t r = 0; r < regions.size(); ++r) {
    const TimingParams params =
        params_in.empty() ? TimingParams::from_config(timing) : params_in[params_in.size() == 1 ? 0 : r];
    const RegionTiming best =
        time_region_within_limits(ctx, RegionJob{regions[r], static_cast<int>(r), pass_offset, params, {}}, q_prev);
    const TimedTrajectory& part = best.part;
    append_samples(tr, part, t0);
    t0 += part.duration_s;
    tr.transit_time_s += part.transit_time_s;
    tr.spray_time_s += part.spray_time_s;
    tr.cycle_time += part.cycle_time;
    if (!best.tracked) ++tr.untracked_regions, tr.untracked_region_ids.push_back(static_cast<int>(r));
    if (!part.q.empty()) q_prev = part.q.back();
    pass_offset += static_cast<int>(regions[r].size());
  }
  tr.duration_s = t0;
  finish_trajectory(robot, tr);
  return tr;
}

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
  tr.cycle_time = piece_times(path, profile, false);
  tr.spray_time_s = tr.cycle_time.spraying_s;
  finish_trajectory(robot, tr);
  return tr;
}

// ------------------------------------------------------------------------------------------------
// Joint moves (re-routed by collision/transit)
// ------------------------------------------------------------------------------------------------

std::vector<char> joint_move_samples(const TimedTrajectory& tr) {
  std::vector<char> out(tr.size(), 0);
  for (std::size_t i = 0; i < tr.size(); ++i)
    out[i] = tr.kind[i] == static_cast<char>(SegmentKind::Transit);
  return out;
}

TimedTrajectory spraying_samples(const TimedTrajectory& tr) {
  TimedTrajectory out;
  for (std::size_t k = 0; k < tr.size(); ++k)
    if (tr.spraying[k])
      push_sample(out, tr.t_s[k], tr.q[k], tr.nozzle[k], tr.spraying[k], tr.pass_index[k], tr.region_index[k], tr.kind[k]);
  return out;
}

std::vector<JointMove> joint_moves(const TimedTrajectory& tr) {
  const auto transit = static_cast<char>(SegmentKind::Transit);
  if (tr.kind.size() != tr.size() || tr.region_index.size() != tr.size() || tr.q.size() != tr.size())
    throw std::invalid_argument("joint_moves: the trajectory has " + std::to_string(tr.size()) + " samples but " +
                                std::to_string(tr.kind.size()) + " sample kinds, " + std::to_string(tr.region_index.size()) +
                                " region indices and " + std::to_string(tr.q.size()) +
                                " joint vectors (a trajectory of times and joints only has no joint moves to find)");
  std::vector<JointMove> out;
  std::size_t i = 0;
  while (i < tr.size()) {
    if (tr.kind[i] != transit) {
      ++i;
      continue;
    }
    std::size_t j = i;
    while (j + 1 < tr.size() && tr.kind[j + 1] == transit) ++j;
    // The first sample of a trajectory is its start posture (kind Transit): the move starts there.
    JointMove m;
    m.start = i == 0 ? 0 : i - 1;
    m.end = j;
    m.region_index = tr.region_index[j];
    if (m.end > m.start) out.push_back(m);
    i = j + 1;
  }
  return out;
}

TimedTrajectory joint_move_through(const Robot& robot, const std::vector<Eigen::VectorXd>& postures,
                                   const TimingConfig& timing, int region_index) {
  if (postures.size() < 2) throw std::invalid_argument("joint_move_through: needs at least two postures");
  TimedTrajectory piece;
  double t0 = 0.0;
  for (std::size_t k = 0; k + 1 < postures.size(); ++k) {
    std::size_t pushed = 0;
    const double T = push_joint_leg(robot, timing, postures[k], postures[k + 1], t0, region_index, piece, pushed);
    if (T > 0.0) t0 += T;
  }
  piece.duration_s = t0;
  piece.transit_time_s = t0;
  return piece;
}

namespace {

// The bucket (and the totals besides duration_s) that time added on the interval ending at sample
// k goes to; `stop_and_go_link[k]`: a Link sample in a run of off-pass samples that holds a joint
// move of its region.
void add_interval_time(TimedTrajectory& tr, std::size_t k, double added_s, const std::vector<char>& stop_and_go_link) {
  CycleTimeBreakdown& b = tr.cycle_time;
  if (stop_and_go_link.size() != tr.size()) {  // times and joints only (from_joints): no flags to tell
    b.other_s += added_s;
    return;
  }
  if (tr.spraying[k]) {
    b.spraying_s += added_s;
    tr.spray_time_s += added_s;
    tr.slowed_spraying_s += added_s;
    return;
  }
  switch (static_cast<SegmentKind>(tr.kind[k])) {
    case SegmentKind::Transit:
      (tr.region_index[k] < 0 ? b.transits_s : b.stop_and_go_s) += added_s;
      tr.transit_time_s += added_s;
      return;
    case SegmentKind::Turn: b.turn_arounds_s += added_s; return;
    case SegmentKind::Lead: b.leads_s += added_s; return;
    case SegmentKind::Link: (stop_and_go_link[k] ? b.stop_and_go_s : b.turn_arounds_s) += added_s; return;
    default: b.other_s += added_s; return;
  }
}

// Per sample: a Link sample whose run of nozzle-off, off-pass samples (within its region) holds a
// joint move (kind Transit) of that region: the run-out and run-in of a stop-and-go move.
std::vector<char> stop_and_go_links(const TimedTrajectory& tr) {
  const std::size_t n = tr.size();
  if (tr.spraying.size() != n || tr.kind.size() != n || tr.region_index.size() != n) return {};
  std::vector<char> out(n, 0);
  const auto off_pass = [&](std::size_t k) {
    return !tr.spraying[k] && static_cast<SegmentKind>(tr.kind[k]) != SegmentKind::Pass && tr.region_index[k] >= 0;
  };
  for (std::size_t a = 0; a < tr.size();) {
    if (!off_pass(a)) {
      ++a;
      continue;
    }
    std::size_t b = a;
    bool joint_move = false;
    while (b < tr.size() && off_pass(b) && tr.region_index[b] == tr.region_index[a])
      joint_move |= static_cast<SegmentKind>(tr.kind[b]) == SegmentKind::Transit, ++b;
    if (joint_move)
      for (std::size_t k = a; k < b; ++k) out[k] = static_cast<SegmentKind>(tr.kind[k]) == SegmentKind::Link;
    a = b;
  }
  return out;
}

}  // namespace

bool slow_to_joint_limits(const Robot& robot, TimedTrajectory& tr, double window_s) {
  if (!(window_s > 0.0 && std::isfinite(window_s)))
    throw std::invalid_argument("slow_to_joint_limits: window_s must be positive and finite");
  if (tr.q.size() != tr.t_s.size())
    throw std::invalid_argument("slow_to_joint_limits: " + std::to_string(tr.q.size()) + " postures for " +
                                std::to_string(tr.t_s.size()) + " times");
  for (std::size_t k = 0; k < tr.size(); ++k) {
    if (tr.q[k].size() != robot.dof() || !tr.q[k].allFinite())
      throw std::invalid_argument("slow_to_joint_limits: posture " + std::to_string(k) + " is not " +
                                  std::to_string(robot.dof()) + " finite joint values");
    if (!std::isfinite(tr.t_s[k]) || (k > 0 && tr.t_s[k] < tr.t_s[k - 1]))
      throw std::invalid_argument("slow_to_joint_limits: times must be finite and non-decreasing (sample " +
                                  std::to_string(k) + ")");
  }
  constexpr int kRounds = 12;
  constexpr double kHeadroom = 1.005;  // a little more than the need: the factor's own rate adds some
  finish_trajectory(robot, tr);
  const double ratio = std::max(tr.max_velocity_ratio, tr.max_acceleration_ratio);
  tr.ratio_before_slowing = std::max(tr.ratio_before_slowing, ratio);  // over every call
  const std::size_t n = tr.size();
  if (n < 3) return ratio <= 1.0;
  const std::vector<char> stop_and_go_link = stop_and_go_links(tr);
  const Eigen::VectorXd& vl = robot.velocity_limits();
  const Eigen::VectorXd& al = robot.acceleration_limits();
  std::vector<char> stretched(n, 0);
  for (int round = 0; round < kRounds && std::max(tr.max_velocity_ratio, tr.max_acceleration_ratio) > 1.0; ++round) {
    // The need at each interval (k - 1, k]: the larger of its two samples'.
    std::vector<double> need(n, 1.0);
    for (std::size_t i = 0; i < n; ++i) {
      const double rv = tr.qd[i].cwiseAbs().cwiseQuotient(vl).maxCoeff();
      const double ra = tr.qdd[i].cwiseAbs().cwiseQuotient(al).maxCoeff();
      const double s = std::max(rv, std::sqrt(ra));
      need[i] = s > 1.0 ? kHeadroom * s : 1.0;
    }
    std::vector<double> interval(n, 1.0);
    for (std::size_t k = 1; k < n; ++k) interval[k] = std::max(need[k - 1], need[k]);
    // Largest within +-window_s, then its average over +-window_s (by time; two-pointer windows
    // over the intervals' midpoints). The average of the largest is no less than each interval's own.
    const auto mid = [&](std::size_t k) { return 0.5 * (tr.t_s[k - 1] + tr.t_s[k]); };
    std::vector<double> widest(n, 1.0), factor(n, 1.0);
    {
      std::size_t lo = 1, hi = 1;
      std::deque<std::size_t> best;  // indices of a decreasing run of interval[] over [lo, hi)
      for (std::size_t k = 1; k < n; ++k) {
        while (hi < n && mid(hi) <= mid(k) + window_s) {
          while (!best.empty() && interval[best.back()] <= interval[hi]) best.pop_back();
          best.push_back(hi++);
        }
        while (mid(lo) < mid(k) - window_s) ++lo;
        while (best.front() < lo) best.pop_front();
        widest[k] = interval[best.front()];
      }
    }
    {
      std::size_t lo = 1, hi = 1;
      double sum = 0.0;
      for (std::size_t k = 1; k < n; ++k) {
        while (hi < n && mid(hi) <= mid(k) + window_s) sum += widest[hi++];
        while (mid(lo) < mid(k) - window_s) sum -= widest[lo++];
        // (A running sum keeps a rounding residue once a need has passed: 1 + 1e-16 is 1.)
        const double mean = sum / static_cast<double>(hi - lo);
        factor[k] = mean > 1.0 + 1e-12 ? mean : 1.0;
      }
    }
    // The intervals stretched, the later samples shifted.
    double shift = 0.0;
    std::vector<double> t_old = tr.t_s;
    for (std::size_t k = 1; k < n; ++k) {
      const double dt = t_old[k] - t_old[k - 1];
      const double added = (factor[k] - 1.0) * dt;
      if (added > 0.0) {
        stretched[k] = 1;
        add_interval_time(tr, k, added, stop_and_go_link);
        tr.slowed_s += added;
      }
      shift += added;
      tr.t_s[k] = t_old[k] + shift;
    }
    tr.duration_s += shift;
    finish_trajectory(robot, tr);
  }
  tr.slowed_intervals += static_cast<int>(std::count(stretched.begin(), stretched.end(), 1));
  return std::max(tr.max_velocity_ratio, tr.max_acceleration_ratio) <= 1.0;
}

void replace_joint_move(const Robot& robot, TimedTrajectory& tr, const JointMove& move, const TimedTrajectory& piece) {
  if (!(move.start < move.end && move.end < tr.size()))
    throw std::invalid_argument("replace_joint_move: samples (" + std::to_string(move.start) + ", " +
                                std::to_string(move.end) + "] are not a move of a trajectory of " +
                                std::to_string(tr.size()) + " samples");
  if (piece.size() == 0 || !piece.q.back().isApprox(tr.q[move.end], 1e-9))
    throw std::invalid_argument("replace_joint_move: the new move does not end where the old one did");
  const double t_start = tr.t_s[move.start];
  const double delta = piece.duration_s - move.duration_s(tr);
  const auto first = static_cast<std::ptrdiff_t>(move.start + 1), last = static_cast<std::ptrdiff_t>(move.end + 1);
  auto splice = [&](auto& dst, const auto& src) {
    dst.erase(dst.begin() + first, dst.begin() + last);
    dst.insert(dst.begin() + first, src.begin(), src.end());
  };
  const std::size_t after = move.start + 1 + piece.size();  // first sample after the new move
  splice(tr.t_s, piece.t_s);
  splice(tr.q, piece.q);
  splice(tr.nozzle, piece.nozzle);
  splice(tr.spraying, piece.spraying);
  splice(tr.pass_index, piece.pass_index);
  splice(tr.region_index, piece.region_index);
  splice(tr.kind, piece.kind);
  for (std::size_t k = move.start + 1; k < after; ++k) tr.t_s[k] += t_start;
  for (std::size_t k = after; k < tr.size(); ++k) tr.t_s[k] += delta;
  tr.duration_s += delta;
  tr.transit_time_s += delta;
  (move.region_index < 0 ? tr.cycle_time.transits_s : tr.cycle_time.stop_and_go_s) += delta;
  finish_trajectory(robot, tr);
}

}  // namespace shotcrete
