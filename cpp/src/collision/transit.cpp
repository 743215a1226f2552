// Transits by the seed method: check every joint move, re-route those closer than the margins
// through postures of maximum space allowance (see transit.hpp).
#include "shotcrete/collision/transit.hpp"

#include <nlopt.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>

#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/trajectory.hpp"

namespace shotcrete {

double posture_allowance(const Robot& robot, const Eigen::VectorXd& q, const WallOctree& wall,
                         const ClearanceConfig& config, const std::vector<std::pair<int, int>>& pairs, double cap_m,
                         const std::vector<char>* fixed) {
  const auto& shapes = robot.collision_shapes();
  if (fixed && fixed->size() != shapes.size())
    throw std::invalid_argument("posture_allowance: `fixed` has " + std::to_string(fixed->size()) + " entries for " +
                                std::to_string(shapes.size()) + " shapes");
  const auto frames = robot.link_frames(q);
  double least = cap_m;
  for (std::size_t k = 0; k < shapes.size(); ++k) {
    if (fixed && (*fixed)[k]) continue;
    const CollisionShape& s = shapes[k];
    const double margin = shape_margin_m(s, config);
    // Bounded by the least allowance so far: a shape farther than that cannot lower it.
    least = std::min(least, wall.distance(s, frames[s.frame], nullptr, std::max(0.0, margin + least)) - margin);
  }
  for (const auto& [a, b] : pairs)
    least = std::min(least, shape_distance(shapes[a], frames[shapes[a].frame], shapes[b], frames[shapes[b].frame]) -
                                config.self_margin_m);
  return least;
}

namespace {

// Least distance less margin over a clearance report (links and the self check).
double report_allowance(const ClearanceReport& rep, const ClearanceConfig& config) {
  double least = std::numeric_limits<double>::infinity();
  for (const auto& l : rep.links)
    if (!l.fixed) least = std::min(least, l.min_m - l.margin_m);
  if (std::isfinite(rep.self.min_m)) least = std::min(least, rep.self.min_m - config.self_margin_m);
  return least;
}

// Every link at least `slack_m` beyond its wall margin and the self check within its margin.
bool keeps_margins_by(const ClearanceReport& rep, const ClearanceConfig& config, double slack_m) {
  for (const auto& l : rep.links)
    if (!l.fixed && !(l.min_m - l.margin_m >= slack_m)) return false;
  return !(rep.self.min_m < config.self_margin_m);
}

std::string worst_of(const ClearanceReport& rep, const ClearanceConfig& config) {
  std::ostringstream o;
  o.precision(3);
  double least = std::numeric_limits<double>::infinity();
  for (const auto& l : rep.links)
    if (!l.fixed && l.min_m - l.margin_m < least) {
      least = l.min_m - l.margin_m;
      o.str("");
      o << l.link << " " << l.min_m << " m (margin " << l.margin_m << ")";
    }
  if (std::isfinite(rep.self.min_m) && rep.self.min_m - config.self_margin_m < least) {
    o.str("");
    o << rep.self.link_a << "-" << rep.self.link_b << " " << rep.self.min_m << " m (margin " << config.self_margin_m << ")";
  }
  return o.str();
}

// A posture of maximum space allowance from `start`: BOBYQA within the joint limits on the
// allowance saturated at cap_m, less a small pull toward `ref` (of two postures with enough room,
// the one nearer `ref`).
// 5 cm of allowance per unit of normalised joint distance: a tie-breaker past the cap, small
// against the allowance below it.
constexpr double kPull_m = 0.05;

// With held_joint >= 0 that joint stays at start's value (swing_room: a slew direction held, and
// no pull: the most room there is, wherever it lies).
Eigen::VectorXd most_room_posture(const Robot& robot, const Eigen::VectorXd& start, const Eigen::VectorXd& ref,
                                  const WallOctree& wall, const ClearanceConfig& config,
                                  const std::vector<std::pair<int, int>>& pairs, double cap_m,
                                  const std::vector<char>& fixed, int held_joint = -1, double pull_m = kPull_m) {
  const Eigen::VectorXd lo_all = robot.lower_limits(), hi_all = robot.upper_limits();
  const Eigen::VectorXd x0_all = start.cwiseMax(lo_all).cwiseMin(hi_all);
  // The free joints (all but the held one) and the posture they make.
  std::vector<int> free_joints;
  for (int j = 0; j < robot.dof(); ++j)
    if (j != held_joint) free_joints.push_back(j);
  const int n = static_cast<int>(free_joints.size());
  const auto posture = [&](const double* x) {
    Eigen::VectorXd q = x0_all;
    for (int i = 0; i < n; ++i) q[free_joints[static_cast<std::size_t>(i)]] = x[i];
    return q;
  };
  Eigen::VectorXd lo(n), hi(n);
  for (int i = 0; i < n; ++i) lo[i] = lo_all[free_joints[static_cast<std::size_t>(i)]], hi[i] = hi_all[free_joints[static_cast<std::size_t>(i)]];
  const Eigen::VectorXd range_all = (hi_all - lo_all).cwiseMax(1e-9);
  const Eigen::VectorXd range = (hi - lo).cwiseMax(1e-9);
  std::function<double(const std::vector<double>&)> objective = [&](const std::vector<double>& x) {
    const Eigen::VectorXd q = posture(x.data());
    const double a = posture_allowance(robot, q, wall, config, pairs, cap_m, &fixed);
    return -(a - pull_m * (q - ref).cwiseQuotient(range_all).norm());
  };
  nlopt::opt opt(nlopt::LN_BOBYQA, static_cast<unsigned>(n));
  opt.set_lower_bounds(std::vector<double>(lo.data(), lo.data() + n));
  opt.set_upper_bounds(std::vector<double>(hi.data(), hi.data() + n));
  opt.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>&, void* data) {
        return (*static_cast<std::function<double(const std::vector<double>&)>*>(data))(x);
      },
      &objective);
  // A tenth of each joint's range, within half the bound gap as BOBYQA needs.
  std::vector<double> step(static_cast<std::size_t>(n));
  for (int j = 0; j < n; ++j) step[static_cast<std::size_t>(j)] = 0.1 * range[j];
  opt.set_initial_step(step);
  // A posture needs room, not precision: millimetres and a few hundred evaluations.
  opt.set_xtol_abs(2e-3);
  opt.set_ftol_abs(1e-3);
  opt.set_maxeval(40 * n);
  std::vector<double> x(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) x[static_cast<std::size_t>(i)] = x0_all[free_joints[static_cast<std::size_t>(i)]];
  double best = 0.0;
  try {
    opt.optimize(x, best);
  } catch (const nlopt::roundoff_limited&) {
    // x holds BOBYQA's best point.
  }
  return posture(x.data()).cwiseMax(lo_all).cwiseMin(hi_all);
}

