// The job summary and its JSON (see job_summary.hpp).
#include "shotcrete/pipeline/job_summary.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "shotcrete/io/json_writer.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/robot/joint_tracking.hpp"  // finite_differences
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/surface/grid.hpp"

namespace shotcrete {

namespace {

TdStatsMm td_stats_mm(const Eigen::VectorXd& td_m, const std::vector<bool>& valid) {
  double sum = 0.0, sum2 = 0.0;
  double lo = std::numeric_limits<double>::infinity(), hi = -lo, abs_max = 0.0;
  int n = 0;
  for (std::size_t c = 0; c < valid.size(); ++c) {
    if (!valid[c]) continue;
    const double r = td_m[static_cast<Eigen::Index>(c)] * 1000.0;
    sum += r;
    sum2 += r * r;
    lo = std::min(lo, r);
    hi = std::max(hi, r);
    abs_max = std::max(abs_max, std::abs(r));
    ++n;
  }
  if (n == 0) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    return {nan, nan, nan, nan, nan};
  }
  return {sum / n, lo, hi, std::sqrt(sum2 / n), abs_max};
}

// a . b with fused multiply-adds in index order, as numpy's dot (OpenBLAS) computed the FK check
// for report.json before it moved here: near 1, acos turns the last bit of an axis dot product into
// 1e-8 rad, so the figure depends on the rounding.
double dot_fma(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::fma(a.z(), b.z(), std::fma(a.y(), b.y(), a.x() * b.x()));
}

std::map<int, int> levels_of_td(const Eigen::VectorXd& td_m, const std::vector<bool>& valid) {
  std::vector<int> levels(valid.size(), kNoDataLevel);
  for (std::size_t c = 0; c < valid.size(); ++c)
    if (valid[c]) levels[c] = level_of_td_mm(td_m[static_cast<Eigen::Index>(c)] * 1000.0);
  return level_counts(levels);
}

int count_passes(const Round& round) {
  int n = 0;
  for (const auto& region : round.regions) n += static_cast<int>(region.passes.size());
  return n;
}

IkSummary summarise_ik(const ArmPlan& arm_plan, const Robot& robot, int check_every) {
  IkSummary ik;
  for (const auto& round : arm_plan.plan.rounds)
    for (const auto& region : round.regions) {
      ++ik.regions;
      for (const auto& pass : region.passes) ik.poses += static_cast<int>(pass.waypoints.size());
    }
  ik.replans = arm_plan.replans;
  ik.learned_speed_bounds = static_cast<int>(arm_plan.learned.speed_mps.size());
  if (ik.regions == 0) return ik;
  if (!arm_plan.trajectory) {
    ik.solved = false;
    ik.error = arm_plan.timing_error;
    return ik;
  }
  // Independent of the tracking itself: FK of the timed joints against the nozzle poses.
  const TimedTrajectory& tr = *arm_plan.trajectory;
  const std::size_t step = static_cast<std::size_t>(std::max(1, check_every));
  ik.checked = true;
  for (std::size_t i = 0; i < tr.size(); i += step) {
    const Eigen::Isometry3d T = robot.fk(tr.q[i]);
    const Eigen::Vector3d axis = T.linear().col(2), miss = T.translation() - tr.nozzle[i].position_m;
    ik.worst_position_error_m = std::max(ik.worst_position_error_m, std::sqrt(dot_fma(miss, miss)));
    ik.worst_angle_error_rad =
        std::max(ik.worst_angle_error_rad, std::acos(std::clamp(dot_fma(axis, tr.nozzle[i].axis), -1.0, 1.0)));
    ++ik.samples_checked;
  }
  ik.untracked_regions = tr.untracked_regions;
  return ik;
}

SwarmSummary summarise_swarm(const ArmPlan& arm_plan) {
  SwarmSummary s;
  s.used = arm_plan.tuned_timing_used;
  s.error = arm_plan.tuning_error;
  s.config_timing_duration_s = arm_plan.config_duration_s;
  if (arm_plan.trajectory) s.duration_s = arm_plan.trajectory->duration_s;
  if (const auto& tun = arm_plan.tuning) {
    s.regions_tuned = static_cast<int>(std::count_if(tun->feasible.begin(), tun->feasible.end(), [](char f) { return f != 0; }));
    s.regions = static_cast<int>(tun->feasible.size());
    for (const auto& p : tun->pso) s.evaluations += p.evaluations;
    s.regions_cut_by_budget = tun->regions_cut_by_budget;
    s.params = tun->params;
  }
  return s;
}

// ---------------------------------------------------------------------------------------------
// JSON
// ---------------------------------------------------------------------------------------------
void write(JsonWriter& w, const std::map<int, int>& counts) {
  w.begin_object();
  for (const auto& [level, n] : counts) w.field(std::to_string(level), n);
  w.end_object();
}

void write(JsonWriter& w, const TdStatsMm& s) {
  w.begin_object().field("mean", s.mean).field("min", s.min).field("max", s.max).field("rms", s.rms);
  w.field("abs_max", s.abs_max).end_object();
}

void write(JsonWriter& w, const DepositDifferenceMm& d) {
  w.begin_object().field("rms", d.rms).field("max_abs", d.max_abs).field("mean", d.mean).end_object();
}

void write(JsonWriter& w, const ExecutedSummary& e) {
  w.begin_object().field("sprayed_m3", e.sprayed_m3).field("rebound_m3", e.rebound_m3);
  w.field("on_wall_m3", e.on_wall_m3).field("outside_m3", e.outside_m3).field("balance_error", e.balance_error);
  w.key("flow").begin_object().field("ramp_s", e.ramp_s).field("switches", e.switches);
  w.field("commanded_switches", e.commanded_switches).field("shortest_on_s", e.shortest_on_s);
  w.field("shortest_off_s", e.shortest_off_s).field("flow_on_s", e.flow_on_s).field("commanded_on_s", e.commanded_on_s);
  w.field("bridged_s", e.bridged_s).field("bridged_volume_m3", e.bridged_volume_m3);
  w.field("extended_s", e.extended_s).field("extended_volume_m3", e.extended_volume_m3);
  w.field("trimmed_s", e.trimmed_s).field("dropped_s", e.dropped_s);
  w.end_object().end_object();
}

void write(JsonWriter& w, const RoundSummary& r) {
  w.begin_object().field("round", r.round).field("kind", r.kind).field("level", r.level);
  w.field("regions", r.regions).field("passes", r.passes).field("spray_time_s", r.spray_time_s);
  w.field("order_method", r.order_method).field("link_length_m", r.link_length_m);
  w.key("levels_before");
  write(w, r.levels_before);
  w.key("levels_after");
  write(w, r.levels_after);
  w.end_object();
}

void write(JsonWriter& w, const IkSummary& ik) {
  w.begin_object().field("poses", ik.poses).field("regions", ik.regions).field("replans", ik.replans);
  w.field("learned_speed_bounds", ik.learned_speed_bounds).field("solved", ik.solved);
  if (!ik.solved) w.field("error", ik.error);
  if (ik.checked) {
    w.field("samples_checked", ik.samples_checked).field("worst_position_error_m", ik.worst_position_error_m);
    w.field("worst_angle_error_rad", ik.worst_angle_error_rad).field("untracked_regions", ik.untracked_regions);
  }
  w.end_object();
}

void write(JsonWriter& w, const TimingParams& p) {
  w.begin_object().field("k1", p.k1).field("k2", p.k2).field("start_length_m", p.start_length_m);
  w.field("end_length_m", p.end_length_m).field("turn_speed_mps", p.turn_speed_mps);
  w.field("turn_accel_mps2", p.turn_accel_mps2).end_object();
}

// Minimum distances: null where nothing was measured (no pair to check).
void write_distance(JsonWriter& w, double d) {
  if (std::isfinite(d)) w.value(d);
  else w.null();
}

void write(JsonWriter& w, const TransitReport& t) {
  w.begin_object().field("checked", t.moves_checked).field("rerouted", t.rerouted).field("failed", t.failed);
  w.field("detour_time_s", t.detour_time_s).key("detours").begin_array();
  for (const auto& d : t.detours) {
    w.begin_object().field("move", d.move).field("region_index", d.region_index).field("start_time_s", d.start_time_s);
    w.field("straight_samples_below", d.straight_samples_below).field("straight_worst", d.straight_worst);
    w.field("straight_min_allowance_m", d.straight_min_allowance_m).field("rerouted", d.rerouted).field("eased", d.eased).key("reason");
    if (d.reason.empty()) w.null();
    else w.value(d.reason);
    w.key("vias").begin_array();
    for (const auto& v : d.vias) {
      w.begin_array();
      for (Eigen::Index j = 0; j < v.size(); ++j) w.value(v[j]);
      w.end_array();
    }
    w.end_array().key("via_allowance_m").begin_array();
    for (double a : d.via_allowance_m) w.value(a);
    w.end_array().key("min_allowance_m");
    if (d.rerouted || d.eased) w.value(d.min_allowance_m);
    else w.null();
    w.field("straight_duration_s", d.straight_duration_s).field("duration_s", d.duration_s);
    w.field("sampled_nodes", d.sampled_nodes).end_object();
  }
  w.end_array().end_object();
}

void write(JsonWriter& w, const ClearanceReport& c, double self_margin_m, const std::optional<TransitReport>& transits) {
  w.begin_object().field("samples_below_margin", c.samples_below_margin());
  w.field("moving_samples_below_margin", c.moving_samples_below_margin()).field("samples", c.samples);
  w.field("octree_resolution_m", c.octree_resolution_m).field("wall_points", static_cast<long>(c.wall_points));
  w.field("carrier_points", c.carrier_points);
  w.field("octree_leaves", static_cast<long>(c.octree_leaves)).field("wall_queries", static_cast<long>(c.wall_queries));
  w.field("field_queries", static_cast<long>(c.field_queries)).field("exact_queries", static_cast<long>(c.exact_queries));
  w.field("self_queries", static_cast<long>(c.self_queries)).key("links").begin_array();
  for (const auto& l : c.links) {
    w.begin_object().field("link", l.link).field("fixed", l.fixed).field("margin_m", l.margin_m).key("min_m");
    write_distance(w, l.min_m);
    w.field("at_time_s", l.at_time_s).key("closest_m").begin_array();
    for (int i = 0; i < 3; ++i) w.value(l.closest_m[i]);
    w.end_array().field("samples_below_margin", l.samples_below_margin).end_object();
  }
  w.end_array().key("self").begin_object().field("link_a", c.self.link_a).field("link_b", c.self.link_b);
  w.field("margin_m", self_margin_m).key("min_m");
  write_distance(w, c.self.min_m);
  w.field("at_time_s", c.self.at_time_s).field("samples_below_margin", c.self.samples_below_margin).end_object();
  if (transits) {
    w.key("transits");
    write(w, *transits);
  }
  w.end_object();
}

void write(JsonWriter& w, const SwarmSummary& s) {
  w.begin_object().field("used", s.used).key("error");
  if (s.error.empty()) w.null();
  else w.value(s.error);
  w.field("config_timing_duration_s", s.config_timing_duration_s).key("duration_s");
  if (s.duration_s) w.value(*s.duration_s);
  else w.null();
  w.field("regions_tuned", s.regions_tuned).field("regions", s.regions).field("evaluations", s.evaluations);
  w.field("regions_cut_by_budget", s.regions_cut_by_budget);
  w.key("params").begin_array();
  for (const auto& p : s.params) write(w, p);
  w.end_array().end_object();
}

void write(JsonWriter& w, const CycleTimeBreakdown& b) {
  w.begin_object().field("spraying", b.spraying_s).field("turn_arounds", b.turn_arounds_s).field("leads", b.leads_s);
  w.field("transits", b.transits_s).field("stop_and_go", b.stop_and_go_s).field("other", b.other_s).end_object();
}

void write_optional(JsonWriter& w, const std::optional<double>& v) {
  if (v) w.value(*v);
  else w.null();
}

// What slow_to_joint_limits did: {added_s, spraying_s, intervals, ratio_before}.
void write_slowed(JsonWriter& w, const TrajectorySummary& t) {
  w.key("slowed_to_joint_limits").begin_object().field("added_s", t.slowed_s).field("spraying_s", t.slowed_spraying_s);
  w.field("intervals", t.slowed_intervals);
  w.field("ratio_before", t.ratio_before_slowing).end_object();
}

// Worst nozzle speed and acceleration over the limits, from the sampled nozzle positions.
void nozzle_ratios(const TimedTrajectory& t, const NozzleLimits& limits, TrajectorySummary& s) {
  std::vector<Eigen::VectorXd> p, v, a;
  p.reserve(t.size());
  for (const auto& pose : t.nozzle) p.emplace_back(pose.position_m);
  finite_differences(t.t_s, p, v, a);
  for (std::size_t i = 0; i < p.size(); ++i) {
    s.max_nozzle_speed_ratio = std::max(s.max_nozzle_speed_ratio, v[i].norm() / limits.max_speed_mps);
    s.max_nozzle_accel_ratio = std::max(s.max_nozzle_accel_ratio, a[i].norm() / limits.max_accel_mps2);
  }
}

// The report's trajectory section: the trajectory's scalars it has always carried, the sample
// rate and the duration with the config's timing, and the swarm.
void write_report_trajectory(JsonWriter& w, const JobSummary& s) {
  const TrajectorySummary& t = *s.trajectory;
  w.begin_object().field("duration_s", t.duration_s).field("spray_time_s", t.spray_time_s);
  w.field("transit_time_s", t.transit_time_s).field("samples", t.samples).field("rate_hz", s.trajectory_rate_hz);
  w.field("max_velocity_ratio", t.max_velocity_ratio).field("max_acceleration_ratio", t.max_acceleration_ratio);
  w.field("max_nozzle_speed_ratio", t.max_nozzle_speed_ratio).field("max_nozzle_accel_ratio", t.max_nozzle_accel_ratio);
  w.field("max_position_violation_rad", t.max_position_violation_rad);
  w.field("max_position_violation_m", t.max_position_violation_m);
  w.field("config_timing_duration_s", s.config_timing_duration_s);
  write_slowed(w, t);
  if (s.swarm) {
    w.key("swarm");
    write(w, *s.swarm);
  }
  w.end_object();
}

}  // namespace

