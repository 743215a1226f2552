#include "rounds.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>

#include "shotcrete/timing/region_spray.hpp"

namespace shotcrete {

int top_level(const std::vector<int>& levels) {
  int top = std::numeric_limits<int>::min();
  for (auto [lv, n] : level_counts(levels)) top = std::max(top, lv);
  return top;
}

double max_td_m(const Grid& grid) {
  double max_td = -std::numeric_limits<double>::infinity();
  for (int c = 0; c < grid.size(); ++c)
    if (grid.valid[c]) max_td = std::max(max_td, grid.td_m[c]);
  return max_td;
}

Grid RoundStages::worked_grid(const Grid& grid) const {
  Grid g = grid;
  for (int c = 0; c < g.size(); ++c)
    if (excluded(c)) g.valid[static_cast<std::size_t>(c)] = 0;
  return g;
}

void RoundContext::report(int round_number, double fraction) const {
  if (progress) progress("round " + std::to_string(round_number), fraction);
}

namespace {

std::string round_name(int number) { return "round " + std::to_string(number); }

// ---------------------------------------------------------------------------------------------
// Graded rounds (thesis): one level per round

// Lower TD bound (mm) of a level: a cell leaves level L once its TD falls below this.
double level_floor_mm(int level) {
  if (level >= 2) return 70.0 * level;
  if (level == 1) return 50.0;
  return -50.0;
}

// A pass shorter than the spot's diameter lays next to nothing on a small region even at the
// slowest speed (a one-cell line is 5 cm long): it is lengthened straight along its chord, about
// its middle, to min_length_m.
void lengthen_short_pass(Pass& pass, double min_length_m, double step_m) {
  if (pass.length_m >= min_length_m || pass.waypoints.size() < 2) return;
  const Eigen::Vector3d a = pass.waypoints.front().position_m, b = pass.waypoints.back().position_m;
  if ((b - a).norm() < 1e-9) return;
  const Eigen::Vector3d dir = (b - a).normalized();
  const Eigen::Vector3d mid = 0.5 * (a + b);
  const Eigen::Vector3d axis = pass.waypoints[pass.waypoints.size() / 2].axis;
  const int n = std::max(2, static_cast<int>(std::ceil(min_length_m / step_m)) + 1);
  pass.waypoints.clear();
  for (int k = 0; k < n; ++k) {
    NozzlePose p;
    p.position_m = mid + (-0.5 + static_cast<double>(k) / (n - 1)) * min_length_m * dir;
    p.axis = axis;
    pass.waypoints.push_back(p);
  }
  pass.length_m = polyline_length(pass.waypoints);
  pass.speed_profile_mps.clear();
}

// What the region's passes should lay (docs/architecture.md §5). The thesis: the region's target
// on each of its cells. Here (unless planner.graded_thesis_objective), beyond it, because a round
// cannot take concrete back: the last round (level 1 -> 0) aims every cell at 5 mm past flush
// instead of one drop for all (the guard below holds the over-fill; aiming at flush left more
// cells just above level 0 for straggler rounds, measured on seeds 1-3); and every cell
// the passes reach outside the region -- and in the last round the region's own cells -- may take
// at most its TD plus graded_overfill_allowance_m, each metre beyond that costing
// graded_guard_weight metres off target. Cells the guard leaves short of level 0 go to the next
// round; without it a round laid up to 95 mm on level-0 cells around a 5-cell region.
SpeedTargets region_targets(const RoundInput& in, const CellSurface& cells, const RoundContext& ctx,
                            const RegionPlan& rp, const std::vector<Eigen::VectorXd>& unit) {
  const PlannerConfig& pc = ctx.config.planner;
  const Grid& grid = in.wall.surface.grid;
  const bool last_round = in.grade.top_level == 1 && !pc.graded_thesis_objective;
  SpeedTargets t;
  std::vector<char> in_region(grid.size(), 0);
  for (int c : rp.region.cells) {
    in_region[c] = 1;
    t.slots.push_back(cells.slot[c]);
    t.target_m.push_back(last_round ? std::max(0.0, grid.td_m[c] + 0.005) : rp.target_thickness_m);
  }
  if (pc.graded_thesis_objective || pc.graded_guard_weight <= 0) return t;
  t.guard_weight = pc.graded_guard_weight;
  // The cells the passes reach: 1 mm or more at the slowest speed.
  Eigen::VectorXd reach = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(cells.cell_ids.size()));
  for (const auto& u : unit) reach += u / pc.min_speed_mps;
  for (std::size_t k = 0; k < cells.cell_ids.size(); ++k) {
    const int c = cells.cell_ids[k];
    if ((in_region[c] && !last_round) || reach[static_cast<Eigen::Index>(k)] < 0.001) continue;
    t.guard_slots.push_back(static_cast<int>(k));
    t.guard_max_m.push_back(std::max(0.0, grid.td_m[c] + pc.graded_overfill_allowance_m));
  }
  return t;
}

// The arm changes the nozzle speed along a pass at most at accel_mps2 (as limit_speed_changes
// holds the levelling rounds' segments): v_i^2 <= v_k^2 + 2 a |s_i - s_k|, by a sweep each way.
// Speeds only go down, so the caps still hold.
void limit_profile_changes(Pass& p, double accel_mps2) {
  auto& v = p.speed_profile_mps;
  for (std::size_t i = 1; i < v.size(); ++i) {
    const double ds = (p.waypoints[i].position_m - p.waypoints[i - 1].position_m).norm();
    v[i] = std::min(v[i], std::sqrt(v[i - 1] * v[i - 1] + 2 * accel_mps2 * ds));
  }
  for (std::size_t i = v.size() - 1; i-- > 0;) {
    const double ds = (p.waypoints[i + 1].position_m - p.waypoints[i].position_m).norm();
    v[i] = std::min(v[i], std::sqrt(v[i + 1] * v[i + 1] + 2 * accel_mps2 * ds));
  }
}

// The passes at the solved speeds: slower where the machine's cap binds (the speed profile the
// arm follows, its changes within speed_change_accel_mps2). var_of[j][i]: the speed variable of
// pass j's waypoint i (the pass's own, j, or one of its ends').
std::vector<Pass> passes_at(std::vector<Pass> passes, const PassSpeeds& speeds, const std::vector<std::vector<double>>& caps,
                            const RoundContext& ctx, const std::vector<std::vector<std::size_t>>& var_of) {
  if (speeds.speeds_mps.size() < passes.size() || caps.size() != passes.size() || var_of.size() != passes.size())
    throw std::logic_error("passes_at: speeds, caps or speed variables do not match the passes");
  for (std::size_t j = 0; j < passes.size(); ++j) {
    Pass& p = passes[j];
    if (var_of[j].size() != p.waypoints.size()) throw std::logic_error("passes_at: one speed variable per waypoint is needed");
    p.speed_mps = speeds.speeds_mps[j];
    p.speed_profile_mps.clear();
    std::vector<double> v(p.waypoints.size());
    bool varies = false;
    for (std::size_t i = 0; i < v.size(); ++i) {
      v[i] = std::min(speeds.speeds_mps[var_of[j][i]], caps[j][i]);
      varies = varies || v[i] != p.speed_mps;
    }
    if (varies) {
      p.speed_profile_mps = std::move(v);
      limit_profile_changes(p, ctx.config.timing.speed_change_accel_mps2);
    }
  }
  return passes;
}

// What a region's passes lay on the cells [m per slot] when they are timed and the pump drives
// them (region_spray: speed ramps, leads and turns, turns sprayed through, spells lengthened,
// flow ramps), and the pump's on-time [s].
struct SprayedPasses {
  Eigen::VectorXd deposit_m;
  double on_time_s = 0;
};
SprayedPasses sprayed_passes(const std::vector<Pass>& passes, const CellSurface& cells, const RoundContext& ctx) {
  const RegionSpray spray = region_spray(passes, ctx.config);
  return {unit_deposit(ctx.model, cells, spray.nozzle, spray.dwell_s, ctx.config.deposition.rebound_fraction),
          spray.flow.on_time_s()};
}

// What one part lays at the solved speeds: unit max(1 / v, floor) [m per slot].
Eigen::VectorXd part_deposit_m(const PassPart& part, const PassSpeeds& speeds) {
  return part.unit * std::max(1.0 / speeds.speeds_mps[part.pass], part.w_floor_s_per_m);
}

// The deposit the solve meant: the sum of its parts' [m per slot].
Eigen::VectorXd solved_deposit_m(const std::vector<PassPart>& parts, const PassSpeeds& speeds) {
  Eigen::VectorXd dep = Eigen::VectorXd::Zero(parts.front().unit.size());
  for (const PassPart& part : parts) dep += part_deposit_m(part, speeds);
  return dep;
}

// The last rounds leave out a pass that brings its cells further from their targets than leaving
// it out: one that reaches (1 mm or more) no cell of level 1 or above and no cell a pass that does
// reaches, such as a line over a streak of level-0 cells that graded_level_margin_m put in the
// region. Such a pass cannot lay less than a pump spell's worth (a 0.2 m pass at 2 s lays 37 mm),
// and on a one-row streak beside flush wall that only moves the error to the rows beside it
// (seed 3: +44 -> +7 mm on the streak, -24 -> -53 mm beside it).
// Greedy, in pass order, on the solve's deposit of each pass; kept only if the passes left, timed
// and sprayed, cost less than all of them. passes / sprayed: the region's, replaced when kept.
void drop_harmful_passes(const RoundInput& in, const CellSurface& cells, const RoundContext& ctx,
                         const std::vector<PassPart>& parts, const PassSpeeds& speeds, const std::vector<std::size_t>& owner,
                         const SpeedTargets& targets, const Eigen::VectorXd& round_deposit_m, bool executed,
                         const std::vector<int>& region_cells,
                         std::vector<Pass>& passes, Eigen::VectorXd& sprayed, std::vector<int>& left_alone) {
  std::vector<Eigen::VectorXd> own(passes.size(), Eigen::VectorXd::Zero(sprayed.size()));
  for (const PassPart& part : parts) own[owner[part.pass]] += part_deposit_m(part, speeds);
  Eigen::VectorXd laid = sprayed;
  double cost = graded_deposit_cost(targets, round_deposit_m + laid);
  std::vector<char> keep(passes.size(), 1);
  // The cells the passes that reach a cell of level 1 or above also reach (1 mm or more): a pass
  // that shares none of them with those passes can be left out without making their speeds, solved
  // with it, wrong where it matters.
  auto reaches = [&](std::size_t j, std::size_t k) { return own[j][static_cast<Eigen::Index>(k)] >= 0.001; };
  std::vector<char> near_level1(cells.cell_ids.size(), 0);
  for (std::size_t j = 0; j < passes.size(); ++j) {
    bool serves = false;
    for (std::size_t k = 0; k < cells.cell_ids.size() && !serves; ++k)
      serves = reaches(j, k) && in.wall.surface.levels[cells.cell_ids[k]] >= 1;
    if (serves)
      for (std::size_t k = 0; k < cells.cell_ids.size(); ++k) near_level1[k] |= reaches(j, k);
  }
  for (std::size_t j = 0; j < passes.size(); ++j) {
    bool eligible = true;
    for (std::size_t k = 0; k < cells.cell_ids.size() && eligible; ++k) eligible = !(reaches(j, k) && near_level1[k]);
    if (!eligible) continue;
    const double c = graded_deposit_cost(targets, round_deposit_m + laid - own[j]);
    if (c < cost) keep[j] = 0, cost = c, laid -= own[j];
  }
  if (std::all_of(keep.begin(), keep.end(), [](char k) { return k != 0; })) return;
  std::vector<Pass> kept;
  for (std::size_t j = 0; j < passes.size(); ++j)
    if (keep[j]) kept.push_back(passes[j]);
  Eigen::VectorXd kept_sprayed = Eigen::VectorXd::Zero(sprayed.size());
  if (!kept.empty()) kept_sprayed = executed ? sprayed_passes(kept, cells, ctx).deposit_m : Eigen::VectorXd(laid);
  if (!(graded_deposit_cost(targets, round_deposit_m + kept_sprayed) < graded_deposit_cost(targets, round_deposit_m + sprayed))) return;
  passes = std::move(kept);
  sprayed = std::move(kept_sprayed);
  // The region's cells the left-out passes reached are left as they are (all of level 0): planned
  // again next round, they would only get the same passes again.
  for (std::size_t j = 0; j < keep.size(); ++j)
    if (!keep[j])
      for (int c : region_cells)
        if (reaches(j, static_cast<std::size_t>(cells.slot[c]))) left_alone.push_back(c);
}

// Passes over one region of the round's level, each at the BOBYQA speed that brings the region's
// cells down by the target; nothing when no pass line crosses the region or every pass is left
// out. round_deposit_m: what the round's regions planned so far lay on the cells [m per slot]
// (timed and sprayed with graded_executed_corrections, else as solved); the region's own is added
// to it. left_alone: cells the region's left-out passes reached (drop_harmful_passes).
std::optional<RegionPlan> graded_region(const RoundInput& in, const CellSurface& cells, RoundContext& ctx,
                                        const Region& region, std::size_t ri, Eigen::VectorXd& round_deposit_m,
                                        std::vector<int>& left_alone) {
  const PlannerConfig& pc = ctx.config.planner;
  const int top = in.grade.top_level;
  RegionPlan rp;
  rp.region = region;
  // Thesis rule: the largest drop that takes every cell one level down (5 mm margin). For the
  // last step (level 1 -> 0) aim at the band's centre instead: the mean TD, so cells end near
  // flush rather than just inside +50 mm. This is the region's target in the report; the speeds
  // aim at per-cell targets in the last round (region_targets) unless graded_thesis_objective.
  rp.target_thickness_m = top == 1 ? std::max(rp.region.td_mean_m, rp.region.td_max_m - 0.045)
                                   : rp.region.td_max_m - level_floor_mm(top) / 1000.0 + 0.005;
  rp.spacing_m = ctx.spacing_m;
  // The level-1 rounds lay the last layer: with graded_last_edge_overrun_m their lines run on that
  // far past the bay's ends, so the end columns get more of the spot (at edge_overrun_m they hold
  // 15-34 of a seed's 26-48 cells above +40 mm). A line is cut where the region leaves more than
  // graded_split_gap_m of it without a cell (else a straggler region at both ends of a row is
  // sprayed across the flush middle). docs/architecture.md §5.
  PlannerConfig lines = pc;
  if (top == 1 && pc.graded_last_edge_overrun_m > 0.0) lines.edge_overrun_m = pc.graded_last_edge_overrun_m;
  rp.passes = plan_passes(in.wall.surface.grid, rp.region.cells, ctx.spacing_m, lines, ctx.lean, pc.graded_split_gap_m);
  if (rp.passes.empty()) return std::nullopt;
  for (auto& p : rp.passes) lengthen_short_pass(p, ctx.model.radius_m, pc.sample_step_m);
  const std::string where = round_name(in.number) + ", region " + std::to_string(ri);
  const double rebound = ctx.config.deposition.rebound_fraction;
  // The machine's speed caps along each pass: where one is below the pass's speed the arm slows
  // to it there, and lays more (PassPart). Waypoints with caps within 5 % of each other share a
  // part, at the lowest of their caps.
  std::vector<std::vector<double>> caps;
  std::vector<PassPart> parts;
  std::vector<Eigen::VectorXd> unit;  // per pass, at 1 m/s: the cells its passes reach
  std::vector<double> v_max;
  {
    std::vector<const Pass*> all;
    std::vector<std::string> names;
    for (std::size_t j = 0; j < rp.passes.size(); ++j) all.push_back(&rp.passes[j]), names.push_back(where + ", pass " + std::to_string(j));
    caps = ctx.caps(all, names);
  }
  // The level-1 rounds lay the last layer, and one speed per pass leaves the bay's end columns
  // short by what every earlier round left them short (seed 2: the level-2 round laid 63 mm on
  // column 0 and 75 mm inside): with graded_end_zone_m, a pass that runs on past a bay end has its
  // own speed over the last graded_end_zone_m of the bay and the run-on (speed variables
  // n_passes.., var_of per waypoint).
  std::vector<std::vector<std::size_t>> var_of(rp.passes.size());
  std::vector<std::size_t> owner;  // per speed variable: its pass
  for (std::size_t j = 0; j < rp.passes.size(); ++j) owner.push_back(j), var_of[j].assign(rp.passes[j].waypoints.size(), j);
  if (top == 1 && pc.graded_end_zone_m > 0.0 && pc.pass_direction == PassDirection::axial) {
    const Grid& g = in.wall.surface.grid;
    const double d_lo = g.d0_m, d_hi = g.d0_m + g.n_d * g.cell_size_m;
    for (std::size_t j = 0; j < rp.passes.size(); ++j) {
      const auto& w = rp.passes[j].waypoints;
      std::vector<double> d(w.size());
      for (std::size_t i = 0; i < w.size(); ++i) d[i] = g.axis.to_cylindrical(w[i].position_m)[2];
      const auto [lo, hi] = std::minmax_element(d.begin(), d.end());
      const bool at_lo = *lo < d_lo, at_hi = *hi > d_hi;  // runs on past that end
      std::size_t n_mid = 0;
      for (double x : d) n_mid += x >= d_lo + pc.graded_end_zone_m && x <= d_hi - pc.graded_end_zone_m;
      if (n_mid < 2) continue;
      std::size_t lo_var = 0, hi_var = 0;
      if (at_lo) lo_var = owner.size(), owner.push_back(j);
      if (at_hi) hi_var = owner.size(), owner.push_back(j);
      for (std::size_t i = 0; i < d.size(); ++i) {
        if (at_lo && d[i] < d_lo + pc.graded_end_zone_m) var_of[j][i] = lo_var;
        if (at_hi && d[i] > d_hi - pc.graded_end_zone_m) var_of[j][i] = hi_var;
      }
    }
  }
  for (std::size_t j = 0; j < rp.passes.size(); ++j) {
    const Pass& p = rp.passes[j];
    const auto& cap = caps[j];
    if (cap.size() != p.waypoints.size() || std::any_of(cap.begin(), cap.end(), [](double v) { return std::isnan(v); }))
      throw std::runtime_error(where + ", pass " + std::to_string(j) + ": the speed cap has no usable value");
    Pass unit_pass = p;
    unit_pass.speed_mps = 1.0;
    const std::vector<double> dwell = unit_pass.dwell_s();
    // (speed variable, cap bin) -> waypoints (bin -1: no cap binds)
    std::map<std::pair<std::size_t, long>, std::vector<std::size_t>> groups;
    for (std::size_t i = 0; i < cap.size(); ++i)
      groups[{var_of[j][i],
              cap[i] >= pc.max_speed_mps ? -1L : static_cast<long>(std::floor(std::log(pc.max_speed_mps / cap[i]) / std::log(1.05)))}]
          .push_back(i);
    unit.push_back(Eigen::VectorXd::Zero(static_cast<Eigen::Index>(cells.cell_ids.size())));
    for (const auto& [key, idx] : groups) {
      const auto [var, bin] = key;
      std::vector<NozzlePose> w;
      std::vector<double> d;
      double lowest = pc.max_speed_mps;
      for (std::size_t i : idx) w.push_back(p.waypoints[i]), d.push_back(dwell[i]), lowest = std::min(lowest, cap[i]);
      PassPart part{var, bin < 0 ? 0.0 : 1.0 / lowest, unit_deposit(ctx.model, cells, w, d, rebound)};
      unit.back() += part.unit;
      parts.push_back(std::move(part));
    }
    // The pass's own speed may reach the fastest cap along it (slower where the others bind),
    // and no faster than lasts the pump's shortest spell: a shorter pass is sprayed for
    // flow.min_on_s anyway, the rest on its leads where the nozzle slows (a 0.2 m pass at 1 m/s
    // laid 10x its deposit there, and four straggler rounds piled 3 mm a round on a cell beside
    // it to level -1); along the pass the speeds see it.
    const double v_spell = ctx.config.flow.min_on_s > 0 ? p.length_m / ctx.config.flow.min_on_s : pc.max_speed_mps;
    v_max.push_back(std::max(std::min(*std::max_element(cap.begin(), cap.end()), v_spell), pc.min_speed_mps * (1.0 + 1e-6)));
    if (*std::min_element(cap.begin(), cap.end()) < pc.max_speed_mps) ++ctx.plan.speed_capped;
  }
  for (std::size_t k = rp.passes.size(); k < owner.size(); ++k) v_max.push_back(v_max[owner[k]]);
  SpeedTargets targets = region_targets(in, cells, ctx, rp, unit);
  // Beyond the thesis, the speeds see what the round's other regions lay (their passes reach
  // into this one: 101 mm laid where 69 were asked) and what the timed passes lay beyond the
  // solve (leads, turns sprayed through, the pump's spells and ramps): the solve is repeated with
  // the difference as a fixed deposit (plan -> time -> simulate -> correct, as the levelling
  // rounds) and kept while the simulated deposit's cost falls. As there, the simulation is of the
  // passes as planned: ordering may reverse a region later (the same passes and turns backwards,
  // where the pump may decide otherwise; graded rounds keep the ordering's direction, planner.cpp).
  const bool executed = pc.graded_executed_corrections > 0 && !pc.graded_thesis_objective;
  auto solve = [&](const SpeedTargets& t, const std::vector<double>& v_start) {
    try {
      return optimise_speeds(parts, owner.size(), t, pc, v_max, v_start, owner);
    } catch (const std::runtime_error& e) {
      throw std::runtime_error(where + ": " + e.what());
    }
  };
  if (executed) targets.background_m = round_deposit_m;
  PassSpeeds speeds = solve(targets, {});
  std::vector<Pass> passes = passes_at(rp.passes, speeds, caps, ctx, var_of);
  Eigen::VectorXd sprayed = executed ? sprayed_passes(passes, cells, ctx).deposit_m : solved_deposit_m(parts, speeds);
  if (executed) {
    double best = graded_deposit_cost(targets, round_deposit_m + sprayed);
    for (int it = 0; it < pc.graded_executed_corrections; ++it) {
      SpeedTargets corrected = targets;
      corrected.background_m = round_deposit_m + sprayed - solved_deposit_m(parts, speeds);
      PassSpeeds speeds_next = solve(corrected, speeds.speeds_mps);
      std::vector<Pass> passes_next = passes_at(rp.passes, speeds_next, caps, ctx, var_of);
      Eigen::VectorXd sprayed_next = sprayed_passes(passes_next, cells, ctx).deposit_m;
      const double c = graded_deposit_cost(targets, round_deposit_m + sprayed_next);
      if (!(c < best)) break;
      best = c;
      speeds = std::move(speeds_next);
      passes = std::move(passes_next);
      sprayed = std::move(sprayed_next);
    }
  }
  if (top == 1 && !pc.graded_thesis_objective)
    drop_harmful_passes(in, cells, ctx, parts, speeds, owner, targets, round_deposit_m, executed, region.cells, passes, sprayed,
                        left_alone);
  if (passes.empty()) return std::nullopt;
  round_deposit_m += sprayed;
  rp.passes = std::move(passes);
  rp.note = speeds.note;
  if (!rp.note.empty()) ctx.plan.warnings.push_back(where + ": " + rp.note);
  return rp;
}

class GradedRounds : public RoundStages {
 public:
  explicit GradedRounds(double level_margin_m) : margin_mm_(1000.0 * level_margin_m) {}
  RoundKind kind() const override { return RoundKind::graded; }

