#pragma once
// The nozzle path of a region and its speed profile (docs/architecture.md §8).
//
// Region path: lead-in (straight run-up before the first pass, length start_length_m) -> pass ->
// [extension line] -> half circle (diameter = pass spacing) -> [extension line] -> pass ... ->
// lead-out (run-out after the last pass, length end_length_m). Pass speeds are set by the
// deposition, so the nozzle reaches cruise speed before a pass starts and sprays only on passes
// (and on the turns when spray_on_turns is set).
#include <utility>
#include <vector>

#include "shotcrete/config.hpp"  // TimingConfig
#include "shotcrete/planning/planner.hpp"  // Pass
#include "shotcrete/timing/cartesian_path.hpp"
#include "shotcrete/timing/speed_profile.hpp"

namespace shotcrete {

/// How region_path builds the lead-in, lead-out and the joins between consecutive passes.
struct RegionPathOptions {
  double lead_in_m = 0.1;   // straight run-up before the first pass (> 0: the nozzle starts from rest)
  double lead_out_m = 0.1;  // straight run-out after the last pass (> 0: it stops there)
  bool spray_on_turns = false;
  int first_pass_index = 0;  // global number of the first pass
  double turn_run_m = 0.0;   // straight runs before / after a turn arc; stop-and-go runs (0.1 m if 0)
  /// > 0: the run-out / run-in of a stop-and-go join are lengthened so that their plain cycloidal
  /// stop and start (region_profile: no cruise, peak v^2 / length) stay within that acceleration
  /// at the pass end speeds.
  double stop_accel_mps2 = 0.0;
  double turn_speed_mps = 0.0;  // arc speed the turn runs are sized for (0: the pass speeds)
  /// > 0 (with turn_run_m > 0): the runs before and after a turn arc are lengthened so that the
  /// change between the pass speed and the arc speed (region_profile's, from turn_speed_mps and the
  /// centripetal cap at turn_accel_mps2) peaks at turn_accel_mps2.
  double turn_accel_mps2 = 0.0;
  /// > 0: a turn whose arc runs at its own speed and would be shorter gets runs long enough for
  /// an arc speed at which runs + arc last this long (region_profile slows it so; the pump's off
  /// spell, timing.min_turn_s).
  double min_turn_s = 0.0;
  /// Empty, or one value in (0, 1] per gap between consecutive passes: scales stop_accel_mps2 and
  /// turn_accel_mps2 for that gap alone, and the turn arc's accel_scale (the profile's arc speed):
  /// time_plan eases only the joins where the arm needs it.
  std::vector<double> gap_accel_scale;
};

/// Region path: lead-in, passes joined by turn-arounds (serpentine as given), lead-out. Two
/// consecutive passes that are not serpentine neighbours (not running opposite ways side by side,
/// e.g. pieces of one line in optimal mode) are joined by stop-and-go instead: run-out along the
/// pass with a cycloidal stop, a straight rest-to-rest move, run-in with a cycloidal start. A pass
/// that continues the previous one along its line (straight to 1 mm, or the same Pass::line >= 0
/// at most 0.5 m ahead and less far across than along) is joined by a spray-off gap without a stop. A
/// pass with a speed profile (optimal mode) keeps it: constant-speed runs with the planner's dwell
/// semantics (waypoint i owns half of each neighbouring interval at speed_at(i)), joined by
/// cycloidal changes centred on the run boundaries (peak speed_change_accel_mps2).
/// Throws std::invalid_argument for an empty region, a pass with fewer than 2 waypoints or a
/// non-positive speed, or options out of range.
CartesianPath region_path(const std::vector<Pass>& passes, const RegionPathOptions& options);

/// The region path time_plan times (and the swarm's RegionJointModel models): region_path with the
/// config's turn runs, stop-and-go runs sized for timing.nozzle_max_accel_mps2 and turn runs sized
/// for the config's turn speed at timing.turn_accel_mps2 (speed_change_accel_mps2 when 0). The geometry depends on the
/// config only, never on the tuned TimingParams (they shape the speed profile along it), so one
/// joint path serves every particle of the swarm.
CartesianPath timing_region_path(const std::vector<Pass>& passes, double lead_in_m, double lead_out_m,
                                 const TimingConfig& timing, int first_pass_index = 0,
                                 const std::vector<double>& gap_accel_scale = {});

/// Tunable timing parameters (the swarm's particle).
struct TimingParams {
  double k1 = 0.5;                // start: share of Ts spent accelerating
  double k2 = 0.5;                // end: share of Te spent cruising
  double start_length_m = 0.1;    // lead-in length
  double end_length_m = 0.1;      // lead-out length
  double min_lead_s = 0.0;        // least duration of a lead (lead_lengths; not tuned)
  double turn_speed_mps = 0.0;    // speed in the middle of a turn-around; 0 = pass speeds
  double speed_change_accel_mps2 = 0.5;  // peak of speed changes inside a pass and of the
                                         // centripetal acceleration on turn arcs (not tuned)
  double turn_accel_mps2 = 0.0;  // centripetal acceleration capping the turn arc speed when > 0
                                 // (tuned); 0 = speed_change_accel_mps2
  double min_turn_s = 0.0;       // a turn at its own speed is slowed to last at least this (runs +
                                 // arc), within the turn acceleration; 0 = none (not tuned)
  static TimingParams from_config(const TimingConfig& config);
};

/// Lead-in and lead-out lengths [m] of a region: at least params' start / end lengths, and long
/// enough for the paper's start and end profiles to stay within the accelerations at the first and
/// last pass speeds (start peak v^2 (2 - k1) / (k1 s), end peak v^2 (1 + k2) / ((1 - k2) s)), and
/// for them to last at least params.min_lead_s (a start of length s lasts 2 s / (v (2 - k1)), an
/// end 2 s / (v (1 + k2))): the pump's ramp runs on the leads, clear of the joint moves around.
std::pair<double, double> lead_lengths(const std::vector<Pass>& passes, const TimingParams& params,
                                       double start_accel_mps2, double end_accel_mps2);

/// Speed profile of a region path built by region_path (same lead lengths): cycloid start, pass
/// speeds on passes and links, cycloidal speed changes on turns (pass speed -> turn speed -> next
/// pass speed, or pass speed -> next pass speed when turn_speed_mps == 0; with turn runs the
/// changes happen on the runs and the arc runs at the turn speed), cycloid end (k1, k2 on the lead-in
/// and lead-out; stop-and-go runs stop and start without a cruise).
SpeedProfile region_profile(const CartesianPath& path, const TimingParams& params);

/// Quintic baseline: every pass extended by its acceleration / deceleration run, straight
/// step-overs, full stop at every corner. The step-over cruises at stepover_speed_mps.
struct BaselinePath {
  CartesianPath path;
  SpeedProfile profile;
};
BaselinePath quintic_baseline(const std::vector<Pass>& passes, double max_accel_mps2, double stepover_speed_mps,
                              int first_pass_index = 0);

}  // namespace shotcrete
