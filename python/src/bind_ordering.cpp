#include "bindings.hpp"
#include "shotcrete/ordering/ordering.hpp"
#include "shotcrete/types.hpp"

using namespace shotcrete;

namespace {

std::vector<Eigen::Vector3d> rows_of(const Points& p) {
  std::vector<Eigen::Vector3d> v(static_cast<size_t>(p.rows()));
  for (Eigen::Index i = 0; i < p.rows(); ++i) v[static_cast<size_t>(i)] = p.row(i).transpose();
  return v;
}

Points points_of(const std::vector<Eigen::Vector3d>& v) {
  Points p(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) p.row(static_cast<Eigen::Index>(i)) = v[i].transpose();
  return p;
}

OrderingProblem make_problem(const Points& a, const Points& b, std::optional<Eigen::Vector3d> start) {
  if (a.rows() != b.rows())
    throw std::invalid_argument("ordering: a_m has " + std::to_string(a.rows()) + " rows but b_m has " +
                                std::to_string(b.rows()));
  OrderingProblem p;
  p.a_m = rows_of(a);
  p.b_m = rows_of(b);
  p.start_m = start;
  return p;
}

py::dict result_dict(const OrderingResult& r) {
  py::dict d;
  d["order"] = r.order;
  d["reversed"] = r.reversed;
  d["link_length_m"] = r.link_length_m;
  d["solve_time_s"] = r.solve_time_s;
  d["method"] = r.method;
  py::dict conv;
  conv["best"] = r.best_per_iteration;
  conv["mean"] = r.mean_per_iteration;
  d["convergence"] = conv;
  return d;
}

}  // namespace

void bind_ordering(py::module_& m) {
  py::class_<OrderingProblem>(m, "OrderingProblem",
                              "Regions to link: region i is the segment a_m[i] -> b_m[i] (metres), sprayed either "
                              "way; start_m is an optional fixed start point.")
      .def(py::init(&make_problem), py::arg("a_m"), py::arg("b_m"), py::arg("start_m") = py::none(),
           "a_m, b_m: (n, 3) endpoints [m]; start_m: (3,) or None.")
      .def_property(
          "a_m", [](const OrderingProblem& p) { return points_of(p.a_m); },
          [](OrderingProblem& p, const Points& a) { p.a_m = rows_of(a); }, "(n, 3) endpoints A [m]")
      .def_property(
          "b_m", [](const OrderingProblem& p) { return points_of(p.b_m); },
          [](OrderingProblem& p, const Points& b) { p.b_m = rows_of(b); }, "(n, 3) endpoints B [m]")
      .def_readwrite("start_m", &OrderingProblem::start_m, "start point [m] or None")
      .def("__len__", [](const OrderingProblem& p) { return p.a_m.size(); })
      .def("__repr__", [](const OrderingProblem& p) {
        return "<OrderingProblem " + std::to_string(p.a_m.size()) + " regions" +
               (p.start_m ? " with start>" : ">");
      });

  py::class_<OrderingResult>(m, "OrderingResult", "An order of the regions with a direction per region.")
      .def(py::init<>())
      .def_readwrite("order", &OrderingResult::order, "region indices in spraying order")
      .def_readwrite("reversed", &OrderingResult::reversed, "reversed[i]: region i sprayed B -> A (by region)")
      .def_readwrite("link_length_m", &OrderingResult::link_length_m, "transit length of the open path [m]")
      .def_readwrite("solve_time_s", &OrderingResult::solve_time_s)
      .def_readwrite("method", &OrderingResult::method, "solver(s) used, e.g. 'aco+ls'")
      .def_readwrite("best_per_iteration", &OrderingResult::best_per_iteration,
                     "ACO/GA: best-so-far length per iteration/generation [m]")
      .def_readwrite("mean_per_iteration", &OrderingResult::mean_per_iteration,
                     "ACO/GA: mean length of the ants/population per iteration/generation [m]")
      .def("to_dict", &result_dict,
           "The JSON contract: order, reversed, link_length_m, solve_time_s, method, convergence {best, mean}.")
      .def("__repr__", [](const OrderingResult& r) {
        return "<OrderingResult " + r.method + " n=" + std::to_string(r.order.size()) +
               " link_length_m=" + std::to_string(r.link_length_m) + ">";
      });

  m.def("validate_ordering_problem", &validate_ordering_problem, py::arg("problem"),
        "Raise ValueError for a/b size mismatch, a non-finite coordinate or one beyond 1e6 m (naming the "
        "region, endpoint and value).");
  m.def("link_length", &link_length, py::arg("problem"), py::arg("order"), py::arg("reversed"),
        "Transit length [m] of an order (a permutation) with reversed indexed by region.");
  m.def("solve_ordering", &solve_ordering, py::arg("problem"), py::arg("config"), py::arg("progress") = nullptr,
        "Dispatch on config.method (aco | ga | nn | exact | best); config is an OrderingConfig "
        "(config.ordering). aco/ga/nn are polished by local search when config.local_search. From 150 "
        "regions on, best is the scalable path (method nn+ils). Iterations stop once "
        "config.time_budget_s is spent. progress(stage: str, fraction: float) is called per phase.",
        py::call_guard<py::gil_scoped_release>());
  m.def("solve_aco", &solve_aco, py::arg("problem"), py::arg("config"), py::arg("progress") = nullptr,
        "Ant colony (Ant-Cycle); the hybrid with per-iteration local search when config.local_search.",
        py::call_guard<py::gil_scoped_release>());
  m.def("solve_ga", &solve_ga, py::arg("problem"), py::arg("config"), py::arg("progress") = nullptr,
        "Genetic algorithm: order + direction bits, order crossover, inversion mutation.",
        py::call_guard<py::gil_scoped_release>());
  m.def("solve_nearest_neighbour", &solve_nearest_neighbour, py::arg("problem"),
        "Nearest neighbour from the start point or the best bounding-box corner.");
  m.def("solve_exact", &solve_exact, py::arg("problem"),
        "Exact dynamic programming over subsets (n <= 20; memory about 2^n * 2n * 9 bytes).",
        py::call_guard<py::gil_scoped_release>());
  m.def("improve_local", &improve_local, py::arg("problem"), py::arg("initial"),
        "2-opt with block reversal (flipping directions), or-opt and direction flips until no move improves.");
  m.def(
      "apply_ga_preset",
      [](OrderingConfig& c, const std::string& preset) {
        apply_ga_preset(c, preset);
        return c;
      },
      py::arg("config"), py::arg("preset"),
      "Set the published GA parameters in place: 'a' = Pc 0.9 / Pm 0.1 / 400 generations, "
      "'b' = Pc 0.2 / Pm 0.05 / 100 generations (population 100). Returns the config.");
}