  // The level the rounds work on: the cell's, except that a level-0 cell within the margin of
  // level 1's floor still counts as level 1. The executed deposit differs from the planner's by
  // up to about 0.6 mm on a cell, and a cell planned at +49.99 mm was executed at +50.02 mm
  // (level 1, the job not executable).
  int working_level(const SprayedWall& wall, int c) const {
    const int level = wall.surface.levels[c];
    return level == 0 && wall.surface.grid.td_m[c] * 1000.0 >= level_floor_mm(1) - margin_mm_ ? 1 : level;
  }

  std::vector<int> active_levels(const SprayedWall& wall) const override {
    std::vector<int> lv(wall.surface.levels.size());
    for (std::size_t c = 0; c < lv.size(); ++c) lv[c] = working_level(wall, static_cast<int>(c));
    for (std::size_t c = 0; c < set_aside_.size(); ++c)
      if (set_aside_[c]) lv[c] = kNoDataLevel;
    mask(lv);
    return lv;
  }

  bool finished(const Grade& grade) const override { return grade.top_level <= 0; }

  std::vector<RegionPlan> plan_regions(const RoundInput& in, const CellSurface& cells, RoundContext& ctx) override {
    const auto regions = find_regions(in.wall.surface.grid, active_levels(in.wall), in.grade.top_level,
                                      ctx.config.regions.min_region_cells);
    std::vector<RegionPlan> out;
    Eigen::VectorXd round_deposit_m = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(cells.cell_ids.size()));
    set_aside_.resize(in.wall.surface.grid.size(), 0);
    for (std::size_t ri = 0; ri < regions.size(); ++ri) {
      std::vector<int> left_alone;
      auto rp = graded_region(in, cells, ctx, regions[ri], ri, round_deposit_m, left_alone);
      // Cells at level 0 that only the margin put in a region and no pass helps: left as they
      // are, for good.
      const auto& cs = regions[ri].cells;
      if (!rp && std::all_of(cs.begin(), cs.end(), [&](int c) { return in.wall.surface.levels[c] == 0; }))
        left_alone.insert(left_alone.end(), cs.begin(), cs.end());
      for (int c : left_alone) set_aside_[c] = 1;
      if (!rp) continue;
      ctx.report(in.number, 0.6 * (ri + 1) / regions.size());
      out.push_back(std::move(*rp));
    }
    return out;
  }

