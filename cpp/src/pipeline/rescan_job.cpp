#include "shotcrete/pipeline/rescan_job.hpp"

#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "shotcrete/surface/preprocess.hpp"

namespace shotcrete {
namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::string percent(double share) {
  std::ostringstream s;
  s << std::lround(share * 100.0) << "%";
  return s.str();
}

Cloud checked(const Cloud& cloud, const IoConfig& io, const char* name) {
  try {
    check_cloud(cloud, io);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string(name) + ": " + e.what());
  }
  return io.unit_scale != 1.0 ? scale_cloud(cloud, io.unit_scale) : cloud;
}

}  // namespace

ReferenceTest reference_test(const Config& config, ReferenceArea area, const Grid* grid,
                             const Eigen::VectorXd* predicted_deposit_m, const Cloud* mask) {
  switch (area) {
    case ReferenceArea::dry:
      if (grid == nullptr || predicted_deposit_m == nullptr)
        throw std::invalid_argument("rescan.reference dry needs the job's grid and predicted deposit");
      return dry_reference(*grid, *predicted_deposit_m, config.rescan, config.profile.max_deviation_m);
    case ReferenceArea::box:
      return box_reference(config.rescan);
    case ReferenceArea::mask:
      if (mask == nullptr) throw std::invalid_argument("rescan.reference mask needs a mask cloud");
      return mask_reference(*mask, config.rescan);
  }
  throw std::invalid_argument("rescan.reference: unknown reference area");
}

Config calibrated_config(const Config& config, double flow_factor) {
  Config cal = config;
  cal.deposition.peak_rate_mps = config.deposition.peak_rate_mps * flow_factor;
  validate(cal);
  return cal;
}

RescanOutcome rescan_job(const Grid& grid, const Eigen::VectorXd& predicted_deposit_m, const Cloud& before_in,
                         const Cloud& after_in, const Config& config, const Cloud* mask,
                         const Eigen::Matrix4d& initial, const Robot* robot, const ProgressFn& progress) {
  auto report = [&](const char* stage, double fraction) {
    if (progress) progress(stage, fraction);
  };
  if (predicted_deposit_m.size() != grid.size())
    throw std::invalid_argument("rescan: predicted deposit has " + std::to_string(predicted_deposit_m.size()) +
                                " values for a grid of " + std::to_string(grid.size()) + " cells");
  const Cloud before = checked(before_in, config.io, "before-scan");
  const Cloud after = checked(after_in, config.io, "after-scan");
  RescanOutcome out;

  report("register", 0.0);
  auto t0 = std::chrono::steady_clock::now();
  const ReferenceTest test = reference_test(config, config.rescan.reference, &grid, &predicted_deposit_m, mask);
  out.registration = register_scans(before, after, test, config.rescan, initial);
  out.register_s = seconds_since(t0);
  report("register", 1.0);

  t0 = std::chrono::steady_clock::now();
  const Cloud after_reg = transform_cloud(after, out.registration.transform);
  out.thickness = measure_cells(grid, before, after_reg, config.rescan);
  out.measure_s = seconds_since(t0);
  // The before-scan must show the TD the job planned on, cell by cell.
  const int cells = grid.valid_count();
  int both = 0, miss = 0;
  double sq = 0.0;
  for (int c = 0; c < grid.size(); ++c) {
    const double a = out.thickness.before_td_m[c], b = grid.td_m[c];
    if (!std::isfinite(a) || !std::isfinite(b)) continue;
    ++both;
    sq += (a - b) * (a - b);
    miss += std::abs(a - b) > kRescanMatchTd_m;
  }
  if (both < 0.5 * cells)
    throw std::invalid_argument("before-scan: only " + std::to_string(both) + " of the job's " + std::to_string(cells) +
                                " cells hold before points (not the bay the job planned, or another axis)");
  out.before_td_rms_m = std::sqrt(sq / both);
  out.before_td_miss_share = static_cast<double>(miss) / both;
  if (out.before_td_miss_share > kRescanMatchMissShare)
    throw std::invalid_argument("before-scan: " + percent(out.before_td_miss_share) +
                                " of the job's cells show a TD more than " +
                                std::to_string(std::lround(kRescanMatchTd_m * 1000)) +
                                " mm from the job's (not the scan the job planned on)");
  if (out.thickness.measured < 0.5 * cells)
    throw std::invalid_argument("after-scan: only " + std::to_string(out.thickness.measured) + " of the job's " +
                                std::to_string(cells) +
                                " cells could be measured (the after-scan does not cover the bay)");
  out.comparison = compare_cells(out.thickness.thickness_m, predicted_deposit_m);
  try {
    out.calibration = calibrate_flow(out.thickness.thickness_m, predicted_deposit_m, config.rescan);
  } catch (const std::invalid_argument& e) {
    out.calibration_error = e.what();
  }
  if (robot == nullptr || !out.calibration) return out;

  report("correction", 0.0);
  t0 = std::chrono::steady_clock::now();
  out.calibrated = calibrated_config(config, out.calibration->factor);
  // wall_points is the bay already; sprayed near flush it would look lined to grid.bay detect.
  out.correction_config = *out.calibrated;
  out.correction_config->grid.bay = BaySelection::whole;
  // A thin finishing layer: the last cells off flush are worth more seconds than in a first round.
  out.correction_config->planner.time_weight_mm2_per_s = config.rescan.correction_time_weight_mm2_per_s;
  // ... and laid on lines at the two-pass spacing: one pump spell on the job's close lines lays
  // more than its thin cells need.
  out.correction_config->planner.levelling_spacing_ratio = config.rescan.correction_spacing_ratio;
  out.correction_config->planner.levelling_pitch_window = 0.0;  // that spacing itself (near a ripple minimum)
  // Its end cells need too little for a spell of their own: the lines run on further past the ends.
  out.correction_config->planner.edge_overrun_m = config.rescan.correction_edge_overrun_m;
  // Every round of the correction alike (its layer is thin from the first).
  out.correction_config->planner.levelling_late_spacing_ratio = config.rescan.correction_spacing_ratio;
  out.correction_config->planner.levelling_late_edge_overrun_m = config.rescan.correction_edge_overrun_m;
  // The rig that sprays the correction stands where it stood for the job (the robot given).
  out.correction_config->robot.place_base = false;
  const Cloud wall = wall_points(grid, after_reg, out.thickness.residual_td_m, kRescanWallBand_m);
  out.correction_surface = build_surface(wall, *out.correction_config);
  out.correction = plan_for_arm(*out.correction_surface, *out.correction_config, *robot, progress);
  out.correction_s = seconds_since(t0);
  report("correction", 1.0);
  return out;
}

}  // namespace shotcrete
