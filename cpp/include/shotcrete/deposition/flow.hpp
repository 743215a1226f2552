#pragma once
// The pump's flow (docs/architecture.md §9): a wet-mix pump cannot switch the concrete flow at
// will; spells on and off last at least FlowConfig's minimums and every switch ramps.
#include <vector>

#include "shotcrete/config.hpp"

namespace shotcrete {

/// The pump's flow over time: spells [on_s[k], off_s[k]] with the flow on, each ramping linearly
/// from 0 to full over ramp_s centred on on_s[k] and back over ramp_s centred on off_s[k] (so a
/// ramp lays the same volume as an ideal step at the switching instant).
struct FlowSchedule {
  std::vector<double> on_s, off_s;  // sorted, off_s[k] - on_s[k] >= min_on_s, gaps >= min_off_s
  double ramp_s = 0.0;
  double commanded_on_s = 0.0;  // flow-on time the spraying flags (or the program) ask for
  double bridged_s = 0.0;       // off-gaps shorter than min_off_s the flow stayed on through
  double extended_s = 0.0;      // flow-on time added to spells shorter than min_on_s
  double trimmed_s = 0.0;       // commanded flow-on time cut off the ends of two spells to widen a gap
                                // to min_off_s (cheaper than bridging it)
  double dropped_s = 0.0;       // commanded flow-on time switched off: spells or their ends the pump
                                // could not serve without spraying into a joint move
  int commanded_switches = 0;   // on and off switches the flags (or the program) ask for
  /// On and off switches of the schedule.
  int switches() const { return 2 * static_cast<int>(on_s.size()); }
  /// Shortest spell with the flow on / off between two spells [s] (0 when there is none).
  double shortest_on_s() const;
  double shortest_off_s() const;
  /// Flow-on time of the schedule (ramps lay as much as steps) [s].
  double on_time_s() const;
  /// Flow (share of full, 0..1) at time t.
  double flow_at(double t_s) const;
  /// Integral of the flow from -infinity to t [s of full flow].
  double integral_to(double t_s) const;
};

/// The schedule the pump runs for the spraying flags of samples at t_s (strictly increasing): the
/// flags ask for the flow over each flagged sample's share of time (from the midpoint with its
/// previous sample to the midpoint with its next; the first and last samples reach the ends), as
/// spray_dwells does; an off-gap shorter than min_off_s is widened to it by cutting the ends of the
/// spells around it (trimmed_s) when that cuts less than the gap and both keep min_on_s, else
/// bridged; spells shorter than min_on_s are extended about their middle (within [t_s.front(),
/// t_s.back()]), until both hold.
/// `blocked` (empty, or one flag per sample): samples where the flow must be off, ramps included:
/// the joint moves, where the arm swings the nozzle from rest to rest (spraying there piles concrete
/// where it stands and streaks it across the wall). Spells are clipped to end and start half a ramp
/// clear of them, are never bridged across one and grow only within the free time between two; a
/// spell that cannot reach min_on_s there, or the shorter of two spells closer than min_off_s
/// around one, is switched off (dropped_s). `ends_blocked`: the samples lie between two joint
/// moves as time_plan joins a region to its transits: the first sample is the last of the move
/// before (its share blocked), the move after starts one sample interval after the last. Throws
/// std::invalid_argument for unequal sizes, non-increasing times or a config that validate rejects.
FlowSchedule flow_schedule(const std::vector<double>& t_s, const std::vector<char>& spraying, const FlowConfig& flow,
                           const std::vector<char>& blocked = {}, bool ends_blocked = false);

/// The schedule the pump runs for a program of commanded spells [on_s[k], off_s[k]] (sorted, not
/// empty, apart, within [t_s.front(), t_s.back()]) over samples at t_s: a program laid out on other
/// durations (the planner's timing of a region, run on the arm's): a spell or gap that came out
/// shorter than its minimum is first stretched into its neighbours' slack (gaps beyond min_off_s,
/// spells beyond min_on_s, the free time to the ends of its window between joint moves; counted as
/// extended / trimmed), then the rules of flow_schedule apply. Throws std::invalid_argument for a malformed program and as flow_schedule.
FlowSchedule program_schedule(const std::vector<double>& on_s, const std::vector<double>& off_s,
                              const std::vector<double>& t_s, const FlowConfig& flow,
                              const std::vector<char>& blocked = {}, bool ends_blocked = false);

/// Full-flow dwell of every sample: the schedule's flow integrated over the sample's share of
/// time (midpoints with its neighbours; the first and last samples take everything before / after),
/// every dwell >= 0 (rounding below 0 is cut); the dwells add up to the schedule's on_time_s (to
/// rounding).
std::vector<double> flow_dwells(const FlowSchedule& schedule, const std::vector<double>& t_s);

}  // namespace shotcrete
