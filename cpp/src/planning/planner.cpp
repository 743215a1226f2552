// The planner's round loop: grade -> plan the round -> order -> deposit -> stop test, with the
// steps that differ between graded and levelling rounds in rounds.cpp.
#include "shotcrete/planning/planner.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>

#include "rounds.hpp"
#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/ordering/ordering.hpp"
#include "shotcrete/timing/region_spray.hpp"

namespace shotcrete {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Adds what a region's passes lay on the wall (per point) to `deposit`, sprayed as the trajectory
// and the pump will spray them (region_spray: timed Cartesian path, flow schedule); returns the
// pump's on-time.
double add_region_deposit(const std::vector<Pass>& passes, const SurfaceIndex& index, const SpotModel& model,
                          const Config& config, Eigen::VectorXd& deposit) {
  const RegionSpray spray = region_spray(passes, config);
  accumulate_dwells(model, index, spray.nozzle, spray.dwell_s, config.deposition.rebound_fraction, deposit);
  return spray.flow.on_time_s();
}
struct RegionDeposit {
  Eigen::VectorXd deposit_m;  // per point of the cloud
  double on_time_s = 0;
};
RegionDeposit region_deposit(const std::vector<Pass>& passes, const SurfaceIndex& index, const SpotModel& model,
                             const Config& config) {
  RegionDeposit out;
  out.deposit_m = Eigen::VectorXd::Zero(index.cloud().size());
  out.on_time_s = add_region_deposit(passes, index, model, config, out.deposit_m);
  return out;
}
// Per region of a round: its deposit where already simulated (the direction check), else empty.
using KnownDeposits = std::vector<std::optional<RegionDeposit>>;

// A levelling region the ordering reversed is sprayed the other way than its speeds were solved
// for (against its own timed deposit), and the pump's rules do not run the same both ways (a gap
// near flow.min_off_s bridged one way and kept the other: 24 mm apart on seed 6's second round, 3
// cells over-filled to level -1). Where the reversed region lays more than kReversalTolerance_m
// differently anywhere, it keeps the direction it was solved in, and the round's transit length is
// that of the order so kept. Graded rounds keep the ordering's directions: their speeds follow the
// target thickness, not a solve in one direction (and keeping the solved directions there left 7
// cells at level -1 on seed 4 where the ordering's left none).
constexpr double kReversalTolerance_m = 0.002;

// A region's passes sprayed the other way: their order and each pass reversed.
void reverse_passes(std::vector<Pass>& passes) {
  std::reverse(passes.begin(), passes.end());
  for (auto& p : passes) reverse_pass(p);
}

void keep_solved_directions(Round& round, const OrderingProblem& problem, std::vector<bool> reversed,
                            const SurfaceIndex& index, const SpotModel& model, const Config& config,
                            KnownDeposits& known) {
  bool changed = false;
  for (std::size_t k = 0; k < round.regions.size(); ++k) {
    RegionPlan& r = round.regions[k];
    if (!r.reversed) continue;
    std::vector<Pass> solved = r.passes;
    reverse_passes(solved);
    RegionDeposit kept = region_deposit(r.passes, index, model, config);
    RegionDeposit other = region_deposit(solved, index, model, config);
    if (kept.deposit_m.size() == 0 ||
        (kept.deposit_m - other.deposit_m).cwiseAbs().maxCoeff() <= kReversalTolerance_m) {
      known[k] = std::move(kept);
      continue;
    }
    known[k] = std::move(other);
    r.passes = std::move(solved);
    r.reversed = false;
    reversed[static_cast<std::size_t>(round.order[k])] = false;
    changed = true;
  }
  if (changed) round.link_length_m = link_length(problem, round.order, reversed);
}

// Order: the shortest transit through the round's regions, from where the nozzle is; a reversed
// levelling region keeps its solved direction where the pump would lay it differently.
KnownDeposits order_regions(Round& round, const std::optional<Eigen::Vector3d>& start, const SurfaceIndex& index,
                            const SpotModel& model, const Config& config) {
  KnownDeposits known(round.regions.size());
  if (round.regions.empty()) return known;
  OrderingProblem problem;
  for (const auto& r : round.regions) {
    problem.a_m.push_back(r.entry_m());
    problem.b_m.push_back(r.exit_m());
  }
  problem.start_m = start;
  const OrderingResult res = solve_ordering(problem, config.ordering);
  std::vector<RegionPlan> ordered;
  for (int i : res.order) {
    RegionPlan r = round.regions[i];
    if (res.reversed[i]) {
      reverse_passes(r.passes);
      r.reversed = true;
    }
    ordered.push_back(std::move(r));
  }
  round.regions = std::move(ordered);
  round.order = res.order;
  round.link_length_m = res.link_length_m;
  round.order_method = res.method;
  if (round.kind == RoundKind::levelling) keep_solved_directions(round, problem, res.reversed, index, model, config, known);
  return known;
}

// Deposit: each region sprayed on the full cloud as the trajectory and the pump will spray it
// (region_spray: timed Cartesian path, flow schedule; the direction check's deposit where it
// simulated the region already), then the wall re-graded. `index` is of the wall before the round.
void spray_round(Round& round, SprayedWall& wall, const SurfaceIndex& index, const SpotModel& model,
                 const Config& config, Plan& plan, const KnownDeposits& known) {
  Eigen::VectorXd deposit = Eigen::VectorXd::Zero(wall.surface.cloud.size());
  for (std::size_t k = 0; k < round.regions.size(); ++k) {
    if (known[k]) {
      deposit += known[k]->deposit_m;
      round.spray_time_s += known[k]->on_time_s;
      continue;
    }
    round.spray_time_s += add_region_deposit(round.regions[k].passes, index, model, config, deposit);
  }
  deposit_layer(wall, deposit);
  plan.deposited_m += deposit;
  round.levels_after = level_counts(wall.surface.levels);
  round.td_after_m = wall.surface.grid.td_m;
  plan.spray_time_s += round.spray_time_s;
}

// Why the loop ended when no stage gave a reason: flush, cells set aside, or the round limit.
StopReason stop_after_loop(const SprayedWall& wall, const RoundStages& stages) {
  if (top_level(wall.surface.levels) <= 0) return {StopKind::flush, ""};
  if (top_level(stages.active_levels(wall)) <= 0)
    return {StopKind::no_progress, "the cells set aside stay above level 0"};
  return {StopKind::max_rounds, ""};
}

// The plan's summary of the sprayed wall and the physical limit of the spraying time.
void finish_plan(Plan& plan, const SprayedWall& wall, const Surface& surface, const SpotModel& model, double rebound,
                 const RoundStages& stages) {
  const Grid& grid = wall.surface.grid;
  for (int c = 0; c < grid.size(); ++c)
    if (grid.valid[c] && wall.surface.levels[c] > 0 && !stages.excluded(c)) plan.unreachable_cells.push_back(c);
  plan.td_after_m = grid.td_m;
  plan.sprayed_cloud = wall.surface.cloud;
  plan.required_volume_m3 = missing_volume_m3(surface.grid);
  plan.deposition_rate_m3ps = model.volume_rate_m3ps() * (1.0 - rebound);
  plan.physical_limit_s = plan.required_volume_m3 / plan.deposition_rate_m3ps;
}

}  // namespace

