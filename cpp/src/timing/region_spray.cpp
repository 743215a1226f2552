// The spray of one region along its timed Cartesian path (see region_spray.hpp).
#include "shotcrete/timing/region_spray.hpp"

#include "shotcrete/timing/region_path.hpp"
#include "shotcrete/timing/sampling.hpp"

namespace shotcrete {

RegionSpray region_spray(const std::vector<Pass>& passes, const Config& config) {
  const TimingConfig& tc = config.timing;
  const TimingParams params = TimingParams::from_config(tc);
  const auto [lead_in_m, lead_out_m] = lead_lengths(passes, params, tc.nozzle_max_accel_mps2, tc.nozzle_max_accel_mps2);
  const CartesianPath path = timing_region_path(passes, lead_in_m, lead_out_m, tc);
  TimingParams leads = params;
  leads.start_length_m = lead_in_m;
  leads.end_length_m = lead_out_m;
  const CartesianSamples cs = sample_path(path, region_profile(path, leads), tc.trajectory_rate_hz);
  RegionSpray out;
  out.t_s = cs.t_s;
  out.nozzle = cs.nozzle;
  out.pass_index = cs.pass_index;
  // The stop-and-go middles are joint moves in time_plan, and so are the transits into and out of
  // the region: the pump is off through them, ramps included.
  std::vector<char> blocked(cs.t_s.size(), 0);
  for (std::size_t k = 0; k < cs.t_s.size(); ++k) {
    double local = 0.0;
    blocked[k] = path.pieces()[path.locate(cs.s_m[k], local)].motion == PieceMotion::RestToRest;
  }
  out.flow = flow_schedule(cs.t_s, cs.spraying, config.flow, blocked, /*ends_blocked=*/true);
  out.spraying = cs.spraying;
  out.blocked = std::move(blocked);
  out.dwell_s = flow_dwells(out.flow, cs.t_s);
  return out;
}

}  // namespace shotcrete
