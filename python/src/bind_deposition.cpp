#include <sstream>

#include "bindings.hpp"
#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/deposition/wall.hpp"

using namespace shotcrete;

namespace {

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

// The thickness argument of accumulate_*: None -> fresh zeros; a float64 C-contiguous array of
// one entry per point -> updated in place (and returned).
py::array_t<double> thickness_array(py::object thickness, Eigen::Index n) {
  if (thickness.is_none()) {
    py::array_t<double> out(n);
    std::fill(out.mutable_data(), out.mutable_data() + n, 0.0);
    return out;
  }
  if (!py::isinstance<py::array_t<double>>(thickness))
    throw py::type_error("thickness_m must be a float64 numpy array (updated in place) or None");
  auto arr = thickness.cast<py::array_t<double>>();
  if (arr.ndim() != 1 || arr.shape(0) != n || !(arr.flags() & py::array::c_style) || !arr.writeable())
    throw std::invalid_argument("thickness_m must be a writeable contiguous float64 array of shape (" +
                                std::to_string(n) + ",)");
  return arr;
}

template <class F> py::array_t<double> accumulate_into(const SurfaceIndex& s, py::object thickness, F&& f) {
  const Eigen::Index n = s.cloud().size();
  py::array_t<double> arr = thickness_array(thickness, n);
  Eigen::VectorXd t = Eigen::Map<const Eigen::VectorXd>(arr.data(), n);
  {
    py::gil_scoped_release release;
    f(t);
  }
  std::copy(t.data(), t.data() + n, arr.mutable_data());
  return arr;
}

// Elementwise f over a float64 array (any shape), same shape out; scalars work as 0-d arrays.
template <class F> py::object map_array(const DoubleArray& x, F&& f) {
  if (x.ndim() == 0) return py::float_(f(*x.data()));
  py::array_t<double> out(std::vector<py::ssize_t>(x.shape(), x.shape() + x.ndim()));
  const double* in = x.data();
  double* o = out.mutable_data();
  for (py::ssize_t i = 0; i < x.size(); ++i) o[i] = f(in[i]);
  return out;
}

std::vector<NozzlePose> poses_from_arrays(const Points& positions, const Points& axes) {
  if (axes.rows() != positions.rows() && axes.rows() != 1)
    throw std::invalid_argument("axes must have one row per position (or a single row for all)");
  std::vector<NozzlePose> out(positions.rows());
  for (Eigen::Index i = 0; i < positions.rows(); ++i) {
    out[i].position_m = positions.row(i).transpose();
    out[i].axis = axes.row(axes.rows() == 1 ? 0 : i).transpose();
  }
  return out;
}

}  // namespace

