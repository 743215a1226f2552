#include "bindings.hpp"

void bind_planner(py::module_& m) {}