// q with the telescopes (prismatic joints) all the way in.
Eigen::VectorXd folded(const Robot& robot, const Eigen::VectorXd& q) {
  Eigen::VectorXd f = q;
  for (int j = 0; j < robot.dof(); ++j)
    if (robot.joint_is_prismatic()[static_cast<std::size_t>(j)]) f[j] = robot.lower_limits()[j];
  return f;
}

// How far a point of the arm can move per unit of each joint at most [m per rad or m]: for a
// turning joint, the chain's length from its axis point to the farthest shape it moves (the
// distances between successive link frames, the telescopes in or out, whichever is longer, and the
// shape's reach from its frame: a bound by the triangle inequality, whatever the posture); 1 for
// a sliding one. Bounds the step between two postures the sampled planner checks, and weighs its
// joint distances.
std::vector<double> joint_levers(const Robot& robot) {
  Eigen::VectorXd in = robot.neutral(), out = robot.neutral();
  for (int j = 0; j < robot.dof(); ++j)
    if (robot.joint_is_prismatic()[static_cast<std::size_t>(j)]) in[j] = robot.lower_limits()[j], out[j] = robot.upper_limits()[j];
  std::vector<JointAxis> axes_in, axes_out;
  const auto f_in = robot.link_frames(in, axes_in), f_out = robot.link_frames(out, axes_out);
  const auto gap = [&](std::size_t f, const Eigen::Vector3d& from_in, const Eigen::Vector3d& from_out) {
    return std::max((f_in[f].translation() - from_in).norm(), (f_out[f].translation() - from_out).norm());
  };
  std::vector<double> lever(static_cast<std::size_t>(robot.dof()), 1.0);
  for (std::size_t j = 0; j < lever.size(); ++j) {
    if (!axes_out[j].rotational) continue;
    // chain[f]: from the axis point to frame f's origin along the chain, at most.
    const auto first = static_cast<std::size_t>(axes_out[j].first_frame);
    std::vector<double> chain(f_out.size(), 0.0);
    if (first < f_out.size()) chain[first] = gap(first, axes_in[j].point_m, axes_out[j].point_m);
    for (std::size_t f = first + 1; f < f_out.size(); ++f)
      chain[f] = chain[f - 1] + gap(f, f_in[f - 1].translation(), f_out[f - 1].translation());
    double reach = 0.1;
    for (const CollisionShape& s : robot.collision_shapes()) {
      if (s.frame < axes_out[j].first_frame) continue;
      const double r = s.kind == CollisionShape::Kind::box      ? 0.5 * s.size_m.norm()
                       : s.kind == CollisionShape::Kind::sphere ? s.radius_m
                                                                : std::hypot(s.radius_m, 0.5 * s.length_m);
      reach = std::max(reach, chain[static_cast<std::size_t>(s.frame)] + s.origin.translation().norm() + r);
    }
    lever[j] = reach;
  }
  return lever;
}

// The sampled planner's steps: the most a point of the arm moves between two checked postures
// [m] (each posture keeps half of it beyond the margins, so the arm between them keeps the
// margins); the longest extension of a tree [m].
constexpr double kSampledCheckStep_m = 0.1;
constexpr double kSampledExtend_m = 1.5;
// Near an end with less room than the sampled planner asks (sampled_route): how far the arm may
// move from it keeping only the end's room [m], and how fast the room asked grows beyond [m of
// room per m of motion].
constexpr double kSampledNear_m = 0.5;
constexpr double kSampledRamp = 0.5;
// Rounds of shortening the sampled path (sampled_route): three in four a random shortcut, every
// fourth a dropped posture.
constexpr int kSampledShortcuts = 100;

struct Router {
  const Robot& robot;
  const WallOctree& wall;
  const ClearanceConfig& config;
  const TimingConfig& timing;
  int region_index;
  std::vector<std::pair<int, int>> pairs;
  std::vector<char> fixed;  // fixed_shapes: left out of every judgement of a posture or a move
  int optimisations = 0;
  int sampled_nodes = 0;  // postures the sampled planner added to its trees
  // Of the one-via and fold-swing-unfold routes tried that break a margin, the one with the fewest
  // link-samples below a margin (then the one least short of them: report_allowance) and its
  // postures after qa: what may replace a move no clear route was found for (clear_transits).
  int best_effort_below = std::numeric_limits<int>::max();
  double best_effort_allowance_m = -std::numeric_limits<double>::infinity();
  std::vector<Eigen::VectorXd> best_effort{};
  // Whether `piece` (postures `route` after qa) keeps every margin; a route of the whole move (the
  // outermost route call, depth top_depth; not a leg of it) that does not is remembered when it
  // breaks them less than any before.
  int top_depth = 2;
  bool clear_or_note(const TimedTrajectory& piece, const std::vector<Eigen::VectorXd>& route, bool whole_move) {
    if (piece.size() == 0) return true;
    const ClearanceReport rep = check_clearance_octree(robot, piece, wall, config);
    const int below = rep.moving_samples_below_margin();
    if (below == 0) return true;
    const double allowance = report_allowance(rep, config);
    if (whole_move && (below < best_effort_below || (below == best_effort_below && allowance > best_effort_allowance_m)))
      best_effort_below = below, best_effort_allowance_m = allowance, best_effort = route;
    return false;
  }