ExecutedSummary summarise_executed(const ExecutedDeposit& ex) {
  ExecutedSummary e;
  e.sprayed_m3 = ex.volumes.sprayed_m3;
  e.rebound_m3 = ex.volumes.rebound_m3;
  e.on_wall_m3 = ex.volumes.on_wall_m3;
  e.outside_m3 = ex.volumes.outside_m3;
  e.balance_error = ex.volumes.balance_error();
  e.switches = ex.flow.switches();
  e.commanded_switches = ex.flow.commanded_switches;
  e.shortest_on_s = ex.flow.shortest_on_s();
  e.shortest_off_s = ex.flow.shortest_off_s();
  e.flow_on_s = ex.flow.on_time_s();
  e.commanded_on_s = ex.flow.commanded_on_s;
  e.bridged_s = ex.flow.bridged_s;
  e.bridged_volume_m3 = ex.bridged_volume_m3;
  e.extended_s = ex.flow.extended_s;
  e.extended_volume_m3 = ex.extended_volume_m3;
  e.trimmed_s = ex.flow.trimmed_s;
  e.dropped_s = ex.flow.dropped_s;
  e.ramp_s = ex.flow.ramp_s;
  return e;
}

TrajectorySummary summarise_trajectory(const TimedTrajectory& t, const NozzleLimits& nozzle_limits) {
  if (!(nozzle_limits.max_speed_mps > 0.0) || !(nozzle_limits.max_accel_mps2 > 0.0))
    throw std::invalid_argument("summarise_trajectory: the nozzle limits must be > 0 (speed " +
                                std::to_string(nozzle_limits.max_speed_mps) + " m/s, acceleration " +
                                std::to_string(nozzle_limits.max_accel_mps2) + " m/s^2)");
  TrajectorySummary s;
  s.samples = t.size();
  s.duration_s = t.duration_s;
  s.spray_time_s = t.spray_time_s;
  s.transit_time_s = t.transit_time_s;
  s.cycle_time = t.cycle_time;
  nozzle_ratios(t, nozzle_limits, s);
  s.max_velocity_ratio = t.max_velocity_ratio;
  s.max_acceleration_ratio = t.max_acceleration_ratio;
  s.worst_velocity_joint = t.worst_velocity_joint;
  s.worst_acceleration_joint = t.worst_acceleration_joint;
  s.max_position_violation_rad = t.max_position_violation_rad;
  s.max_position_violation_m = t.max_position_violation_m;
  s.untracked_regions = t.untracked_regions;
  s.slowed_s = t.slowed_s;
  s.slowed_spraying_s = t.slowed_spraying_s;
  s.slowed_intervals = t.slowed_intervals;
  s.ratio_before_slowing = t.ratio_before_slowing;
  return s;
}