  StopReason nothing_to_spray(const Grade&) const override {
    return {StopKind::no_progress, "no pass could be planned over the remaining cells"};
  }

  // Cells whose level the round could not lower are set aside (reported), so the rest of the bay
  // still gets finished; the graded rounds stop only when nothing is left.
  std::optional<StopReason> stop_test(const RoundInput& in, const Round& round, RoundContext& ctx) override {
    const int top = in.grade.top_level;
    std::vector<int> not_lowered;
    std::size_t sprayed = 0;
    for (const auto& r : round.regions) {
      sprayed += r.region.cells.size();
      for (int c : r.region.cells)
        if (working_level(in.wall, c) >= top) not_lowered.push_back(c);
    }
    if (not_lowered.size() == sprayed) {
      set_aside_.resize(in.wall.surface.grid.size(), 0);
      for (int c : not_lowered) set_aside_[c] = 1;
      ctx.plan.warnings.push_back(round_name(in.number) + ": " + std::to_string(not_lowered.size()) +
                                  " cells of level " + std::to_string(top) +
                                  " did not go down a level (too small a region or at the edge of the scan); set aside");
    }
    return std::nullopt;
  }

 private:
  std::vector<char> set_aside_;  // per cell
  double margin_mm_;              // planner.graded_level_margin_m
};

