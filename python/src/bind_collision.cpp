#include "bindings.hpp"
#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/collision/transit.hpp"
#include "shotcrete/robot/robot.hpp"
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
      .def_readonly("size_m", &CollisionShape::size_m)
      .def_readonly("carrier", &CollisionShape::carrier,
                    "on a link fixed to base_link off the chain (the rig's carrier), in base_link's frame");
  m.def(
      "machine_points",
      [](const Points& xyz_m, const Robot& robot, double tolerance_m) {
        const std::vector<char> m = machine_points(xyz_m, robot, tolerance_m);
        py::array_t<bool> out(static_cast<py::ssize_t>(m.size()));
        auto o = out.mutable_unchecked<1>();
        for (std::size_t i = 0; i < m.size(); ++i) o(static_cast<py::ssize_t>(i)) = m[i] != 0;
        return out;
      },
      py::arg("xyz_m"), py::arg("robot"), py::arg("tolerance_m"),
      "Per point (n x 3, tunnel frame; bool array), True when it is the machine's own where the robot stands: in the "
      "column of a carrier box (across it, widened by tolerance_m; up to its top + tolerance_m).");
  m.def("box_signed_distance",
        [](const CollisionShape& box, const Eigen::Matrix4d& link_pose, const Eigen::Vector3d& p) {
          Eigen::Vector3d g;
          const double d = box_signed_distance(box, Eigen::Isometry3d(link_pose), p, &g);
          return py::make_tuple(d, g);
        },
        py::arg("box"), py::arg("link_pose"), py::arg("p"),
        "(signed distance m, its gradient) of a point to a box shape at its link's 4x4 world pose (negative inside).");
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
          "(distance m, the wall's closest point) of a shape at its link's 4x4 world pose; reads at most a leaf "
          "diagonal short, never long")
      .def(
          "exact_distance",
          [](const WallOctree& w, const CollisionShape& s, const Eigen::Matrix4d& link_pose) {
            Eigen::Vector3d closest;
            const double d = w.exact_distance(s, Eigen::Isometry3d(link_pose), &closest);
            return py::make_tuple(d, closest);
          },
          py::arg("shape"), py::arg("link_pose"),
          "(distance m, the nearest wall point): the octree's answer refined over the points within its bound "
          "(KD-tree): the minimum over every point")
      .def_property_readonly("field_voxel_m", &WallOctree::field_voxel_m, "edge of the distance field's cells [m]")
      .def(
          "field_lower_bound",
          [](const WallOctree& w, const CollisionShape& s, const Eigen::Matrix4d& link_pose) {
            return w.field_lower_bound(s, Eigen::Isometry3d(link_pose));
          },
          py::arg("shape"), py::arg("link_pose"),
          "lower bound [m] on exact_distance from the wall's Euclidean distance field (never above it)");
  m.def(
      "point_shape_distance",
      [](const Eigen::Vector3d& p, const CollisionShape& s, const Eigen::Matrix4d& link_pose) {
        return point_shape_distance(p, s, Eigen::Isometry3d(link_pose));
      },
      py::arg("point"), py::arg("shape"), py::arg("link_pose"), "Exact distance of a point to a shape (0 inside).");
  py::class_<LinkClearance>(m, "LinkClearance")
      .def_readonly("link", &LinkClearance::link)
      .def_readonly("fixed", &LinkClearance::fixed, "no joint moves the link's shapes (fixed_shapes)")
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
      .def_readonly("carrier_points", &ClearanceReport::carrier_points,
                    "scan points left out as the machine's own (the rig's carrier where it stood)")
      .def_readonly("samples", &ClearanceReport::samples)
      .def_readonly("wall_queries", &ClearanceReport::wall_queries, "octree readings (FCL; check_clearance_octree)")
      .def_readonly("field_queries", &ClearanceReport::field_queries,
                    "distance-field bounds of a shape at a sample (check_clearance)")
      .def_readonly("exact_queries", &ClearanceReport::exact_queries, "exact distances to the wall's points")
      .def_readonly("self_queries", &ClearanceReport::self_queries)
      .def_readonly("seconds", &ClearanceReport::seconds)
      .def_property_readonly("samples_below_margin", &ClearanceReport::samples_below_margin)
      .def_property_readonly("moving_samples_below_margin", &ClearanceReport::moving_samples_below_margin,
                             "samples_below_margin without the fixed links (those no posture changes)");
  m.def(
      "check_clearance",
      [](const Robot& robot, const TimedTrajectory& trajectory, const WallOctree& wall, const ClearanceConfig& config,
         const ProgressFn& progress) {
        py::gil_scoped_release release;
        return check_clearance(robot, trajectory, wall, config, progress);
      },
      py::arg("robot"), py::arg("trajectory"), py::arg("wall"), py::arg("config"), py::arg("progress") = nullptr,
      "Least distance of every link to the wall and between non-neighbouring links along the trajectory, and "
      "the samples below the margins (exact: samples are skipped only where a motion bound proves them clear, "
      "and those the distance field bounds below a margin are measured exactly); each link's min_m is its least "
      "exact distance over every sample (branch and bound), at_time_s the earliest sample where it occurs.");
  m.def("shape_margin_m", &shape_margin_m, py::arg("shape"), py::arg("config"),
        "Wall margin of a shape: nozzle_margin_m for links named nozzle*, else link_margin_m.");
  m.def("self_check_pairs", &self_check_pairs, py::arg("robot"),
        "Shape index pairs checked against each other (not neighbours, not touching at neutral).");
  m.def(
      "posture_allowance",
      [](const Robot& robot, const Eigen::VectorXd& q, const WallOctree& wall, const ClearanceConfig& config, double cap_m,
         bool without_fixed) {
        const std::vector<char> fixed = without_fixed ? fixed_shapes(robot) : std::vector<char>{};
        return posture_allowance(robot, q, wall, config, self_check_pairs(robot), cap_m, without_fixed ? &fixed : nullptr);
      },
      py::arg("robot"), py::arg("q"), py::arg("wall"), py::arg("config"), py::arg("cap_m") = 10.0,
      py::arg("without_fixed") = false,
      "Least distance less margin of posture q over the link shapes (wall) and link pairs, at most cap_m [m]; "
      "without_fixed: leaving out the shapes no joint moves (fixed_shapes), as the transit router and start_posture do.");
  m.def(
      "fixed_shapes", [](const Robot& robot) { const auto f = fixed_shapes(robot); return std::vector<bool>(f.begin(), f.end()); },
      py::arg("robot"),
      "Per collision shape: True when no joint moves it (the base; a turret cylinder slewing about its own axis).");
  py::class_<TransitDetour>(m, "TransitDetour", "A joint move that came closer than the margins.")
      .def_readonly("move", &TransitDetour::move, "index among the trajectory's joint moves (0 = from the start)")
      .def_readonly("region_index", &TransitDetour::region_index, "-1 between regions, else a stop-and-go move")
      .def_readonly("start_time_s", &TransitDetour::start_time_s)
      .def_readonly("straight_samples_below", &TransitDetour::straight_samples_below)
      .def_readonly("straight_worst", &TransitDetour::straight_worst)
      .def_readonly("straight_min_allowance_m", &TransitDetour::straight_min_allowance_m)
      .def_readonly("rerouted", &TransitDetour::rerouted)
      .def_readonly("eased", &TransitDetour::eased,
                    "no clear route, but one with at most half the straight move's link-samples below a margin (or fewer, 0.1 m less short of them) replaced it (from or to a posture itself short of the margins: one routed with the margins lowered by its shortfall); still a failure")
      .def_readonly("reason", &TransitDetour::reason)
      .def_readonly("vias", &TransitDetour::vias)
      .def_readonly("via_allowance_m", &TransitDetour::via_allowance_m)
      .def_readonly("min_allowance_m", &TransitDetour::min_allowance_m)
      .def_readonly("straight_duration_s", &TransitDetour::straight_duration_s)
      .def_readonly("duration_s", &TransitDetour::duration_s)
      .def_readonly("optimisations", &TransitDetour::optimisations)
      .def_readonly("sampled_nodes", &TransitDetour::sampled_nodes, "postures the sampled planner (RRT-Connect) added");
  py::class_<TransitReport>(m, "TransitReport", "The joint moves of a trajectory checked and re-routed.")
      .def_readonly("moves_checked", &TransitReport::moves_checked)
      .def_readonly("rerouted", &TransitReport::rerouted)
      .def_readonly("failed", &TransitReport::failed)
      .def_readonly("detour_time_s", &TransitReport::detour_time_s)
      .def_readonly("detours", &TransitReport::detours)
      .def_readonly("seconds", &TransitReport::seconds);
  py::class_<StartPosture>(m, "StartPosture", "The posture a job starts from.")
      .def_readonly("q", &StartPosture::q)
      .def_readonly("preferred", &StartPosture::preferred, "the posture asked for (the stow)")
      .def_readonly("moved", &StartPosture::moved, "q is not `preferred`: that one broke a margin, q keeps them")
      .def_readonly("preferred_allowance_m", &StartPosture::preferred_allowance_m)
      .def_readonly("allowance_m", &StartPosture::allowance_m, "< 0: no clear posture was found")
      .def_readonly("optimisations", &StartPosture::optimisations);
  m.def(
      "start_posture",
      [](const Robot& robot, const Eigen::VectorXd& preferred, const WallOctree& wall, const ClearanceConfig& config) {
        py::gil_scoped_release release;
        return start_posture(robot, preferred, wall, config);
      },
      py::arg("robot"), py::arg("preferred"), py::arg("wall"), py::arg("config"),
      "`preferred` when it keeps every margin from the wall, else the nearest posture found that does (the transit "
      "router's search of maximum space allowance from it, its telescopes in, the neutral posture, turned about the "
      "first joint).");
  py::class_<SwingRoom>(m, "SwingRoom", "How much room the arm has to slew all the way round (swing_room).")
      .def_readonly("least_m", &SwingRoom::least_m,
                    "over the slew directions, the most space allowance a posture has there (capped at via_allowance_m) [m]")
      .def_readonly("worst_slew_rad", &SwingRoom::worst_slew_rad, "the direction with the least [rad]")
      .def_readonly("worst_q", &SwingRoom::worst_q, "the roomiest posture found there")
      .def_readonly("directions", &SwingRoom::directions)
      .def_readonly("optimisations", &SwingRoom::optimisations);
  m.def(
      "swing_room",
      [](const Robot& robot, const WallOctree& wall, const ClearanceConfig& config, double step_rad) {
        py::gil_scoped_release release;
        return swing_room(robot, wall, config, step_rad);
      },
      py::arg("robot"), py::arg("wall"), py::arg("config"), py::arg("step_rad") = kSwingStepRad,
      "At every slew direction (step_rad apart), the posture of most space allowance with the slew held (saturated at "
      "config.via_allowance_m); the least of those and where.");
  m.def("base_room", &base_room, py::arg("robot"), py::arg("wall"), py::arg("config"),
        "Least exact distance of the links no joint moves (the base) to the wall less base_margin_m [m].");
  py::class_<BasePlacement>(m, "BasePlacement", "Where the job places the arm's base (place_base).")
      .def_readonly("checked", &BasePlacement::checked, "the placement was measured (robot.place_base, clearance, a scan)")
      .def_readonly("configured_m", &BasePlacement::configured_m, "robot.base_position_m [m]")
      .def_readonly("position_m", &BasePlacement::position_m, "where the job places the base [m]")
      .def_readonly("shift_m", &BasePlacement::shift_m, "along the tunnel axis from configured_m [m]")
      .def_readonly("moved", &BasePlacement::moved)
      .def_readonly("found", &BasePlacement::found, "position_m has room to slew every way")
      .def_readonly("configured_room_m", &BasePlacement::configured_room_m, "swing_room's least at the configured place [m]")
      .def_readonly("configured_short_slew_rad", &BasePlacement::configured_short_slew_rad,
                    "the configured place's first slew direction short of room, from slew 0 outward [rad]")
      .def_readonly("configured_base_room_m", &BasePlacement::configured_base_room_m)
      .def_readonly("room_m", &BasePlacement::room_m, "swing_room's least at position_m [m]")
      .def_readonly("base_room_m", &BasePlacement::base_room_m, "base_room at position_m [m]")
      .def_readonly("places_tried", &BasePlacement::places_tried)
      .def_readonly("seconds", &BasePlacement::seconds);
  m.def(
      "place_base_on_wall",
      [](const Robot& robot, const WallOctree& wall, const Eigen::Vector3d& along, const ClearanceConfig& config,
         double max_shift_m) {
        py::gil_scoped_release release;
        return place_base(robot, wall, along, config, max_shift_m);
      },
      py::arg("robot"), py::arg("wall"), py::arg("along"), py::arg("config"), py::arg("max_shift_m"),
      "The robot's base when the arm has room there to slew every way (swing_room >= via_allowance_m) and its fixed "
      "links keep base_margin_m; else the nearest such place along `along` within max_shift_m (0.1 m steps), never "
      "carrying the base's fixed links through a point of the wall.");
  m.def(
      "clear_transits",
      [](const Robot& robot, TimedTrajectory& trajectory, const WallOctree& wall, const ClearanceConfig& config,
         const TimingConfig& timing) {
        py::gil_scoped_release release;
        return clear_transits(robot, trajectory, wall, config, timing);
      },
      py::arg("robot"), py::arg("trajectory"), py::arg("wall"), py::arg("config"), py::arg("timing"),
      "Checks every joint move of the trajectory and re-routes (in place) those closer than the margins through "
      "via postures of maximum space allowance.");
}
