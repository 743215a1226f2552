#include "bindings.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/collision/clearance.hpp"

using namespace shotcrete;

namespace {

py::array_t<double> reach_grid(const std::vector<double>& v, const ReachMap& m) {
  py::array_t<double> out({m.theta_rad.size(), m.d_m.size()});
  std::copy(v.begin(), v.end(), out.mutable_data());
  return out;
}

py::array_t<double> as_array(const std::vector<double>& v) {
  py::array_t<double> out(v.size());
  std::copy(v.begin(), v.end(), out.mutable_data());
  return out;
}

}  // namespace

void bind_robot(py::module_& m) {
  m.def("bundled_urdf_path", &bundled_urdf_path, "URDF in the source tree (Python prefers its installed copy).");

  py::class_<Robot>(m, "Robot", "The 8-DOF spraying manipulator read from a URDF (KDL chain base_link -> nozzle_tip).")
      .def_static("load", &Robot::load, py::arg("config"),
                  "Load config.urdf_path (empty: the bundled URDF) with base_link at config.base_position_m.")
      .def_static("load_file", &Robot::load_file, py::arg("urdf_path"), py::arg("base_position_m"),
                  "Load an explicit URDF file.")
      .def_static("from_string", &Robot::from_string, py::arg("urdf_xml"), py::arg("base_position_m"))
      .def_property_readonly("dof", &Robot::dof)
      .def_property_readonly("joint_names", &Robot::joint_names)
      .def_property_readonly("joint_is_prismatic", &Robot::joint_is_prismatic)
      .def_property_readonly("lower_limits", &Robot::lower_limits, "[rad] or [m]")
      .def_property_readonly("upper_limits", &Robot::upper_limits, "[rad] or [m]")
      .def_property_readonly("velocity_limits", &Robot::velocity_limits, "[rad/s] or [m/s]")
      .def_property_readonly("acceleration_limits", &Robot::acceleration_limits, "[rad/s^2] or [m/s^2]")
      .def_property_readonly("urdf_path", &Robot::urdf_path)
      .def_property_readonly("base_pose", [](const Robot& r) { return Eigen::Matrix4d(r.base_pose().matrix()); })
      .def_property_readonly("shoulder_position", &Robot::shoulder_position)
      .def_property_readonly("max_reach_m", &Robot::max_reach_m)
      .def(
          "link_frames",
          [](const Robot& r, const Eigen::VectorXd& q) {
            std::vector<Eigen::Matrix4d> out;
            for (const auto& f : r.link_frames(q)) out.push_back(f.matrix());
            return out;
          },
          py::arg("q"), "4x4 world poses of base_link and of the link at the tip of every chain segment")
      .def_property_readonly("link_names", &Robot::link_names)
      .def_property_readonly("collision_shapes", &Robot::collision_shapes, "the links' URDF <collision> shapes")
      .def("fk", [](const Robot& r, const Eigen::VectorXd& q) { return Eigen::Matrix4d(r.fk(q).matrix()); },
           py::arg("q"), "4x4 pose of nozzle_tip in the tunnel frame; column 2 is the spray axis.")
      .def("jacobian", &Robot::jacobian, py::arg("q"), "6 x dof geometric Jacobian (linear; angular), tunnel frame.")
      .def("placed_at", &Robot::placed_at, py::arg("base_position_m"),
           "The same robot with base_link at base_position_m in the tunnel frame [m].")
      .def("neutral", &Robot::neutral, "Ready posture, the default IK seed.")
      .def("stow", &Robot::stow, "Folded posture every trajectory starts from (URDF stow=, default neutral).")
      .def("within_limits", &Robot::within_limits, py::arg("q"), py::arg("slack") = 1e-9);

  py::class_<IkResult>(m, "IkResult")
      .def_readonly("success", &IkResult::success)
      .def_readonly("q", &IkResult::q)
      .def_readonly("position_error_m", &IkResult::position_error_m)
      .def_readonly("angle_error_rad", &IkResult::angle_error_rad)
      .def_readonly("iterations", &IkResult::iterations)
      .def_readonly("restarts", &IkResult::restarts)
      .def_readonly("reason", &IkResult::reason)
      .def("__repr__", [](const IkResult& r) {
        return std::string("<IkResult ") + (r.success ? "success" : "failed: " + r.reason) + ">";
      });

  m.def("solve_ik_5dof", &solve_ik_5dof, py::arg("robot"), py::arg("target"), py::arg("seed"), py::arg("config"),
        "5-DOF IK (nozzle position + spray axis; roll free). success only within limits and tolerance.");
  m.def(
      "solve_ik_kdl_nr_jl",
      [](const Robot& r, const Eigen::Matrix4d& target, const Eigen::VectorXd& seed, const RobotConfig& c, int it) {
        Eigen::Isometry3d t;
        t.matrix() = target;
        return solve_ik_kdl_nr_jl(r, t, seed, c, it);
      },
      py::arg("robot"), py::arg("target"), py::arg("seed"), py::arg("config"), py::arg("max_iterations") = 500,
      "Plain KDL ChainIkSolverPos_NR_JL on the full 6-DOF pose (4x4, tunnel frame): the baseline.");

  py::class_<JointPath>(m, "JointPath")
      .def_property_readonly("q",
                             [](const JointPath& p) {
                               Eigen::MatrixXd out(p.q.size(), p.q.empty() ? 0 : p.q.front().size());
                               for (size_t k = 0; k < p.q.size(); ++k) out.row(k) = p.q[k].transpose();
                               return out;
                             },
                             "(waypoints, dof) joint positions")
      .def_readonly("position_error_m", &JointPath::position_error_m)
      .def_readonly("angle_error_rad", &JointPath::angle_error_rad)
      .def_readonly("max_position_error_m", &JointPath::max_position_error_m)
      .def_readonly("max_angle_error_rad", &JointPath::max_angle_error_rad)
      .def_readonly("max_joint_step", &JointPath::max_joint_step)
      .def_readonly("inserted_substeps", &JointPath::inserted_substeps);
  m.def("solve_path", &solve_path, py::arg("robot"), py::arg("waypoints"), py::arg("seed"), py::arg("config"),
        "IK along a pass, warm-started and continuous; RuntimeError names the unreachable waypoint.");

  py::class_<ReachMap>(m, "ReachMap", "Reachability of a half-cylinder bay at a standoff, nozzle normal to the wall.")
      .def_readonly("radius_m", &ReachMap::radius_m)
      .def_readonly("standoff_m", &ReachMap::standoff_m)
      .def_property_readonly("theta_rad", [](const ReachMap& m) { return as_array(m.theta_rad); })
      .def_property_readonly("d_m", [](const ReachMap& m) { return as_array(m.d_m); })
      .def_property_readonly("reached",
                             [](const ReachMap& m) {
                               std::vector<double> v(m.reached.begin(), m.reached.end());
                               return reach_grid(v, m);
                             },
                             "(n_theta, n_d) 1 = reached")
      .def_property_readonly("position_error_m", [](const ReachMap& m) { return reach_grid(m.position_error_m, m); })
      .def_property_readonly("angle_error_rad", [](const ReachMap& m) { return reach_grid(m.angle_error_rad, m); })
      .def_property_readonly("min_limit_margin", [](const ReachMap& m) { return reach_grid(m.min_limit_margin, m); },
                             "smallest distance of any joint to its limit, as a share of its range")
      .def_readonly("n_reached", &ReachMap::n_reached)
      .def_readonly("n_total", &ReachMap::n_total)
      .def("fraction", &ReachMap::fraction);
  m.def("reachability_map", &reachability_map, py::arg("robot"), py::arg("config"), py::arg("radius_m"),
        py::arg("standoff_m") = 1.0, py::arg("bay_length_m") = 1.2, py::arg("n_theta") = 61, py::arg("n_d") = 13);

  py::class_<IkBenchmark>(m, "IkBenchmark", "Random reachable poses (FK of random q), timed in C++.")
      .def_readonly("samples", &IkBenchmark::samples)
      .def_readonly("solved_5dof_neutral", &IkBenchmark::solved_5dof_neutral)
      .def_readonly("solved_5dof_random_seed", &IkBenchmark::solved_5dof_random_seed)
      .def_readonly("solved_5dof_no_restart", &IkBenchmark::solved_5dof_no_restart)
      .def_readonly("solved_kdl_6dof", &IkBenchmark::solved_kdl_6dof)
      .def_readonly("limit_violations", &IkBenchmark::limit_violations)
      .def_readonly("tolerance_misses", &IkBenchmark::tolerance_misses)
      .def_readonly("max_position_error_m", &IkBenchmark::max_position_error_m)
      .def_readonly("max_angle_error_rad", &IkBenchmark::max_angle_error_rad)
      .def_property_readonly("time_5dof_neutral_s", [](const IkBenchmark& b) { return as_array(b.time_5dof_neutral_s); })
      .def_property_readonly("time_5dof_random_seed_s",
                             [](const IkBenchmark& b) { return as_array(b.time_5dof_random_seed_s); })
      .def_property_readonly("time_5dof_no_restart_s",
                             [](const IkBenchmark& b) { return as_array(b.time_5dof_no_restart_s); })
      .def_property_readonly("time_kdl_6dof_s", [](const IkBenchmark& b) { return as_array(b.time_kdl_6dof_s); });
  m.def("ik_benchmark", &ik_benchmark, py::arg("robot"), py::arg("config"), py::arg("samples"), py::arg("seed") = 1);
}
