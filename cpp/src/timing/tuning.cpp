// Timing tuning: the region joint model the swarm evaluates its particles on, and the per-region
// AIWCPSO over the timing parameters.
#include "shotcrete/timing/tuning.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <tuple>

#include "detail.hpp"
#include "shotcrete/robot/joint_tracking.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/trajectory.hpp"  // quintic_nozzle_duration

namespace shotcrete {

using namespace timing_detail;

// The config's bound, or more where fast end passes need it: room for k1, k2 down to 0.5 at the
// nozzle acceleration limit (start peak v^2 (2 - k1) / (k1 s)), and for leads of min_lead_s at
// any k1, k2 (lead_lengths).
double timing_detail::swarm_max_lead(const std::vector<Pass>& passes, const TimingConfig& timing) {
  double v_end = 0.0;
  if (!passes.empty() && !passes.front().waypoints.empty() && !passes.back().waypoints.empty())
    v_end = std::max(passes.front().speed_at(0), passes.back().speed_at(passes.back().waypoints.size() - 1));
  return std::max({timing.max_lead_length_m, 3.0 * v_end * v_end / timing.nozzle_max_accel_mps2, v_end * timing.min_lead_s});
}

// ------------------------------------------------------------------------------------------------
// RegionJointModel
// ------------------------------------------------------------------------------------------------

namespace {
void widen(NozzleCheck& c, double v, double a) {
  c.max_speed_mps = std::max(c.max_speed_mps, v);
  c.max_accel_mps2 = std::max(c.max_accel_mps2, a);
}
}  // namespace

RegionJointModel::RegionJointModel(const Robot& robot, const std::vector<Pass>& passes, double max_lead_m,
                                   const TimingConfig& timing, const Eigen::VectorXd& seed,
                                   const RobotConfig& robot_config, double step_m, const NullSpaceObjective& objective)
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
    st.q = timing_joint_path(robot, poses, q_prev, robot_config, &tracked, objective);
    tracked_ = tracked_ && tracked;
    finite_differences(st.s, st.q, st.dq, st.ddq, true);
    if (c > 0)
      move_s_.push_back(quintic_nozzle_duration(robot, q_prev, st.q.front(), timing.nozzle_max_speed_mps,
                                                timing.nozzle_max_accel_mps2));
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

bool RegionJointModel::tuned_at(double s) const {
  double local = 0.0;
  const PathPiece& piece = path_.pieces()[path_.locate(s, local)];
  return piece.kind == SegmentKind::Lead || piece.kind == SegmentKind::Turn ||
         (piece.kind == SegmentKind::Link && (piece.motion == PieceMotion::ByKind || piece.motion == PieceMotion::Creep));
}

void RegionJointModel::check_samples(const SpeedProfile& prof, double offset, double rate_hz, Evaluation& ev) const {
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
    widen(ev.nozzle, st.v_mps, accel);
    if (tuned_at(s)) {
      ev.tuned_velocity_ratio = std::max(ev.tuned_velocity_ratio, rv);
      ev.tuned_acceleration_ratio = std::max(ev.tuned_acceleration_ratio, ra);
      widen(ev.tuned_nozzle, st.v_mps, accel);
    }
  }
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
  check_samples(prof, offset, rate_hz, ev);
  // Exact peaks of the profile's speed changes (the sampling may step over them).
  double t0 = 0.0;
  for (const auto& p : prof.pieces()) {
    widen(ev.nozzle, 0.0, p.peak_accel_mps2());
    if (tuned_at(offset + prof.at(t0 + 0.5 * p.duration_s).s_m)) widen(ev.tuned_nozzle, 0.0, p.peak_accel_mps2());
    t0 += p.duration_s;
  }
  for (NozzleCheck* c : {&ev.nozzle, &ev.tuned_nozzle}) {
    c->speed_ratio = c->max_speed_mps / limits.max_speed_mps;
    c->accel_ratio = c->max_accel_mps2 / limits.max_accel_mps2;
  }
  Eigen::VectorXd q, dq, ddq;
  interpolate(stretches_.front(), offset, q, dq, ddq);
  ev.q_first = q;
  interpolate(stretches_.back(), offset + prof.length_m(), q, dq, ddq);
  ev.q_last = q;
  return ev;
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

struct TuningContext {
  const Robot* robot;  // nullptr: nozzle limits only
  const TimingConfig& timing;
  const RobotConfig& robot_config;
  NozzleLimits limits;
  // The swarm keeps a margin on the joint limits: its arc-length model and the final sampled
  // trajectory differ slightly (start configuration, discretisation).
  double joint_share;
  const NullSpaceObjective& objective;  // the regions' tracking (plan_for_arm's clearance term)
};

// The joint model of region r from q_prev. The longest lead-ins / lead-outs may leave the reach:
// max_lead is halved until the region's joint path exists (time_plan does the same).
RegionJointModel region_model(const TuningContext& ctx, const std::vector<Pass>& passes, std::size_t r,
                              const Eigen::VectorXd& q_prev, double& max_lead) {
  for (;;) {
    try {
      return RegionJointModel(*ctx.robot, passes, max_lead, ctx.timing, q_prev, ctx.robot_config, 0.005, ctx.objective);
    } catch (const std::exception& e) {
      if (max_lead <= 0.05)
        throw std::runtime_error("tune_timing: region " + std::to_string(r) + " (with " + num(max_lead) +
                                 " m leads): " + e.what());
      max_lead = std::max(0.05, 0.5 * max_lead);
    }
  }
}

// Fitness of a region's parameters: execution time of the region plus the transit to it from
// q_prev; infeasible -> penalty above any time (1e6 x the worst ratio). q_last (optional): the
// joints where the region ends.
struct RegionCost {
  const TuningContext& ctx;
  const std::vector<Pass>& passes;
  const Eigen::VectorXd& q_prev;
  const std::optional<RegionJointModel>& model;

