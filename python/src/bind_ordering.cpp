#include "bindings.hpp"

void bind_ordering(py::module_& m) {}
