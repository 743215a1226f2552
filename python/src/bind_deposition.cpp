#include "bindings.hpp"

void bind_deposition(py::module_& m) {}
