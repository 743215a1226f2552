#pragma once
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "shotcrete/deposition/deposition.hpp"

namespace py = pybind11;

// (N, 3) arrays of nozzle positions [m] / unit spray axes, for every binding that returns poses.
inline Eigen::MatrixXd pose_positions(const std::vector<shotcrete::NozzlePose>& poses) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(poses.size()), 3);
  for (std::size_t i = 0; i < poses.size(); ++i) m.row(static_cast<Eigen::Index>(i)) = poses[i].position_m.transpose();
  return m;
}
inline Eigen::MatrixXd pose_axes(const std::vector<shotcrete::NozzlePose>& poses) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(poses.size()), 3);
  for (std::size_t i = 0; i < poses.size(); ++i) m.row(static_cast<Eigen::Index>(i)) = poses[i].axis.transpose();
  return m;
}

// The core writes its summaries as JSON (to_json); Python gets them as dicts from the same text.
inline py::object json_loads(const std::string& text) { return py::module_::import("json").attr("loads")(text); }

// One function per core header; module.cpp calls them all.
void bind_config(py::module_& m);
void bind_surface(py::module_& m);
void bind_deposition(py::module_& m);
void bind_ordering(py::module_& m);
void bind_robot(py::module_& m);
void bind_planner(py::module_& m);
void bind_timing(py::module_& m);
void bind_pipeline(py::module_& m);
void bind_collision(py::module_& m);
void bind_rescan(py::module_& m);