  // Posture of the move's sample where a link comes closest to breaking its margin.
  static Eigen::VectorXd worst_posture(const TimedTrajectory& piece, const ClearanceReport& rep, const ClearanceConfig& cfg) {
    double least = std::numeric_limits<double>::infinity(), at = 0.0;
    for (const auto& l : rep.links)
      if (!l.fixed && l.min_m - l.margin_m < least) least = l.min_m - l.margin_m, at = l.at_time_s;
    if (std::isfinite(rep.self.min_m) && rep.self.min_m - cfg.self_margin_m < least) at = rep.self.at_time_s;
    const auto k = std::lower_bound(piece.t_s.begin(), piece.t_s.end(), at) - piece.t_s.begin();
    return piece.q[static_cast<std::size_t>(std::min<std::ptrdiff_t>(k, static_cast<std::ptrdiff_t>(piece.size()) - 1))];
  }

  // posture_allowance without the fixed shapes.
  double allowance(const Eigen::VectorXd& q, double cap_m) const {
    return posture_allowance(robot, q, wall, config, pairs, cap_m, &fixed);
  }
  // A posture of maximum space allowance from `start` (most_room_posture), counted.
  Eigen::VectorXd via_from(const Eigen::VectorXd& start, const Eigen::VectorXd& ref, double cap_m) {
    ++optimisations;
    return most_room_posture(robot, start, ref, wall, config, pairs, cap_m, fixed);
  }

  Eigen::VectorXd folded(const Eigen::VectorXd& q) const { return shotcrete::folded(robot, q); }
  // Starts of the via search and the posture each pulls toward: the straight move's worst sample
  // pushed out of the wall (a local deflection), its midpoint, the midpoint with the telescopes in,
  // a quarter and three quarters along it, the stow posture.
  std::vector<std::pair<Eigen::VectorXd, Eigen::VectorXd>> starts(const Eigen::VectorXd& qa, const Eigen::VectorXd& qb,
                                                                  const Eigen::VectorXd& worst) const {
    const Eigen::VectorXd mid = 0.5 * (qa + qb);
    return {{worst, worst}, {mid, mid}, {folded(mid), mid}, {0.75 * qa + 0.25 * qb, mid}, {0.25 * qa + 0.75 * qb, mid},
            {robot.stow(), mid}};
  }

  // Postures after qa up to qb (qb last) whose rest-to-rest quintics keep every margin; none when
  // no route of at most 2^depth legs was found.
  std::optional<std::vector<Eigen::VectorXd>> route(const Eigen::VectorXd& qa, const Eigen::VectorXd& qb, int depth) {
    const TimedTrajectory straight = joint_move_through(robot, {qa, qb}, timing, region_index);
    if (straight.size() == 0) return std::vector<Eigen::VectorXd>{qb};
    const ClearanceReport rep = check_clearance_octree(robot, straight, wall, config);
    if (rep.moving_samples_below_margin() == 0) return std::vector<Eigen::VectorXd>{qb};
    if (depth == 0) return std::nullopt;
    const Eigen::VectorXd worst = worst_posture(straight, rep, config);
    // Vias sought with the allowance saturated at via_allowance_m first (the nearest posture with
    // that much room), then at three times it, then unsaturated (the seed method's maximum).
    std::vector<Eigen::VectorXd> vias;
    std::optional<std::vector<Eigen::VectorXd>> best;
    for (const double cap : {config.via_allowance_m, 3.0 * config.via_allowance_m, 10.0}) {
      const std::size_t first_new = vias.size();
      for (const auto& [start, ref] : starts(qa, qb, worst)) {
        Eigen::VectorXd v = via_from(start, ref, cap);
        if (allowance(v, 0.0) < 0.0) continue;
        const bool seen = std::any_of(vias.begin(), vias.end(), [&](const Eigen::VectorXd& u) { return (u - v).norm() < 1e-3; });
        if (!seen) vias.push_back(std::move(v));
      }
      // One via: the fastest route that keeps the margins.
      double best_s = std::numeric_limits<double>::infinity();
      for (std::size_t k = first_new; k < vias.size(); ++k) {
        const TimedTrajectory piece = joint_move_through(robot, {qa, vias[k], qb}, timing, region_index);
        const std::vector<Eigen::VectorXd> legs{vias[k], qb};
        if (piece.duration_s < best_s && clear_or_note(piece, legs, depth == top_depth)) best = legs, best_s = piece.duration_s;
      }
      if (best) return best;
    }
    // Fold, swing, unfold: the telescopes in at the start, the swing, the telescopes out at the
    // goal (each folded posture pushed to the via allowance when it lacks room itself).
    {
      const Eigen::VectorXd fa = via_from(folded(qa), folded(qa), config.via_allowance_m);
      const Eigen::VectorXd fb = via_from(folded(qb), folded(qb), config.via_allowance_m);
      if (allowance(fa, 0.0) >= 0.0 && allowance(fb, 0.0) >= 0.0 &&
          clear_or_note(joint_move_through(robot, {qa, fa, fb, qb}, timing, region_index), {fa, fb, qb}, depth == top_depth))
        return std::vector<Eigen::VectorXd>{fa, fb, qb};
    }
    if (depth == 1) return std::nullopt;
    // Else each leg re-routed the same way, through the (at most three) vias with the most room.
    std::vector<std::pair<double, std::size_t>> room;
    for (std::size_t k = 0; k < vias.size(); ++k) room.emplace_back(-allowance(vias[k], 10.0), k);
    std::sort(room.begin(), room.end());
    if (room.size() > 3) room.resize(3);
    for (const auto& [negative_room, k] : room) {
      const Eigen::VectorXd& v = vias[k];
      auto left = route(qa, v, depth - 1);
      if (!left) continue;
      auto right = route(v, qb, depth - 1);
      if (!right) continue;
      left->insert(left->end(), right->begin(), right->end());
      return left;
    }
    return std::nullopt;
  }

