#include "bindings.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/io/io.hpp"
#include "shotcrete/surface/preprocess.hpp"
#include "shotcrete/surface/profile.hpp"
#include "shotcrete/surface/surface.hpp"
#include "shotcrete/io/survey.hpp"
#include "shotcrete/io/synth.hpp"

using namespace shotcrete;

namespace {

Cloud make_cloud(const Points& xyz, std::optional<Points> normals) {
  Cloud c;
  c.xyz = xyz;
  if (normals) {
    if (normals->rows() != xyz.rows())
      throw std::invalid_argument("normals must have one row per point (" + std::to_string(xyz.rows()) + ")");
    c.normals = *normals;
  }
  return c;
}

template <class T> py::array_t<T> as_map(const std::vector<T>& v, const Grid& g) {
  py::array_t<T> out({g.n_theta, g.n_d});
  std::copy(v.begin(), v.end(), out.mutable_data());
  return out;
}

}  // namespace

void bind_surface(py::module_& m) {
  py::class_<Cloud>(m, "Cloud", "Point cloud in metres: xyz (N, 3) float64 and optional normals (N, 3).")
      .def(py::init(&make_cloud), py::arg("xyz"), py::arg("normals") = py::none())
      .def_readwrite("xyz", &Cloud::xyz, "(N, 3) coordinates [m]")
      .def_readwrite("normals", &Cloud::normals, "(N, 3) unit normals toward the axis, or (0, 3)")
      .def("has_normals", &Cloud::has_normals)
      .def("__len__", &Cloud::size)
      .def("__repr__", [](const Cloud& c) {
        return "<Cloud " + std::to_string(c.size()) + " points" + (c.has_normals() ? " with normals>" : ">");
      });

  m.def("read_cloud", &read_cloud, py::arg("path"), "Read a .pcd, .ply or .xyz/.txt/.csv cloud (metres).");
  m.def("write_cloud", &write_cloud, py::arg("path"), py::arg("cloud"), py::arg("scalar") = Eigen::VectorXd(),
        "Write .pcd/.ply (binary) or .xyz; `scalar` goes to the intensity field.");
  m.def("check_cloud", &check_cloud, py::arg("cloud"), py::arg("io"),
        "Raise ValueError for an empty cloud, NaN/inf points or a millimetre-sized extent.");
  m.def("preprocess", &preprocess, py::arg("cloud"), py::arg("config"), "Crop, voxel and outlier filters.");
  m.def("voxel_downsample", &voxel_downsample, py::arg("cloud"), py::arg("voxel_size_m"));
  m.def("remove_statistical_outliers", &remove_statistical_outliers, py::arg("cloud"), py::arg("neighbors"),
        py::arg("std_ratio"));
  m.def("crop_box", &crop_box, py::arg("cloud"), py::arg("min_m"), py::arg("max_m"));

  py::class_<TunnelAxis>(m, "TunnelAxis", "Tunnel frame: ex along the axis, ey across, ez up.")
      .def(py::init<>())
      .def_static("from_direction", &TunnelAxis::from_direction, py::arg("origin_m"), py::arg("direction"))
      .def_readwrite("origin_m", &TunnelAxis::origin_m)
      .def_readonly("ex", &TunnelAxis::ex)
      .def_readonly("ey", &TunnelAxis::ey)
      .def_readonly("ez", &TunnelAxis::ez)
      .def("to_cylindrical", &TunnelAxis::to_cylindrical, py::arg("p"), "(r, theta, d) of a point")
      .def("to_cartesian", &TunnelAxis::to_cartesian, py::arg("r_m"), py::arg("theta_rad"), py::arg("d_m"));
  py::class_<SectionVertex>(m, "SectionVertex")
      .def(py::init([](double y_m, double z_m, double bulge) { return SectionVertex{y_m, z_m, bulge}; }), py::arg("y_m"),
           py::arg("z_m"), py::arg("bulge") = 0.0)
      .def_readwrite("y_m", &SectionVertex::y_m)
      .def_readwrite("z_m", &SectionVertex::z_m)
      .def_readwrite("bulge", &SectionVertex::bulge, "DXF bulge to the next vertex: tan(included angle / 4), ccw > 0");
  py::class_<DesignProfile>(m, "DesignProfile",
                            "Design line of the cross-section: a circle, or a section of lines and arcs (TD along its normal).")
      .def(py::init<>())
      .def_static("circle", &DesignProfile::circle, py::arg("radius_m"))
      .def_static("from_section", &DesignProfile::from_section, py::arg("vertices"),
                  "Section from vertices (y along the frame's ey, z up, m from the axis; DXF bulges). ValueError, one line, "
                  "when it is not star-shaped about the axis or crosses the invert below it.")
      .def_readwrite("radius_m", &DesignProfile::radius_m, "circle: radius; section: mean radius (arc length / angle) [m]")
      .def_property_readonly("is_circle", &DesignProfile::is_circle)
      .def_property_readonly("polyline_m", [](const DesignProfile& p) {
        Eigen::MatrixX2d out(static_cast<Eigen::Index>(p.polyline_m.size()), 2);
        for (std::size_t i = 0; i < p.polyline_m.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = p.polyline_m[i].transpose();
        return out;
      }, "section flattened to chords (N x 2: y, z) in increasing theta; empty for a circle")
      .def_property_readonly("theta_min_rad", &DesignProfile::theta_min_rad)
      .def_property_readonly("theta_max_rad", &DesignProfile::theta_max_rad)
      .def("covers", &DesignProfile::covers, py::arg("theta_rad"))
      .def("radius_at", &DesignProfile::radius_at, py::arg("theta_rad"), "distance from the axis to the line along theta [m]")
      .def("normal_at", &DesignProfile::normal_at, py::arg("theta_rad"), "outward unit normal (y, z)")
      .def("normal_cos_at", &DesignProfile::normal_cos_at, py::arg("theta_rad"))
      .def("td_m", &DesignProfile::td_m, py::arg("r_m"), py::arg("theta_rad"), "TD along the line's normal [m]")
      .def("radial_offset_m", &DesignProfile::radial_offset_m, py::arg("td_m"), py::arg("theta_rad"));
  m.def("read_section_csv", &read_section_csv, py::arg("path"), "Vertices of a design section CSV (y_m,z_m[,bulge]).");
  py::class_<AlignmentPoint>(m, "AlignmentPoint")
      .def_readonly("chainage_m", &AlignmentPoint::chainage_m)
      .def_readonly("xyz_m", &AlignmentPoint::xyz_m);
  m.def("read_alignment_csv", &read_alignment_csv, py::arg("path"), "Points of an alignment CSV (chainage_m,x_m,y_m,z_m).");
  py::class_<AxisOnAlignment>(m, "AxisOnAlignment")
      .def_readonly("axis", &AxisOnAlignment::axis)
      .def_readonly("chainage_m", &AxisOnAlignment::chainage_m, "chainage of the axis origin (the job frame's d = 0)")
      .def_readonly("start_m", &AxisOnAlignment::start_m)
      .def_readonly("end_m", &AxisOnAlignment::end_m)
      .def_readonly("deviation_m", &AxisOnAlignment::deviation_m, "largest distance of the alignment from the straight axis")
      .def_readonly("scan_offset_m", &AxisOnAlignment::scan_offset_m);
  m.def("axis_on_alignment", &axis_on_alignment, py::arg("alignment"), py::arg("centre_m"), py::arg("half_span_m"),
        py::arg("max_offset_m") = 20.0, "The straight axis standing for the alignment around a scan's centre.");
  m.def("with_alignment_axis", [](const Config& config, const Points& xyz_m) {
        AxisOnAlignment at;
        Config out = with_alignment_axis(config, xyz_m, &at);
        return std::make_pair(out, config.profile.alignment_path.empty() ? py::object(py::none()) : py::cast(at));
      }, py::arg("config"), py::arg("xyz_m"),
      "(config, AxisOnAlignment or None): the config with the axis of profile.alignment_path where the points lie "
      "(grid.bay_start_m/bay_end_m taken as chainages); unchanged without an alignment.");
  m.def("local_origin", [](const Points& xyz_m) -> Eigen::Vector3d { return local_origin(xyz_m); }, py::arg("xyz_m"),
        "The bounding-box centre of the finite rows (metres), rounded to whole 100 m; (0, 0, 0) for none.");
  m.def("local_frame_origin", &local_frame_origin, py::arg("xyz"), py::arg("io"),
        "The local origin [m] of a cloud in its input units (io.unit_scale); (0, 0, 0) for a cloud wider than "
        "io.max_extent_m (docs/architecture.md §3, survey coordinates).");
  m.def("to_local_frame", [](const Eigen::Vector3d& origin_m, const Cloud& cloud, const Config& config) {
        Cloud c = cloud;
        Config k = config;
        to_local_frame(origin_m, c, k);
        return std::make_pair(c, k);
      }, py::arg("origin_m"), py::arg("cloud"), py::arg("config"),
      "(cloud, config) moved into the local frame of origin_m (the cloud in its input units; the axis origin, crop "
      "box and robot base); ValueError naming the key when the config lies more than 1 km from the cloud.");
  m.def("design_profile_from_config", &design_profile_from_config, py::arg("profile"),
        "The circle of profile.design_radius_m or the section of profile.section_path.");
  py::class_<AxisFit>(m, "AxisFit")
      .def_readonly("axis", &AxisFit::axis)
      .def_readonly("radius_m", &AxisFit::radius_m)
      .def_readonly("rms_m", &AxisFit::rms_m)
      .def_readonly("arc_rad", &AxisFit::arc_rad)
      .def_readonly("points", &AxisFit::points)
      .def_readonly("inlier_share", &AxisFit::inlier_share, "points / the cloud's points (the rest is not wall)")
      .def_readonly("origin_fitted", &AxisFit::origin_fitted);
  m.def("fit_axis", &fit_axis, py::arg("cloud"), py::arg("profile") = ProfileConfig(), py::arg("grid") = GridConfig(),
        "Fit the tunnel axis to the wall of a cloud with normals, which may hold a whole scene (RANSAC seed, the "
        "points the grid takes as wall, a lower-envelope cylinder fit, repeated until it settles); ValueError, one "
        "line, when the cloud is not a tunnel wall.");
  m.def("estimate_normals", &estimate_normals, py::arg("cloud"), py::arg("k_neighbors"), py::arg("axis"),
        "PCL k-NN normals oriented toward the tunnel axis.");

  m.attr("NO_DATA_LEVEL") = kNoDataLevel;
  py::class_<Grid>(m, "Grid", "Unrolled wall grid; cell = row * n_d + col, rows along theta, cols along d.")
      .def_readonly("axis", &Grid::axis)
      .def_readonly("profile", &Grid::profile)
      .def_readonly("cell_size_m", &Grid::cell_size_m)
      .def_readonly("dtheta_rad", &Grid::dtheta_rad)
      .def_readonly("theta0_rad", &Grid::theta0_rad)
      .def_readonly("d0_m", &Grid::d0_m)
      .def_readonly("n_theta", &Grid::n_theta)
      .def_readonly("n_d", &Grid::n_d)
      .def_readonly("points_not_wall", &Grid::points_not_wall, "points near the design line left out: normal tilted (face, floor)")
      .def_readonly("points_outside_bay", &Grid::points_outside_bay, "points near the design line left out: outside the bay")
      .def_readonly("points_obstacle", &Grid::points_obstacle,
                    "wall-like points left out: grid.obstacle_gap_m inside their cell's outermost surface (a duct)")
      .def_property_readonly("count", [](const Grid& g) { return as_map(g.count, g); }, "(n_theta, n_d) points per cell")
      .def_property_readonly("valid", [](const Grid& g) {
        std::vector<std::uint8_t> v(g.valid.begin(), g.valid.end());
        return as_map(v, g).attr("astype")("bool");
      }, "(n_theta, n_d) True where the cell has data")
      .def_readonly("mean_xyz", &Grid::mean_xyz, "(cells, 3) mean point per cell [m]")
      .def_readonly("mean_normal", &Grid::mean_normal, "(cells, 3) mean unit normal per cell")
      .def_property_readonly("td_m", [](const Grid& g) {
        std::vector<double> v(g.td_m.data(), g.td_m.data() + g.td_m.size());
        return as_map(v, g);
      }, "(n_theta, n_d) mean TD per cell [m], NaN where empty")
      .def("theta_center", &Grid::theta_center, py::arg("row"))
      .def("d_center", &Grid::d_center, py::arg("col"))
      .def("cell_at", &Grid::cell_at, py::arg("theta_rad"), py::arg("d_m"))
      .def("design_point", &Grid::design_point, py::arg("cell"))
      .def("valid_count", &Grid::valid_count)
      .def("__len__", &Grid::size);
  py::class_<BayRange>(m, "BayRange", "Chainage range [start_m, end_m) along the axis, m.")
      .def(py::init([](double start_m, double end_m) { return BayRange{start_m, end_m}; }), py::arg("start_m"), py::arg("end_m"))
      .def_readonly("start_m", &BayRange::start_m)
      .def_readonly("end_m", &BayRange::end_m);
  py::class_<BaySelectionResult>(m, "BaySelection", "How the bay was chosen from the scan (grid.bay).")
      .def_readonly("mode", &BaySelectionResult::mode)
      .def_readonly("range", &BaySelectionResult::range)
      .def_readonly("scan_start_m", &BaySelectionResult::scan_start_m)
      .def_readonly("scan_end_m", &BaySelectionResult::scan_end_m)
      .def_readonly("lined_columns", &BaySelectionResult::lined_columns)
      .def_readonly("scan_columns", &BaySelectionResult::scan_columns)
      .def_readonly("warning", &BaySelectionResult::warning, "set when detect found only lining (the whole scan is gridded)");
  m.def("build_grid",
        [](const Cloud& cloud, const TunnelAxis& axis, const DesignProfile& profile, const GridConfig& config,
           double max_deviation_m, const std::optional<BayRange>& bay) {
          return build_grid(cloud, axis, profile, config, max_deviation_m, bay);
        },
        py::arg("cloud"), py::arg("axis"), py::arg("profile"), py::arg("config"),
        py::arg("max_deviation_m"), py::arg("bay") = std::nullopt,
        "Grid a cloud with normals (optionally only the bay's chainage range).");
  m.def("select_bay", &select_bay, py::arg("whole_scan"), py::arg("config"),
        "The bay of a whole-scan grid: whole, the config's range, or the longest stretch that is not lining.");
  m.def("missing_volume_m3", &missing_volume_m3, py::arg("grid"),
        "Volume [m^3] between the wall and the design line over the valid cells with TD > 0 (the required volume).");
  m.def("point_td", &point_td, py::arg("cloud"), py::arg("axis"), py::arg("profile"), "Per-point TD [m].");
  m.def("level_of_td_mm", &level_of_td_mm, py::arg("td_mm"), "Priority level of a TD in millimetres.");
  m.def("cell_levels", &cell_levels, py::arg("grid"), "Level per cell (NO_DATA_LEVEL where empty).");
  m.def("level_counts", &level_counts, py::arg("levels"));

  py::class_<Region>(m, "Region")
      .def_readonly("cells", &Region::cells)
      .def_readonly("level", &Region::level)
      .def_readonly("td_min_m", &Region::td_min_m)
      .def_readonly("td_max_m", &Region::td_max_m)
      .def_readonly("td_mean_m", &Region::td_mean_m)
      .def_readonly("row_min", &Region::row_min)
      .def_readonly("row_max", &Region::row_max)
      .def_readonly("col_min", &Region::col_min)
      .def_readonly("col_max", &Region::col_max);
  m.def("find_regions", &find_regions, py::arg("grid"), py::arg("levels"), py::arg("level"), py::arg("min_cells"),
        "4-connected regions of one level; small ones merge into the nearest.");

  py::class_<DigPit>(m, "DigPit")
      .def_readonly("d_m", &DigPit::d_m)
      .def_readonly("s_m", &DigPit::s_m)
      .def_readonly("depth_m", &DigPit::depth_m)
      .def_readonly("radius_m", &DigPit::radius_m);
  py::class_<SyntheticBay>(m, "SyntheticBay", "Half-cylinder bay with dig pits (seeded).")
      .def_readonly("config", &SyntheticBay::config)
      .def_readonly("pits", &SyntheticBay::pits)
      .def_readonly("axis", &SyntheticBay::axis)
      .def("td_at", &SyntheticBay::td_at, py::arg("d_m"), py::arg("theta_rad"), "Noise-free TD [m].")
      .def("sample", &SyntheticBay::sample, py::arg("cell_size_m") = 0.05, "Sample the wall as a Cloud.")
      .def("sample_context", &SyntheticBay::sample_context, py::arg("cell_size_m"), py::arg("points_per_cell"),
           py::arg("noise_m"), py::arg("seed"),
           "The unsprayed surroundings (synth.context_*): lined previous bay, invert, face; empty when disabled.")
      .def("sample_scan", &SyntheticBay::sample_scan, py::arg("cell_size_m") = 0.05,
           "What a scanner sees before spraying: the wall plus the context when synth.context_enabled, less the "
           "scanner's shadow when synth.context_scanner_shadow.")
      .def("muck_height_at", &SyntheticBay::muck_height_at, py::arg("d_m"), py::arg("y_m"),
           "Height [m] of the muck pile above the invert at (d along the axis, y across); 0 off it.")
      .def("scanner_sees", &SyntheticBay::scanner_sees, py::arg("point_m"),
           "Whether the scanner at synth.context_scanner_position_m sees the point (world frame).")
      .def("drop_shadowed", &SyntheticBay::drop_shadowed, py::arg("cloud"),
           "The points of `cloud` the scanner sees (the cloud itself without synth.context_scanner_shadow).");
  m.def("make_synthetic_bay", &make_synthetic_bay, py::arg("config"));

  py::class_<Surface>(m, "Surface", "Preprocessed cloud with normals, axis, grid and levels.")
      .def_readonly("cloud", &Surface::cloud)
      .def_readonly("axis", &Surface::axis)
      .def_readonly("profile", &Surface::profile)
      .def_readonly("axis_fit_rms_m", &Surface::axis_fit_rms_m)
      .def_readonly("axis_fit", &Surface::axis_fit, "AxisFit, or None when the axis came from the config")
      .def_readonly("grid", &Surface::grid)
      .def_readonly("bay", &Surface::bay, "BaySelection: the chainage range of the bay the grid covers")
      .def_readonly("levels", &Surface::levels)
      .def_property_readonly(
          "in_grid",
          [](const Surface& s) {
            py::array_t<bool> a(static_cast<py::ssize_t>(s.in_grid.size()));
            auto m = a.mutable_unchecked<1>();
            for (std::size_t i = 0; i < s.in_grid.size(); ++i) m(static_cast<py::ssize_t>(i)) = s.in_grid[i] != 0;
            return a;
          },
          "per point of `cloud`: True when gridded (wall, near the design line, in the bay); the rest are "
          "obstacles and references (the clearance's wall holds every point)")
      .def_readonly("timings_s", &Surface::timings_s);
  m.def("build_surface", &build_surface, py::arg("cloud"), py::arg("config"),
        py::call_guard<py::gil_scoped_release>(),
        "Check, preprocess, normals, axis, grid and levels of a raw cloud.");
}