// ---------------------------------------------------------------------------------------------
// Levelling rounds (optimal mode): every cell short of flush, a dwell per segment

// The lines' pitch for a spacing ratio: the least ripple of equal lines near ratio x the two-pass
// spacing (closer lines than that spacing: at 0.5 the default spot's lines laid 5.6 % peak to
// peak across them, a ripple the speeds along the lines cannot take out; 8 mm RMS of row-to-row
// residual on seeds 1-3 against 2.7-2.8 mm along the rows).
double levelling_pitch_m(const PlannerConfig& pc, double ratio, const RoundContext& ctx) {
  const double nominal = ratio * ctx.spacing_m;
  if (pc.levelling_pitch_window <= 0) return nominal;
  const auto known = ctx.pitch_m.find(ratio);
  if (known != ctx.pitch_m.end()) return known->second;
  const double pitch_m =
      least_ripple_pitch(ctx.model, nominal * (1.0 - pc.levelling_pitch_window), nominal * (1.0 + pc.levelling_pitch_window)).pitch_m;
  ctx.pitch_m[ratio] = pitch_m;
  return pitch_m;
}

// How much more a cell above level 0 weighs in a levelling round that would otherwise spray nothing
// (tried in turn), and how far past flush that round may take a cell (level -1 from 50 mm).
constexpr double kStragglerGuard[] = {10.0, 100.0};
constexpr double kStragglerFloor_mm = 45.0;