  double operator()(const TimingParams& p, Eigen::VectorXd* q_last) const {
    double time = 0.0, worst = 0.0;
    if (model) {
      const auto ev = model->evaluate(p, ctx.limits);
      time = ev.duration_s + quintic_nozzle_duration(*ctx.robot, q_prev, ev.q_first, ctx.timing.nozzle_max_speed_mps,
                                                     ctx.timing.nozzle_max_accel_mps2);
      // Only what the parameters shape (see Evaluation): an excess elsewhere would make every
      // particle infeasible alike; plan_for_arm and time_plan deal with it.
      const double jm = ctx.joint_share;
      worst = std::max({ev.tuned_velocity_ratio / jm, ev.tuned_acceleration_ratio / jm, ev.tuned_nozzle.speed_ratio,
                        ev.tuned_nozzle.accel_ratio});
      if (q_last) *q_last = ev.q_last;
    } else {
      const CartesianPath path = timing_region_path(passes, p.start_length_m, p.end_length_m, ctx.timing);
      const SpeedProfile prof = region_profile(path, p);
      const auto c = check_nozzle(path, prof, ctx.limits, 100.0);
      time = prof.duration_s();
      worst = std::max(c.speed_ratio, c.accel_ratio);
    }
    return worst <= 1.0 ? time : 1e6 * worst;
  }
};

// The swarm's box over (k1, k2, start length, end length, turn speed, turn acceleration) and its
// first particle (the config's parameters).
struct SearchBox {
  Eigen::VectorXd lo, hi, x0;
};
SearchBox search_box(const std::vector<Pass>& passes, const TimingConfig& timing, double min_lead, double max_lead) {
  const TimingParams p0 = TimingParams::from_config(timing);
  double vmin_pass = std::numeric_limits<double>::infinity(), vsum = 0.0;
  for (const auto& p : passes) {
    vmin_pass = std::min(vmin_pass, p.speed_mps);
    vsum += p.speed_mps;
  }
  const double turn_accel0 = p0.turn_accel_mps2 > 0.0 ? p0.turn_accel_mps2 : p0.speed_change_accel_mps2;
  SearchBox b{Eigen::VectorXd(6), Eigen::VectorXd(6), Eigen::VectorXd(6)};
  b.lo << 0.05, 0.0, min_lead, min_lead, std::min(0.02, vmin_pass), std::min(0.1, turn_accel0);
  b.hi << 1.0, 0.95, max_lead, max_lead, timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2;
  b.x0 << p0.k1, p0.k2, p0.start_length_m, p0.end_length_m,
      p0.turn_speed_mps > 0.0 ? p0.turn_speed_mps : vsum / static_cast<double>(passes.size()), turn_accel0;
  return b;
}

}  // namespace