Plan plan_bay(const Surface& surface, const Config& config, const ProgressFn& progress, const SpeedCapFn& speed_cap,
              const std::vector<int>& excluded_cells, const std::vector<Eigen::Vector3d>& lean) {
  validate(config);
  const auto t_start = Clock::now();
  const PlannerConfig& pc = config.planner;
  const SpotModel model = spot_model_from_config(config.deposition);
  const double rebound = config.deposition.rebound_fraction;
  const double spacing = pass_spacing(model, 0.07).spacing_m;  // scale-free in the target
  if (!surface.cloud.has_normals()) throw std::invalid_argument("plan_bay: the surface cloud has no normals");

  Plan plan;
  plan.grid_before = surface.grid;
  SprayedWall wall = unsprayed_wall(surface, config.profile.max_deviation_m);
  plan.deposited_m = Eigen::VectorXd::Zero(surface.cloud.size());
  plan.timings_s["setup"] = seconds_since(t_start);
  WaypointCaps caps(speed_cap, pc, plan.warnings);
  if (!lean.empty() && lean.size() != static_cast<std::size_t>(surface.grid.size()))
    throw std::invalid_argument("plan_bay: lean has " + std::to_string(lean.size()) + " entries for " +
                                std::to_string(surface.grid.size()) + " grid cells");
  RoundContext ctx{config, model, spacing, caps, plan, progress, lean.empty() ? nullptr : &lean};
  const std::unique_ptr<RoundStages> stages =
      pc.mode == PlannerMode::graded ? graded_rounds(pc.graded_level_margin_m) : levelling_rounds(pc.finish_tolerance_m);
  if (!excluded_cells.empty()) {
    std::vector<char> mask(static_cast<std::size_t>(surface.grid.size()), 0);
    for (int c : excluded_cells)
      if (c >= 0 && c < surface.grid.size()) mask[static_cast<std::size_t>(c)] = 1;
    stages->exclude(std::move(mask));
  }
  std::optional<Eigen::Vector3d> nozzle_at;
  std::optional<StopReason> stop;
  for (int number = 1; number <= pc.max_rounds && !stop; ++number) {
    // Grade (the grid without the excluded cells, the same for grading and planning the round).
    const Grid worked = stages->worked_grid(wall.surface.grid);
    const RoundInput in{number, {top_level(stages->active_levels(wall)), max_td_m(worked)}, wall};
    if (stages->finished(in.grade)) break;  // the reason is settled after the loop
    // A round is never cut short (its deposit would be half a pattern); the budget only keeps the
    // next one from starting, and the plan says so.
    if (number > 1 && seconds_since(t_start) > pc.time_budget_s) {
      stop = StopReason{StopKind::time_budget, "after round " + std::to_string(number - 1) + ", " +
                                                   std::to_string(std::lround(seconds_since(t_start))) + " s"};
      break;
    }
    ctx.report(number, 0.0);
    const auto t_round = Clock::now();
    Round round;
    round.kind = stages->kind();
    round.level = in.grade.top_level;
    round.levels_before = level_counts(wall.surface.levels);
    // Plan the round.
    const std::vector<int> active_before = stages->active_levels(wall);
    round.regions = stages->plan_regions(in, CellSurface(worked), ctx);
    if (round.regions.empty()) {
      // Planning may have set cells aside (graded: level-0 cells of the margin that no pass
      // helps): finished, or another round over the cells left.
      const std::vector<int> active_after = stages->active_levels(wall);
      if (stages->finished({top_level(active_after), in.grade.max_td_m})) break;
      if (active_after != active_before) continue;
      stop = stages->nothing_to_spray(in.grade);
      break;
    }
    // Order, deposit, stop test.
    // One index of the wall as it stands for the ordering's direction check and the deposit.
    const SurfaceIndex index(wall.surface.cloud, 0.05);
    const KnownDeposits known = order_regions(round, nozzle_at, index, model, config);
    nozzle_at = round.regions.back().exit_m();
    ctx.report(number, 0.7);
    spray_round(round, wall, index, model, config, plan, known);
    plan.timings_s["round_" + std::to_string(number)] = seconds_since(t_round);
    plan.rounds.push_back(std::move(round));
    ctx.report(number, 1.0);
    stop = stages->stop_test(in, plan.rounds.back(), ctx);
  }
  plan.stop_reason = stop ? *stop : stop_after_loop(wall, *stages);
  if (plan.stop_reason.kind == StopKind::time_budget)
    plan.warnings.push_back("planning stopped before it finished: planner.time_budget_s (" +
                            std::to_string(std::lround(pc.time_budget_s)) + " s) spent, " + plan.stop_reason.detail);
  finish_plan(plan, wall, surface, model, rebound, *stages);
  if (caps.active()) plan.timings_s["speed_caps"] = caps.seconds();
  plan.timings_s["total"] = seconds_since(t_start);
  return plan;
}

}  // namespace shotcrete