  // The fallback when no via route clears a move (a swing folded round a face or a duct): a
  // joint-space RRT-Connect (Kuffner & LaValle 2000, the planner MoveIt uses through OMPL) whose
  // postures keep `slack_m` beyond the margins (posture_allowance), checked every
  // kSampledCheckStep_m of the arm's motion (joint_levers), with at most config.sampled_route_nodes
  // nodes added (0: off); the path found is shortened greedily (each posture joined to the
  // farthest later one it reaches clear), then by shortcuts and dropped postures that save time,
  // and its inner postures are the vias (the quickest path, else the greedy one, else the path as
  // found; with an end short of the margins the quickest only). Seeded per move: the same answer
  // every run.
  // Clear only when the rest-to-rest quintics through them keep every margin at every sample
  // (clear_or_note; else remembered as a best effort like any route).
  std::optional<std::vector<Eigen::VectorXd>> sampled_route(const Eigen::VectorXd& qa, const Eigen::VectorXd& qb,
                                                            unsigned seed) {
    if (config.sampled_route_nodes <= 0) return std::nullopt;
    const std::vector<double> lever = joint_levers(robot);
    const int n = robot.dof();
    const auto reach = [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {  // how far the arm moves [m], at most
      double d = 0.0;
      for (int j = 0; j < n; ++j) d += lever[static_cast<std::size_t>(j)] * std::abs(b[j] - a[j]);
      return d;
    };
    // Half a check step beyond the margins at each posture; an end with less (a region's own
    // posture near a face, short of the margins) lets the postures within kSampledNear_m of the
    // arm's motion from it keep only what it has, and kSampledRamp more per metre beyond: the
    // route leaves it, and comes to the other end, by the quickest way out of what it is close to.
    const double slack_m = 0.5 * kSampledCheckStep_m;
    const double end_a = std::min(slack_m, allowance(qa, slack_m)), end_b = std::min(slack_m, allowance(qb, slack_m));
    const auto need = [&](const Eigen::VectorXd& q) {
      return std::min({slack_m, end_a + kSampledRamp * std::max(0.0, reach(qa, q) - kSampledNear_m),
                       end_b + kSampledRamp * std::max(0.0, reach(qb, q) - kSampledNear_m)});
    };
    const auto clear = [&](const Eigen::VectorXd& q) { return allowance(q, slack_m) >= need(q) - 1e-9; };
    // The postures strictly after a up to b, in an order that meets an obstacle early (every
    // 8th, then every 4th between, ...).
    const auto edge_clear = [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
      const int steps = std::max(1, static_cast<int>(std::ceil(reach(a, b) / kSampledCheckStep_m)));
      if (!clear(b)) return false;
      for (int stride = 8; stride >= 1; stride /= 2)
        for (int k = stride; k < steps; k += stride)
          if (stride == 8 || k % (2 * stride) != 0)
            if (!clear(a + (b - a) * (static_cast<double>(k) / steps))) return false;
      return true;
    };
    struct Tree {
      std::vector<Eigen::VectorXd> q;
      std::vector<int> parent;
    };
    Tree from_a{{qa}, {-1}}, from_b{{qb}, {-1}};
    const auto nearest = [&](const Tree& t, const Eigen::VectorXd& q) {
      int best = 0;
      double best_d = std::numeric_limits<double>::infinity();
      for (std::size_t i = 0; i < t.q.size(); ++i) {
        const double d = reach(t.q[i], q);
        if (d < best_d) best_d = d, best = static_cast<int>(i);
      }
      return best;
    };
    enum class Step { trapped, advanced, reached };
    // Toward target from the tree's nearest posture by at most kSampledExtend_m, as far as the
    // postures stay clear (checked in order, every kSampledCheckStep_m).
    const auto extend = [&](Tree& t, const Eigen::VectorXd& target) {
      const int i = nearest(t, target);
      const Eigen::VectorXd from = t.q[static_cast<std::size_t>(i)];
      const double d = reach(from, target);
      const bool whole = d <= kSampledExtend_m;
      const Eigen::VectorXd to = whole ? target : Eigen::VectorXd(from + (target - from) * (kSampledExtend_m / d));
      const int steps = std::max(1, static_cast<int>(std::ceil(reach(from, to) / kSampledCheckStep_m)));
      int last = 0;
      while (last < steps && clear(from + (to - from) * (static_cast<double>(last + 1) / steps))) ++last;
      if (last == 0) return Step::trapped;
      t.q.push_back(from + (to - from) * (static_cast<double>(last) / steps)), t.parent.push_back(i), ++sampled_nodes;
      return whole && last == steps ? Step::reached : Step::advanced;
    };
    const auto path_to_root = [](const Tree& t, int i) {
      std::vector<Eigen::VectorXd> out;
      for (; i >= 0; i = t.parent[static_cast<std::size_t>(i)]) out.push_back(t.q[static_cast<std::size_t>(i)]);
      return out;
    };
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    const Eigen::VectorXd lo = robot.lower_limits(), span = robot.upper_limits() - robot.lower_limits();
    Tree* grow = &from_a;
    Tree* other = &from_b;
    std::vector<Eigen::VectorXd> path;
    // (The straight move is what failed.) At most 4 samples per node allowed: trees that cannot
    // grow (an end boxed in at the checks' resolution) give up too.
    for (int tries = 0; path.empty() && tries < 4 * config.sampled_route_nodes &&
                        static_cast<int>(from_a.q.size() + from_b.q.size()) < 2 + config.sampled_route_nodes;
         ++tries) {
      Eigen::VectorXd sample(n);
      for (int j = 0; j < n; ++j) sample[j] = lo[j] + unit(rng) * span[j];
      if (extend(*grow, sample) != Step::trapped) {
        const Eigen::VectorXd reached = grow->q.back();
        Step s = Step::advanced;
        while (s == Step::advanced) s = extend(*other, reached);
        if (s == Step::reached) {
          std::vector<Eigen::VectorXd> a_side = path_to_root(from_a, static_cast<int>(from_a.q.size()) - 1);
          std::vector<Eigen::VectorXd> b_side = path_to_root(from_b, static_cast<int>(from_b.q.size()) - 1);
          std::reverse(a_side.begin(), a_side.end());  // qa ... meeting posture
          path = a_side;
          path.insert(path.end(), b_side.begin() + 1, b_side.end());  // the meeting posture once ... qb
        }
      }
      std::swap(grow, other);
    }
    if (path.empty()) return std::nullopt;
    // Greedy shortening: from each kept posture, the farthest later one it reaches clear.
    std::vector<Eigen::VectorXd> kept{path.front()};
    for (std::size_t i = 0; i + 1 < path.size();) {
      std::size_t j = path.size() - 1;
      while (j > i + 1 && !edge_clear(path[i], path[j])) --j;
      kept.push_back(path[j]);
      i = j;
    }
    // Then shortcuts between two points of the path (OMPL's random shortcutting) and dropped
    // postures, each kept when its edge is clear and the rest-to-rest legs take less time: the
    // samples wander in every joint, the legs need not.
    const auto duration_of = [&](const std::vector<Eigen::VectorXd>& postures) {
      double total = 0.0;
      for (std::size_t k = 0; k + 1 < postures.size(); ++k)
        total += quintic_nozzle_duration(robot, postures[k], postures[k + 1], timing.nozzle_max_speed_mps,
                                         timing.nozzle_max_accel_mps2);
      return total;
    };
    std::vector<Eigen::VectorXd> quick = kept;
    double quick_s = duration_of(quick);
    bool shortened = false;  // quick is not kept
    for (int round = 0; round < kSampledShortcuts && quick.size() > 2; ++round) {
      std::vector<Eigen::VectorXd> tried;
      Eigen::VectorXd a, b;
      if (round % 4 == 3) {  // drop one posture
        const std::size_t k =
            std::min(quick.size() - 2, 1 + static_cast<std::size_t>(unit(rng) * static_cast<double>(quick.size() - 2)));
        a = quick[k - 1], b = quick[k + 1];
        tried = quick;
        tried.erase(tried.begin() + static_cast<std::ptrdiff_t>(k));
      } else {  // a point on leg i to a point on a later leg j
        const std::size_t legs_n = quick.size() - 1;
        std::size_t i = static_cast<std::size_t>(unit(rng) * static_cast<double>(legs_n));
        std::size_t j = static_cast<std::size_t>(unit(rng) * static_cast<double>(legs_n));
        i = std::min(i, legs_n - 1), j = std::min(j, legs_n - 1);
        if (i > j) std::swap(i, j);
        if (i == j) continue;
        a = quick[i] + unit(rng) * (quick[i + 1] - quick[i]);
        b = quick[j] + unit(rng) * (quick[j + 1] - quick[j]);
        tried.assign(quick.begin(), quick.begin() + static_cast<std::ptrdiff_t>(i) + 1);
        tried.push_back(a), tried.push_back(b);
        tried.insert(tried.end(), quick.begin() + static_cast<std::ptrdiff_t>(j) + 1, quick.end());
      }
      const double tried_s = duration_of(tried);
      if (tried_s < quick_s - 1e-3 && edge_clear(a, b)) quick = std::move(tried), quick_s = tried_s, shortened = true;
    }
    // The quickest path, else the shortened one, else the path as found (a check between
    // postures can miss what the samples of the timed move meet).
    // An end short of the margins: no route clears them; the quickest path is the best effort (the
    // others, with more rest-to-rest legs, would win it by a few link-samples at twice the time).
    const bool end_short = std::min(end_a, end_b) < 0.0;
    for (const auto* postures : {&quick, &kept, &path}) {
      if ((postures == &kept && !shortened) || (postures == &path && kept.size() == path.size())) continue;  // checked
      std::vector<Eigen::VectorXd> legs(postures->begin() + 1, postures->end());
      if (clear_or_note(joint_move_through(robot, *postures, timing, region_index), legs, true)) return legs;
      if (end_short) break;
    }
    return std::nullopt;
  }
};

// A move as a trajectory of its own (start sample included) for check_clearance_octree.
TimedTrajectory move_samples(const TimedTrajectory& tr, const JointMove& m) {
  TimedTrajectory out;
  for (std::size_t k = m.start; k <= m.end; ++k) out.t_s.push_back(tr.t_s[k]), out.q.push_back(tr.q[k]);
  return out;
}

}  // namespace

