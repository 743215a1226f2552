#include <sstream>

#include "bindings.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/pipeline/job_summary.hpp"
#include "shotcrete/timing/timing.hpp"

using namespace shotcrete;

namespace {

template <class T> py::array_t<T> to_array(const std::vector<T>& v) {
  py::array_t<T> out(static_cast<py::ssize_t>(v.size()));
  std::copy(v.begin(), v.end(), out.mutable_data());
  return out;
}
py::array_t<int> to_int_array(const std::vector<char>& v) {
  py::array_t<int> out(static_cast<py::ssize_t>(v.size()));
  std::copy(v.begin(), v.end(), out.mutable_data());
  return out;
}
py::array_t<bool> to_bool_array(const std::vector<char>& v) {
  py::array_t<bool> out(static_cast<py::ssize_t>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) out.mutable_data()[i] = v[i] != 0;
  return out;
}
Eigen::MatrixXd rows(const std::vector<Eigen::VectorXd>& v) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(v.size()), v.empty() ? 0 : v.front().size());
  for (std::size_t i = 0; i < v.size(); ++i) m.row(static_cast<Eigen::Index>(i)) = v[i].transpose();
  return m;
}

// A pass from Python: a dict {"positions": (K,3), "axes": (K,3) or (3,), "speed_mps": v}, a tuple
// (positions, axes, speed_mps), or a bound Pass object.
Pass pass_from_py(const py::handle& h, std::size_t r, std::size_t i) {
  const std::string where = "region " + std::to_string(r) + " pass " + std::to_string(i);
  py::object pos, ax, spd;
  if (py::isinstance<py::dict>(h)) {
    const auto d = py::reinterpret_borrow<py::dict>(h);
    for (const char* k : {"positions", "axes", "speed_mps"})
      if (!d.contains(k)) throw py::value_error(where + ": missing key '" + std::string(k) + "'");
    pos = d["positions"];
    ax = d["axes"];
    spd = d["speed_mps"];
  } else if (py::isinstance<py::tuple>(h) || py::isinstance<py::list>(h)) {
    const auto t = py::reinterpret_borrow<py::sequence>(h);
    if (t.size() != 3) throw py::value_error(where + ": expected (positions, axes, speed_mps)");
    pos = t[0];
    ax = t[1];
    spd = t[2];
  } else {
    try {
      return h.cast<Pass>();
    } catch (const py::cast_error&) {
      throw py::value_error(where + ": expected a dict, a (positions, axes, speed_mps) tuple or a Pass");
    }
  }
  const Eigen::MatrixXd P = pos.cast<Eigen::MatrixXd>();
  Eigen::MatrixXd A = ax.cast<Eigen::MatrixXd>();
  if (P.cols() != 3) throw py::value_error(where + ": positions must be (K, 3)");
  if (A.size() == 3) A = Eigen::MatrixXd(A.reshaped(1, 3).replicate(P.rows(), 1));  // no aliasing
  if (A.rows() != P.rows() || A.cols() != 3) throw py::value_error(where + ": axes must be (K, 3) or (3,)");
  Pass p;
  p.speed_mps = spd.cast<double>();
  for (Eigen::Index k = 0; k < P.rows(); ++k) {
    NozzlePose w;
    w.position_m = P.row(k).transpose();
    w.axis = A.row(k).transpose();
    p.waypoints.push_back(w);
    if (k > 0) p.length_m += (P.row(k) - P.row(k - 1)).norm();
  }
  return p;
}
std::vector<Pass> region_from_py(const py::handle& h, std::size_t r = 0) {
  std::vector<Pass> out;
  std::size_t i = 0;
  for (const auto& p : h) out.push_back(pass_from_py(p, r, i++));
  return out;
}
std::vector<std::vector<Pass>> regions_from_py(const py::handle& h) {
  std::vector<std::vector<Pass>> out;
  std::size_t r = 0;
  for (const auto& reg : h) out.push_back(region_from_py(reg, r++));
  return out;
}

py::dict samples_dict(const CartesianSamples& s) {
  py::dict d;
  d["t_s"] = to_array(s.t_s);
  d["s_m"] = to_array(s.s_m);
  d["positions"] = pose_positions(s.nozzle);
  d["axes"] = pose_axes(s.nozzle);
  d["speed_mps"] = to_array(s.speed_mps);
  d["tangential_accel_mps2"] = to_array(s.tangential_accel_mps2);
  d["normal_accel_mps2"] = to_array(s.normal_accel_mps2);
  d["spraying"] = to_bool_array(s.spraying);
  d["pass_index"] = to_array(s.pass_index);
  d["kind"] = to_int_array(s.kind);
  d["dwell_s"] = to_array(spray_dwells(s.t_s, s.spraying));
  return d;
}

}  // namespace

