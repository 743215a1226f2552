#include "bindings.hpp"
#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/timing/trajectory.hpp"

using namespace shotcrete;

void bind_collision(py::module_& m) {
  py::class_<CollisionShape> shape(m, "CollisionShape", "A <collision> shape of a URDF link, in its link frame.");
  py::enum_<CollisionShape::Kind>(shape, "Kind")
      .value("cylinder", CollisionShape::Kind::cylinder)
      .value("box", CollisionShape::Kind::box)
      .value("sphere", CollisionShape::Kind::sphere);
  shape.def_readonly("link", &CollisionShape::link)
      .def_readonly("frame", &CollisionShape::frame, "index into Robot.link_frames()")
      .def_readonly("kind", &CollisionShape::kind)
      .def_property_readonly("origin", [](const CollisionShape& s) { return Eigen::Matrix4d(s.origin.matrix()); })
      .def_readonly("radius_m", &CollisionShape::radius_m)
      .def_readonly("length_m", &CollisionShape::length_m)
      .def_readonly("size_m", &CollisionShape::size_m);
  py::class_<WallOctree>(m, "WallOctree", "The wall as an octree of points (FCL + octomap) for distance queries.")
      .def(py::init<const Points&, double>(), py::arg("xyz_m"), py::arg("resolution_m"))
      .def_property_readonly("resolution_m", &WallOctree::resolution_m)
      .def_property_readonly("occupied_leaves", &WallOctree::occupied_leaves)
      .def(
          "distance",
          [](const WallOctree& w, const CollisionShape& s, const Eigen::Matrix4d& link_pose) {
            Eigen::Vector3d closest;
            const double d = w.distance(s, Eigen::Isometry3d(link_pose), &closest);
            return py::make_tuple(d, closest);
          },
          py::arg("shape"), py::arg("link_pose"),
          "(distance m, the wall's closest point) of a shape at its link's 4x4 world pose; reads at most half a "
          "leaf diagonal short, never long");
  m.def(
      "point_shape_distance",
      [](const Eigen::Vector3d& p, const CollisionShape& s, const Eigen::Matrix4d& link_pose) {
        return point_shape_distance(p, s, Eigen::Isometry3d(link_pose));
      },
      py::arg("point"), py::arg("shape"), py::arg("link_pose"), "Exact distance of a point to a shape (0 inside).");
  py::class_<LinkClearance>(m, "LinkClearance")
      .def_readonly("link", &LinkClearance::link)
      .def_readonly("margin_m", &LinkClearance::margin_m)
      .def_readonly("min_m", &LinkClearance::min_m)
      .def_readonly("at_time_s", &LinkClearance::at_time_s)
      .def_readonly("closest_m", &LinkClearance::closest_m)
      .def_readonly("samples_below_margin", &LinkClearance::samples_below_margin);
  py::class_<SelfClearance>(m, "SelfClearance")
      .def_readonly("link_a", &SelfClearance::link_a)
      .def_readonly("link_b", &SelfClearance::link_b)
      .def_readonly("min_m", &SelfClearance::min_m)
      .def_readonly("at_time_s", &SelfClearance::at_time_s)
      .def_readonly("samples_below_margin", &SelfClearance::samples_below_margin);
  py::class_<ClearanceReport>(m, "ClearanceReport", "The space allowance of every link along a trajectory.")
      .def_readonly("links", &ClearanceReport::links)
      .def_readonly("self_clearance", &ClearanceReport::self)
      .def_readonly("octree_resolution_m", &ClearanceReport::octree_resolution_m)
      .def_readonly("octree_leaves", &ClearanceReport::octree_leaves)
      .def_readonly("wall_points", &ClearanceReport::wall_points)
      .def_readonly("samples", &ClearanceReport::samples)
      .def_readonly("wall_queries", &ClearanceReport::wall_queries)
      .def_readonly("self_queries", &ClearanceReport::self_queries)
      .def_readonly("seconds", &ClearanceReport::seconds)
      .def_property_readonly("samples_below_margin", &ClearanceReport::samples_below_margin);
  m.def(
      "check_clearance",
      [](const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall, const ClearanceConfig& config,
         const ProgressFn& progress) {
        py::gil_scoped_release release;
        return check_clearance(robot, trajectory, wall, config, progress);
      },
      py::arg("robot"), py::arg("trajectory"), py::arg("wall"), py::arg("config"), py::arg("progress") = nullptr,
      "Least distance of every link to the wall and between non-neighbouring links along the trajectory, and "
      "the samples below the margins (exact: samples are skipped only where a motion bound proves them clear).");
}