void bind_deposition(py::module_& m) {
  py::class_<SpotModel>(m, "SpotModel",
                        "Spot model at the reference standoff H0: q(r) = q_max (1 - r^2/R^2)^(beta - 1) for r <= R.\n"
                        "Rates are sprayed thickness per second [m/s] (before rebound).")
      .def(py::init([](double reference_standoff_m, double radius_m, double beta, double peak_rate_mps) {
             return SpotModel{reference_standoff_m, radius_m, beta, peak_rate_mps};
           }),
           py::arg("reference_standoff_m") = SpotModel{}.reference_standoff_m, py::arg("radius_m") = SpotModel{}.radius_m,
           py::arg("beta") = SpotModel{}.beta, py::arg("peak_rate_mps") = SpotModel{}.peak_rate_mps,
           "Defaults: the config defaults (fit of data/deposition_stroke.csv).")
      .def_readwrite("reference_standoff_m", &SpotModel::reference_standoff_m, "H0 [m]")
      .def_readwrite("radius_m", &SpotModel::radius_m, "spot radius R at H0 [m]")
      .def_readwrite("beta", &SpotModel::beta, "spot exponent beta (stroke exponent = beta - 1/2)")
      .def_readwrite("peak_rate_mps", &SpotModel::peak_rate_mps, "q_max, sprayed [m/s]")
      .def("rate_at", [](const SpotModel& s, const DoubleArray& r) { return map_array(r, [&](double v) { return s.rate_at(v); }); },
           py::arg("r_m"), "q(r) [m/s] at distance r from the centre")
      .def("cone_half_angle_rad", &SpotModel::cone_half_angle_rad, "atan(R / H0)")
      .def("volume_rate_m3ps", &SpotModel::volume_rate_m3ps, "sprayed volume per second q_max pi R^2 / beta [m^3/s]")
      .def("__repr__", [](const SpotModel& s) {
        std::ostringstream o;
        o << "<SpotModel H0=" << s.reference_standoff_m << " m R=" << s.radius_m << " m beta=" << s.beta
          << " q_max=" << s.peak_rate_mps << " m/s>";
        return o.str();
      });
  m.def("spot_model_from_config", &spot_model_from_config, py::arg("deposition"),
        "SpotModel of config.deposition; ValueError if peak_rate_mps <= 0 (fit it and set it).");
  m.def("stroke_thickness_m",
        [](const SpotModel& s, const DoubleArray& x, double v) {
          return map_array(x, [&](double xi) { return stroke_thickness_m(s, xi, v); });
        },
        py::arg("model"), py::arg("x_m"), py::arg("speed_mps"),
        "Closed-form sprayed cross profile of a straight pass at H0: (q_max/v) R B(1/2, beta) (1 - x^2/R^2)^(beta - 1/2).");

  py::class_<StrokeData>(m, "StrokeData", "A measured stroke (deposited thickness across one pass).")
      .def(py::init([](std::vector<double> position_m, std::vector<double> thickness_m, double standoff_m, double speed_mps,
                       double rebound_fraction) {
             return StrokeData{std::move(position_m), std::move(thickness_m), standoff_m, speed_mps, rebound_fraction};
           }),
           py::arg("position_m"), py::arg("thickness_m"), py::arg("standoff_m") = 1.0, py::arg("speed_mps") = 0.15,
           py::arg("rebound_fraction") = 0.08)
      .def_property_readonly("position_m", [](const StrokeData& d) { return py::array_t<double>(d.position_m.size(), d.position_m.data()); },
                             "(n,) positions across the pass [m]")
      .def_property_readonly("thickness_m", [](const StrokeData& d) { return py::array_t<double>(d.thickness_m.size(), d.thickness_m.data()); },
                             "(n,) deposited thickness [m]")
      .def_readwrite("standoff_m", &StrokeData::standoff_m)
      .def_readwrite("speed_mps", &StrokeData::speed_mps)
      .def_readwrite("rebound_fraction", &StrokeData::rebound_fraction)
      .def("__len__", [](const StrokeData& d) { return d.position_m.size(); });
  m.def("read_stroke_csv", &read_stroke_csv, py::arg("path"), py::arg("standoff_m") = 1.0, py::arg("speed_mps") = 0.15,
        py::arg("rebound_fraction") = 0.08,
        "Read position_mm,thickness_mm; ValueError for < 5 rows, non-numeric cells, negative or all-zero thickness.");

  py::class_<StrokeFit>(m, "StrokeFit", "Least-squares fit of the spot model to a stroke.")
      .def_readonly("model", &StrokeFit::model, "fitted SpotModel (sprayed rates)")
      .def_readonly("stroke_exponent", &StrokeFit::stroke_exponent, "beta - 1/2")
      .def_readonly("peak_thickness_m", &StrokeFit::peak_thickness_m, "deposited stroke peak at the test speed [m]")
      .def_readonly("mse_mm2", &StrokeFit::mse_mm2, "stroke mean squared error [mm^2]")
      .def_readonly("flow_m3ph", &StrokeFit::flow_m3ph, "implied sprayed flow [m^3/h]")
      .def_readonly("deposited_flow_m3ph", &StrokeFit::deposited_flow_m3ph, "flow that stayed on the wall [m^3/h]")
      .def_readonly("center_offset_m", &StrokeFit::center_offset_m, "fitted pass centre in the CSV frame [m]")
      .def_readonly("speed_mps", &StrokeFit::speed_mps)
      .def_readonly("rebound_fraction", &StrokeFit::rebound_fraction)
      .def_readonly("evaluations", &StrokeFit::evaluations, "objective evaluations of the optimiser")
      .def("stroke_at_m", [](const StrokeFit& f, const DoubleArray& x) { return map_array(x, [&](double v) { return f.stroke_at_m(v); }); },
           py::arg("x_m"),
           "fitted deposited stroke at CSV positions [m]");
  m.def("fit_stroke", &fit_stroke, py::arg("data"), py::call_guard<py::gil_scoped_release>(),
        "Fit (R, beta, q_max, centre) to a stroke: closed-form amplitude, multi-start BOBYQA on the shape.");

  py::class_<NozzlePose>(m, "NozzlePose", "Nozzle position [m] and spray axis (normalised where used).")
      .def(py::init([](const Eigen::Vector3d& p, const Eigen::Vector3d& a) { return NozzlePose{p, a}; }),
           py::arg("position_m"), py::arg("axis"))
      .def_readwrite("position_m", &NozzlePose::position_m)
      .def_readwrite("axis", &NozzlePose::axis);
  m.def("nozzle_poses", &poses_from_arrays, py::arg("positions_m"), py::arg("axes"),
        "List of NozzlePose from (K, 3) positions and (K, 3) or (1, 3) axes.");

  m.def("point_rate_mps", &point_rate_mps, py::arg("model"), py::arg("nozzle"), py::arg("p"), py::arg("n"),
        "Thesis eq. 2-13 at point p with normal n (toward the nozzle side): q0(r_proj) (H0/L)^2 cos(gamma)/cos^3(theta)\n"
        "inside the cone and for gamma < 90 deg, else 0 [m/s].");

  py::class_<SurfaceIndex>(m, "SurfaceIndex",
                           "Voxel index over a cloud with normals: spray queries visit only the points near the footprint.")
      .def(py::init<const Cloud&, double>(), py::arg("cloud"), py::arg("cell_size_m") = 0.05,
           py::call_guard<py::gil_scoped_release>())
      .def_property_readonly("cloud", &SurfaceIndex::cloud, py::return_value_policy::reference_internal)
      .def_property_readonly("cell_size_m", &SurfaceIndex::cell_size_m)
      .def("within", [](const SurfaceIndex& s, const Eigen::Vector3d& c, double r) {
             std::vector<int> out;
             s.within(c, r, out);
             return py::array_t<int>(out.size(), out.data());
           }, py::arg("center"), py::arg("radius_m"), "Sorted int32 indices of the points within radius_m of center.")
      .def("reach_ball", &SurfaceIndex::reach_ball, py::arg("model"), py::arg("nozzle"),
           "(center, radius_m) of the ball holding every point this nozzle reaches.")
      .def("__len__", [](const SurfaceIndex& s) { return s.cloud().size(); });

  py::class_<PassSamples>(m, "PassSamples", "A pass resampled at interval midpoints.")
      .def_readonly("poses", &PassSamples::poses)
      .def_property_readonly("dwell_s", [](const PassSamples& p) { return py::array_t<double>(p.dwell_s.size(), p.dwell_s.data()); })
      .def_readonly("length_m", &PassSamples::length_m);
  m.def("resample_pass", &resample_pass, py::arg("polyline"), py::arg("speed_mps"), py::arg("step_m"),
        "Midpoints of ceil(length / step_m) equal intervals, each dwelling step / speed.");

  m.def("accumulate_dwells",
        [](const SpotModel& model, const SurfaceIndex& s, const std::vector<NozzlePose>& poses, const std::vector<double>& dwell,
           double rebound, py::object thickness) {
          return accumulate_into(s, thickness, [&](Eigen::VectorXd& t) { accumulate_dwells(model, s, poses, dwell, rebound, t); });
        },
        py::arg("model"), py::arg("surface"), py::arg("poses"), py::arg("dwell_s"), py::arg("rebound_fraction") = 0.08,
        py::arg("thickness_m") = py::none(),
        "Deposited thickness [m] per point (float64 (N,)) of dwells at poses; adds into thickness_m in place if given.");
  m.def("accumulate_pass",
        [](const SpotModel& model, const SurfaceIndex& s, const std::vector<NozzlePose>& poly, double speed, double step,
           double rebound, py::object thickness) {
          return accumulate_into(s, thickness, [&](Eigen::VectorXd& t) { accumulate_pass(model, s, poly, speed, step, rebound, t); });
        },
        py::arg("model"), py::arg("surface"), py::arg("polyline"), py::arg("speed_mps"), py::arg("step_m") = 0.01,
        py::arg("rebound_fraction") = 0.08, py::arg("thickness_m") = py::none(),
        "Deposited thickness [m] per point (float64 (N,)) of a pass along a polyline of poses at speed_mps;\n"
        "adds into thickness_m in place if given.");
  py::class_<SprayedWall>(m, "SprayedWall",
                          "The wall as it is sprayed: the scan's surface moved by every layer so far, on the scan's cells.")
      .def_readonly("surface", &SprayedWall::surface, "cloud, grid and levels of the wall as sprayed so far")
      .def_property_readonly(
          "cell_of_point",
          [](const SprayedWall& w) { return py::array_t<int>(w.cell_of_point.size(), w.cell_of_point.data()); },
          "the scan's cell of every point (-1: outside the grid band), int32 (N,)");
  m.def("unsprayed_wall", &unsprayed_wall, py::arg("surface"), py::arg("max_deviation_m"),
        "The wall before spraying: the surface's cloud on its grid (points farther than max_deviation_m\n"
        "from the design line belong to no cell; use config.profile.max_deviation_m).");
  m.def("deposit_layer", &deposit_layer, py::arg("wall"), py::arg("thickness_m"),
        "Put a layer on the wall in place (the planner's deposit): every point moves toward the axis along\n"
        "its ray by thickness / cos(tilt); cell means, TD, levels and the normals of the sprayed cells follow.");

  py::class_<PassSpacing>(m, "PassSpacing", "Golden-section pass spacing (thesis 3.5).")
      .def_readonly("spacing_m", &PassSpacing::spacing_m)
      .def_readonly("overlap_m", &PassSpacing::overlap_m)
      .def_readonly("band_min_m", &PassSpacing::band_min_m, "smallest thickness between the pass centres [m]")
      .def_readonly("band_max_m", &PassSpacing::band_max_m, "largest thickness between the pass centres [m]");
  m.def("pass_spacing", &pass_spacing, py::arg("model"), py::arg("target_thickness_m"),
        "Overlap minimising sum (Td - T(x))^2 on a 1 mm grid for two strokes peaking at Td; spacing = 2R - overlap.");
  py::class_<LinePitch>(m, "LinePitch", "A pitch of equal parallel strokes and the ripple of their sum")
      .def_readonly("pitch_m", &LinePitch::pitch_m, "line pitch [m]")
      .def_readonly("ripple", &LinePitch::ripple, "(max - min) / mean of the strokes' sum across the lines [-]");
  m.def("line_ripple", &line_ripple, py::arg("model"), py::arg("pitch_m"),
        "(max - min) / mean across many equal parallel strokes at pitch_m (cross profile (1 - (x/R)^2)^(beta - 1/2)).");
  m.def("least_ripple_pitch", &least_ripple_pitch, py::arg("model"), py::arg("lo_m"), py::arg("hi_m"),
        "The pitch in [lo_m, hi_m] (0.1 mm steps) whose equal strokes ripple least (line_ripple).");
}
