#include "bindings.hpp"

void bind_robot(py::module_& m) {}