std::string to_json(const TrajectorySummary& t) {
  JsonWriter w;
  w.begin_object().field("samples", t.samples).field("duration_s", t.duration_s);
  w.field("spray_time_s", t.spray_time_s).field("transit_time_s", t.transit_time_s).key("cycle_time_breakdown_s");
  write(w, t.cycle_time);
  w.field("max_velocity_ratio", t.max_velocity_ratio).field("max_acceleration_ratio", t.max_acceleration_ratio);
  w.field("max_nozzle_speed_ratio", t.max_nozzle_speed_ratio).field("max_nozzle_accel_ratio", t.max_nozzle_accel_ratio);
  w.field("worst_velocity_joint", t.worst_velocity_joint).field("worst_acceleration_joint", t.worst_acceleration_joint);
  w.field("max_position_violation_rad", t.max_position_violation_rad);
  w.field("max_position_violation_m", t.max_position_violation_m).field("untracked_regions", t.untracked_regions);
  write_slowed(w, t);
  w.end_object();
  return w.str();
}

namespace {
std::string fmt(double v, int digits) {
  std::ostringstream o;
  o.setf(std::ios::fixed);
  o.precision(digits);
  o << v;
  return o.str();
}
}  // namespace

JobSummary summarise_job(const Surface& surface, const ArmPlan& arm_plan, const Robot& given_robot, const Config& config,
                         const JobSummaryOptions& options) {
  const Robot robot = placed_robot(given_robot, arm_plan.base_placement);  // the arm the trajectory is of
  const Grid& grid = surface.grid;
  const Plan& plan = arm_plan.plan;
  if (plan.td_after_m.size() != static_cast<Eigen::Index>(grid.valid.size()))
    throw std::invalid_argument("summarise_job: the plan has " + std::to_string(plan.td_after_m.size()) +
                                " cells, the surface's grid " + std::to_string(grid.valid.size()) +
                                ": plan the same surface");
  JobSummary s;
  s.mode = enum_name(config.planner.mode);
  s.cells = grid.valid_count();
  s.grid_n_theta = grid.n_theta;
  s.grid_cell_size_m = grid.cell_size_m;
  s.spot_diameter_m = 2.0 * config.deposition.spot_radius_m;
  s.grid_n_d = grid.n_d;
  s.points_in = options.points_in;
  s.points_used = static_cast<long>(surface.cloud.size());
  s.design_radius_m = surface.profile.radius_m;
  s.design_shape = surface.profile.is_circle() ? "circle" : "section";
  s.design_section_path = config.profile.section_path;
  s.design_theta_min_deg = surface.profile.theta_min_rad() * 180.0 / M_PI;
  s.design_theta_max_deg = surface.profile.theta_max_rad() * 180.0 / M_PI;
  s.design_arc_length_m = surface.profile.radius_m * (surface.profile.theta_max_rad() - surface.profile.theta_min_rad());
  s.axis_fit_rms_m = surface.axis_fit_rms_m;
  s.axis_estimated = surface.axis_fit.has_value();
  s.axis_origin_m = surface.axis.origin_m;
  s.bay = surface.bay;
  s.points_not_wall = grid.points_not_wall;
  s.points_outside_bay = grid.points_outside_bay;
  s.points_obstacle = grid.points_obstacle;
  s.axis_direction = surface.axis.ex;
  if (surface.axis_fit) {
    s.axis_fit_arc_deg = surface.axis_fit->arc_rad * 180.0 / M_PI;
    s.axis_fit_points = surface.axis_fit->points;
    s.axis_fit_inlier_share = surface.axis_fit->inlier_share;
  }
  s.levels_before = level_counts(surface.levels);
  s.td_before_mm = td_stats_mm(grid.td_m, grid.valid);

  s.planned_levels_after = levels_of_td(plan.td_after_m, grid.valid);
  s.planned_residual_mm = td_stats_mm(plan.td_after_m, grid.valid);
  s.levels_after = s.planned_levels_after;
  s.residual_mm = s.planned_residual_mm;
  if (const auto& ex = arm_plan.executed) {
    s.deposit_source = "executed";
    s.levels_after = levels_of_td(ex->td_after_m, grid.valid);
    s.residual_mm = td_stats_mm(ex->td_after_m, grid.valid);
    // TD planned - TD executed = deposit executed - deposit planned (both from the same scan).
    s.planned_vs_executed_mm = deposit_difference_mm(plan.td_after_m, ex->td_after_m, grid.valid);
    s.executed = summarise_executed(*ex);
  }

  s.rounds = static_cast<int>(plan.rounds.size());
  for (std::size_t i = 0; i < plan.rounds.size(); ++i) {
    const Round& r = plan.rounds[i];
    RoundSummary rs{static_cast<int>(i) + 1, enum_name(r.kind), r.level, static_cast<int>(r.regions.size()), count_passes(r),
                    r.spray_time_s, r.order_method, r.link_length_m, r.levels_before, r.levels_after};
    s.regions += rs.regions;
    s.passes += rs.passes;
    s.link_length_m += r.link_length_m;
    s.rounds_detail.push_back(std::move(rs));
  }
  s.stop_reason = plan.stop_reason.text();
  s.warnings = plan.warnings;
  if (!surface.bay.warning.empty()) s.warnings.insert(s.warnings.begin(), surface.bay.warning);
  s.unreachable_cells = static_cast<int>(plan.unreachable_cells.size());
  s.spray_time_s = plan.spray_time_s;
  s.required_volume_m3 = plan.required_volume_m3;
  s.deposition_rate_m3ph = plan.deposition_rate_m3ps * 3600.0;
  s.physical_limit_s = plan.physical_limit_s;
  if (plan.physical_limit_s > 0) s.spray_time_ratio = plan.spray_time_s / plan.physical_limit_s;
  s.sprayed_volume_m3 = plan.spray_time_s * plan.deposition_rate_m3ps;
  s.speed_capped = plan.speed_capped;

  s.ik = summarise_ik(arm_plan, robot, options.check_every);
  s.trajectory_rate_hz = config.timing.trajectory_rate_hz;
  s.config_timing_duration_s = arm_plan.config_duration_s;
  if (arm_plan.trajectory) {
    s.trajectory = summarise_trajectory(*arm_plan.trajectory,
                                        NozzleLimits{config.timing.nozzle_max_speed_mps, config.timing.nozzle_max_accel_mps2});
    s.cycle_time_s = s.trajectory->duration_s;
    if (plan.physical_limit_s > 0) s.cycle_time_ratio = *s.cycle_time_s / plan.physical_limit_s;
    if (arm_plan.tuning || !arm_plan.tuning_error.empty()) s.swarm = summarise_swarm(arm_plan);
  }
  if (arm_plan.clearance) s.clearance = arm_plan.clearance;
  if (arm_plan.transits) s.transits = arm_plan.transits;
  if (arm_plan.obstructed) {
    s.obstructed = arm_plan.obstructed;
    // Those left above level 0 are counted as obstructed, not among the cells the plan left short.
    const Eigen::VectorXd& td = arm_plan.executed ? arm_plan.executed->td_after_m : plan.td_after_m;
    for (int c : s.obstructed->cells)
      if (std::isfinite(td[c]) && level_of_td_mm(td[c] * 1000.0) > 0) ++s.obstructed_above_level_0;
  }
  s.self_margin_m = config.clearance.self_margin_m;
  if (arm_plan.base_placement.checked) {
    s.base_placement = arm_plan.base_placement;
    const BasePlacement& b = *s.base_placement;
    // What the configured place lacks: room for the base's own links, or room to slew.
    const std::string lacks =
        b.configured_base_room_m < 0.0
            ? "the base's fixed links come within clearance.base_margin_m of the scan at robot.base_position_m (" +
                  fmt(-b.configured_base_room_m, 2) + " m short)"
            : "the arm has too little room to slew every way at robot.base_position_m (" + fmt(b.configured_room_m, 2) +
                  " m of " + fmt(config.clearance.via_allowance_m, 2) + " m beyond the margins toward slew " +
                  fmt(b.configured_short_slew_rad, 2) + " rad)";
    if (b.moved)
      s.warnings.push_back(lacks + ": the base is placed " + fmt(std::abs(b.shift_m), 1) + " m " +
                           (b.shift_m < 0.0 ? "back" : "forward") + " along the axis (report.json base_placement)");
    else if (!b.found)
      s.warnings.push_back(lacks + " and no place within robot.max_base_shift_m (" + fmt(config.robot.max_base_shift_m, 1) +
                           " m) along the axis has room without passing through the scan: the base stays");
  }
  if (arm_plan.start) {
    s.start = arm_plan.start;
    s.joint_names = robot.joint_names();
    if (s.start->moved)
      s.warnings.push_back("the stow posture comes within the clearance margins of the scan (" +
                           fmt(-s.start->preferred_allowance_m, 2) +
                           " m short): the job starts from the nearest posture clear of it (report.json start_posture)");
    else if (s.start->allowance_m < 0.0)
      s.warnings.push_back("the stow posture comes within the clearance margins of the scan (" +
                           fmt(-s.start->allowance_m, 2) + " m short) and no posture clear of it was found nearby");
  }
  if (s.trajectory && s.trajectory->slowed_s > 0.0)
    s.warnings.push_back("the timed motion broke a joint limit (up to " + fmt(s.trajectory->ratio_before_slowing, 2) +
                         "x): the arm is slowed to it for " + fmt(s.trajectory->slowed_s, 1) + " s more, " +
                         fmt(s.trajectory->slowed_spraying_s, 1) +
                         " s of it spraying, which lays more concrete there (counted in the executed deposit; "
                         "report.json trajectory.slowed_to_joint_limits)");
  s.problems = plan_problems(s);
  s.status = s.problems.empty() ? "ok" : "not_executable";
  return s;
}

