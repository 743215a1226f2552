#pragma once
// What the nozzle lays along one region when it follows the region's timed Cartesian path
// (docs/architecture.md §5 and §9): the planner deposits its rounds with this, so that its
// estimate includes what the trajectory does to the planned speeds (cycloidal speed changes,
// leads, turns) and what the pump does to the planned spray (minimum spells, ramps).
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"  // NozzlePose
#include "shotcrete/deposition/flow.hpp"
#include "shotcrete/planning/planner.hpp"  // Pass

namespace shotcrete {

struct RegionSpray {
  std::vector<double> t_s;           // sample times from the start of the lead-in
  std::vector<NozzlePose> nozzle;    // nozzle pose of every sample
  std::vector<double> dwell_s;       // full-flow dwell of every sample (flow_dwells)
  std::vector<int> pass_index;       // the region's pass a sample lies on (-1 off the passes)
  std::vector<char> spraying;        // the commanded spray (passes, joins sprayed through)
  std::vector<char> blocked;         // the flow must be off (the stop-and-go middles: joint moves)
  FlowSchedule flow;                 // the pump's schedule over the region
  double duration_s() const { return t_s.empty() ? 0.0 : t_s.back(); }
};

/// The region's passes as time_plan lays them out (timing_region_path with lead_lengths at the
/// nozzle acceleration limit, region_profile with the config's timing parameters), sampled at
/// timing.trajectory_rate_hz, with the pump's flow schedule (config.flow) over its spraying flags.
/// The arm's own re-timing (joint limits, tuned parameters) is not modelled: the planner's speed
/// caps keep the passes within the arm's reach of the Cartesian timing. Throws
/// std::invalid_argument as region_path does.
RegionSpray region_spray(const std::vector<Pass>& passes, const Config& config);

}  // namespace shotcrete