TimingTuning tune_timing(const Robot* robot, const std::vector<std::vector<Pass>>& regions, const Eigen::VectorXd& q_start,
                         const TimingConfig& timing, const RobotConfig& robot_config, const ProgressFn& progress,
                         const NullSpaceObjective& objective) {
  const auto t_start = std::chrono::steady_clock::now();
  if (regions.empty()) throw std::invalid_argument("tune_timing: no regions");
  if (robot && q_start.size() != robot->dof()) throw std::invalid_argument("tune_timing: q_start does not match the robot");
  const TuningContext ctx{robot, timing, robot_config, NozzleLimits{timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2},
                          1.0 - timing.joint_limit_margin, objective};
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
    if (robot) model.emplace(region_model(ctx, regions[r], r, q_prev, max_lead));
    const double min_lead = std::min(0.02, max_lead);
    const RegionCost cost{ctx, regions[r], q_prev, model};
    // A particle's leads at least as long as time_plan makes them for the pump's ramps
    // (lead_lengths' min_lead_s; its acceleration floor is the swarm's own nozzle check).
    auto with_lead_floor = [&](TimingParams p) {
      const double inf = std::numeric_limits<double>::infinity();
      std::tie(p.start_length_m, p.end_length_m) = lead_lengths(regions[r], p, inf, inf);
      return p;
    };
    TimingParams p0_region = p0;
    p0_region.start_length_m = std::clamp(p0.start_length_m, min_lead, max_lead);
    p0_region.end_length_m = std::clamp(p0.end_length_m, min_lead, max_lead);
    p0_region = with_lead_floor(p0_region);
    // Leads the model does not reach (its max_lead halved to stay within the reach): infeasible.
    auto modelled = [&](const TimingParams& p) {
      return !model || (p.start_length_m <= max_lead + 1e-12 && p.end_length_m <= max_lead + 1e-12);
    };
    const double initial_region = modelled(p0_region) ? cost(p0_region, nullptr) : 2e6;
    out.initial_feasible = out.initial_feasible && initial_region < 1e6;
    initial += initial_region;
    const SearchBox box = search_box(regions[r], timing, min_lead, max_lead);
    PsoOptions opt = PsoOptions::from_config(timing);
    opt.seed += r;
    // Region r's share of the budget ends at (r + 1) / n of it: time a region leaves unused
    // goes to the next ones.
    const double share = timing.pso_time_budget_s * static_cast<double>(r + 1) / static_cast<double>(regions.size());
    opt.deadline = t_start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(share));
    if (progress) progress("tuning timing", static_cast<double>(r) / static_cast<double>(regions.size()));
    out.pso.push_back(pso_minimize([&](const Eigen::VectorXd& x) {
                                     const TimingParams p = with_lead_floor(params_of(x, timing));
                                     return modelled(p) ? cost(p, nullptr) : 2e6;
                                   },
                                   box.lo, box.hi, opt, {box.x0}));
    out.regions_cut_by_budget += out.pso.back().stopped_by_deadline ? 1 : 0;
    // No feasible particle: the config's parameters, which time_plan eases where the arm needs it.
    out.feasible.push_back(out.pso.back().best_f < 1e6);
    out.params.push_back(out.feasible.back() ? with_lead_floor(params_of(out.pso.back().best_x, timing)) : p0);
    out.duration_s += out.feasible.back() ? out.pso.back().best_f : initial_region;
    const TimingParams& used = out.feasible.back() ? out.params.back() : p0_region;
    if (model && modelled(used)) cost(used, &q_prev);
  }
  out.initial_duration_s = out.initial_feasible ? initial : std::numeric_limits<double>::infinity();
  if (progress) progress("tuning timing", 1.0);
  return out;
}

}  // namespace shotcrete
