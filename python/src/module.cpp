#include "bindings.hpp"

PYBIND11_MODULE(_core, m) {
  m.doc() = "shotcrete core (C++): surface, deposition, planning, ordering, robot, timing, pipeline";
  bind_config(m);
  bind_surface(m);
  bind_deposition(m);
  bind_ordering(m);
  bind_robot(m);
  bind_planner(m);
  bind_timing(m);
  bind_collision(m);
  bind_pipeline(m);
  bind_rescan(m);
}