void bind_timing(py::module_& m) {
  py::enum_<SpeedShape>(m, "SpeedShape").value("CYCLOID", SpeedShape::Cycloid).value("QUINTIC", SpeedShape::Quintic);
  py::enum_<SegmentKind>(m, "SegmentKind")
      .value("PASS", SegmentKind::Pass)
      .value("TURN", SegmentKind::Turn)
      .value("LEAD", SegmentKind::Lead)
      .value("LINK", SegmentKind::Link)
      .value("TRANSIT", SegmentKind::Transit);
  py::enum_<PieceMotion>(m, "PieceMotion", "How the speed profile treats a path piece.")
      .value("BY_KIND", PieceMotion::ByKind)
      .value("STOP_AT_END", PieceMotion::StopAtEnd)
      .value("REST_TO_REST", PieceMotion::RestToRest)
      .value("START_FROM_REST", PieceMotion::StartFromRest)
      .value("SPRAY_OFF_GAP", PieceMotion::SprayOffGap)
      .value("CREEP", PieceMotion::Creep);

  py::class_<SpeedPiece>(m, "SpeedPiece", "Speed change v0 -> v1 over duration_s (cycloid or quintic shape).")
      .def(py::init([](double v0, double v1, double T, SpeedShape s) { return SpeedPiece{v0, v1, T, s}; }),
           py::arg("v0_mps"), py::arg("v1_mps"), py::arg("duration_s"), py::arg("shape") = SpeedShape::Cycloid)
      .def_readonly("v0_mps", &SpeedPiece::v0_mps)
      .def_readonly("v1_mps", &SpeedPiece::v1_mps)
      .def_readonly("duration_s", &SpeedPiece::duration_s)
      .def_readonly("shape", &SpeedPiece::shape)
      .def_property_readonly("length_m", &SpeedPiece::length_m)
      .def_property_readonly("peak_accel_mps2", &SpeedPiece::peak_accel_mps2);

  py::class_<SpeedProfile>(m, "SpeedProfile", "Speed along a path: pieces one after the other from s = 0.")
      .def(py::init<>())
      .def("append", py::overload_cast<const SpeedPiece&>(&SpeedProfile::append), py::arg("piece"))
      .def("extend", py::overload_cast<const SpeedProfile&>(&SpeedProfile::append), py::arg("profile"))
      .def_property_readonly("duration_s", &SpeedProfile::duration_s)
      .def_property_readonly("length_m", &SpeedProfile::length_m)
      .def_property_readonly("pieces", &SpeedProfile::pieces)
      .def("at",
           [](const SpeedProfile& p, double t) {
             const auto s = p.at(t);
             py::dict d;
             d["s_m"] = s.s_m;
             d["v_mps"] = s.v_mps;
             d["a_mps2"] = s.a_mps2;
             d["j_mps3"] = s.j_mps3;
             return d;
           },
           py::arg("t_s"), "State {s_m, v_mps, a_mps2, j_mps3} at time t (clamped).")
      .def("evaluate",
           [](const SpeedProfile& p, const Eigen::VectorXd& t) {
             Eigen::MatrixXd out(t.size(), 4);
             for (Eigen::Index i = 0; i < t.size(); ++i) {
               const auto s = p.at(t[i]);
               out.row(i) << s.s_m, s.v_mps, s.a_mps2, s.j_mps3;
             }
             return out;
           },
           py::arg("t_s"), "(N, 4) array of s, v, a, jerk at the given times.")
      .def("time_at_distance", &SpeedProfile::time_at_distance, py::arg("s_m"));

  m.def("cycloid_start", &cycloid_start, py::arg("s_start_m"), py::arg("v_mps"), py::arg("k1"),
        "Paper start profile: cycloidal acceleration over k1 Ts, cruise until Ts = 2 s / (v (2 - k1)).");
  m.def("cycloid_end", &cycloid_end, py::arg("s_end_m"), py::arg("v_mps"), py::arg("k2"),
        "Paper end profile: cruise until k2 Te, cycloidal stop at Te = 2 s / (v (1 + k2)).");
  m.def("rest_to_rest", &rest_to_rest, py::arg("length_m"), py::arg("v_mps"), py::arg("accel_time_s"),
        py::arg("shape") = SpeedShape::Quintic, "Rest-to-rest move (quintic: the baseline).");

  py::class_<TimingParams>(m, "TimingParams", "Tunable timing parameters (the swarm's particle).")
      .def(py::init<>())
      .def_static("from_config", &TimingParams::from_config, py::arg("timing_config"))
      .def_readwrite("k1", &TimingParams::k1)
      .def_readwrite("k2", &TimingParams::k2)
      .def_readwrite("start_length_m", &TimingParams::start_length_m)
      .def_readwrite("end_length_m", &TimingParams::end_length_m)
      .def_readwrite("turn_speed_mps", &TimingParams::turn_speed_mps)
      .def_readwrite("turn_accel_mps2", &TimingParams::turn_accel_mps2,
                     "centripetal acceleration capping the turn arc speed; 0 = speed_change_accel_mps2")
      .def_readwrite("speed_change_accel_mps2", &TimingParams::speed_change_accel_mps2)
      .def_readwrite("min_turn_s", &TimingParams::min_turn_s,
                     "least duration of a turn at its own speed (the pump's off spell) [s]; 0 = none")
      .def_readwrite("min_lead_s", &TimingParams::min_lead_s,
                     "least duration of a lead-in or lead-out (the pump's ramp runs on it) [s]; 0 = none")
      .def("to_dict", [](const TimingParams& p) {
        py::dict d;
        d["k1"] = p.k1;
        d["k2"] = p.k2;
        d["start_length_m"] = p.start_length_m;
        d["end_length_m"] = p.end_length_m;
        d["turn_speed_mps"] = p.turn_speed_mps;
        d["turn_accel_mps2"] = p.turn_accel_mps2;
        return d;
      });

  py::class_<CartesianPath>(m, "CartesianPath", "Nozzle path of a region: lead-in, passes, turn-arounds, lead-out.")
      .def_property_readonly("length_m", &CartesianPath::length_m)
      .def_property_readonly("piece_kinds",
                             [](const CartesianPath& p) {
                               std::vector<SegmentKind> k;
                               for (const auto& x : p.pieces()) k.push_back(x.kind);
                               return k;
                             })
      .def_property_readonly("piece_motions",
                             [](const CartesianPath& p) {
                               std::vector<PieceMotion> k;
                               for (const auto& x : p.pieces()) k.push_back(x.motion);
                               return k;
                             })
      .def_property_readonly("piece_lengths_m",
                             [](const CartesianPath& p) {
                               std::vector<double> k;
                               for (const auto& x : p.pieces()) k.push_back(x.length_m());
                               return k;
                             })
      .def_property_readonly("turn_radii_m",
                             [](const CartesianPath& p) {
                               std::vector<double> k;
                               for (const auto& x : p.pieces())
                                 if (x.is_arc) k.push_back(x.radius_m);
                               return k;
                             })
      .def("poses",
           [](const CartesianPath& p, const Eigen::VectorXd& s) {
             Eigen::MatrixXd out(s.size(), 6);
             for (Eigen::Index i = 0; i < s.size(); ++i) {
               const auto q = p.pose_at(s[i]);
               out.row(i) << q.position_m.transpose(), q.axis.transpose();
             }
             return out;
           },
           py::arg("s_m"), "(N, 6) positions and axes at arc lengths s.")
      .def("tangents",
           [](const CartesianPath& p, const Eigen::VectorXd& s) {
             Eigen::MatrixXd out(s.size(), 3);
             for (Eigen::Index i = 0; i < s.size(); ++i) out.row(i) = p.tangent_at(s[i]).transpose();
             return out;
           },
           py::arg("s_m"));

  m.def(
      "region_path",
      [](const py::handle& passes, double lead_in, double lead_out, bool spray_on_turns, double turn_run_m) {
        RegionPathOptions o;
        o.lead_in_m = lead_in;
        o.lead_out_m = lead_out;
        o.spray_on_turns = spray_on_turns;
        o.turn_run_m = turn_run_m;
        return region_path(region_from_py(passes), o);
      },
      py::arg("passes"), py::arg("lead_in_m"), py::arg("lead_out_m"), py::arg("spray_on_turns") = false,
      py::arg("turn_run_m") = 0.0,
      "Serpentine path of one region; passes as dicts {positions, axes, speed_mps}, tuples or Pass objects.");
  m.def(
      "timing_region_path",
      [](const py::handle& passes, double lead_in, double lead_out, const TimingConfig& tc) {
        return timing_region_path(region_from_py(passes), lead_in, lead_out, tc);
      },
      py::arg("passes"), py::arg("lead_in_m"), py::arg("lead_out_m"), py::arg("timing_config"),
      "The region path time_plan times: turn and stop-and-go runs sized by the timing config.");
  m.def("region_profile", &region_profile, py::arg("path"), py::arg("params"),
        "Cycloid start/end, pass speeds, cycloidal speed changes on the turns.");
  m.def(
      "quintic_baseline",
      [](const py::handle& passes, double accel, double stepover) {
        auto b = quintic_baseline(region_from_py(passes), accel, stepover);
        return py::make_tuple(b.path, b.profile);
      },
      py::arg("passes"), py::arg("max_accel_mps2"), py::arg("stepover_speed_mps"),
      "Baseline: quintic acceleration/deceleration, full stop at every corner -> (path, profile).");
  m.def(
      "sample_path",
      [](const CartesianPath& path, const SpeedProfile& prof, double rate) { return samples_dict(sample_path(path, prof, rate)); },
      py::arg("path"), py::arg("profile"), py::arg("rate_hz"),
      "Samples (steps <= 1/rate) as a dict of arrays, with dwell_s for accumulate_dwells.");
  m.def(
      "check_nozzle",
      [](const CartesianPath& path, const SpeedProfile& prof, double vmax, double amax) {
        const auto c = check_nozzle(path, prof, NozzleLimits{vmax, amax});
        py::dict d;
        d["max_speed_mps"] = c.max_speed_mps;
        d["max_accel_mps2"] = c.max_accel_mps2;
        d["speed_ratio"] = c.speed_ratio;
        d["accel_ratio"] = c.accel_ratio;
        d["ok"] = c.ok();
        return d;
      },
      py::arg("path"), py::arg("profile"), py::arg("max_speed_mps"), py::arg("max_accel_mps2"));
  m.def("spray_dwells", &spray_dwells, py::arg("t_s"), py::arg("spraying"));
  m.def("quintic_min_duration", &quintic_min_duration, py::arg("q0"), py::arg("q1"), py::arg("velocity_limits"),
        py::arg("acceleration_limits"), "Shortest rest-to-rest joint quintic within the limits [s].");
  m.def("quintic_nozzle_duration", &quintic_nozzle_duration, py::arg("robot"), py::arg("q0"), py::arg("q1"),
        py::arg("max_speed_mps"), py::arg("max_accel_mps2"),
        "Shortest rest-to-rest joint quintic within the joint limits and the nozzle's speed / acceleration limits [s].");

  py::class_<TimedTrajectory>(m, "TimedTrajectory", "Timed joint trajectory with nozzle poses and spraying flags.")
      .def_static(
          "from_joints",
          [](const std::vector<double>& t_s, const Eigen::MatrixXd& q) {
            if (static_cast<Eigen::Index>(t_s.size()) != q.rows())
              throw std::invalid_argument("TimedTrajectory.from_joints: " + std::to_string(t_s.size()) + " times but " +
                                          std::to_string(q.rows()) + " rows of joints");
            if (!q.allFinite()) throw std::invalid_argument("TimedTrajectory.from_joints: joints contain NaN or inf");
            for (std::size_t k = 1; k < t_s.size(); ++k)
              if (!(t_s[k] >= t_s[k - 1]))
                throw std::invalid_argument("TimedTrajectory.from_joints: times must be finite and non-decreasing (sample " +
                                            std::to_string(k) + ")");
            TimedTrajectory t;
            t.t_s = t_s;
            for (Eigen::Index i = 0; i < q.rows(); ++i) t.q.push_back(q.row(i).transpose());
            t.duration_s = t_s.empty() ? 0.0 : t_s.back() - t_s.front();
            return t;
          },
          py::arg("t_s"), py::arg("q"),
          "Times and joints only (no derivatives, poses or flags), e.g. a saved trajectory for check_clearance.")
      .def_property_readonly("t_s", [](const TimedTrajectory& t) { return to_array(t.t_s); })
      .def_property_readonly("q", [](const TimedTrajectory& t) { return rows(t.q); })
      .def_property_readonly("qd", [](const TimedTrajectory& t) { return rows(t.qd); })
      .def_property_readonly("qdd", [](const TimedTrajectory& t) { return rows(t.qdd); })
      .def_property_readonly("positions", [](const TimedTrajectory& t) { return pose_positions(t.nozzle); })
      .def_property_readonly("axes", [](const TimedTrajectory& t) { return pose_axes(t.nozzle); })
      .def_property_readonly("spraying", [](const TimedTrajectory& t) { return to_bool_array(t.spraying); })
      .def_property_readonly("pass_index", [](const TimedTrajectory& t) { return to_array(t.pass_index); })
      .def_property_readonly("region_index", [](const TimedTrajectory& t) { return to_array(t.region_index); })
      .def_property_readonly("kind", [](const TimedTrajectory& t) { return to_int_array(t.kind); })
      .def_property_readonly("dwell_s", [](const TimedTrajectory& t) { return to_array(spray_dwells(t.t_s, t.spraying)); })
      .def_readonly("duration_s", &TimedTrajectory::duration_s)
      .def_readonly("spray_time_s", &TimedTrajectory::spray_time_s)
      .def_readonly("transit_time_s", &TimedTrajectory::transit_time_s)
      .def_readonly("cycle_time", &TimedTrajectory::cycle_time, "duration_s by what the arm does (CycleTimeBreakdown)")
      .def_readonly("max_velocity_ratio", &TimedTrajectory::max_velocity_ratio)
      .def_readonly("max_acceleration_ratio", &TimedTrajectory::max_acceleration_ratio)
      .def_readonly("worst_velocity_joint", &TimedTrajectory::worst_velocity_joint)
      .def_readonly("worst_acceleration_joint", &TimedTrajectory::worst_acceleration_joint)
      .def_readonly("max_position_violation_rad", &TimedTrajectory::max_position_violation_rad,
                    "largest excursion of a revolute joint outside its position limits [rad]")
      .def_readonly("max_position_violation_m", &TimedTrajectory::max_position_violation_m,
                    "largest excursion of a prismatic joint outside its position limits [m]")
      .def_readonly("untracked_regions", &TimedTrajectory::untracked_regions)
      .def_readonly("untracked_region_ids", &TimedTrajectory::untracked_region_ids, "their region indices")
      .def_readonly("slowed_s", &TimedTrajectory::slowed_s, "time slow_to_joint_limits added [s]")
      .def_readonly("slowed_spraying_s", &TimedTrajectory::slowed_spraying_s, "of it, spraying [s]")
      .def_readonly("slowed_intervals", &TimedTrajectory::slowed_intervals, "sample intervals it stretched")
      .def_readonly("ratio_before_slowing", &TimedTrajectory::ratio_before_slowing,
                    "worst joint velocity / acceleration ratio before it")
      .def("joint_table", &TimedTrajectory::joint_table, "(N, 1 + 3 dof): t, q, qd, qdd")
      .def("joint_table_header", &TimedTrajectory::joint_table_header)
      .def("to_csv", &TimedTrajectory::to_csv)
      .def(
          "summary",
          [](const TimedTrajectory& t, const TimingConfig& timing) {
            return json_loads(to_json(
                summarise_trajectory(t, NozzleLimits{timing.nozzle_max_speed_mps, timing.nozzle_max_accel_mps2})));
          },
          py::arg("timing") = TimingConfig{},
          "The scalars (summarise_trajectory) as a dict; nozzle ratios against timing.nozzle_max_* (default: the "
          "default config's limits).")
      .def("__len__", &TimedTrajectory::size);

  m.def(
      "time_plan",
      [](const Robot& robot, const py::handle& regions, const Eigen::VectorXd& q_start, const TimingConfig& tc,
         const RobotConfig& rc, const py::object& params) {
        const auto regs = regions_from_py(regions);
        std::vector<TimingParams> per_region;
        if (py::isinstance<TimingParams>(params)) per_region.push_back(params.cast<TimingParams>());
        else if (!params.is_none()) per_region = params.cast<std::vector<TimingParams>>();
        py::gil_scoped_release release;
        return time_plan(robot, regs, q_start, tc, rc, per_region);
      },
      py::arg("robot"), py::arg("regions"), py::arg("q_start"), py::arg("timing_config"), py::arg("robot_config"),
      py::arg("params") = py::none(),
      "Regions (lists of passes) in spraying order -> timed joint trajectory at the config's rate. params: None\n"
      "(the config's), one TimingParams for every region, or a list with one per region (tune_timing's).");

  m.def(
      "slow_to_joint_limits",
      [](const Robot& robot, TimedTrajectory trajectory, double window_s) {
        py::gil_scoped_release release;
        const bool within = slow_to_joint_limits(robot, trajectory, window_s);
        return std::make_pair(trajectory, within);
      },
      py::arg("robot"), py::arg("trajectory"), py::arg("window_s") = 1.0,
      "(a copy of the trajectory slowed where its finite-difference joint velocities or accelerations break a limit:\n"
      "the same samples and joint path, the time between them stretched by a smooth factor; whether it ends within\n"
      "the limits). A trajectory within its limits comes back as it was.");

  m.def(
      "time_path",
      [](const Robot& robot, const CartesianPath& path, const SpeedProfile& prof, const Eigen::VectorXd& seed,
         double rate, const RobotConfig& rc) {
        py::gil_scoped_release release;
        return time_path(robot, path, prof, seed, rate, rc);
      },
      py::arg("robot"), py::arg("path"), py::arg("profile"), py::arg("seed"), py::arg("rate_hz"), py::arg("robot_config"),
      "One timed Cartesian path in joint space, rest to rest, with the limit check (no transits).");

  // (N, 6) rows of position and axis -> poses.
  auto poses_of = [](const Eigen::MatrixXd& poses6) {
    if (poses6.cols() != 6) throw py::value_error("poses must be (N, 6): position and axis");
    std::vector<NozzlePose> poses(static_cast<std::size_t>(poses6.rows()));
    for (Eigen::Index i = 0; i < poses6.rows(); ++i) {
      poses[static_cast<std::size_t>(i)].position_m = poses6.row(i).head<3>().transpose();
      poses[static_cast<std::size_t>(i)].axis = poses6.row(i).tail<3>().transpose();
    }
    return poses;
  };
  m.def(
      "joint_speed_limits",
      [poses_of](const Robot& robot, const Eigen::MatrixXd& poses6, const Eigen::VectorXd& seed, double accel,
                 double share) { return joint_speed_limits(robot, poses_of(poses6), seed, accel, share); },
      py::arg("robot"), py::arg("poses"), py::arg("seed"), py::arg("tangential_accel_mps2"), py::arg("limit_share") = 1.0,
      "Per pose of (N, 6) poses: the highest constant nozzle speed [m/s] the arm follows within limit_share of its\n"
      "joint velocity and acceleration limits, leaving room for speed changes of tangential_accel_mps2 (inf: no bound).");
  m.def(
      "track_joint_path",
      [poses_of](const Robot& robot, const Eigen::MatrixXd& poses6, const Eigen::VectorXd& q0, double gain) {
        const auto poses = poses_of(poses6);
        double em = 0.0, ea = 0.0;
        const auto q = track_joint_path(robot, poses, q0, gain, &em, &ea);
        return py::make_tuple(rows(q), em, ea);
      },
      py::arg("robot"), py::arg("poses"), py::arg("q0"), py::arg("limit_gain") = 0.02,
      "Exact joint tracking of (N, 6) poses from q0 -> (q (N, dof), max position error, max angle error).");

  py::class_<PsoOptions>(m, "PsoOptions")
      .def(py::init<>())
      .def_static("from_config", &PsoOptions::from_config, py::arg("timing_config"))
      .def_readwrite("particles", &PsoOptions::particles)
      .def_readwrite("iterations", &PsoOptions::iterations)
      .def_readwrite("seed", &PsoOptions::seed)
      .def_readwrite("a", &PsoOptions::a)
      .def_readwrite("b", &PsoOptions::b)
      .def_readwrite("w_min", &PsoOptions::w_min)
      .def_readwrite("w_max", &PsoOptions::w_max);
  py::class_<PsoResult>(m, "PsoResult")
      .def_readonly("best_x", &PsoResult::best_x)
      .def_readonly("best_f", &PsoResult::best_f)
      .def_readonly("best_history", &PsoResult::best_history)
      .def_readonly("success_history", &PsoResult::success_history)
      .def_readonly("evaluations", &PsoResult::evaluations)
      .def_readonly("stopped_by_deadline", &PsoResult::stopped_by_deadline, "the deadline stopped the iterations early");
  m.def("pso_minimize", &pso_minimize, py::arg("f"), py::arg("lower"), py::arg("upper"), py::arg("options"),
        py::arg("initial") = std::vector<Eigen::VectorXd>{},
        "Particle swarm with adaptive inertia weight and acceleration coefficients (AIWCPSO), seeded.");

  py::class_<TimingTuning>(m, "TimingTuning")
      .def_readonly("params", &TimingTuning::params, "one TimingParams per region")
      .def_property_readonly("feasible",
                             [](const TimingTuning& t) { return std::vector<bool>(t.feasible.begin(), t.feasible.end()); })
      .def_readonly("duration_s", &TimingTuning::duration_s)
      .def_readonly("initial_duration_s", &TimingTuning::initial_duration_s)
      .def_readonly("initial_feasible", &TimingTuning::initial_feasible)
      .def_readonly("pso", &TimingTuning::pso)
      .def_readonly("regions_cut_by_budget", &TimingTuning::regions_cut_by_budget,
                    "swarms stopped early by timing.pso_time_budget_s");
  m.def(
      "tune_timing",
      [](const Robot* robot, const py::handle& regions, const Eigen::VectorXd& q_start, const TimingConfig& tc,
         const RobotConfig& rc) {
        const auto regs = regions_from_py(regions);
        py::gil_scoped_release release;
        return tune_timing(robot, regs, q_start, tc, rc);
      },
      py::arg("robot"), py::arg("regions"), py::arg("q_start"), py::arg("timing_config"), py::arg("robot_config"),
      "AIWCPSO per region over (k1, k2, start/end length, turn speed, turn acceleration): minimum execution time "
      "within joint and nozzle limits (robot None: nozzle limits only).");

  py::class_<SpeedCapMap>(m, "SpeedCapMap", "Speed bounds near points, learned from timed trajectories.")
      .def(py::init<>())
      .def_readwrite("radius_m", &SpeedCapMap::radius_m)
      .def_property_readonly("points_m",
                             [](const SpeedCapMap& c) {
                               Eigen::MatrixXd P(static_cast<Eigen::Index>(c.points_m.size()), 3);
                               for (std::size_t i = 0; i < c.points_m.size(); ++i) P.row(static_cast<Eigen::Index>(i)) = c.points_m[i].transpose();
                               return P;
                             },
                             "(N, 3) [m]")
      .def_readonly("speed_mps", &SpeedCapMap::speed_mps)
      .def("at", &SpeedCapMap::at, py::arg("point_m"), "lowest bound within radius_m [m/s] (inf: none)")
      .def("learn", &SpeedCapMap::learn, py::arg("trajectory"), py::arg("velocity_limits"),
           py::arg("acceleration_limits"), py::arg("limit_share"),
           "adds bounds where the trajectory breaks a joint limit on a pass (velocity also on leads / links)");
  py::class_<ArmPlan>(m, "ArmPlan", "A bay planned, simulated and timed for an arm.")
      .def_readonly("plan", &ArmPlan::plan)
      .def_property_readonly("trajectory",
                             [](const ArmPlan& a) -> py::object {
                               return a.trajectory ? py::cast(*a.trajectory) : py::none();
                             },
                             "TimedTrajectory, or None when the timing failed (timing_error)")
      .def_readonly("timing_error", &ArmPlan::timing_error)
      .def_readonly("replans", &ArmPlan::replans)
      .def_readonly("learned", &ArmPlan::learned)
      .def_property_readonly("tuning",
                             [](const ArmPlan& a) -> py::object { return a.tuning ? py::cast(*a.tuning) : py::none(); },
                             "TimingTuning when timing.tune_with_pso, else None")
      .def_readonly("config_duration_s", &ArmPlan::config_duration_s,
                    "trajectory duration with the config's timing parameters [s]")
      .def_readonly("tuned_timing_used", &ArmPlan::tuned_timing_used)
      .def_readonly("clearance_term_used", &ArmPlan::clearance_term_used,
                    "the regions were tracked with the clearance term (clearance.null_space_gain > 0)")
      .def_readonly("tuning_error", &ArmPlan::tuning_error)
      .def_property_readonly("executed",
                             [](const ArmPlan& a) -> py::object { return a.executed ? py::cast(*a.executed) : py::none(); },
                             "ExecutedDeposit of the trajectory kept, or None without a trajectory")
      .def_property_readonly("clearance",
                             [](const ArmPlan& a) -> py::object { return a.clearance ? py::cast(*a.clearance) : py::none(); },
                             "ClearanceReport of the trajectory (clearance.enabled), or None")
      .def_property_readonly("transits",
                             [](const ArmPlan& a) -> py::object { return a.transits ? py::cast(*a.transits) : py::none(); },
                             "TransitReport of its joint moves (clearance.enabled), or None")
      .def_property_readonly("obstructed",
                             [](const ArmPlan& a) -> py::object { return a.obstructed ? py::cast(*a.obstructed) : py::none(); },
                             "ObstructedCells: cells no clear pose sprays (clearance.enabled), or None")
      .def_property_readonly("start",
                             [](const ArmPlan& a) -> py::object { return a.start ? py::cast(*a.start) : py::none(); },
                             "StartPosture the trajectory starts from (clearance.enabled), or None (the stow posture)")
      .def_readonly("base_placement", &ArmPlan::base_placement,
                    "BasePlacement: where the base stood for the plan (place_base; placed_robot(robot, it) is the arm)");
  py::class_<ObstructedCells>(m, "ObstructedCells", "Cells of the bay no clear nozzle pose can spray.")
      .def_readonly("cells", &ObstructedCells::cells)
      .def_readonly("margin_m", &ObstructedCells::margin_m)
      .def_readonly("least_distance_m", &ObstructedCells::least_distance_m)
      .def_readonly("nearest_obstacle_m", &ObstructedCells::nearest_obstacle_m)
      .def_readonly("links", &ObstructedCells::links)
      .def_readonly("obstacle_points", &ObstructedCells::obstacle_points)
      .def_readonly("lean", &ObstructedCells::lean,
                    "per grid cell the nozzle's lean off square (tangent 3-vector, length = angle [rad]); empty: none leans")
      .def_readonly("leaned_cells", &ObstructedCells::leaned_cells, "cells sprayed from a leaned pose (clear)")
      .def_readonly("max_lean_rad", &ObstructedCells::max_lean_rad);
  m.def(
      "obstructed_cells",
      [](const Surface& surface, const Robot& robot, const Config& config, const std::vector<bool>& machine) {
        const std::vector<char> m(machine.begin(), machine.end());
        py::gil_scoped_release release;
        return obstructed_cells(surface, robot, config, m);
      },
      py::arg("surface"), py::arg("robot"), py::arg("config"), py::arg("machine") = std::vector<bool>{},
        "Cells whose spraying pose (nozzle tip at planner.standoff_m square to the design line) brings a nozzle link "
        "rigid with the tip within clearance.nozzle_margin_m of a point of the scan outside the grid, and no lean "
        "up to clearance.max_nozzle_lean_rad clears it; the lean field of the cells a lean clears. `machine`: the "
        "scan's points that are the machine's own (scan_machine_points), not obstacles.");
  m.def("spraying_samples", &spraying_samples, py::arg("trajectory"),
        "The trajectory's spraying samples only (times, joints, poses; no derivatives): check_clearance of it "
        "gives the clearance while spraying.");
  m.def(
      "joint_moves",
      [](const TimedTrajectory& tr) {
        std::vector<std::tuple<std::size_t, std::size_t, int>> out;
        for (const auto& mv : joint_moves(tr)) out.emplace_back(mv.start, mv.end, mv.region_index);
        return out;
      },
      py::arg("trajectory"),
      "The rest-to-rest joint moves as (start, end, region_index): samples (start, end], region -1 between regions.");
  m.def(
      "arm_wall",
      [](const Surface& surface, const ExecutedDeposit& executed, const std::vector<bool>& machine) {
        return arm_wall(surface, executed, std::vector<char>(machine.begin(), machine.end()));
      },
      py::arg("surface"), py::arg("executed"), py::arg("machine") = std::vector<bool>{},
      "The wall the arm meets: the scan's points (less the machine's own, `machine`: scan_machine_points) "
      "and the executed deposit's surface (n x 3).");
  m.def(
      "scan_machine_points",
      [](const Surface& surface, const Config& config, const Robot& robot) {
        return to_bool_array(scan_machine_points(surface, config, robot));
      },
      py::arg("surface"), py::arg("config"), py::arg("robot"),
      "Per scan point (bool array), True for the machine's own where `robot` stands (the rig's carrier in the scan: "
      "the URDF's carrier box's column up to its top, along the axis, clearance.carrier_tolerance_m): not obstacles.");
  m.def("carrier_along_axis", &carrier_along_axis, py::arg("robot"), py::arg("surface"),
        "`robot` with its carrier turned to lie along the surface's axis.");
  m.def(
      "arm_clearance",
      [](const Surface& surface, const TimedTrajectory& trajectory, const ExecutedDeposit& executed, const Robot& robot,
         const ClearanceConfig& config, const ProgressFn& progress, const std::vector<bool>& machine) {
        const std::vector<char> m(machine.begin(), machine.end());
        py::gil_scoped_release release;
        return arm_clearance(surface, trajectory, executed, robot, config, progress, m);
      },
      py::arg("surface"), py::arg("trajectory"), py::arg("executed"), py::arg("robot"), py::arg("config"),
      py::arg("progress") = nullptr, py::arg("machine") = std::vector<bool>{},
      "check_clearance of the trajectory against the wall as scanned (less the machine's own points, `machine`) and "
      "as sprayed (ArmPlan.clearance).");
  m.def(
      "place_base",
      [](const Surface& surface, const Config& config, const Robot& robot) {
        py::gil_scoped_release release;
        return place_base(surface, config, robot);
      },
      py::arg("surface"), py::arg("config"), py::arg("robot"),
      "Where the job places the arm's base: with robot.place_base, clearance.enabled and a scan, the nearest place\n"
      "along the axis (robot.max_base_shift_m) where the arm has room to slew every way; else the configured one.");
  m.def("placed_robot", &placed_robot, py::arg("robot"), py::arg("placement"), "`robot` at placement.position_m.");
  m.def(
      "plan_for_arm",
      [](const Surface& surface, const Config& config, const Robot& robot, const ProgressFn& progress) {
        return plan_for_arm(surface, config, robot, progress);
      },
      py::arg("surface"), py::arg("config"), py::arg("robot"), py::arg("progress") = nullptr,
      "plan_bay with the speeds the arm can follow along every pass, time_plan, and up to\n"
      "timing.max_replans re-plans at lower speeds where the timed passes still break a joint limit.");
}
