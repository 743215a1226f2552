#include "bindings.hpp"
#include "shotcrete/io/synth.hpp"
#include "shotcrete/pipeline/rescan_job.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/rescan/rescan.hpp"

using namespace shotcrete;

void bind_rescan(py::module_& m) {
  py::class_<AfterScan>(m, "AfterScan", "A synthetic scan after spraying and its ground truth.")
      .def_readonly("cloud", &AfterScan::cloud, "the scan, in its own frame (p_before = pose @ p_after)")
      .def_readonly("pose", &AfterScan::pose, "(4, 4) true after -> before transform")
      .def_readonly("true_thickness_m", &AfterScan::true_thickness_m, "per lattice cell: mean radial layer [m], NaN: invalid")
      .def_readonly("layer_scale", &AfterScan::layer_scale, "flow scale x rebound ratio applied to the deposit");
  m.def("after_pose", &after_pose, py::arg("synth"), "(4, 4) transform of synth.after_pose_rpy_rad / after_pose_translation_m.");
  m.def("make_after_scan", &make_after_scan, py::arg("bay"), py::arg("lattice"), py::arg("deposit_m"), py::arg("config"),
        py::call_guard<py::gil_scoped_release>(),
        "The bay after spraying `deposit_m` (per lattice cell) with synth.after_* errors, seen from the after pose.");
  m.def("grid_from_cells", &grid_from_cells, py::arg("axis"), py::arg("profile"), py::arg("cell_size_m"), py::arg("rows"),
        py::arg("cols"), py::arg("theta_rad"), py::arg("d_m"), py::arg("td_before_m"),
        "The job's grid from its cells (cells.csv); ValueError when they are not on one lattice.");

  py::class_<Registration>(m, "Registration", "After -> before registration on the reference areas.")
      .def_readonly("transform", &Registration::transform, "(4, 4): p_before = T p_after")
      .def_readonly("rms_m", &Registration::rms_m)
      .def_readonly("overlap", &Registration::overlap)
      .def_readonly("iterations", &Registration::iterations)
      .def_readonly("target_points", &Registration::target_points)
      .def_readonly("source_points", &Registration::source_points)
      .def_readonly("time_s", &Registration::time_s);
  m.def(
      "register_scans",
      [](const Cloud& before, const Cloud& after, const Config& config, const std::string& mode, const Grid* grid,
         const std::optional<Eigen::VectorXd>& predicted, const std::optional<Cloud>& mask, const Eigen::Matrix4d& initial) {
        const ReferenceArea area = parse_enum<ReferenceArea>(mode.empty() ? enum_name(config.rescan.reference) : mode, "rescan.reference");
        const ReferenceTest test = reference_test(config, area, grid, predicted ? &*predicted : nullptr, mask ? &*mask : nullptr);
        RescanConfig rc2 = config.rescan;
        rc2.reference = area;
        py::gil_scoped_release release;
        return register_scans(before, after, test, rc2, initial);
      },
      py::arg("before"), py::arg("after"), py::arg("config"), py::arg("reference") = "", py::arg("grid") = nullptr,
      py::arg("predicted_deposit_m") = py::none(), py::arg("mask") = py::none(),
      py::arg("initial") = Eigen::Matrix4d::Identity(),
      "Register `after` to `before` by GICP on the reference areas (reference: dry | box | mask, default "
      "config.rescan.reference; dry needs the job's grid and predicted deposit per cell, mask a cloud). "
      "ValueError: no reference area; RuntimeError: no convergence or overlap below rescan.min_overlap.");
  m.def("transform_cloud", &transform_cloud, py::arg("cloud"), py::arg("transform"), "Cloud moved by a (4, 4) rigid transform.");

  py::class_<M3C2Result>(m, "M3C2Result")
      .def_readonly("distance_m", &M3C2Result::distance_m, "after - before along the normal [m], NaN: too few points")
      .def_readonly("lod95_m", &M3C2Result::lod95_m)
      .def_readonly("before_std_m", &M3C2Result::before_std_m)
      .def_readonly("after_std_m", &M3C2Result::after_std_m)
      .def_readonly("before_count", &M3C2Result::before_count)
      .def_readonly("after_count", &M3C2Result::after_count);
  m.def("m3c2", &m3c2, py::arg("core"), py::arg("normals"), py::arg("before"), py::arg("after"), py::arg("config"),
        py::call_guard<py::gil_scoped_release>(),
        "M3C2 distances at core points along their normals (config: RescanConfig cylinder_*).");
  m.def("measure_points", &measure_points, py::arg("axis"), py::arg("core"), py::arg("before"), py::arg("after_registered"),
        py::arg("config"), py::arg("profile") = DesignProfile::circle(1.0), py::call_guard<py::gil_scoped_release>(),
        "M3C2 at core points along the design line's normal toward the axis (radial on the default circle); "
        "distance_m is the layer (positive: concrete).");
  py::class_<CellThickness>(m, "CellThickness")
      .def_readonly("thickness_m", &CellThickness::thickness_m, "per cell, positive: concrete [m]; NaN: not measured")
      .def_readonly("lod95_m", &CellThickness::lod95_m, "per cell 95 % level of detection [m]")
      .def_readonly("residual_td_m", &CellThickness::residual_td_m, "per cell TD before - thickness [m]")
      .def_readonly("before_td_m", &CellThickness::before_td_m, "per cell TD the before-scan shows along the ray [m]")
      .def_readonly("before_std_m", &CellThickness::before_std_m)
      .def_readonly("after_std_m", &CellThickness::after_std_m)
      .def_readonly("before_count", &CellThickness::before_count)
      .def_readonly("after_count", &CellThickness::after_count)
      .def_readonly("measured", &CellThickness::measured);
  m.def("measure_cells", &measure_cells, py::arg("grid"), py::arg("before"), py::arg("after_registered"), py::arg("config"),
        py::call_guard<py::gil_scoped_release>(),
        "Layer per grid cell, M3C2 along the cell's radial ray (config: RescanConfig).");
  m.def("wall_points", &wall_points, py::arg("grid"), py::arg("cloud"), py::arg("wall_td_m"), py::arg("band_m"),
        "The points of `cloud` within band_m (radially) of the wall at TD wall_td_m of their grid cell.");
  py::class_<Comparison>(m, "Comparison")
      .def_readonly("bias_m", &Comparison::bias_m)
      .def_readonly("rms_m", &Comparison::rms_m)
      .def_readonly("max_abs_m", &Comparison::max_abs_m)
      .def_readonly("cells", &Comparison::cells);
  m.def("compare_cells", &compare_cells, py::arg("measured_m"), py::arg("predicted_m"),
        "Bias, RMS and largest |measured - predicted| over the cells where both are finite.");
  py::class_<Calibration>(m, "Calibration")
      .def_readonly("factor", &Calibration::factor)
      .def_readonly("std_error", &Calibration::std_error)
      .def_readonly("cells", &Calibration::cells)
      .def_readonly("rejected", &Calibration::rejected)
      .def_readonly("residual_rms_m", &Calibration::residual_rms_m);
  m.def("calibrate_flow", &calibrate_flow, py::arg("measured_m"), py::arg("predicted_m"), py::arg("config"),
        "Flow scale factor: robust least squares of measured = factor x predicted (config: RescanConfig).");

  m.attr("RESCAN_WALL_BAND_M") = kRescanWallBand_m;
  m.attr("RESCAN_MATCH_TD_M") = kRescanMatchTd_m;
  m.attr("RESCAN_MATCH_MISS_SHARE") = kRescanMatchMissShare;
  m.def("calibrated_config", &calibrated_config, py::arg("config"), py::arg("flow_factor"),
        "A copy of config with deposition.peak_rate_mps scaled by the calibrated flow factor (validated).");
  py::class_<RescanOutcome>(m, "RescanOutcome", "What rescan_job computed (the loop on a finished job).")
      .def_readonly("registration", &RescanOutcome::registration)
      .def_readonly("thickness", &RescanOutcome::thickness)
      .def_readonly("before_td_rms_m", &RescanOutcome::before_td_rms_m)
      .def_readonly("before_td_miss_share", &RescanOutcome::before_td_miss_share)
      .def_readonly("comparison", &RescanOutcome::comparison)
      .def_readonly("calibration", &RescanOutcome::calibration, "Calibration, or None (calibration_error says why)")
      .def_readonly("calibration_error", &RescanOutcome::calibration_error)
      .def_readonly("calibrated", &RescanOutcome::calibrated, "config with the calibrated deposition rate, or None")
      .def_readonly("correction_config", &RescanOutcome::correction_config, "calibrated, grid.bay whole, planner.time_weight_mm2_per_s = rescan.correction_time_weight_mm2_per_s; or None")
      .def_readonly("correction_surface", &RescanOutcome::correction_surface, "Surface of the corrective round, or None")
      .def_readonly("correction", &RescanOutcome::correction, "ArmPlan of the corrective round, or None")
      .def_readonly("register_s", &RescanOutcome::register_s)
      .def_readonly("measure_s", &RescanOutcome::measure_s)
      .def_readonly("correction_s", &RescanOutcome::correction_s);
  m.def(
      "rescan_job",
      [](const Grid& grid, const Eigen::VectorXd& predicted, const Cloud& before, const Cloud& after, const Config& config,
         const std::optional<Cloud>& mask, const Eigen::Matrix4d& initial, const Robot* robot, const ProgressFn& progress) {
        return rescan_job(grid, predicted, before, after, config, mask ? &*mask : nullptr, initial, robot, progress);
      },
      py::arg("grid"), py::arg("predicted_deposit_m"), py::arg("before"), py::arg("after"), py::arg("config"),
      py::arg("mask") = py::none(), py::arg("initial") = Eigen::Matrix4d::Identity(), py::arg("robot") = nullptr,
      py::arg("progress") = nullptr,
      "The re-scan of a job (the CLI's and the ROS node's one loop): after registered to before on\n"
      "config.rescan.reference, the layer per cell of the job's grid, measured vs predicted, the flow factor,\n"
      "and with a robot the corrective round planned for the arm on the measured residual. ValueError /\n"
      "RuntimeError, one line, for unusable input.");
}