// A route that breaks a margin with fewer link-samples than the straight move but more than half
// as many replaces it only when it comes at least this much less short of the margins [m]: a real
// gain, not one leaf of the octree's reading.
constexpr double kBestEffortGain_m = 0.1;

namespace {

// Whether a route that still breaks a margin at `below` link-samples, `allowance_m` least, may
// replace the straight move `d` (eased): fewer samples below, and at most half of them or 0.1 m
// less short.
bool eases(int below, double allowance_m, const TransitDetour& d) {
  return below < d.straight_samples_below &&
         (below <= d.straight_samples_below / 2 || allowance_m >= d.straight_min_allowance_m + kBestEffortGain_m);
}

// A new move's samples with its start posture qa at t = 0 in front, as the straight move's were
// checked (move_samples).
TimedTrajectory from_start(TimedTrajectory piece, const Eigen::VectorXd& qa) {
  piece.t_s.insert(piece.t_s.begin(), 0.0);
  piece.q.insert(piece.q.begin(), qa);
  return piece;
}

}  // namespace

TransitReport clear_transits(const Robot& robot, TimedTrajectory& trajectory, const WallOctree& wall,
                             const ClearanceConfig& config, const TimingConfig& timing) {
  const auto t0 = std::chrono::steady_clock::now();
  TransitReport rep;
  const auto pairs = self_check_pairs(robot);
  const std::vector<char> fixed = fixed_shapes(robot);
  std::vector<JointMove> moves = joint_moves(trajectory);
  const double leaf_diagonal_m = wall.leaf_diagonal_m();
  rep.moves_checked = static_cast<int>(moves.size());
  for (std::size_t i = 0; i < moves.size(); ++i) {
    const JointMove move = moves[i];
    const TimedTrajectory samples = move_samples(trajectory, move);
    // The exact check first (cheap on the distance field; the octree's FCL readings are not): a
    // move whose links keep their wall margins by a leaf diagonal keeps them on the octree's
    // reading too, which is never more than a diagonal short (the self check is the same exact
    // one in both). Only the others are screened as the router screens.
    if (keeps_margins_by(check_clearance(robot, samples, wall, config), config, leaf_diagonal_m)) continue;
    const ClearanceReport straight = check_clearance_octree(robot, samples, wall, config);
    if (straight.moving_samples_below_margin() == 0) continue;
    TransitDetour d;
    d.move = static_cast<int>(i);
    d.region_index = move.region_index;
    d.start_time_s = trajectory.t_s[move.start];
    d.straight_samples_below = straight.moving_samples_below_margin();
    d.straight_worst = worst_of(straight, config);
    d.straight_min_allowance_m = report_allowance(straight, config);
    d.straight_duration_s = d.duration_s = move.duration_s(trajectory);
    const Eigen::VectorXd qa = trajectory.q[move.start], qb = trajectory.q[move.end];
    Router router{robot, wall, config, timing, move.region_index, pairs, fixed};
    // The move replaced by the postures after qa (the last one qb): vias, durations, the detour.
    const auto replace_by = [&](const std::vector<Eigen::VectorXd>& route) {
      std::vector<Eigen::VectorXd> postures{qa};
      postures.insert(postures.end(), route.begin(), route.end());
      const TimedTrajectory piece = joint_move_through(robot, postures, timing, move.region_index);
      d.vias.assign(route.begin(), route.end() - 1);
      for (const auto& v : d.vias) d.via_allowance_m.push_back(router.allowance(v, 10.0));
      d.duration_s = piece.duration_s;
      rep.detour_time_s += d.duration_s - d.straight_duration_s;
      replace_joint_move(robot, trajectory, move, piece);
      moves = joint_moves(trajectory);  // the later samples moved
      return piece;
    };
    const double end_allowance_m = std::min(router.allowance(qa, 10.0), router.allowance(qb, 10.0));
    if (end_allowance_m < 0.0) {
      // An end posture short of the margins (a pass's start near the face) cannot be reached
      // clear of them, but the move between need not sweep closer still (a straight swing from
      // the start through the face: 2,000 link-samples at 0 m). Where it does (0.1 m closer than
      // its ends), routed with every margin lowered by the shortfall and a leaf diagonal (the
      // octree's reading at the end itself); replaces the move by the eased moves' rule. Still
      // failed.
      const double lowered_by_m = -end_allowance_m + leaf_diagonal_m;
      ClearanceConfig lowered = config;
      for (double* margin : {&lowered.link_margin_m, &lowered.nozzle_margin_m, &lowered.self_margin_m})
        *margin = std::max(0.0, *margin - lowered_by_m);
      Router near{robot, wall, lowered, timing, move.region_index, pairs, fixed};
      // Only a move that sweeps clearly closer than its ends is worth a search (most such moves
      // break the margins at their ends alone: the whole scene has dozens, at minutes of search).
      const bool sweeps_closer = d.straight_min_allowance_m < end_allowance_m - kBestEffortGain_m;
      // The candidates: the via route that keeps the lowered margins (or the one least below
      // them), and the sampled planner's (the margins proper, relaxed near a short end only);
      // the one that breaks the margins proper at the fewest link-samples (then less short) is
      // judged by the eased moves' rule.
      struct Candidate {
        std::vector<Eigen::VectorXd> route;
        std::string how;
        int below = std::numeric_limits<int>::max();
        double allowance_m = -std::numeric_limits<double>::infinity();
        double duration_s = 0.0;
      };
      std::vector<Candidate> candidates;
      if (config.reroute_transits && sweeps_closer) {
        std::ostringstream by;
        by.precision(3);
        by << lowered_by_m << " m";
        if (auto r = near.route(qa, qb, near.top_depth)) candidates.push_back({*r, "routed with the margins lowered by " + by.str()});
        else if (!near.best_effort.empty())
          candidates.push_back({near.best_effort, "no route keeps the margins lowered by " + by.str() +
                                                      ": the one least below them replaced the move"});
        const std::string sampled = "routed by the sampled planner (RRT-Connect), short of the margins near its ends only";
        if (auto r = router.sampled_route(qa, qb, static_cast<unsigned>(i) + 1u)) candidates.push_back({*r, sampled});
        else if (!router.best_effort.empty()) candidates.push_back({router.best_effort, sampled});
      }
      for (Candidate& c : candidates) {
        std::vector<Eigen::VectorXd> postures{qa};
        postures.insert(postures.end(), c.route.begin(), c.route.end());
        // With qa itself, as the straight move was counted (move_samples).
        const TimedTrajectory piece = joint_move_through(robot, postures, timing, move.region_index);
        const ClearanceReport along = check_clearance_octree(robot, from_start(piece, qa), wall, config);
        c.below = along.moving_samples_below_margin();
        c.allowance_m = report_allowance(along, config);
        c.duration_s = piece.duration_s;
      }
      // Of the candidates that may replace the move by the eased moves' rule (at most half the
      // link-samples below, or fewer 0.1 m less short), or fewer at no more time than the
      // straight move, the one with the fewest below (then the least short).
      const auto may_replace = [&](const Candidate& c) {
        return c.route.size() > 1 && (eases(c.below, c.allowance_m, d) ||
                                      (c.below < d.straight_samples_below && c.duration_s <= d.straight_duration_s));
      };
      candidates.erase(std::remove_if(candidates.begin(), candidates.end(), [&](const Candidate& c) { return !may_replace(c); }),
                       candidates.end());
      const auto best = std::min_element(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
        return a.below < b.below || (a.below == b.below && a.allowance_m > b.allowance_m);
      });
      std::ostringstream why;
      why.precision(3);
      why << "its start or goal posture is itself " << -end_allowance_m << " m closer than the margins";
      if (!config.reroute_transits) why << " (clearance.reroute_transits is off)";
      if (best != candidates.end()) {
        d.min_allowance_m = best->allowance_m;
        why << "; " << best->how << " (" << best->below
            << " link-samples below the margins proper; the straight move " << d.straight_samples_below << ")";
        replace_by(best->route);
        d.eased = true;
      }
      router.optimisations += near.optimisations;
      d.reason = why.str();
    } else if (!config.reroute_transits) {
      d.reason = "clearance.reroute_transits is off";
    } else if (auto route = router.route(qa, qb, router.top_depth);
               route || (route = router.sampled_route(qa, qb, static_cast<unsigned>(i) + 1u))) {
      const TimedTrajectory checked = from_start(replace_by(*route), qa);
      d.min_allowance_m = report_allowance(check_clearance_octree(robot, checked, wall, config), config);
      d.rerouted = true;
    } else if (!router.best_effort.empty() && eases(router.best_effort_below, router.best_effort_allowance_m, d)) {
      // No clear route, but one with at most half the straight move's link-samples below a margin
      // (a straight swing through a face: 2,000 of them, every one 0.4 m short, where the reading
      // saturates), or fewer that come 0.1 m less short: it replaces the move, which still counts
      // as failed, and the clearance check counts what it breaks.
      replace_by(router.best_effort);
      d.min_allowance_m = router.best_effort_allowance_m;
      std::ostringstream why;
      why.precision(3);
      why << "no route found (via postures, then sampled) that keeps the margins; the one with the fewest link-samples below them ("
          << router.best_effort_below << ", " << -d.min_allowance_m << " m short; the straight move " << d.straight_samples_below
          << ", " << -d.straight_min_allowance_m << " m) replaced the move";
      d.reason = why.str();
      d.eased = true;
    } else {
      d.reason = "no route found (via postures, then sampled) that keeps the margins";
    }
    d.optimisations = router.optimisations;
    d.sampled_nodes = router.sampled_nodes;
    if (d.rerouted) ++rep.rerouted;
    else ++rep.failed;
    rep.detours.push_back(std::move(d));
  }
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