// Whether a round on lines of pitch_m solves the look-ahead's later rounds on the wide lines: with
// the option, a look-ahead, and lines that are not the wide ones already.
constexpr double kLateLayerAllowance = 1.25;  // levelling_sides
bool lookahead_on_late_lines(const PlannerConfig& pc, const RoundContext& ctx, double pitch_m) {
  return pc.levelling_lookahead_late_lines && pc.levelling_lookahead_rounds > 1 &&
         std::abs(levelling_pitch_m(pc, pc.levelling_late_spacing_ratio, ctx) - pitch_m) > 1e-9;
}

// One set of pass lines over every cell still short of flush (even spacing across the crown), then
// split into the right and left walls so each side is sprayed bottom-up. The rounds after the
// first lay their lines at planner.levelling_late_spacing_ratio with levelling_late_edge_overrun_m
// (`late`: those lines for the look-ahead) once the layer left is thin: levelling_late_td_quantile
// (95 %) of the open cells miss no more than those lines lay in a round at the slowest speed (the
// first round leaves a few pits deeper; a small slice whose first round left 100 mm broadly ended
// its three rounds with 67 cells at level 1 on the wide lines). Where the first round's solve
// counted on the wide lines (levelling_lookahead_late_lines) it leaves nearly every cell open, and
// a few deeper pits cost another wide round over them only: 1.25 x that layer (seed 4: the 95th
// percentile at 118 mm against 116 took close lines over the whole wall, cycle-time ratio 1.456
// instead of 1.351; the small horseshoe slice, 60 % of its cells over 100 mm, still takes them).
std::vector<RegionPlan> levelling_sides(const RoundInput& in, const std::vector<int>& open_cells, RoundContext& ctx,
                                        bool late = false) {
  PlannerConfig pc = ctx.config.planner;
  const double late_pitch_m = levelling_pitch_m(pc, pc.levelling_late_spacing_ratio, ctx);
  double pitch_m = levelling_pitch_m(pc, pc.levelling_spacing_ratio, ctx);
  if (!late && in.number >= 2 && !open_cells.empty()) {
    const double late_layer_m = ctx.model.volume_rate_m3ps() * (1.0 - ctx.config.deposition.rebound_fraction) /
                                (pc.min_speed_mps * late_pitch_m);
    std::vector<double> td;
    for (int c : open_cells) td.push_back(in.wall.surface.grid.td_m[c]);
    const auto q = td.begin() + static_cast<long>(pc.levelling_late_td_quantile * static_cast<double>(td.size() - 1));
    std::nth_element(td.begin(), q, td.end());
    const bool counted_on = lookahead_on_late_lines(pc, ctx, pitch_m);
    late = *q <= late_layer_m * (counted_on ? kLateLayerAllowance : 1.0);
  }
  if (late) {
    pitch_m = late_pitch_m;
    pc.edge_overrun_m = pc.levelling_late_edge_overrun_m;
  }
  const Grid& grid = in.wall.surface.grid;
  const bool axial = pc.pass_direction == PassDirection::axial;
  // Closer lines than the two-pass spacing: the per-segment speeds then shape the layer
  // across the lines too (measured: RMS 6.5 mm instead of 10 mm on the default bay).
  const auto all = plan_passes(grid, open_cells, pitch_m, pc, ctx.lean);
  RegionPlan side[2];
  for (const auto& p : all) {
    const Eigen::Vector3d mid = p.waypoints[p.waypoints.size() / 2].position_m;
    const bool left = axial && grid.axis.to_cylindrical(mid)[1] > M_PI / 2;
    side[left ? 1 : 0].passes.push_back(p);
  }
  std::reverse(side[1].passes.begin(), side[1].passes.end());  // left wall: springline up
  for (auto& c : open_cells) side[axial && grid.theta_center(grid.row_of(c)) > M_PI / 2 ? 1 : 0].region.cells.push_back(c);
  std::vector<RegionPlan> sides;
  for (auto& rp : side) {
    if (rp.passes.empty()) continue;
    rp.region.level = in.grade.top_level;
    rp.spacing_m = pitch_m;
    sides.push_back(std::move(rp));
  }
  return sides;
}