std::vector<PlanProblem> plan_problems(const JobSummary& s) {
  std::vector<PlanProblem> out;
  const int cells_in_grid = s.grid_n_theta * s.grid_n_d;
  if (cells_in_grid > 0 && s.cells < kMinGridCoverage * cells_in_grid)
    out.push_back({"sparse_grid", "the scan covers " + std::to_string(s.cells) + " of the grid's " +
                                      std::to_string(cells_in_grid) + " cells (less than " +
                                      fmt(100.0 * kMinGridCoverage, 0) + " %): holes are neither graded nor sprayed"});
  const double arc_m = s.grid_n_theta * s.grid_cell_size_m, length_m = s.grid_n_d * s.grid_cell_size_m;
  if (s.spot_diameter_m > 0 && std::min(arc_m, length_m) < s.spot_diameter_m)
    out.push_back({"narrow_scan", "the scan's wall spans " + fmt(arc_m, 2) + " m across by " + fmt(length_m, 2) +
                                      " m along the axis, narrower than one spray spot (" + fmt(s.spot_diameter_m, 2) +
                                      " m): a line or strip of points, not a bay to spray"});
  int above = 0;
  for (const auto& [level, n] : s.levels_after)
    if (level > 0) above += n;
  if (s.obstructed && !s.obstructed->cells.empty()) {
    const auto& o = *s.obstructed;
    out.push_back({"obstructed_cells",
                   std::to_string(o.cells.size()) + " cells cannot be sprayed from a clear pose: with the nozzle at its standoff " +
                       "over them, " + (o.links.empty() ? std::string("the nozzle") : o.links.front()) + " comes within " +
                       fmt(o.least_distance_m, 2) + " m of a point of the scan outside the grid (margin " + fmt(o.margin_m, 2) +
                       " m; nearest at " + fmt(o.nearest_obstacle_m.x(), 2) + ", " + fmt(o.nearest_obstacle_m.y(), 2) + ", " +
                       fmt(o.nearest_obstacle_m.z(), 2) + " m): the deposit the plan models there is not achievable"});
  }
  if (s.unreachable_cells > 0)
    out.push_back({"unreachable_cells", std::to_string(s.unreachable_cells) +
                                            " cells above level 0 that no pass can fill (beyond the arm's reach or the bay's "
                                            "passes, or no pass the pump can run lays them less than it over-fills others; "
                                            "stop reason: " + s.stop_reason + ")"});
  above -= s.obstructed_above_level_0;
  if (above > s.unreachable_cells)
    out.push_back({"cells_above_level_0", std::to_string(above - std::max(0, s.unreachable_cells)) +
                                              " more cells are left above level 0 by the " + s.deposit_source +
                                              " deposit (stop reason: " + s.stop_reason + ")"});
  if (!s.ik.solved) out.push_back({"arm_cannot_follow", "the arm cannot follow the plan: " + s.ik.error});
  const int untracked = std::max(s.ik.untracked_regions, s.trajectory ? s.trajectory->untracked_regions : 0);
  if (untracked > 0)
    out.push_back({"untracked_regions", std::to_string(untracked) + " regions where the arm does not track the nozzle path"});
  if (const auto& t = s.trajectory) {
    const double limit = 1.0 + kLimitRatioTolerance;
    if (t->max_velocity_ratio > limit || t->max_acceleration_ratio > limit || t->max_position_violation_rad > 1e-9 ||
        t->max_position_violation_m > 1e-9)
      out.push_back({"joint_limits", "the trajectory breaks joint limits: velocity " + fmt(t->max_velocity_ratio, 3) +
                                         "x, acceleration " + fmt(t->max_acceleration_ratio, 3) + "x, position " +
                                         fmt(t->max_position_violation_rad, 4) + " rad / " +
                                         fmt(t->max_position_violation_m, 4) + " m outside"});
    if (t->max_nozzle_speed_ratio > limit || t->max_nozzle_accel_ratio > limit)
      out.push_back({"nozzle_limits", "the nozzle moves beyond its limits: speed " + fmt(t->max_nozzle_speed_ratio, 3) +
                                          "x, acceleration " + fmt(t->max_nozzle_accel_ratio, 3) + "x"});
  }
  if (const auto& c = s.clearance) {
    // The links no joint moves: their distance is the base's place, the same at every sample.
    std::string base;
    for (const auto& l : c->links)
      if (l.fixed && l.samples_below_margin > 0)
        base += (base.empty() ? "" : ", ") + l.link + " " + fmt(l.min_m, 2) + " m";
    if (!base.empty())
      out.push_back({"base_clearance", "the arm's base stands in the scan (links no joint moves): " + base +
                                           " from it (the nearest points: report.json clearance.links); no posture changes "
                                           "that: place the base elsewhere (robot.base_position_m)"});
  }
  if (const auto& c = s.clearance; c && c->moving_samples_below_margin() > 0) {
    std::string worst;
    for (const auto& l : c->links)
      if (!l.fixed && l.samples_below_margin > 0)
        worst += (worst.empty() ? "" : ", ") + l.link + " " + fmt(l.min_m, 2) + " m (margin " + fmt(l.margin_m, 2) + ")";
    if (c->self.samples_below_margin > 0)
      worst += (worst.empty() ? "" : ", ") + c->self.link_a + "-" + c->self.link_b + " " + fmt(c->self.min_m, 2) + " m";
    std::string moves;
    if (s.transits && s.transits->failed > 0) {
      const auto eased = std::count_if(s.transits->detours.begin(), s.transits->detours.end(), [](const auto& d) { return d.eased; });
      for (const auto& d : s.transits->detours)
        if (!d.rerouted) {
          moves = "; " + std::to_string(s.transits->failed) + " joint move(s) not re-routed clear" +
                  (eased > 0 ? " (" + std::to_string(eased) + " of them eased onto a route with fewer samples below)" : "") +
                  " (move " + std::to_string(d.move) + ": " + d.reason + ")";
          break;
        }
    }
    out.push_back({"clearance", "the arm comes closer than its margins at " + std::to_string(c->moving_samples_below_margin()) +
                                    " link-samples: " + worst + moves});
  }
  return out;
}