StartPosture start_posture(const Robot& robot, const Eigen::VectorXd& preferred, const WallOctree& wall,
                           const ClearanceConfig& config) {
  if (preferred.size() != robot.dof()) throw std::invalid_argument("start_posture: the posture does not match the robot");
  const auto pairs = self_check_pairs(robot);
  const std::vector<char> fixed = fixed_shapes(robot);
  StartPosture out;
  out.q = out.preferred = preferred;
  out.preferred_allowance_m = out.allowance_m = posture_allowance(robot, preferred, wall, config, pairs, 10.0, &fixed);
  if (out.preferred_allowance_m >= 0.0) return out;
  const Eigen::VectorXd range = (robot.upper_limits() - robot.lower_limits()).cwiseMax(1e-9);
  // Starts: the preferred and the neutral postures, each with its telescopes in, and each of
  // those turned about the first joint (the slew: the boom swung away from what it points into).
  // (Turns clamped to the joint's limits; repeated starts dropped.)
  std::vector<Eigen::VectorXd> starts;
  for (const Eigen::VectorXd& base : {preferred, robot.neutral()})
    for (const Eigen::VectorXd& q : {base, folded(robot, base)})
      for (const double turn : {0.0, 0.5 * M_PI, -0.5 * M_PI, M_PI, -M_PI}) {
        Eigen::VectorXd s = q;
        s[0] = std::clamp(s[0] + turn, robot.lower_limits()[0], robot.upper_limits()[0]);
        const bool seen = std::any_of(starts.begin(), starts.end(), [&](const Eigen::VectorXd& u) { return (u - s).norm() < 1e-6; });
        if (!seen) starts.push_back(std::move(s));
      }
  double best_distance = std::numeric_limits<double>::infinity();
  for (const double cap : {config.via_allowance_m, 3.0 * config.via_allowance_m, 10.0}) {
    for (const auto& s : starts) {
      ++out.optimisations;
      const Eigen::VectorXd q = most_room_posture(robot, s, preferred, wall, config, pairs, cap, fixed);
      const double allowance = posture_allowance(robot, q, wall, config, pairs, 10.0, &fixed);
      const double distance = (q - preferred).cwiseQuotient(range).norm();
      if (allowance >= 0.0 && distance < best_distance) {
        best_distance = distance;
        out.q = q, out.allowance_m = allowance, out.moved = true;
      }
    }
    if (out.moved) break;  // the nearest posture with room at the smallest saturation that has one
  }
  return out;
}