// The sides' passes cut into segments about segment_length_m long, with their unit deposits on
// the cells and the machine's speed caps. Later lines (the look-ahead's, never sprayed) are
// numbered from first_side, past the round's own sides, and take no speed caps (the IK's cost).
void add_segments(const RoundInput& in, const CellSurface& cells, const std::vector<RegionPlan>& sides,
                  RoundContext& ctx, DwellProblem& problem, bool later = false, std::size_t first_side = 0) {
  const PlannerConfig& pc = ctx.config.planner;
  const double rebound = ctx.config.deposition.rebound_fraction;
  std::vector<const Pass*> all;
  std::vector<std::string> names;
  for (std::size_t s = 0; s < sides.size(); ++s)
    for (const Pass& pass : sides[s].passes)
      all.push_back(&pass), names.push_back(round_name(in.number) + ", side " + std::to_string(s) + ", line " + std::to_string(pass.line));
  std::vector<std::vector<double>> caps;
  if (later) {
    for (const Pass* pass : all) caps.emplace_back(pass->waypoints.size(), pc.max_speed_mps);
  } else {
    caps = ctx.caps(all, names);
  }
  std::size_t next = 0;
  for (std::size_t s = 0; s < sides.size(); ++s)
    for (std::size_t p = 0; p < sides[s].passes.size(); ++p) {
      const Pass& pass = sides[s].passes[p];
      const std::size_t nw = pass.waypoints.size();
      const std::vector<double>& cap = caps[next++];
      // Segments of equal length, about segment_length_m: a short last piece would bound the
      // speed change into it (limit_speed_changes) and starve the cells at the pass's end.
      const std::size_t per = std::max<std::size_t>(1, std::llround(pc.segment_length_m / pc.sample_step_m));
      const std::size_t n_seg = std::max<std::size_t>(1, static_cast<std::size_t>(std::llround(static_cast<double>(nw - 1) / static_cast<double>(per))));
      for (std::size_t k = 0; k < n_seg && nw >= 2; ++k) {
        Segment seg;
        seg.side = first_side + s;
        seg.pass = p;
        seg.later = later;
        seg.first = k * (nw - 1) / n_seg;
        seg.last = (k + 1) * (nw - 1) / n_seg;
        if (seg.last <= seg.first) continue;
        std::vector<NozzlePose> poses(pass.waypoints.begin() + seg.first, pass.waypoints.begin() + seg.last + 1);
        Pass piece;
        piece.waypoints = poses;
        piece.speed_mps = 1.0;
        seg.length_m = polyline_length(poses);
        // (Along the scan's normals the square pose is not the design's: no lean measured.)
        seg.lean_slowdown = pc.offset_along_normal ? 1.0
                                                   : lean_slowdown(poses, pc.standoff_m, in.wall.surface.grid.axis,
                                                                   in.wall.surface.grid.profile);
        seg.cap_mps = *std::min_element(cap.begin() + seg.first, cap.begin() + seg.last + 1);
        // thickness in mm per (s/m) of dwell: speed 1 m/s means dwell 1 s per metre.
        problem.unit_mm.push_back(sparsify(unit_deposit(ctx.model, cells, poses, piece.dwell_s(), rebound) * 1000.0));
        problem.segments.push_back(seg);
        if (!later && seg.cap_mps < pc.max_speed_mps) ++ctx.plan.speed_capped;
      }
    }
}

// Least squares, then the arm's speed-change limit; the capped segments become floors of the next
// solve so the others can compensate; the limiter has the last word. Each solve starts at the
// dwells before it (w: the first one's start; empty: all 0).
std::vector<double> limited_dwells(const DwellProblem& problem, std::vector<double> floor, double accel_mps2,
                                   std::vector<double> w = {}) {
  for (int it = 0; it < 3; ++it) {
    w = optimise_dwell(problem, floor, w);
    for (std::size_t j = 0; j < w.size(); ++j)  // the look-ahead's rest: later rounds (on later lines: theirs)
      if (!problem.segments[j].later) w[j] = std::min(w[j], round_dwell_max(problem, j));
    const auto limited = limit_speed_changes(problem.segments, w, accel_mps2);
    for (std::size_t j = 0; j < w.size(); ++j)
      if (limited[j] > w[j] * (1 + 1e-9)) floor[j] = std::max(floor[j], limited[j]);
    w = limited;
  }
  return w;
}

