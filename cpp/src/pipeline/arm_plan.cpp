// Bay planning for a given arm: caps, plan, time, learn, re-plan (see arm_plan.hpp).
#include "shotcrete/pipeline/arm_plan.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <chrono>
#include <mutex>
#include <stdexcept>
#include <string>
#include <memory>

#include "shotcrete/planning/passes.hpp"
#include "shotcrete/robot/robot.hpp"

namespace shotcrete {

double SpeedCapMap::at(const Eigen::Vector3d& p) const {
  double best = std::numeric_limits<double>::infinity();
  const double r2 = radius_m * radius_m;
  for (std::size_t i = 0; i < points_m.size(); ++i)
    if (speed_mps[i] < best && (points_m[i] - p).squaredNorm() <= r2) best = speed_mps[i];
  return best;
}

namespace {
// Pass sample next to the lead or link sample i (the pass end a run-out leaves, or the pass start a
// run-in reaches): along samples of i's kind backwards, else forwards; -1 when neither meets a pass.
long adjacent_pass_sample(const TimedTrajectory& tr, std::size_t i) {
  const char kind = tr.kind[i];
  const auto pass = static_cast<char>(SegmentKind::Pass);
  std::size_t j = i;
  while (j > 0 && tr.kind[j] == kind) --j;
  if (tr.kind[j] == pass) return static_cast<long>(j);
  j = i;
  while (j + 1 < tr.size() && tr.kind[j] == kind) ++j;
  return tr.kind[j] == pass ? static_cast<long>(j) : -1;
}
// Pass samples on either side of the turn-around sample i (across its arc and runs): the pass end
// the turn leaves and the pass start it reaches; -1 where a joint move or the trajectory's end
// comes first.
std::pair<long, long> passes_around_turn(const TimedTrajectory& tr, std::size_t i) {
  const auto off_pass = [&](std::size_t j) {
    const auto k = static_cast<SegmentKind>(tr.kind[j]);
    return k == SegmentKind::Turn || k == SegmentKind::Link;
  };
  const auto pass = static_cast<char>(SegmentKind::Pass);
  std::size_t a = i, b = i;
  while (a > 0 && off_pass(a)) --a;
  while (b + 1 < tr.size() && off_pass(b)) ++b;
  return {tr.kind[a] == pass ? static_cast<long>(a) : -1L, tr.kind[b] == pass ? static_cast<long>(b) : -1L};
}
// Worst joint velocity or acceleration ratio of each region's samples (joint moves between
// regions excluded: quintics within the limits by construction).
std::vector<double> region_worst_ratio(const TimedTrajectory& tr, std::size_t regions, const Robot& robot) {
  std::vector<double> worst(regions, 0.0);
  for (std::size_t i = 0; i < tr.size(); ++i) {
    if (tr.region_index[i] < 0 || static_cast<std::size_t>(tr.region_index[i]) >= regions) continue;
    const double r = std::max(tr.qd[i].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff(),
                              tr.qdd[i].cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff());
    double& w = worst[static_cast<std::size_t>(tr.region_index[i])];
    w = std::max(w, std::isfinite(r) ? r : std::numeric_limits<double>::infinity());
  }
  return worst;
}
// Exact geometry of a pass (every waypoint's position and axis): the key of the arm's cap cache.
std::vector<double> geometry_key(const std::vector<NozzlePose>& wp) {
  std::vector<double> key;
  key.reserve(wp.size() * 6);
  for (const auto& p : wp) key.insert(key.end(), {p.position_m.x(), p.position_m.y(), p.position_m.z(),
                                                   p.axis.x(), p.axis.y(), p.axis.z()});
  return key;
}
}  // namespace

int SpeedCapMap::learn(const TimedTrajectory& tr, const Eigen::VectorXd& vel_limit, const Eigen::VectorXd& acc_limit,
                       double limit_share) {
  int added = 0;
  // Speed at sample i by central differences; 0 at the ends.
  auto speed_at = [&](std::size_t i) {
    if (i == 0 || i + 1 >= tr.size() || !(tr.t_s[i + 1] > tr.t_s[i - 1])) return 0.0;
    return (tr.nozzle[i + 1].position_m - tr.nozzle[i - 1].position_m).norm() / (tr.t_s[i + 1] - tr.t_s[i - 1]);
  };
  auto add = [&](std::size_t i, double factor) {
    const double v = speed_at(i);
    if (!(v > 0.0) || !(factor < 1.0)) return;
    points_m.push_back(tr.nozzle[i].position_m);
    speed_mps.push_back(v * factor);
    ++added;
  };
  std::map<std::size_t, double> pass_end_factor;  // one bound per pass sample a run leaves / reaches
  // A region the arm does not track exactly runs on the IK's waypoint solutions, a staircase
  // whose finite differences are no joint speeds (the graded springline region of the default
  // bay read 4.3x its acceleration limits at a crawl): nothing to learn. Such a region stays as
  // it is and is reported (untracked_regions).
  const auto untracked = [&](std::size_t i) {
    return std::find(tr.untracked_region_ids.begin(), tr.untracked_region_ids.end(), tr.region_index[i]) !=
           tr.untracked_region_ids.end();
  };
  for (std::size_t i = 1; i + 1 < tr.size(); ++i) {
    if (untracked(i)) continue;
    const auto kind = static_cast<SegmentKind>(tr.kind[i]);
    const bool pass = kind == SegmentKind::Pass || tr.spraying[i];
    const double rv = tr.qd[i].cwiseAbs().cwiseQuotient(vel_limit).maxCoeff();
    if (!pass && kind == SegmentKind::Turn && rv > 1.0) {
      // A turn at about the passes' speeds (its arc under the centripetal cap) over a velocity
      // limit: the passes it joins must be slower (time_plan eases only accelerations).
      const auto [before, after] = passes_around_turn(tr, i);
      for (const long j : {before, after})
        if (j > 0 && speed_at(i) >= 0.9 * speed_at(static_cast<std::size_t>(j))) {
          auto [it, fresh] = pass_end_factor.emplace(static_cast<std::size_t>(j), limit_share / rv);
          if (!fresh) it->second = std::min(it->second, limit_share / rv);
        }
      continue;
    }
    if (!pass && kind != SegmentKind::Link && kind != SegmentKind::Lead) continue;
    Eigen::Index jw = 0;
    const double ra = tr.qdd[i].cwiseAbs().cwiseQuotient(acc_limit).maxCoeff(&jw);
    const double fv = rv > 1.0 ? limit_share / rv : 1.0;
    // A one-sample spike is a step in a joint velocity (the nozzle's axis starts turning where a
    // lead meets a curved pass): the step, and its finite-difference acceleration, scale with v,
    // not v^2, so the bound is linear in the excess (a square root took three re-plans down from
    // 1.20x to 1.07x on a horseshoe slice's pass start).
    const double qa = std::abs(tr.qdd[i][jw]);
    const bool spike = qa > 2.5 * std::max(std::abs(tr.qdd[i - 1][jw]), std::abs(tr.qdd[i + 1][jw]));
    const double fa = ra > 1.0 ? (spike ? limit_share / ra : std::sqrt(limit_share / ra)) : 1.0;
    if (pass) {
      // On a pass qdd = q'' v^2 + q' dv/dt: a lower speed bound shrinks the first part only, and
      // the speed change into a bounded stretch adds to the second. So the bound follows the
      // part that scales with v^2; an excess the speed change makes is not the speed's.
      double fc = fa;
      const double v = speed_at(i);
      if (ra > 1.0 && v > 1e-6 && i >= 2 && i + 2 < tr.size()) {
        const double a = (speed_at(i + 1) - speed_at(i - 1)) / (tr.t_s[i + 1] - tr.t_s[i - 1]);
        const Eigen::VectorXd curve = tr.qdd[i] - tr.qd[i] * (a / v);  // the part that scales with v^2
        const double rc = curve.cwiseAbs().cwiseQuotient(acc_limit).maxCoeff();
        fc = rc > 1.0 ? (spike ? limit_share / rc : std::sqrt(limit_share / rc)) : 1.0;
        // Under the limit without the speed change, over it with: a lower speed takes the
        // curve's part down until both fit, where the change's part alone leaves room (a pass of
        // the pytest slice read 1.006x on the slew joint, nothing learned, no re-plan).
        if (rc <= 1.0 && !spike) {
          const double change = std::abs(tr.qdd[i][jw] - curve[jw]) / acc_limit[jw];
          const double part = std::abs(curve[jw]) / acc_limit[jw];
          if (part > 1e-9 && change < limit_share) fc = std::min(1.0, std::sqrt((limit_share - change) / part));
        }
        // An acceleration whose sign flips from sample to sample is the joint path zig-zagging
        // (two telescopes at their limits, the tracking's limit avoidance against the task), not
        // a curve a lower speed would follow: bounding it took a graded pass of the default bay
        // down to 0.03 m/s over three re-plans and over-filled a pit by 150 mm. It stays, and the
        // limit check reports it.
        if (fc < 1.0) {
          Eigen::Index j = 0;
          tr.qdd[i].cwiseAbs().cwiseQuotient(acc_limit).maxCoeff(&j);
          if (tr.qdd[i - 1][j] * tr.qdd[i][j] < 0.0 && tr.qdd[i + 1][j] * tr.qdd[i][j] < 0.0) fc = 1.0;
        }
      }
      add(i, std::min(fv, fc));
      continue;
    }
    add(i, fv);  // leads and links cruise at the speeds of the passes next to them
    // A run off the pass over a limit: a speed change (a stop, a start, the change to a turn
    // speed) where time_plan cannot lengthen it (the reach ends), or a run at about the pass speed
    // where the arm is slower than on the pass (a lead-in at 0.99 m/s 0.3 m before its 1 m/s
    // pass: farther than the bounds' radius). The pass end it leaves or reaches must be slower; the
    // change scales with v^2 at a given run length, the velocity with v. A run slower than the
    // pass end (a turn at its own speed) is left to its own bound.
    if (ra > 1.0 || rv > 1.0) {
      const long j = adjacent_pass_sample(tr, i);
      if (j > 0) {
        const bool at_pass_speed = speed_at(i) >= 0.9 * speed_at(static_cast<std::size_t>(j));
        const double f = std::min(fa, at_pass_speed ? fv : 1.0);
        if (f < 1.0) {
          auto [it, fresh] = pass_end_factor.emplace(static_cast<std::size_t>(j), f);
          if (!fresh) it->second = std::min(it->second, f);
        }
      }
    }
  }
  for (const auto& [j, factor] : pass_end_factor) add(j, factor);
  return added;
}

namespace {
// timing.tune_with_pso: the swarm's per-region timing replaces the config's when the whole
// trajectory comes out shorter and no worse on the joint limits.
void apply_timing_swarm(ArmPlan& out, const std::vector<std::vector<Pass>>& regions, const Config& config,
                        const Robot& robot, const Eigen::VectorXd& q_start, const ProgressFn& progress,
                        const NullSpaceObjective& clearance_term) {
  if (progress) progress("timing swarm", 0.0);
  try {
    out.tuning = tune_timing(&robot, regions, q_start, config.timing, config.robot,
                             progress ? ProgressFn([&](const std::string&, double f) { progress("timing swarm", 0.8 * f); })
                                      : ProgressFn{},
                             clearance_term);  // the swarm's models track as time_plan does
    const TimedTrajectory& cur = *out.trajectory;
    auto no_worse = [](double tuned_ratio, double ratio) { return tuned_ratio <= std::max(ratio, 1.0) + 1e-9; };
    std::vector<TimingParams> params = out.tuning->params;
    TimedTrajectory tuned = time_plan(robot, regions, q_start, config.timing, config.robot, params, clearance_term);
    // The swarm judges the leads and turns on its model; elsewhere the arm reaches the passes in
    // slightly other postures than the re-plans saw. Regions that came out worse keep the
    // config's parameters, and that mix is timed once more.
    const auto before = region_worst_ratio(cur, regions.size(), robot);
    const auto after = region_worst_ratio(tuned, regions.size(), robot);
    bool mixed = false;
    std::vector<char> used = out.tuning->feasible;
    for (std::size_t r = 0; r < regions.size(); ++r)
      if (!no_worse(after[r], before[r])) params[r] = TimingParams::from_config(config.timing), used[r] = 0, mixed = true;
    if (mixed) {
      if (progress) progress("timing swarm", 0.9);
      tuned = time_plan(robot, regions, q_start, config.timing, config.robot, params, clearance_term);
    }
    if (tuned.duration_s < cur.duration_s && no_worse(tuned.max_velocity_ratio, cur.max_velocity_ratio) &&
        no_worse(tuned.max_acceleration_ratio, cur.max_acceleration_ratio)) {
      out.trajectory = std::move(tuned);
      out.tuning->params = params;
      out.tuning->feasible = used;  // regions timed with the swarm's parameters
      out.tuned_timing_used = true;
    }
  } catch (const std::exception& e) {
    // The config's timing stands; the reason is kept.
    out.tuning_error = e.what();
  }
  if (progress) progress("timing swarm", 1.0);
}

}  // namespace

namespace {

// The scan's points less the machine's own (machine_points; all of them when `machine` is empty).
Points scan_obstacles(const Points& scan, const std::vector<char>& machine) {
  if (machine.empty()) return scan;
  if (machine.size() != static_cast<std::size_t>(scan.rows()))
    throw std::invalid_argument("the machine's points: " + std::to_string(machine.size()) + " flags for " +
                                std::to_string(scan.rows()) + " scan points");
  const auto kept = static_cast<Eigen::Index>(std::count(machine.begin(), machine.end(), 0));
  Points out(kept, 3);
  Eigen::Index k = 0;
  for (Eigen::Index i = 0; i < scan.rows(); ++i)
    if (!machine[static_cast<std::size_t>(i)]) out.row(k++) = scan.row(i);
  return out;
}

}  // namespace

Robot carrier_along_axis(const Robot& robot, const Surface& surface) {
  const Eigen::Vector3d& ex = surface.axis.ex;
  const double horizontal = std::hypot(ex.x(), ex.y());
  // A (near) vertical axis has no heading: the carrier stays as the URDF puts it.
  if (!(horizontal > 1e-6)) return robot;
  return robot.carrier_turned(std::atan2(ex.y(), ex.x()));  // a heading, not a turn: idempotent
}

std::vector<char> scan_machine_points(const Surface& surface, const Config& config, const Robot& robot) {
  if (!config.clearance.enabled) return {};
  std::vector<char> out = machine_points(surface.cloud.xyz, carrier_along_axis(robot, surface), config.clearance.carrier_tolerance_m);
  // The bay's gridded wall is never the machine's (a base standing in a narrow drift).
  for (std::size_t i = 0; i < out.size() && i < surface.in_grid.size(); ++i)
    if (surface.in_grid[i]) out[i] = 0;
  return out;
}

Points arm_wall(const Surface& surface, const ExecutedDeposit& executed, const std::vector<char>& machine) {
  // The wall as scanned (less the machine's own points) and as sprayed: concrete only grows toward
  // the arm, so the union holds every surface the arm meets during the job.
  // The sprayed wall is the scan's cloud with the wall's points moved (the same rows): the
  // machine's own are left out of both.
  const Points scan = scan_obstacles(surface.cloud.xyz, machine);
  const Points sprayed = scan_obstacles(executed.wall.surface.cloud.xyz, machine);
  Points wall(scan.rows() + sprayed.rows(), 3);
  wall << scan, sprayed;
  return wall;
}

ClearanceReport arm_clearance(const Surface& surface, const TimedTrajectory& trajectory, const ExecutedDeposit& executed,
                              const Robot& robot, const ClearanceConfig& config, const ProgressFn& progress,
                              const std::vector<char>& machine) {
  const Points wall = arm_wall(surface, executed, machine);
  const WallOctree octree(wall, config.octree_resolution_m);
  ClearanceReport rep = check_clearance(robot, trajectory, octree, config, progress);
  rep.wall_points = static_cast<std::size_t>(wall.rows());
  rep.carrier_points = static_cast<int>(std::count(machine.begin(), machine.end(), 1));
  return rep;
}

TransitReport arm_transits(const Surface& surface, TimedTrajectory& trajectory, const ExecutedDeposit& executed,
                           const Robot& robot, const ClearanceConfig& config, const TimingConfig& timing,
                           const std::vector<char>& machine) {
  const WallOctree octree(arm_wall(surface, executed, machine), config.octree_resolution_m);
  return clear_transits(robot, trajectory, octree, config, timing);
}

ObstructedCells obstructed_cells(const Surface& surface, const Robot& robot, const Config& config,
                                 const std::vector<char>& machine) {
  if (!machine.empty() && machine.size() != static_cast<std::size_t>(surface.cloud.size()))
    throw std::invalid_argument("obstructed_cells: " + std::to_string(machine.size()) + " machine flags for " +
                                std::to_string(surface.cloud.size()) + " scan points");
  ObstructedCells out;
  out.margin_m = config.clearance.nozzle_margin_m;
  out.least_distance_m = std::numeric_limits<double>::infinity();
  const Grid& grid = surface.grid;
  // Obstacles: every point the grid left out (not wall, in front of the wall, outside the bay).
  std::vector<Eigen::Index> rows;
  for (Eigen::Index i = 0; i < surface.cloud.size(); ++i)
    if ((static_cast<std::size_t>(i) >= surface.in_grid.size() || !surface.in_grid[static_cast<std::size_t>(i)]) &&
        (machine.empty() || !machine[static_cast<std::size_t>(i)]))
      rows.push_back(i);
  out.obstacle_points = static_cast<int>(rows.size());
  if (rows.empty() || grid.size() == 0) return out;
  Points obstacles(static_cast<Eigen::Index>(rows.size()), 3);
  for (std::size_t k = 0; k < rows.size(); ++k) obstacles.row(static_cast<Eigen::Index>(k)) = surface.cloud.xyz.row(rows[k]);
  // The nozzle links rigid with the tip (their pose relative to it the same in two postures):
  // their place at a spraying pose follows from the tip's alone. Links named nozzle*, as the
  // clearance check's nozzle margin.
  // (The stow and the neutral postures may share the wrist's angles: the second posture turns
  // every joint 0.1 off the neutral one.)
  const Eigen::VectorXd q0 = robot.neutral(), q1 = (q0.array() + 0.1).matrix();
  const auto f0 = robot.link_frames(q0), f1 = robot.link_frames(q1);
  const Eigen::Isometry3d t0 = robot.fk(q0), t1 = robot.fk(q1);
  std::vector<std::pair<CollisionShape, Eigen::Isometry3d>> rigid;  // shape, its link's pose in the tip frame
  for (const auto& sh : robot.collision_shapes()) {
    if (!nozzle_shape(sh)) continue;
    const Eigen::Isometry3d r0 = t0.inverse() * f0[static_cast<std::size_t>(sh.frame)];
    const Eigen::Isometry3d r1 = t1.inverse() * f1[static_cast<std::size_t>(sh.frame)];
    if (!r0.matrix().isApprox(r1.matrix(), 1e-9)) continue;
    rigid.emplace_back(sh, r0);
    out.links.push_back(sh.link);
  }
  if (rigid.empty()) return out;
  const WallOctree wall(obstacles, config.clearance.octree_resolution_m);
  const auto& axis = surface.axis;
  const auto& prof = surface.profile;
  const double standoff = config.planner.standoff_m;
  // The nozzle links' least distance to the obstacles with the spray axis `a` on wall point p
  // (the tip at the standoff back along it; x, y any: the roll about the spray is free, and the
  // bundled nozzle link is round about it).
  auto clearance_at = [&](const Eigen::Vector3d& p, const Eigen::Vector3d& a, Eigen::Vector3d* nearest) {
    Eigen::Isometry3d tip = Eigen::Isometry3d::Identity();
    const Eigen::Vector3d x = (std::abs(a.dot(axis.ex)) < 0.9 ? axis.ex : axis.ey).cross(a).normalized();
    tip.linear().col(0) = x;
    tip.linear().col(1) = a.cross(x);
    tip.linear().col(2) = a;
    tip.translation() = p - standoff * a;
    double least = std::numeric_limits<double>::infinity();
    for (const auto& [sh, rel] : rigid) {
      Eigen::Vector3d q;
      const double dist = wall.exact_distance(sh, tip * rel, &q, out.margin_m + 1.0);
      if (dist < least) {
        least = dist;
        if (nearest) *nearest = q;
      }
    }
    return least;
  };
  // Each cell's wall point and square spraying axis (the design line's normal; radial on a circle).
  const int n = grid.size();
  std::vector<Eigen::Vector3d> point(static_cast<std::size_t>(n)), square(static_cast<std::size_t>(n));
  std::vector<char> live(static_cast<std::size_t>(n), 0);
  for (int c = 0; c < n; ++c) {
    if (!grid.valid[static_cast<std::size_t>(c)] || !std::isfinite(grid.td_m[c])) continue;
    const double th = grid.theta_center(grid.row_of(c)), d = grid.d_center(grid.col_of(c));
    Eigen::Vector3d nrm = axis.radial(th);
    if (!prof.is_circle()) {
      const Eigen::Vector3d dn = design_normal(axis, prof, th);
      if (dn.allFinite()) nrm = dn;
    }
    point[static_cast<std::size_t>(c)] = axis.to_cartesian(prof.radius_at(th) + prof.radial_offset_m(grid.td_m[c], th), th, d);
    square[static_cast<std::size_t>(c)] = nrm;
    live[static_cast<std::size_t>(c)] = 1;
  }
  // The spray axis leaned by `lean` (tangent; length = angle) off the square one, as the passes lean it.
  auto leaned = [&](int c, const Eigen::Vector3d& lean) { return leaned_axis(square[static_cast<std::size_t>(c)], lean); };
  // 1. Where the square pose is too close, the least lean (steps of 0.05 rad, along the axis or
  //    around it, either way) that clears the obstacles, with half a cell and 1 cm to spare (a
  //    one-cell pass runs half a cell either side; the spline between knots); at the bay's end
  //    columns of axial passes with the run-on at a leaning end (planner.leaned_edge_overrun_m),
  //    the lean held, and 1 cm to spare.
  const double max_lean = config.clearance.max_nozzle_lean_rad, step = 0.05, spare_inner = 0.5 * grid.cell_size_m + 0.01;
  const PlannerConfig& pc = config.planner;
  const bool axial_runon = pc.pass_direction == PassDirection::axial;
  const double leaned_runon = leaned_edge_overrun_m(pc, longest_edge_overrun_m(pc));
  const double spare_end = leaned_runon > 0.0 ? std::max(spare_inner, leaned_runon + 0.01) : spare_inner;
  auto spare_of = [&](int c) {
    const int col = grid.col_of(c);
    return axial_runon && (col == 0 || col == grid.n_d - 1) ? spare_end : spare_inner;
  };
  std::vector<Eigen::Vector3d> need(static_cast<std::size_t>(n), Eigen::Vector3d::Zero());
  std::vector<int> square_blocked;
  for (int c = 0; c < n; ++c) {
    if (!live[static_cast<std::size_t>(c)]) continue;
    const Eigen::Vector3d& p = point[static_cast<std::size_t>(c)];
    if (clearance_at(p, square[static_cast<std::size_t>(c)], nullptr) >= out.margin_m) continue;
    square_blocked.push_back(c);
    const Eigen::Vector3d& a0 = square[static_cast<std::size_t>(c)];
    const Eigen::Vector3d along = (axis.ex - axis.ex.dot(a0) * a0).normalized(), around = a0.cross(along);
    const Eigen::Vector3d dirs[4] = {along, -along, around, -around};
    bool found = false;
    // Steps of 0.05 rad, and the limit itself last (a limit between two steps is not rounded down).
    std::vector<double> angles;
    for (int i = 1; i * step < max_lean - 1e-9; ++i) angles.push_back(i * step);
    if (max_lean > 0.0) angles.push_back(max_lean);
    for (const double angle : angles) {
      if (found) break;
      for (const auto& t : dirs)
        if (clearance_at(p, leaned(c, angle * t), nullptr) >= out.margin_m + spare_of(c)) {
          need[static_cast<std::size_t>(c)] = angle * t;
          found = true;
          break;
        }
    }
  }
  // 2. The lean field: each needed lean fades out over the wall around its cell at
  //    clearance.nozzle_lean_fade_rad_per_m (so along a pass the nozzle moves forward at
  //    1 - rate * standoff of its spot's speed or more, never back); a cell takes the strongest
  //    of those reaching it.
  // (Across a circumferential pass the spray axis turns by 1 / R per metre of wall as well.)
  const double fade_rad_per_m = config.clearance.nozzle_lean_fade_rad_per_m;
  const double fade_limit = 1.0 / standoff - (config.planner.pass_direction == PassDirection::circumferential ? 1.0 / prof.radius_m : 0.0);
  if (max_lean > 0.0 && !(fade_rad_per_m < fade_limit))
    throw std::invalid_argument("obstructed_cells: clearance.nozzle_lean_fade_rad_per_m = " + std::to_string(fade_rad_per_m) +
                                " must be below " + std::to_string(fade_limit) +
                                " (1 / planner.standoff_m, less 1 / design radius for circumferential passes): a faster "
                                "fade would run the nozzle back along its pass");
  std::vector<Eigen::Vector3d> lean(static_cast<std::size_t>(n), Eigen::Vector3d::Zero());
  const double arc = grid.cell_size_m;  // a row's arc (theta step = cell size / design radius)
  for (int c : square_blocked) {
    const Eigen::Vector3d& v = need[static_cast<std::size_t>(c)];
    const double angle = v.norm();
    if (angle <= 0) continue;
    const int reach = static_cast<int>(std::ceil(angle / fade_rad_per_m / grid.cell_size_m));
    const int r0 = grid.row_of(c), c0 = grid.col_of(c);
    for (int r = std::max(0, r0 - reach); r <= std::min(grid.n_theta - 1, r0 + reach); ++r)
      for (int k = std::max(0, c0 - reach); k <= std::min(grid.n_d - 1, c0 + reach); ++k) {
        const double dist = std::hypot((r - r0) * arc, (k - c0) * grid.cell_size_m);
        const double a = angle - fade_rad_per_m * dist;
        Eigen::Vector3d& l = lean[static_cast<std::size_t>(grid.index(r, k))];
        if (a > l.norm()) l = (a / angle) * v;
      }
  }
  // 3. Obstructed: the cells whose pose in that field (square, or leaned) still comes too close.
  int leaned_cells = 0;
  for (int c = 0; c < n; ++c) {
    if (!live[static_cast<std::size_t>(c)]) continue;
    const Eigen::Vector3d& l = lean[static_cast<std::size_t>(c)];
    const bool tipped = l.norm() > 1e-9;
    if (!tipped && !std::binary_search(square_blocked.begin(), square_blocked.end(), c)) continue;
    Eigen::Vector3d nearest = Eigen::Vector3d::Zero();
    double least = clearance_at(point[static_cast<std::size_t>(c)], leaned(c, l), &nearest);
    // The field's lean may be another obstacle's, faded, and tip this cell toward something: its
    // own (the least that clears it, or square) before it counts as obstructed.
    const Eigen::Vector3d own = need[static_cast<std::size_t>(c)];
    if (least < out.margin_m && tipped && (own - l).norm() > 1e-9) {
      Eigen::Vector3d q = Eigen::Vector3d::Zero();
      const double alt = clearance_at(point[static_cast<std::size_t>(c)], leaned(c, own), &q);
      if (alt >= out.margin_m) {
        lean[static_cast<std::size_t>(c)] = own;
        least = alt, nearest = q;
      }
    }
    const Eigen::Vector3d& used = lean[static_cast<std::size_t>(c)];
    if (least < out.margin_m) {
      out.cells.push_back(c);
      if (least < out.least_distance_m) out.least_distance_m = least, out.nearest_obstacle_m = nearest;
    } else if (used.norm() > 1e-9) {
      ++leaned_cells;
      out.max_lean_rad = std::max(out.max_lean_rad, used.norm());
    }
  }
  out.leaned_cells = leaned_cells;
  if (leaned_cells > 0) out.lean = std::move(lean);
  if (out.cells.empty()) out.least_distance_m = 0.0;
  return out;
}

BasePlacement place_base(const Surface& surface, const Config& config, const Robot& robot, const WallOctree* scan_wall) {
  if (!config.robot.place_base || !config.clearance.enabled || surface.cloud.xyz.rows() == 0) {
    BasePlacement out;
    out.configured_m = out.position_m = robot.base_pose().translation();
    out.found = true;
    return out;
  }
  const auto t0 = std::chrono::steady_clock::now();
  std::unique_ptr<WallOctree> own;
  if (!scan_wall) {
    const Points obstacles = scan_obstacles(surface.cloud.xyz, scan_machine_points(surface, config, robot));
    if (obstacles.rows() == 0) {  // the scan is all machine: nothing tells where the base can stand
      BasePlacement out;
      out.configured_m = out.position_m = robot.base_pose().translation();
      out.found = true;
      return out;
    }
    own = std::make_unique<WallOctree>(obstacles, config.clearance.octree_resolution_m);
  }
  BasePlacement out = place_base(carrier_along_axis(robot, surface), scan_wall ? *scan_wall : *own, surface.axis.ex,
                                 config.clearance, config.robot.max_base_shift_m);
  out.checked = true;
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();  // with the octree
  return out;
}

Robot placed_robot(const Robot& robot, const BasePlacement& placement) {
  return placement.moved ? robot.placed_at(placement.position_m) : robot;
}

ArmPlan plan_for_arm(const Surface& surface, const Config& config, const Robot& given_robot, const ProgressFn& progress) {
  ArmPlan out;
  // The scan as an obstacle (the base's place, the start posture, the tracking's clearance term).
  // The scan holds the rig's carrier where it stood (the given robot's base): those points are the
  // machine's own (its carrier shape stands for them and moves with the base), not obstacles.
  // The carrier lies along the tunnel's axis, behind the arm (carrier_along_axis).
  const Robot machine_robot = carrier_along_axis(given_robot, surface);
  const std::vector<char> machine = scan_machine_points(surface, config, given_robot);
  const int machine_count = static_cast<int>(std::count(machine.begin(), machine.end(), 1));
  std::unique_ptr<WallOctree> scan_wall;
  if (config.clearance.enabled && surface.cloud.xyz.rows() > machine_count)
    scan_wall = std::make_unique<WallOctree>(scan_obstacles(surface.cloud.xyz, machine), config.clearance.octree_resolution_m);
  if (progress) progress("base placement", 0.0);
  out.base_placement = place_base(surface, config, given_robot, scan_wall.get());  // turns it too
  if (progress) progress("base placement", 1.0);
  const Robot robot = placed_robot(machine_robot, out.base_placement);
  if (config.clearance.enabled) out.obstructed = obstructed_cells(surface, robot, config, machine);
  // The arm's caps depend on a pass's geometry only: the lines of a round repeat across re-plans,
  // so they are computed once per distinct pass, keyed by every waypoint's position and axis.
  // The planner asks for the passes of a region at once, from several threads (WaypointCaps):
  // the cache is read and filled under a lock, the caps computed outside it.
  auto cache = std::make_shared<std::map<std::vector<double>, std::vector<double>>>();
  auto cache_mutex = std::make_shared<std::mutex>();
  const SpeedCapFn arm = arm_speed_caps(robot, config);
  const SpeedCapFn cap = [&, cache, cache_mutex](const std::vector<NozzlePose>& wp) {
    if (wp.empty()) return std::vector<double>{};
    std::vector<double> key = geometry_key(wp);
    std::vector<double> c;
    {
      const std::lock_guard<std::mutex> lock(*cache_mutex);
      const auto it = cache->find(key);
      if (it != cache->end()) c = it->second;
    }
    if (c.empty()) {
      c = arm(wp);
      const std::lock_guard<std::mutex> lock(*cache_mutex);
      cache->emplace(std::move(key), c);
    }
    if (!out.learned.points_m.empty())
      for (std::size_t k = 0; k < wp.size(); ++k) c[k] = std::min(c[k], out.learned.at(wp[k].position_m));
    return c;
  };
  const double share = 1.0 - config.timing.joint_limit_margin;
  // The tracking's clearance term steers the spare degrees of freedom by the wall as scanned: a
  // guide, not a bound (the sprayed layers bring the wall up to 0.41 m nearer on the default bay by
  // the job's end, mean 0.20 m; the check below measures against the wall as sprayed).
  NullSpaceObjective clearance_term;
  if (scan_wall) {
    if (config.clearance.null_space_gain > 0.0) clearance_term = clearance_objective(robot, *scan_wall, config.clearance);
    // The job starts from the stow posture unless that one is in something the scan holds (the
    // boom pointing into the face): then from the nearest posture with room.
    out.start = start_posture(robot, robot.stow(), *scan_wall, config.clearance);
  }
  out.clearance_term_used = clearance_term.active();
  const Eigen::VectorXd q_start = out.start ? out.start->q : robot.stow();
  std::vector<std::vector<Pass>> regions;
  for (int attempt = 0;; ++attempt) {
    const std::string prefix = attempt == 0 ? "" : "re-plan " + std::to_string(attempt) + ": ";
    out.plan = plan_bay(surface, config, progress ? ProgressFn([&](const std::string& s, double f) { progress(prefix + s, f); }) : ProgressFn{}, cap,
                        out.obstructed ? out.obstructed->cells : std::vector<int>{},
                        out.obstructed ? out.obstructed->lean : std::vector<Eigen::Vector3d>{});
    out.replans = attempt;
    if (progress) progress(prefix + "trajectory", 0.0);
    regions.clear();
    for (const auto& round : out.plan.rounds)
      for (const auto& region : round.regions) regions.push_back(region.passes);  // in spraying order
    out.trajectory.reset();
    out.timing_error.clear();
    if (regions.empty()) break;
    try {
      out.trajectory = time_plan(robot, regions, q_start, config.timing, config.robot, {}, clearance_term);
    } catch (const std::exception& e) {
      out.timing_error = e.what();
      break;
    }
    if (progress) progress(prefix + "trajectory", 1.0);
    if (attempt >= config.timing.max_replans) break;
    if (out.learned.learn(*out.trajectory, robot.velocity_limits(), robot.acceleration_limits(), share) == 0) break;
  }
  if (!out.trajectory) return out;
  out.config_duration_s = out.trajectory->duration_s;
  if (config.timing.tune_with_pso) apply_timing_swarm(out, regions, config, robot, q_start, progress, clearance_term);
  // What the re-plans' bounds and the regions' easing left over a joint limit is slowed down to it
  // (the same joint path, later times): the arm can run what is reported, and the deposit below
  // is what the slower motion lays.
  slow_to_joint_limits(robot, *out.trajectory);
  if (progress) progress("executed deposit", 0.0);
  out.executed = execute_deposit(surface, out.plan, *out.trajectory, config);
  if (progress) progress("executed deposit", 1.0);
  if (config.clearance.enabled) {
    if (progress) progress("transits", 0.0);
    Points wall = arm_wall(surface, *out.executed, machine);
    auto octree = std::make_unique<WallOctree>(wall, config.clearance.octree_resolution_m);
    out.transits = clear_transits(robot, *out.trajectory, *octree, config.clearance, config.timing);
    if (progress) progress("transits", 1.0);
    // A re-route (or an eased move) spreads the samples after it in time: the pump's flow
    // (off-gaps it bridges) is laid again on the trajectory kept, and the wall it leaves is the
    // one checked.
    const bool replaced = out.transits->rerouted > 0 || std::any_of(out.transits->detours.begin(), out.transits->detours.end(),
                                                                     [](const TransitDetour& d) { return d.eased; });
    if (replaced) {
      slow_to_joint_limits(robot, *out.trajectory);  // a new move's joins with its neighbours
      out.executed = execute_deposit(surface, out.plan, *out.trajectory, config);
      wall = arm_wall(surface, *out.executed, machine);
      octree = std::make_unique<WallOctree>(wall, config.clearance.octree_resolution_m);
    }
    out.clearance = check_clearance(robot, *out.trajectory, *octree, config.clearance, progress);
    out.clearance->wall_points = static_cast<std::size_t>(wall.rows());
    out.clearance->carrier_points = machine_count;
  }
  return out;
}

}  // namespace shotcrete
