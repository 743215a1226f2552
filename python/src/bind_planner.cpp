#include "bindings.hpp"
#include "shotcrete/planning/planner.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/timing.hpp"

using namespace shotcrete;


void bind_planner(py::module_& m) {
  py::class_<Pass>(m, "Pass", "A nozzle pass: waypoints along a clamped cubic spline, speed(s) in m/s.")
      .def(py::init<>())
      .def_readwrite("waypoints", &Pass::waypoints)
      .def_readwrite("speed_mps", &Pass::speed_mps, "constant (graded) or mean (optimal) speed [m/s]")
      .def_readwrite("length_m", &Pass::length_m)
      .def_readwrite("speed_profile_mps", &Pass::speed_profile_mps, "speed per waypoint (empty: constant)")
      .def_readwrite("line", &Pass::line, "index of the slicing plane")
      .def_readwrite("tight_start", &Pass::tight_start,
                     "the nozzle leans at the start to keep clear of something before it, with room for the run-on only "
                     "(the joins there stop within v^2 / a: a tight turn)")
      .def_readwrite("tight_end", &Pass::tight_end, "as tight_start, at the end")
      .def_property_readonly("positions_m", [](const Pass& p) { return pose_positions(p.waypoints); }, "(N, 3) nozzle positions [m]")
      .def_property_readonly("axes", [](const Pass& p) { return pose_axes(p.waypoints); }, "(N, 3) unit spray axes")
      .def("duration_s", &Pass::duration_s)
      .def("dwell_s", &Pass::dwell_s)
      .def("speed_at", &Pass::speed_at, py::arg("waypoint"));
  py::class_<RegionPlan>(m, "RegionPlan")
      .def_readonly("region", &RegionPlan::region)
      .def_readonly("target_thickness_m", &RegionPlan::target_thickness_m)
      .def_readonly("spacing_m", &RegionPlan::spacing_m)
      .def_readonly("passes", &RegionPlan::passes)
      .def_readonly("reversed", &RegionPlan::reversed)
      .def_readonly("note", &RegionPlan::note)
      .def("entry_m", &RegionPlan::entry_m)
      .def("exit_m", &RegionPlan::exit_m);
  py::class_<Round>(m, "Round")
      .def_property_readonly("kind", [](const Round& r) { return std::string(enum_name(r.kind)); },
                             "graded (one level, thesis) or levelling (optimal mode)")
      .def_readonly("level", &Round::level)
      .def_readonly("regions", &Round::regions)
      .def_readonly("order", &Round::order)
      .def_readonly("link_length_m", &Round::link_length_m)
      .def_readonly("order_method", &Round::order_method)
      .def_readonly("levels_before", &Round::levels_before)
      .def_readonly("levels_after", &Round::levels_after)
      .def_readonly("td_after_m", &Round::td_after_m, "per grid cell (flat, row * n_d + col) [m]")
      .def_readonly("spray_time_s", &Round::spray_time_s);
  py::class_<Plan>(m, "Plan", "Rounds of regions and passes, with the simulated result.")
      .def_readonly("rounds", &Plan::rounds)
      .def_readonly("grid_before", &Plan::grid_before)
      .def_readonly("td_after_m", &Plan::td_after_m, "per grid cell (flat) after the last round [m]")
      .def_readonly("deposited_m", &Plan::deposited_m, "per surface point, all rounds [m]")
      .def_readonly("sprayed_cloud", &Plan::sprayed_cloud)
      .def_readonly("spray_time_s", &Plan::spray_time_s)
      .def_readonly("required_volume_m3", &Plan::required_volume_m3)
      .def_readonly("deposition_rate_m3ps", &Plan::deposition_rate_m3ps)
      .def_readonly("physical_limit_s", &Plan::physical_limit_s)
      .def_property_readonly("stop_reason", [](const Plan& p) { return p.stop_reason.text(); },
                             "flush | no progress: <what> | max rounds reached (planner.max_rounds) | levelled: <why>")
      .def_readonly("unreachable_cells", &Plan::unreachable_cells)
      .def_readonly("warnings", &Plan::warnings)
      .def_readonly("speed_capped", &Plan::speed_capped,
                    "passes (graded) / segments (optimal) whose speed bound the arm's joint limits lowered")
      .def_readonly("timings_s", &Plan::timings_s);
  m.def(
      "plan_bay",
      [](const Surface& surface, const Config& config, const ProgressFn& progress, const Robot* robot) {
        return plan_bay(surface, config, progress, robot ? arm_speed_caps(*robot, config) : SpeedCapFn{});
      },
      py::arg("surface"), py::arg("config"), py::arg("progress") = nullptr, py::arg("robot") = nullptr,
      "Plan and simulate a bay: rounds until flush (graded or optimal mode, config.planner.mode).\n"
      "progress(stage: str, fraction: float) is called between stages. With a robot, every pass or\n"
      "segment is bounded by the speed the arm can follow there within its joint velocity and\n"
      "acceleration limits (timing.joint_limit_margin kept free), so the simulated deposit is sprayable.");
  m.def(
      "plan_passes",
      [](const Grid& grid, const std::vector<int>& cells, double spacing_m, const PlannerConfig& config,
         const std::vector<Eigen::Vector3d>& lean,
         double split_gap_m) { return plan_passes(grid, cells, spacing_m, config, &lean, split_gap_m); },
      py::arg("grid"), py::arg("cells"), py::arg("spacing_m"), py::arg("config"),
      py::arg("lean") = std::vector<Eigen::Vector3d>{}, py::arg("split_gap_m") = 0.0,
      "Pass lines over grid cells: slicing planes, crossing points, standoff offset, spline. lean (empty,\n"
      "or one 3-vector per grid cell): the nozzle's lean off square there, tangent to the wall, length =\n"
      "angle [rad] (ObstructedCells.lean). split_gap_m > 0: a line is cut into several passes where more\n"
      "than that length of wall [m] along it holds none of the cells.");
  m.def("clamped_cubic_spline", &clamped_cubic_spline, py::arg("points"), py::arg("step_m"));
}
