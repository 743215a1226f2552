#include "bindings.hpp"
#include "shotcrete/timing/region_spray.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/pipeline/job_summary.hpp"
#include "shotcrete/robot/robot.hpp"

using namespace shotcrete;

namespace {
void bind_executed(py::module_& m) {
  py::class_<FlowSchedule>(m, "FlowSchedule", "The pump's flow: spells on, centred linear ramps.")
      .def_readonly("on_s", &FlowSchedule::on_s)
      .def_readonly("off_s", &FlowSchedule::off_s)
      .def_readonly("ramp_s", &FlowSchedule::ramp_s)
      .def_readonly("commanded_on_s", &FlowSchedule::commanded_on_s)
      .def_readonly("bridged_s", &FlowSchedule::bridged_s)
      .def_readonly("extended_s", &FlowSchedule::extended_s)
      .def_readonly("trimmed_s", &FlowSchedule::trimmed_s)
      .def_readonly("dropped_s", &FlowSchedule::dropped_s)
      .def_readonly("commanded_switches", &FlowSchedule::commanded_switches)
      .def("switches", &FlowSchedule::switches)
      .def("shortest_on_s", &FlowSchedule::shortest_on_s)
      .def("shortest_off_s", &FlowSchedule::shortest_off_s)
      .def("on_time_s", &FlowSchedule::on_time_s)
      .def("flow_at", &FlowSchedule::flow_at, py::arg("t_s"))
      .def("integral_to", &FlowSchedule::integral_to, py::arg("t_s"));
  m.def(
      "flow_schedule",
      [](const std::vector<double>& t_s, const py::array_t<double, py::array::forcecast>& spraying, const FlowConfig& flow,
         const std::optional<py::array_t<double, py::array::forcecast>>& blocked, bool ends_blocked) {
        auto flags_of = [](const py::array_t<double, py::array::forcecast>& a) {
          std::vector<char> flags(static_cast<std::size_t>(a.size()));
          for (py::ssize_t i = 0; i < a.size(); ++i) flags[static_cast<std::size_t>(i)] = a.data()[i] != 0.0;
          return flags;
        };
        return flow_schedule(t_s, flags_of(spraying), flow, blocked ? flags_of(*blocked) : std::vector<char>{}, ends_blocked);
      },
      py::arg("t_s"), py::arg("spraying"), py::arg("flow"), py::arg("blocked") = py::none(), py::arg("ends_blocked") = false,
        "The pump's schedule for the spraying flags of samples at t_s (FlowConfig); `blocked`: samples where the flow "
        "must be off, ramps included (joint moves); `ends_blocked`: the samples lie between two joint moves as a "
        "trajectory joins a region to its transits (the first sample is the last of the move before, the next move "
        "starts a sample interval after the last); ValueError on bad input.");
  m.def(
      "program_schedule",
      [](const std::vector<double>& on_s, const std::vector<double>& off_s, const std::vector<double>& t_s,
         const FlowConfig& flow, const std::optional<py::array_t<double, py::array::forcecast>>& blocked, bool ends_blocked) {
        std::vector<char> flags;
        if (blocked)
          for (py::ssize_t i = 0; i < blocked->size(); ++i) flags.push_back(blocked->data()[i] != 0.0);
        return program_schedule(on_s, off_s, t_s, flow, flags, ends_blocked);
      },
      py::arg("on_s"), py::arg("off_s"), py::arg("t_s"), py::arg("flow"), py::arg("blocked") = py::none(),
      py::arg("ends_blocked") = false,
      "The pump's schedule for a program of commanded spells [on_s[k], off_s[k]] over samples at t_s: spells or "
      "gaps a little short of the minimums (a program laid out on other durations) stretched into their "
      "neighbours' slack first, then flow_schedule's rules; ValueError on a malformed program.");
  py::class_<PumpProgram>(m, "PumpProgram", "Commanded pump spells [on_s[k], off_s[k]] [s].")
      .def_readonly("on_s", &PumpProgram::on_s)
      .def_readonly("off_s", &PumpProgram::off_s);
  m.def("planned_pump_program", &planned_pump_program, py::arg("plan"), py::arg("trajectory"), py::arg("config"),
        "The plan's pump program on the trajectory's timing: each region's planned switches (region_spray) moved "
        "to where the trajectory reaches the same place of the same pass or join; ValueError when the "
        "trajectory is not the plan's.");
  m.def(
      "region_spray",
      [](const std::vector<Pass>& passes, const Config& config) {
        const RegionSpray rs = region_spray(passes, config);
        py::dict d;
        d["t_s"] = rs.t_s;
        d["positions_m"] = pose_positions(rs.nozzle);
        d["axes"] = pose_axes(rs.nozzle);
        d["dwell_s"] = rs.dwell_s;
        d["pass_index"] = rs.pass_index;
        d["spraying"] = std::vector<bool>(rs.spraying.begin(), rs.spraying.end());
        d["blocked"] = std::vector<bool>(rs.blocked.begin(), rs.blocked.end());
        d["flow"] = rs.flow;
        return d;
      },
      py::arg("passes"), py::arg("config"),
      "What the planner deposits one region with: its timed Cartesian path (no joint re-timing) and the "
      "pump's flow; a dict of t_s, positions_m, axes (unit spray axes), dwell_s (full-flow dwell per sample), pass_index (-1 off the passes), spraying (commanded), blocked (stop-and-go middles) and flow (FlowSchedule).");
  m.def("flow_dwells", &flow_dwells, py::arg("schedule"), py::arg("t_s"),
        "Full-flow dwell of every sample: the schedule's flow over the sample's share of time.");
  py::class_<DepositVolumes>(m, "DepositVolumes", "Volumes of the executed deposit [m^3].")
      .def_readonly("sprayed_m3", &DepositVolumes::sprayed_m3)
      .def_readonly("rebound_m3", &DepositVolumes::rebound_m3)
      .def_readonly("on_wall_m3", &DepositVolumes::on_wall_m3)
      .def_readonly("outside_m3", &DepositVolumes::outside_m3)
      .def("balance_error", &DepositVolumes::balance_error);
  py::class_<ExecutedDeposit>(m, "ExecutedDeposit", "The deposit laid along the timed trajectory with the pump's flow.")
      .def_readonly("deposited_m", &ExecutedDeposit::deposited_m)
      .def_readonly("td_after_m", &ExecutedDeposit::td_after_m)
      .def_readonly("round_deposited_m", &ExecutedDeposit::round_deposited_m)
      .def_readonly("round_td_after_m", &ExecutedDeposit::round_td_after_m)
      .def_property_readonly("sprayed_cloud", [](const ExecutedDeposit& e) { return e.wall.surface.cloud; })
      .def_property_readonly("levels", [](const ExecutedDeposit& e) { return e.wall.surface.levels; })
      .def_readonly("flow", &ExecutedDeposit::flow)
      .def_readonly("volumes", &ExecutedDeposit::volumes)
      .def_readonly("bridged_volume_m3", &ExecutedDeposit::bridged_volume_m3)
      .def_readonly("extended_volume_m3", &ExecutedDeposit::extended_volume_m3);
  m.def("execute_deposit",
        py::overload_cast<const Surface&, const Plan&, const TimedTrajectory&, const Config&>(&execute_deposit),
        py::arg("surface"), py::arg("plan"), py::arg("trajectory"), py::arg("config"),
        "The deposit the trajectory lays on the surface, round by round on the moved wall, the pump running the "
        "plan's program (planned_pump_program, program_schedule).");
}
}  // namespace