std::string JobSummary::to_json() const {
  JsonWriter w;
  w.begin_object().field("mode", mode).field("status", status).key("problems").begin_array();
  for (const auto& p : problems) w.begin_object().field("code", p.code).field("message", p.message).end_object();
  w.end_array().field("cells", cells);
  w.field("grid_cell_size_m", grid_cell_size_m).field("spot_diameter_m", spot_diameter_m);
  w.key("grid_shape").begin_array().value(grid_n_theta).value(grid_n_d).end_array();
  // Grid cells no scan point fell in (a scanner's shadow, a gap): neither graded nor sprayed.
  w.field("holes", grid_n_theta * grid_n_d - cells);
  w.field("points_in", points_in).field("points_used", points_used);
  w.field("design_radius_m", design_radius_m).field("axis_fit_rms_m", axis_fit_rms_m);
  w.key("design_profile").begin_object().field("shape", design_shape).field("section_path", design_section_path);
  w.field("theta_min_deg", design_theta_min_deg).field("theta_max_deg", design_theta_max_deg);
  w.field("arc_length_m", design_arc_length_m).end_object();
  w.key("axis").begin_object().field("estimated", axis_estimated).key("origin_m").begin_array();
  for (int k = 0; k < 3; ++k) w.value(axis_origin_m[k]);
  w.end_array().key("direction").begin_array();
  for (int k = 0; k < 3; ++k) w.value(axis_direction[k]);
  w.end_array().key("fit_arc_deg");
  write_optional(w, axis_fit_arc_deg);
  w.key("fit_points");
  if (axis_fit_points) w.value(*axis_fit_points);
  else w.null();
  w.key("fit_inlier_share");
  write_optional(w, axis_fit_inlier_share);
  w.end_object();
  w.key("bay").begin_object().field("selection", bay.mode).field("start_m", bay.range.start_m).field("end_m", bay.range.end_m);
  w.field("scan_start_m", bay.scan_start_m).field("scan_end_m", bay.scan_end_m);
  w.field("lined_columns", bay.lined_columns).field("scan_columns", bay.scan_columns);
  w.field("points_not_wall", points_not_wall).field("points_outside_bay", points_outside_bay);
  w.field("points_obstacle", points_obstacle).end_object();
  w.key("levels_before");
  write(w, levels_before);
  w.key("td_before_mm");
  write(w, td_before_mm);
  w.key("levels_after");
  write(w, levels_after);
  w.key("residual_mm");
  write(w, residual_mm);
  w.field("deposit_source", deposit_source).key("planned_levels_after");
  write(w, planned_levels_after);
  w.key("planned_residual_mm");
  write(w, planned_residual_mm);
  w.key("planned_vs_executed_mm");
  if (planned_vs_executed_mm) write(w, *planned_vs_executed_mm);
  else w.null();
  w.field("rounds", rounds).field("regions", regions).field("passes", passes).field("stop_reason", stop_reason);
  w.key("warnings").begin_array();
  for (const auto& text : warnings) w.value(text);
  w.end_array();
  w.field("unreachable_cells", unreachable_cells).field("spray_time_s", spray_time_s);
  w.field("required_volume_m3", required_volume_m3).field("deposition_rate_m3ph", deposition_rate_m3ph);
  w.field("physical_limit_s", physical_limit_s).key("spray_time_ratio");
  write_optional(w, spray_time_ratio);
  w.field("sprayed_volume_m3", sprayed_volume_m3).field("link_length_m", link_length_m);
  w.key("executed");
  if (executed) write(w, *executed);
  else w.null();
  w.field("speed_capped", speed_capped).key("rounds_detail").begin_array();
  for (const auto& r : rounds_detail) write(w, r);
  w.end_array().key("ik");
  write(w, ik);
  w.key("total_time_s");
  write_optional(w, cycle_time_s);
  w.key("cycle_time_s");
  write_optional(w, cycle_time_s);
  w.key("cycle_time_breakdown_s");
  if (trajectory) write(w, trajectory->cycle_time);
  else w.null();
  w.key("cycle_time_ratio");
  write_optional(w, cycle_time_ratio);
  if (trajectory) {
    w.key("trajectory");
    write_report_trajectory(w, *this);
  }
  if (clearance) {
    w.key("clearance");
    write(w, *clearance, self_margin_m, transits);
  }
  if (base_placement) {
    const BasePlacement& b = *base_placement;
    auto point = [&](const char* key, const Eigen::Vector3d& p) {
      w.key(key).begin_array().value(p.x()).value(p.y()).value(p.z()).end_array();
    };
    w.key("base_placement").begin_object().field("moved", b.moved).field("found", b.found);
    point("configured_m", b.configured_m);
    point("position_m", b.position_m);
    w.field("shift_m", b.shift_m).field("room_m", b.room_m).field("base_room_m", b.base_room_m);
    w.field("configured_room_m", b.configured_room_m).field("configured_short_slew_rad", b.configured_short_slew_rad);
    w.field("configured_base_room_m", b.configured_base_room_m);
    w.field("places_tried", b.places_tried);
    w.end_object();
  }
  if (start) {
    auto joints = [&](const Eigen::VectorXd& q) {
      w.begin_object();
      for (Eigen::Index j = 0; j < q.size(); ++j)
        w.field(static_cast<std::size_t>(j) < joint_names.size() ? joint_names[static_cast<std::size_t>(j)] : std::to_string(j), q[j]);
      w.end_object();
    };
    w.key("start_posture").begin_object().field("moved_from_stow", start->moved);
    w.field("allowance_m", start->allowance_m).field("stow_allowance_m", start->preferred_allowance_m);
    w.key("joints");
    joints(start->q);
    w.key("stow");
    joints(start->preferred);
    w.end_object();
  }
  if (obstructed) {
    const auto& o = *obstructed;
    w.key("obstructed").begin_object().field("cells", static_cast<int>(o.cells.size())).field("margin_m", o.margin_m);
    w.field("least_distance_m", o.least_distance_m).field("obstacle_points", o.obstacle_points);
    w.field("above_level_0", obstructed_above_level_0);
    w.field("leaned_cells", o.leaned_cells).field("max_lean_deg", o.max_lean_rad * 180.0 / M_PI);
    w.key("nearest_obstacle_m").begin_array().value(o.nearest_obstacle_m.x()).value(o.nearest_obstacle_m.y())
        .value(o.nearest_obstacle_m.z()).end_array();
    w.key("links").begin_array();
    for (const auto& l : o.links) w.value(l);
    w.end_array().key("cell_ids").begin_array();
    for (int c : o.cells) w.value(c);
    w.end_array().end_object();
  }
  w.end_object();
  return w.str();
}

}  // namespace shotcrete