// The dwells with an on/off pattern the pump can follow: segments the pump would spray through
// are forced on (at least their fastest dwell) and stretches too short to switch on for are
// forced off (their deposit removed from the problem), then the least squares is solved again
// with that pattern, until flow_spell_fix has nothing left to change. w_start: where the first
// solve starts (empty: all 0).
std::vector<double> solve_dwells(DwellProblem problem, double accel_mps2, const FlowConfig& flow,
                                 const std::vector<double>& w_start = {}) {
  const std::size_t n = problem.segments.size();
  std::vector<double> floor(n, 0.0);
  std::vector<double> w = limited_dwells(problem, floor, accel_mps2, w_start);
  for (int it = 0; it < 6; ++it) {
    const FlowSpellFix fix = flow_spell_fix(problem, w, flow, accel_mps2);
    if (fix.empty()) break;
    for (std::size_t j : fix.force_on) floor[j] = std::max(floor[j], 1.0 / problem.segments[j].cap_mps);
    for (std::size_t j : fix.force_off) {
      problem.unit_mm[j] = Sparse();
      floor[j] = 0.0;
    }
    w = limited_dwells(problem, floor, accel_mps2, w);
  }
  return w;
}

// How near a tight end of its line (Pass::tight_*) a run of it starts or ends to be tight [m].
constexpr double kTightNearM = 0.4;

// Rebuild the passes of one side: runs of sprayed segments become passes with a per-waypoint speed.
RegionPlan sprayed_runs(const RegionPlan& side, std::size_t s, const std::vector<Segment>& segs,
                        const std::vector<double>& w) {
  RegionPlan out = side;
  out.passes.clear();
  for (std::size_t p = 0; p < side.passes.size(); ++p) {
    const Pass& pass = side.passes[p];
    std::vector<double> cum(pass.waypoints.size(), 0.0);  // length along the pass to each waypoint
    for (std::size_t a = 1; a < cum.size(); ++a)
      cum[a] = cum[a - 1] + (pass.waypoints[a].position_m - pass.waypoints[a - 1].position_m).norm();
    Pass cur;
    auto flush_cur = [&]() {
      if (cur.waypoints.size() >= 2) {
        cur.length_m = polyline_length(cur.waypoints);
        cur.speed_mps = cur.length_m / cur.duration_s();
        out.passes.push_back(cur);
      }
      cur = Pass();
    };
    for (std::size_t j = 0; j < segs.size(); ++j) {
      if (segs[j].later || segs[j].side != s || segs[j].pass != p) continue;
      if (w[j] <= 0) {
        flush_cur();
        continue;
      }
      const double v = 1.0 / w[j];
      const std::size_t from = cur.waypoints.empty() ? segs[j].first : segs[j].first + 1;
      // A run that starts or ends near a tight end of its line is tight too: a turn there runs on
      // 0.2 m and more, and 0.4 m back from the end the faded lean (clearance's default 0.5 rad/m
      // at a 1 m standoff) gains the nozzle about 0.25 m of room.
      if (cur.waypoints.empty()) {
        cur.line = pass.line;
        cur.tight_start = pass.tight_start && cum[segs[j].first] <= kTightNearM;
      }
      cur.tight_end = pass.tight_end && cum.back() - cum[segs[j].last] <= kTightNearM;
      for (std::size_t a = from; a <= segs[j].last; ++a) {
        cur.waypoints.push_back(pass.waypoints[a]);
        cur.speed_profile_mps.push_back(v);
      }
    }
    flush_cur();
  }
  return out;
}

// What a round's regions lay on the cells [mm per slot] (sprayed_passes) and the pump's on-time
// [s]. The order the round is later sprayed in may reverse a region, the same passes and turns
// backwards; where the pump then lays it differently, the region keeps this direction
// (keep_solved_directions, planner.cpp).
struct SprayedRound {
  Eigen::VectorXd deposit_mm;
  double on_time_s = 0;
};
SprayedRound sprayed_round(const std::vector<RegionPlan>& regions, const CellSurface& cells, const RoundContext& ctx) {
  SprayedRound out;
  out.deposit_mm = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(cells.cell_ids.size()));
  for (const auto& r : regions) {
    const SprayedPasses sprayed = sprayed_passes(r.passes, cells, ctx);
    out.deposit_mm += sprayed.deposit_m * 1000.0;
    out.on_time_s += sprayed.on_time_s;
  }
  return out;
}

class LevellingRounds : public RoundStages {
 public:
  RoundKind kind() const override { return RoundKind::levelling; }

  std::vector<int> active_levels(const SprayedWall& wall) const override {
    std::vector<int> lv = wall.surface.levels;
    mask(lv);
    return lv;
  }

  bool finished(const Grade& grade) const override {
    return grade.top_level <= 0 && grade.max_td_m <= tolerance_m_;
  }

