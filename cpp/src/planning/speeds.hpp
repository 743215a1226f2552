#pragma once
// Nozzle speeds of the planner's rounds: BOBYQA speeds per pass (graded rounds), least-squares
// dwell per segment and the arm's speed-change limit (levelling rounds), and the machine's speed
// caps along a pass.
#include <cstddef>
#include <string>
#include <vector>

#include "shotcrete/planning/planner.hpp"

namespace shotcrete {

// ---------------------------------------------------------------------------------------------
// Graded rounds: one speed per pass

struct PassSpeeds {
  std::vector<double> speeds_mps;  // per speed variable: one per pass, then any end speeds (tied_to)
  std::string note;                // why the target cannot be met, if so
};

/// What the passes of one region should lay, per cell slot (unit_per_pass's index).
struct SpeedTargets {
  std::vector<int> slots;            // the region's cells
  std::vector<double> target_m;      // per region slot: the thickness it should get
  std::vector<int> guard_slots;      // cells kept from over-filling (what the passes reach outside the
                                     // region; in the last round also the region's own cells)
  std::vector<double> guard_max_m;   // per guard slot: the most it may get before it is over-filled
  double guard_weight = 1.0;         // cost of a metre over a guard limit, relative to a metre off target
  Eigen::VectorXd background_m;      // per cell slot: deposit the speeds do not control, laid anyway
                                     // (other regions of the round, the timed passes' difference from
                                     // the solve); empty: none
};

/// The objective's cell terms at a deposit given per cell slot [m], background included: how good
/// a deposit, however laid (the timed passes' simulated one), is for the region.
double graded_deposit_cost(const SpeedTargets& targets, const Eigen::VectorXd& deposit_m);

/// BOBYQA speeds of the passes of one region: minimise
///   sum_region |t_c - T_c(v)| + guard_weight * sum_guard max(0, T_c(v) - max_c)
/// with T_c(v) the passes' deposit plus the background.
/// (the thesis's sum |Td - T_s(V)|, with a target per cell, and the cells around the region that
/// its spray reaches kept from over-filling). unit_per_pass[j][slot]: thickness on a cell slot from
/// pass j at 1 m/s. v_max: per pass upper bound (the machine's speed cap, at most max_speed_mps,
/// above min_speed_mps). One pass is solved exactly by a golden-section search. Throws
/// std::invalid_argument on an ill-posed problem, std::runtime_error if NLopt fails.
PassSpeeds optimise_speeds(const std::vector<Eigen::VectorXd>& unit_per_pass, const SpeedTargets& targets,
                           const PlannerConfig& cfg, const std::vector<double>& v_max);

/// Part of a pass with the machine's speed cap: at the pass's dwell w [s/m] (1 / speed) it lays
/// unit * max(w, w_floor_s_per_m), for the arm slows to its cap there whatever the pass speed
/// (w_floor = 1 / cap; 0 for the part where no cap binds).
struct PassPart {
  std::size_t pass = 0;
  double w_floor_s_per_m = 0.0;
  Eigen::VectorXd unit;  // thickness per cell slot at 1 m/s
};
/// The same with passes given as parts (each pass needs at least one).
/// v_start (empty: one common speed): where the search starts, e.g. the speeds of the same region
/// solved with another background (BOBYQA's first steps then a tenth of the speeds, not a quarter).
/// tied_to (empty: none): per speed variable, the one it follows while BOBYQA searches (itself for
/// a searched one; a pass's end speeds follow the pass's own); the polish that finishes the search
/// then moves every variable on its own. Keeps BOBYQA's dimension at the passes' count.
PassSpeeds optimise_speeds(const std::vector<PassPart>& parts, std::size_t n_passes, const SpeedTargets& targets,
                           const PlannerConfig& cfg, const std::vector<double>& v_max,
                           const std::vector<double>& v_start = {}, const std::vector<std::size_t>& tied_to = {});

// ---------------------------------------------------------------------------------------------
// Levelling rounds: one dwell per segment

/// Sparse thickness vector over the cell slots (entries above 1e-9).
struct Sparse {
  std::vector<int> idx;
  std::vector<double> val;
};
Sparse sparsify(const Eigen::VectorXd& v);

/// A constant-speed piece of a pass line of the levelling round, one dwell variable.
struct Segment {
  std::size_t side = 0, pass = 0;   // which region (wall side) and which of its passes
  std::size_t first = 0, last = 0;  // waypoint range [first, last]
  double length_m = 0;
  double cap_mps = 0;               // fastest speed the machine allows on the segment
  bool later = false;               // a line of the look-ahead's later rounds: solved for, never sprayed
  double lean_slowdown = 1;         // a square nozzle's path to the same spots / this nozzle's: a
                                    // leaning nozzle moves slower than its spot (lean_slowdown())
};

/// The least-squares problem of the levelling round:
///   min 1/2 |x - t|^2 + sum_c guard_weight_c/2 [(x - hi)_c+^2 + (lo - x)_c+^2] + lambda L.w,
///   x = U w + background, w in {0} u [w_min, w_max_j] (w: dwell per unit length [s/m]; w_max_j:
///   dwell_bounds, guard_weight_c: guard_weight or guard_weight_cell).
/// The guard (planner.levelling_guard_*) holds every cell's final residual within a band: least
/// squares alone trades a few big errors for many small ones (a pit filled at the cost of its
/// shoulders over-filled 40 mm). Both terms are convex in w, so is the objective.
struct DwellProblem {
  std::vector<Segment> segments;
  std::vector<Sparse> unit_mm;   // per segment: thickness [mm] on the cell slots per s/m of dwell
  Eigen::VectorXd target_mm;     // per cell slot
  Eigen::VectorXd background_mm; // per cell slot: deposit the dwells do not control, laid anyway (empty: none)
  Eigen::VectorXd guard_hi_mm;   // per cell slot: deposit beyond which a cell counts as over-filled (empty: no guard)
  Eigen::VectorXd guard_lo_mm;   // per cell slot: deposit below which it counts as under-filled (empty: no guard)
  double guard_weight = 0;       // cost of a mm past a guard limit, relative to a mm off target (squared)
  Eigen::VectorXd guard_weight_cell;  // per cell slot: its own guard_weight (empty: guard_weight for all)
  double lambda_mm2_per_s = 0;   // planner.time_weight_mm2_per_s
  double w_max_s_per_m = 0;      // dwell at the slowest speed: the most a round sprays (a leaning
                                 // nozzle's segment: x its lean_slowdown, round_dwell_max)
  int lookahead_rounds = 1;      // the solve may give a segment lookahead_rounds x its round's most
                                 // (round_dwell_max; the rounds after this one add the rest); the
                                 // round sprays at most that.
                                 // With segments of later lines (Segment::later): this round's
                                 // take their round's most, the later lines (lookahead_rounds - 1)
                                 // x theirs.
};

/// The most dwell the solve gives each segment [s/m] (DwellProblem::lookahead_rounds).
std::vector<double> dwell_bounds(const DwellProblem& problem);

/// The most dwell one round gives segment j [s/m]: the slowest speed is the spot's over the wall,
/// so a leaning nozzle, which moves slower than a square one over the same spots, may move slower
/// by its Segment::lean_slowdown.
inline double round_dwell_max(const DwellProblem& problem, std::size_t j) {
  return problem.w_max_s_per_m * problem.segments[j].lean_slowdown;
}

/// How much slower the poses' nozzle moves than a square nozzle aimed at the same spots: the
/// length of the path of a nozzle standing standoff_m back along the design's normal (radial on a
/// circle) from each pose's spot (the point standoff_m along its axis), over the nozzle's own
/// path. 1 for square poses (the two paths are the same), never below 1, at most
/// kMaxLeanSlowdown. A nozzle whose lean toward a face fades at a rate along its pass moves at
/// about 1 - rate x standoff of a square one's speed (clearance.nozzle_lean_fade_rad_per_m).
constexpr double kMaxLeanSlowdown = 4.0;
double lean_slowdown(const std::vector<NozzlePose>& poses, double standoff_m, const TunnelAxis& axis,
                     const DesignProfile& profile);

/// Guard limits for cells with TD td_mm [mm] (negative: over-filled): over-filled past band_mm
/// beyond flush (a cell already past it may take nothing more), under-filled past band_mm short of
/// flush.
void set_guard(DwellProblem& problem, const Eigen::VectorXd& td_mm, double band_mm, double weight);

/// Coordinate descent for the dwells (each coordinate minimised exactly: the objective is
/// piecewise quadratic along it); w_min[j] = 1 / cap of segment j (the nozzle cannot spray
/// faster); w_floor[j] > 0 forces segment j to spray with at least that dwell (from the limiter).
/// Dwells up to lookahead_rounds x w_max: the caller clips them to one round's. The descent starts
/// at w_start (clamped to the bounds, NaN as 0; empty: every dwell 0): the solve of a problem a little
/// changed (a floor more, a fixed deposit) starts at the last one's dwells. It stops when a sweep
/// moves no dwell by 1e-4 of the largest bound, when ten sweeps lower the objective by less than
/// 1e-4 of it (kDwellObjectiveTolerance), or after 300 sweeps.
std::vector<double> optimise_dwell(const DwellProblem& problem, const std::vector<double>& w_floor,
                                   const std::vector<double>& w_start = {});

/// The objective of DwellProblem at dwells w (for tests and reports).
double dwell_objective(const DwellProblem& problem, const std::vector<double>& w);

/// The objective's cell terms (no time term) at a deposit given per cell slot [mm], background
/// included: how good a deposit, however laid, is for the problem.
double deposit_cost(const DwellProblem& problem, const Eigen::VectorXd& deposit_mm);

/// The arm cannot change the nozzle speed at will: caps the dwells so that speed changes along
/// every pass line stay within accel_mps2 (see speeds.cpp).
std::vector<double> limit_speed_changes(const std::vector<Segment>& segs, std::vector<double> w, double accel_mps2);

/// The deposit the solve means: sum_j w_j U_j over this round's segments (not the later lines'),
/// background not included [mm per cell slot].
Eigen::VectorXd solved_deposit_mm(const DwellProblem& problem, const std::vector<double>& w);

/// What the pump needs of the segments' on/off pattern: segments to force on (with at least
/// their fastest dwell) and to force off, so that along every pass line each spray-off gap between
/// two sprayed stretches lasts at least min_off_s and each sprayed stretch at least min_on_s (times
/// margin_ratio: the trajectory's speed changes shift the times a little). A short gap is sprayed
/// through; a stretch shorter than half the minimum is switched off, a longer one lengthened over
/// its off neighbours (their time counted at the fastest speed accel_mps2 lets the nozzle reach
/// from the stretch, as limit_speed_changes allows). Where the segments forced on would lay, at
/// their fastest dwell, more than 5 mm past the guard's upper limit of a cell (guarded problems
/// only), the stretch is switched off instead of lengthened and the gap widened instead of sprayed
/// through (the ends of the stretches beside it switched off until it lasts min_off_s).
struct FlowSpellFix {
  std::vector<std::size_t> force_on, force_off;
  bool empty() const { return force_on.empty() && force_off.empty(); }
};
FlowSpellFix flow_spell_fix(const DwellProblem& problem, const std::vector<double>& w, const FlowConfig& flow,
                            double accel_mps2, double margin_ratio = 1.2);

// ---------------------------------------------------------------------------------------------
// The machine's speed caps

/// Per waypoint of a pass: the fastest speed the machine allows there (the SpeedCapFn), clamped to
/// [min, max] speed; max speed everywhere without one. A cap below the slowest speed is reported
/// once per pass in `warnings` (the pass is sprayed at the slowest speed there).
class WaypointCaps {
 public:
  WaypointCaps(SpeedCapFn fn, const PlannerConfig& config, std::vector<std::string>& warnings)
      : fn_(std::move(fn)), config_(config), warnings_(warnings) {}
  /// The caps of several passes at once: the SpeedCapFn runs on them in parallel (every SpeedCapFn
  /// of the core is safe from several threads: arm_speed_caps, plan_for_arm's cache), the checks
  /// and warnings follow in pass order. `where` names each pass in warnings and errors ("round 2,
  /// region 3, pass 1").
  std::vector<std::vector<double>> operator()(const std::vector<const Pass*>& passes, const std::vector<std::string>& where);
  bool active() const { return static_cast<bool>(fn_); }
  double seconds() const { return seconds_; }  // time spent in the SpeedCapFn

 private:
  std::vector<double> checked(const Pass& pass, const std::vector<double>& c, const std::string& where);
  SpeedCapFn fn_;
  const PlannerConfig& config_;
  std::vector<std::string>& warnings_;
  double seconds_ = 0.0;
};

}  // namespace shotcrete
