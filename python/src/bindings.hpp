#pragma once
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

// One function per core header; module.cpp calls them all.
void bind_config(py::module_& m);
void bind_surface(py::module_& m);
void bind_deposition(py::module_& m);
void bind_ordering(py::module_& m);
void bind_robot(py::module_& m);
void bind_planner(py::module_& m);
void bind_timing(py::module_& m);