  std::vector<RegionPlan> plan_regions(const RoundInput& in, const CellSurface& cells, RoundContext& ctx) override {
    const PlannerConfig& pc = ctx.config.planner;
    const Grid& grid = in.wall.surface.grid;
    // Every cell that still misses more than the tolerance is covered; the target is the TD.
    DwellProblem problem;
    problem.target_mm = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(cells.cell_ids.size()));
    std::vector<int> open_cells;
    for (std::size_t k = 0; k < cells.cell_ids.size(); ++k) {
      const int c = cells.cell_ids[k];
      problem.target_mm[k] = std::max(0.0, grid.td_m[c]) * 1000.0;  // mm
      if (grid.td_m[c] > pc.finish_tolerance_m) open_cells.push_back(c);
    }
    const std::vector<RegionPlan> sides = levelling_sides(in, open_cells, ctx);
    add_segments(in, cells, sides, ctx, problem);
    // A round on the close lines solves the look-ahead's later rounds on the wide lines they will
    // take, not on its own: a steep flank the close lines could follow in three rounds, a wide
    // round cannot (seed 1: round 2 laid 85 mm on a flank rising 25 mm a row, 35 mm over). Not in
    // the last round planner.max_rounds allows: nothing would lay what it leaves them.
    const std::size_t own_segments = problem.segments.size();
    if (!sides.empty() && in.number < pc.max_rounds && lookahead_on_late_lines(pc, ctx, sides.front().spacing_m))
      add_segments(in, cells, levelling_sides(in, open_cells, ctx, true), ctx, problem, true, sides.size());
    ctx.report(in.number, 0.3);
    problem.lambda_mm2_per_s = pc.time_weight_mm2_per_s;
    problem.w_max_s_per_m = 1.0 / pc.min_speed_mps;
    problem.lookahead_rounds = pc.levelling_lookahead_rounds;
    Eigen::VectorXd td_mm(static_cast<Eigen::Index>(cells.cell_ids.size()));
    for (std::size_t k = 0; k < cells.cell_ids.size(); ++k) td_mm[k] = grid.td_m[cells.cell_ids[k]] * 1000.0;
    set_guard(problem, td_mm, pc.levelling_guard_band_m * 1000.0, pc.levelling_guard_weight);
    const double accel = ctx.config.timing.speed_change_accel_mps2;
    auto runs_of = [&](const std::vector<double>& w) {
      std::vector<RegionPlan> out;
      for (std::size_t s = 0; s < sides.size(); ++s) {
        RegionPlan rp = sprayed_runs(sides[s], s, problem.segments, w);
        if (!rp.passes.empty()) out.push_back(std::move(rp));
      }
      return out;
    };
    std::vector<double> w = solve_dwells(problem, accel, ctx.config.flow);
    std::vector<RegionPlan> out = runs_of(w);
    if (out.empty() && problem.segments.size() > own_segments) {
      // The later lines took all there was to lay: this round sprays its own share after all.
      problem.segments.resize(own_segments);
      problem.unit_mm.resize(own_segments);
      w = solve_dwells(problem, accel, ctx.config.flow);
      out = runs_of(w);
    }
    // A round that lays a cell past -45 mm (level -1 from -50 mm) that was not, or more than
    // 0.5 mm on one that was (the retry below).
    auto sinks = [&](const Eigen::VectorXd& laid) {
      for (Eigen::Index k = 0; k < td_mm.size(); ++k)
        if (td_mm[k] - laid[k] < std::min(td_mm[k], -kStragglerFloor_mm) - 0.5) return true;
      return false;
    };
    bool straggling = false;
    if (out.empty() && problem.guard_weight > 0) {
      // Every segment left off while cells stay above level 0: the guard traded them for their
      // neighbours' over-fill (a cell at +55 mm among cells at -30 mm, which any spot over it
      // reaches; the bay left unfinished). Their own guard is raised, 10x then 100x (the others
      // keep theirs), and the round taken once its passes, timed and pumped, bring one of them
      // within level 0 and sink no cell (100x with no such test traded the scene without the
      // duct's 3 cells at +52 mm for 26 at up to -96 mm).
      std::vector<Eigen::Index> stragglers;
      for (Eigen::Index k = 0; k < td_mm.size(); ++k)
        if (level_of_td_mm(td_mm[k]) >= 1) stragglers.push_back(k);
      for (double raise : kStragglerGuard) {
        if (stragglers.empty()) break;
        DwellProblem raised = problem;
        raised.guard_weight_cell = Eigen::VectorXd::Constant(td_mm.size(), problem.guard_weight);
        for (Eigen::Index k : stragglers) raised.guard_weight_cell[k] *= raise;
        std::vector<double> w_raised = solve_dwells(raised, accel, ctx.config.flow);
        std::vector<RegionPlan> out_raised = runs_of(w_raised);
        if (out_raised.empty()) continue;
        const Eigen::VectorXd laid = sprayed_round(out_raised, cells, ctx).deposit_mm;
        const bool helps = std::any_of(stragglers.begin(), stragglers.end(),
                                       [&](Eigen::Index k) { return level_of_td_mm(td_mm[k] - laid[k]) <= 0; });
        if (!helps || sinks(laid)) continue;
        problem = std::move(raised);
        w = std::move(w_raised);
        out = std::move(out_raised);
        straggling = true;
        break;
      }
    }
    if (pc.levelling_executed_corrections <= 0 || out.empty()) return out;
    // The solve's segments are not what the arm and the pump do with them: the timed passes
    // change speed over ramps, turns too short for the pump's off spell are sprayed through,
    // short spells are lengthened. Re-solve with that difference as a fixed deposit (plan ->
    // time -> simulate -> correct) and keep the pattern whose own simulated deposit, with its
    // pump time at the time weight, costs least.
    SprayedRound sprayed = sprayed_round(out, cells, ctx);
    auto cost = [&](const SprayedRound& sr) {
      return deposit_cost(problem, sr.deposit_mm) + problem.lambda_mm2_per_s * sr.on_time_s;
    };
    double best = cost(sprayed);
    for (int it = 0; it < pc.levelling_executed_corrections; ++it) {
      DwellProblem corrected = problem;
      corrected.background_mm = sprayed.deposit_mm - solved_deposit_mm(problem, w);
      std::vector<double> w_next = solve_dwells(corrected, accel, ctx.config.flow, w);
      std::vector<RegionPlan> out_next = runs_of(w_next);
      if (out_next.empty()) break;
      SprayedRound sprayed_next = sprayed_round(out_next, cells, ctx);
      const double c = cost(sprayed_next);
      if (!(c < best) || (straggling && sinks(sprayed_next.deposit_mm))) break;
      best = c;
      w = std::move(w_next);
      out = std::move(out_next);
      sprayed = std::move(sprayed_next);
    }
    return out;
  }

  // Every segment was skipped: with the bay at level 0, no spraying pays off at the time weight.
  StopReason nothing_to_spray(const Grade& grade) const override {
    if (grade.top_level <= 0) return {StopKind::levelled, "no further pass pays off at planner.time_weight_mm2_per_s"};
    return {StopKind::no_progress, "no pass could be planned over the remaining cells"};
  }

  // With the time weight, the last cells off flush are not worth another round.
  std::optional<StopReason> stop_test(const RoundInput& in, const Round&, RoundContext&) override {
    const bool stalled = in.grade.max_td_m - max_td_m(worked_grid(in.wall.surface.grid)) <= 0.001;
    if (!stalled) return std::nullopt;
    if (top_level(active_levels(in.wall)) <= 0)
      return StopReason{StopKind::levelled, "another round would lower the largest TD by less than 1 mm"};
    return StopReason{StopKind::no_progress, "a levelling round lowered the largest TD by less than 1 mm"};
  }

  explicit LevellingRounds(double finish_tolerance_m) : tolerance_m_(finish_tolerance_m) {}

 private:
  double tolerance_m_;
};

}  // namespace

std::unique_ptr<RoundStages> graded_rounds(double level_margin_m) { return std::make_unique<GradedRounds>(level_margin_m); }
std::unique_ptr<RoundStages> levelling_rounds(double finish_tolerance_m) {
  return std::make_unique<LevellingRounds>(finish_tolerance_m);
}

}  // namespace shotcrete
