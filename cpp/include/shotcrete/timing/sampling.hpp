#pragma once
// Sampling of a timed Cartesian path at a fixed rate, the spray dwell of each sample and the
// nozzle speed / acceleration check (docs/architecture.md §8).
#include <vector>

#include "shotcrete/deposition/deposition.hpp"  // NozzlePose
#include "shotcrete/timing/cartesian_path.hpp"
#include "shotcrete/timing/speed_profile.hpp"

namespace shotcrete {

struct CartesianSamples {
  std::vector<double> t_s;
  std::vector<double> s_m;
  std::vector<NozzlePose> nozzle;
  std::vector<double> speed_mps, tangential_accel_mps2, normal_accel_mps2;
  std::vector<char> spraying;
  std::vector<int> pass_index;
  std::vector<char> kind;  // SegmentKind
};

/// Samples at t = 0, 1/rate, ... and always the end time.
CartesianSamples sample_path(const CartesianPath& path, const SpeedProfile& profile, double rate_hz);

/// Dwell per sample for accumulate_dwells: each spraying sample stands for the time from the
/// midpoint with its previous sample to the midpoint with its next one (so the dwells of a pass add
/// up to its duration); non-spraying samples dwell 0.
std::vector<double> spray_dwells(const std::vector<double>& t_s, const std::vector<char>& spraying);

struct NozzleLimits {
  double max_speed_mps = 1.0;
  double max_accel_mps2 = 2.0;
};
/// Largest speed / limit and |acceleration| / limit (tangential and centripetal) on a dense sampling.
struct NozzleCheck {
  double max_speed_mps = 0.0, max_accel_mps2 = 0.0;
  double speed_ratio = 0.0, accel_ratio = 0.0;
  bool ok() const { return speed_ratio <= 1.0 + 1e-9 && accel_ratio <= 1.0 + 1e-9; }
};
NozzleCheck check_nozzle(const CartesianPath& path, const SpeedProfile& profile, const NozzleLimits& limits,
                         double rate_hz = 500.0);

}  // namespace shotcrete