// Starts tried at a direction short of room after the usual ones (swing_room).
constexpr int kSwingExtraStarts = 8;

SwingRoom swing_room(const Robot& robot, const WallOctree& wall, const ClearanceConfig& config, double step_rad,
                     double stop_below_m, double first_rad) {
  if (!(step_rad >= 1e-3 && step_rad <= 2.0 * M_PI)) throw std::invalid_argument("swing_room: step_rad must be within 0.001..2 pi rad");
  const auto pairs = self_check_pairs(robot);
  const std::vector<char> fixed = fixed_shapes(robot);
  const double cap = config.via_allowance_m;
  SwingRoom out;
  out.least_m = cap;
  // The directions: multiples of step_rad (slew 0, straight ahead along base_link's x, among
  // them) within the joint's range, and its two limits.
  const double lo = robot.lower_limits()[0], hi = robot.upper_limits()[0];
  std::vector<double> slews{lo};
  for (int k = static_cast<int>(std::floor(lo / step_rad)) + 1; k * step_rad < hi; ++k)
    if (k * step_rad > lo + 1e-9 && k * step_rad < hi - 1e-9) slews.push_back(k * step_rad);
  if (hi > lo) slews.push_back(hi);
  // Nearest first_rad first: where a place is likely short, it is found short soonest.
  if (std::isfinite(first_rad))
    std::stable_sort(slews.begin(), slews.end(),
                     [&](double a, double b) { return std::abs(a - first_rad) < std::abs(b - first_rad); });
  Eigen::VectorXd last;  // the roomiest posture at the slew before: the next one starts there
  for (const double slew : slews) {
    std::vector<Eigen::VectorXd> starts;
    if (last.size() > 0) starts.push_back(last);
    for (const Eigen::VectorXd& q : {robot.stow(), robot.neutral()}) {
      starts.push_back(q);
      starts.push_back(folded(robot, q));
    }
    // A direction short of room after those gets kSwingExtraStarts more, spread over the joint
    // ranges (the search is local; the same seed each direction, so the answer is repeatable).
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    const Eigen::VectorXd lo_q = robot.lower_limits(), span = robot.upper_limits() - robot.lower_limits();
    for (int k = 0; k < kSwingExtraStarts; ++k) {
      Eigen::VectorXd q(robot.dof());
      for (int j = 0; j < robot.dof(); ++j) q[j] = lo_q[j] + unit(rng) * span[j];
      starts.push_back(q);
    }
    double best = -std::numeric_limits<double>::infinity();
    for (Eigen::VectorXd s : starts) {
      s[0] = slew;
      ++out.optimisations;
      const Eigen::VectorXd q = most_room_posture(robot, s, s, wall, config, pairs, cap, fixed, 0, 0.0);
      const double a = posture_allowance(robot, q, wall, config, pairs, cap, &fixed);
      if (a > best) best = a, last = q;
      if (best >= cap - kSwingRoomSlack_m) break;  // room enough: the other starts cannot add to it
    }
    ++out.directions;
    if (best < out.least_m || out.worst_q.size() == 0) out.least_m = std::min(out.least_m, best), out.worst_slew_rad = slew, out.worst_q = last;
    if (out.least_m < stop_below_m) break;
  }
  return out;
}