void bind_pipeline(py::module_& m) {
  bind_executed(m);
  py::class_<TdStatsMm>(m, "TdStatsMm", "A TD over the valid grid cells [mm].")
      .def_readonly("mean", &TdStatsMm::mean)
      .def_readonly("min", &TdStatsMm::min)
      .def_readonly("max", &TdStatsMm::max)
      .def_readonly("rms", &TdStatsMm::rms)
      .def_readonly("abs_max", &TdStatsMm::abs_max);
  py::class_<RoundSummary>(m, "RoundSummary")
      .def_readonly("round", &RoundSummary::round)
      .def_readonly("kind", &RoundSummary::kind)
      .def_readonly("level", &RoundSummary::level)
      .def_readonly("regions", &RoundSummary::regions)
      .def_readonly("passes", &RoundSummary::passes)
      .def_readonly("spray_time_s", &RoundSummary::spray_time_s)
      .def_readonly("order_method", &RoundSummary::order_method)
      .def_readonly("link_length_m", &RoundSummary::link_length_m)
      .def_readonly("levels_before", &RoundSummary::levels_before)
      .def_readonly("levels_after", &RoundSummary::levels_after);
  py::class_<IkSummary>(m, "IkSummary", "The arm on the plan, with an FK check of the trajectory samples.")
      .def_readonly("poses", &IkSummary::poses)
      .def_readonly("regions", &IkSummary::regions)
      .def_readonly("replans", &IkSummary::replans)
      .def_readonly("learned_speed_bounds", &IkSummary::learned_speed_bounds)
      .def_readonly("solved", &IkSummary::solved)
      .def_readonly("error", &IkSummary::error)
      .def_readonly("checked", &IkSummary::checked)
      .def_readonly("samples_checked", &IkSummary::samples_checked)
      .def_readonly("worst_position_error_m", &IkSummary::worst_position_error_m)
      .def_readonly("worst_angle_error_rad", &IkSummary::worst_angle_error_rad)
      .def_readonly("untracked_regions", &IkSummary::untracked_regions);
  py::class_<CycleTimeBreakdown>(m, "CycleTimeBreakdown", "Where a trajectory's time goes [s]; the parts add up to it.")
      .def_readonly("spraying_s", &CycleTimeBreakdown::spraying_s)
      .def_readonly("turn_arounds_s", &CycleTimeBreakdown::turn_arounds_s)
      .def_readonly("leads_s", &CycleTimeBreakdown::leads_s)
      .def_readonly("transits_s", &CycleTimeBreakdown::transits_s)
      .def_readonly("stop_and_go_s", &CycleTimeBreakdown::stop_and_go_s)
      .def_readonly("other_s", &CycleTimeBreakdown::other_s)
      .def("total_s", &CycleTimeBreakdown::total_s);
  py::class_<TrajectorySummary>(m, "TrajectorySummary", "The scalars of a timed trajectory.")
      .def_readonly("samples", &TrajectorySummary::samples)
      .def_readonly("duration_s", &TrajectorySummary::duration_s)
      .def_readonly("spray_time_s", &TrajectorySummary::spray_time_s)
      .def_readonly("transit_time_s", &TrajectorySummary::transit_time_s)
      .def_readonly("max_velocity_ratio", &TrajectorySummary::max_velocity_ratio)
      .def_readonly("max_acceleration_ratio", &TrajectorySummary::max_acceleration_ratio)
      .def_readonly("cycle_time", &TrajectorySummary::cycle_time)
      .def_readonly("max_nozzle_speed_ratio", &TrajectorySummary::max_nozzle_speed_ratio)
      .def_readonly("max_nozzle_accel_ratio", &TrajectorySummary::max_nozzle_accel_ratio)
      .def_readonly("worst_velocity_joint", &TrajectorySummary::worst_velocity_joint)
      .def_readonly("worst_acceleration_joint", &TrajectorySummary::worst_acceleration_joint)
      .def_readonly("max_position_violation_rad", &TrajectorySummary::max_position_violation_rad)
      .def_readonly("max_position_violation_m", &TrajectorySummary::max_position_violation_m)
      .def_readonly("untracked_regions", &TrajectorySummary::untracked_regions)
      .def_readonly("slowed_s", &TrajectorySummary::slowed_s, "time slow_to_joint_limits added [s]")
      .def_readonly("slowed_spraying_s", &TrajectorySummary::slowed_spraying_s, "of it, spraying [s]")
      .def_readonly("slowed_intervals", &TrajectorySummary::slowed_intervals)
      .def_readonly("ratio_before_slowing", &TrajectorySummary::ratio_before_slowing)
      .def("to_json", [](const TrajectorySummary& s) { return to_json(s); })
      .def("to_dict", [](const TrajectorySummary& s) { return json_loads(to_json(s)); });
  m.def(
      "summarise_trajectory",
      [](const TimedTrajectory& t, const TimingConfig& timing) {
        return summarise_trajectory(t, NozzleLimits{timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2});
      },
      py::arg("trajectory"), py::arg("timing"), "The trajectory's scalars; nozzle ratios against timing.nozzle_max_*.");
  py::class_<SwarmSummary>(m, "SwarmSummary", "The timing swarm of a plan for the arm.")
      .def_readonly("used", &SwarmSummary::used)
      .def_readonly("error", &SwarmSummary::error)
      .def_readonly("config_timing_duration_s", &SwarmSummary::config_timing_duration_s)
      .def_readonly("duration_s", &SwarmSummary::duration_s)
      .def_readonly("regions_tuned", &SwarmSummary::regions_tuned)
      .def_readonly("regions", &SwarmSummary::regions)
      .def_readonly("evaluations", &SwarmSummary::evaluations)
      .def_readonly("regions_cut_by_budget", &SwarmSummary::regions_cut_by_budget)
      .def_readonly("params", &SwarmSummary::params);
  py::class_<PlanProblem>(m, "PlanProblem", "Why a plan is not one the machine can execute as reported.")
      .def_readonly("code", &PlanProblem::code)
      .def_readonly("message", &PlanProblem::message)
      .def("__repr__", [](const PlanProblem& p) { return "PlanProblem(" + p.code + ": " + p.message + ")"; });
  m.def("plan_problems", &plan_problems, py::arg("summary"),
        "The problems of a JobSummary (empty: the plan is right): cells left above level 0 or unreachable, an arm "
        "that cannot follow, joint or nozzle limits broken, a grid mostly made of holes.");
  py::class_<JobSummary>(m, "JobSummary",
                         "The summary of a job planned for the arm: report.json's figures, the ROS node's ~summary.")
      .def_readonly("mode", &JobSummary::mode)
      .def_readonly("status", &JobSummary::status, "ok | not_executable (problems says why)")
      .def_readonly("problems", &JobSummary::problems)
      .def_readonly("cells", &JobSummary::cells)
      .def_property_readonly("grid_shape", [](const JobSummary& s) { return py::make_tuple(s.grid_n_theta, s.grid_n_d); })
      .def_readonly("points_in", &JobSummary::points_in)
      .def_readonly("points_used", &JobSummary::points_used)
      .def_readonly("design_radius_m", &JobSummary::design_radius_m)
      .def_readonly("axis_fit_rms_m", &JobSummary::axis_fit_rms_m)
      .def_readonly("axis_estimated", &JobSummary::axis_estimated)
      .def_readonly("axis_origin_m", &JobSummary::axis_origin_m)
      .def_readonly("axis_direction", &JobSummary::axis_direction)
      .def_readonly("axis_fit_arc_deg", &JobSummary::axis_fit_arc_deg)
      .def_readonly("axis_fit_points", &JobSummary::axis_fit_points)
      .def_readonly("axis_fit_inlier_share", &JobSummary::axis_fit_inlier_share)
      .def_readonly("levels_before", &JobSummary::levels_before)
      .def_readonly("td_before_mm", &JobSummary::td_before_mm)
      .def_readonly("levels_after", &JobSummary::levels_after)
      .def_readonly("residual_mm", &JobSummary::residual_mm)
      .def_readonly("deposit_source", &JobSummary::deposit_source)
      .def_readonly("planned_levels_after", &JobSummary::planned_levels_after)
      .def_readonly("planned_residual_mm", &JobSummary::planned_residual_mm)
      .def_property_readonly("planned_vs_executed_mm",
                             [](const JobSummary& s) -> py::object {
                               if (!s.planned_vs_executed_mm) return py::none();
                               const auto& d = *s.planned_vs_executed_mm;
                               py::dict out;
                               out["rms"] = d.rms, out["max_abs"] = d.max_abs, out["mean"] = d.mean;
                               return out;
                             })
      .def_property_readonly("executed", [](const JobSummary& s) -> py::object {
        return json_loads(s.to_json())["executed"];
      })
      .def_readonly("rounds", &JobSummary::rounds)
      .def_readonly("regions", &JobSummary::regions)
      .def_readonly("passes", &JobSummary::passes)
      .def_readonly("stop_reason", &JobSummary::stop_reason)
      .def_readonly("warnings", &JobSummary::warnings)
      .def_readonly("unreachable_cells", &JobSummary::unreachable_cells)
      .def_readonly("spray_time_s", &JobSummary::spray_time_s)
      .def_readonly("required_volume_m3", &JobSummary::required_volume_m3)
      .def_readonly("deposition_rate_m3ph", &JobSummary::deposition_rate_m3ph)
      .def_readonly("physical_limit_s", &JobSummary::physical_limit_s)
      .def_readonly("cycle_time_s", &JobSummary::cycle_time_s)
      .def_readonly("cycle_time_ratio", &JobSummary::cycle_time_ratio)
      .def_readonly("spray_time_ratio", &JobSummary::spray_time_ratio)
      .def_readonly("sprayed_volume_m3", &JobSummary::sprayed_volume_m3)
      .def_readonly("link_length_m", &JobSummary::link_length_m)
      .def_readonly("speed_capped", &JobSummary::speed_capped)
      .def_readonly("rounds_detail", &JobSummary::rounds_detail)
      .def_readonly("ik", &JobSummary::ik)
      .def_readonly("trajectory", &JobSummary::trajectory)
      .def_readonly("trajectory_rate_hz", &JobSummary::trajectory_rate_hz)
      .def_readonly("config_timing_duration_s", &JobSummary::config_timing_duration_s)
      .def_readonly("swarm", &JobSummary::swarm)
      .def("to_json", &JobSummary::to_json, "report.json's figures as compact JSON (17 significant digits)")
      .def("to_dict", [](const JobSummary& s) { return json_loads(s.to_json()); },
           "json.loads(to_json()): the dict report.json starts with");
  m.def(
      "summarise_job",
      [](const Surface& surface, const ArmPlan& arm_plan, const Robot& robot, const Config& config, long points_in,
         int check_every) {
        return summarise_job(surface, arm_plan, robot, config, JobSummaryOptions{points_in, check_every});
      },
      py::arg("surface"), py::arg("arm_plan"), py::arg("robot"), py::arg("config"), py::arg("points_in") = 0,
      py::arg("check_every") = 10,
      "The summary of a bay planned for the arm (plan_for_arm) on surface; points_in: points of the raw cloud.\n"
      "The IK check runs FK on every check_every-th trajectory sample; robot: as given to plan_for_arm (placed\n"
      "where arm_plan.base_placement says).");
}