namespace {

// Least exact distance to `wall` of the shapes no joint moves (fixed_shapes), the base moved by
// `shift` (a pure translation: their frames move with it); infinite without such shapes.
double fixed_distance(const Robot& robot, const WallOctree& wall, const Eigen::Vector3d& shift = Eigen::Vector3d::Zero()) {
  const std::vector<char> fixed = fixed_shapes(robot);
  const auto& shapes = robot.collision_shapes();
  const auto frames = robot.link_frames(robot.stow());
  double least = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < shapes.size(); ++k)
    if (fixed[k])
      least = std::min(least, wall.exact_distance(shapes[k], Eigen::Translation3d(shift) * frames[shapes[k].frame]));
  return least;
}

// Whether the shapes no joint moves, carried from `from` to `to` (base positions) in steps of at most
// kBaseWayStep_m, overlap a point of `wall` at some step after `from`: a face between two places
// closes the way past it (every fixed shape is thicker than a step, so none slips through a
// wall one point thick), while a point the base only comes near does not.
bool way_blocked(const Robot& robot, const WallOctree& wall, const Eigen::Vector3d& from, const Eigen::Vector3d& to) {
  const int steps = std::max(1, static_cast<int>(std::ceil((to - from).norm() / kBaseWayStep_m - 1e-9)));
  const Eigen::Vector3d base = robot.base_pose().translation();
  for (int i = 1; i <= steps; ++i)
    if (fixed_distance(robot, wall, from + (to - from) * (static_cast<double>(i) / steps) - base) <= 0.0) return true;
  return false;
}

}  // namespace

double base_room(const Robot& robot, const WallOctree& wall, const ClearanceConfig& config) {
  return fixed_distance(robot, wall) - config.base_margin_m;
}

BasePlacement place_base(const Robot& robot, const WallOctree& wall, const Eigen::Vector3d& along,
                         const ClearanceConfig& config, double max_shift_m) {
  if (!(along.norm() > 0.0) || !along.allFinite()) throw std::invalid_argument("place_base: the axis direction is not a vector");
  if (!(max_shift_m >= 0.0 && max_shift_m <= kMaxBaseShift_m))
    throw std::invalid_argument("robot.max_base_shift_m must be within 0.." + std::to_string(kMaxBaseShift_m) + " m");
  const auto t0 = std::chrono::steady_clock::now();
  const Eigen::Vector3d ex = along.normalized();
  BasePlacement out;
  out.configured_m = out.position_m = robot.base_pose().translation();
  const double need = config.via_allowance_m - kSwingRoomSlack_m;
  // A place is given up at its first direction short of room (a direction short after the usual
  // starts costs kSwingExtraStarts more searches): the configured place's directions from straight
  // ahead (slew 0, where a face usually is) outward, a candidate's from the configured place's
  // short direction outward.
  double first_rad = 0.0;
  const auto fits = [&](const Robot& r, SwingRoom& room, double& base, bool configured) {
    base = base_room(r, wall, config);
    if (base < 0.0 && !configured) return false;  // the configured place's room is reported all the same
    room = swing_room(r, wall, config, kSwingStepRad, need, first_rad);
    return base >= 0.0 && room.least_m >= need;
  };
  SwingRoom room;
  double base = 0.0;
  ++out.places_tried;
  out.found = fits(robot, room, base, true);
  out.configured_room_m = out.room_m = room.least_m;
  out.configured_base_room_m = out.base_room_m = base;
  out.configured_short_slew_rad = first_rad = room.worst_slew_rad;
  // Without a fixed collision shape nothing tells where the base can stand (it could be carried
  // through a face into the unscanned rock beyond): it stays.
  const std::vector<char> fixed = fixed_shapes(robot);
  const bool can_move = std::any_of(fixed.begin(), fixed.end(), [](char f) { return f != 0; });
  if (!out.found && can_move) {
    // Away from what the configured place lacks room for first: its short slew direction (slew 0
    // points along base_link's x); at each distance, nearest first.
    const Eigen::Vector3d toward(std::cos(room.worst_slew_rad), std::sin(room.worst_slew_rad), 0.0);
    const double away = toward.dot(ex) > 0.0 ? -1.0 : 1.0;
    const int steps = static_cast<int>(std::floor(max_shift_m / kBaseShiftStep_m + 1e-9));
    bool closed[2] = {false, false};  // the way past a point of the scan, {away, toward}
    for (int k = 1; k <= steps && !out.found; ++k)
      for (const int side : {0, 1}) {
        const double sign = side == 0 ? away : -away;
        const double shift = sign * k * kBaseShiftStep_m;
        const Eigen::Vector3d last = out.configured_m + sign * (k - 1) * kBaseShiftStep_m * ex;
        if (closed[side] || (closed[side] = way_blocked(robot, wall, last, out.configured_m + shift * ex))) continue;
        Robot moved = robot.placed_at(out.configured_m + shift * ex);
        ++out.places_tried;
        SwingRoom r;
        double b = 0.0;
        if (fits(moved, r, b, false)) {
          out.found = out.moved = true;
          out.shift_m = shift;
          out.position_m = moved.base_pose().translation();
          out.room_m = r.least_m, out.base_room_m = b;
          break;
        }
      }
  }
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace shotcrete
