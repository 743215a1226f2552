#pragma once
// The closed loop on a finished job (docs/architecture.md §12): the after-scan registered to the
// before-scan on the reference areas, the layer measured per cell, measured vs predicted, the flow
// calibrated and the corrective round planned for the arm on the measured residual. One function
// that the Python API / CLI (shotcrete.rescan) and the ROS node (~rescan) both call.
#include <Eigen/Core>
#include <optional>
#include <string>

#include "shotcrete/config.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/rescan/rescan.hpp"
#include "shotcrete/surface/surface.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

class Robot;

/// The after-scan's points the corrective round plans on: within this of the measured wall (radially).
constexpr double kRescanWallBand_m = 0.1;
/// A before-scan whose TD along the cells' rays differs from the job's by more than
/// kRescanMatchTd_m in more than kRescanMatchMissShare of the cells is not the scan the job planned
/// on (a share, not an RMS: a few cells of a crossing surface the job gridded must not refuse it).
constexpr double kRescanMatchTd_m = 0.02;
constexpr double kRescanMatchMissShare = 0.1;

/// The reference test of `area`: dry needs the job's grid and predicted deposit per cell, mask a
/// cloud (std::invalid_argument, one line, otherwise).
ReferenceTest reference_test(const Config& config, ReferenceArea area, const Grid* grid,
                             const Eigen::VectorXd* predicted_deposit_m, const Cloud* mask);

/// `config` with the deposition rate scaled by the calibrated flow factor (validated).
Config calibrated_config(const Config& config, double flow_factor);

struct RescanOutcome {
  Registration registration;
  CellThickness thickness;              // per cell of the job's grid, after-scan registered
  double before_td_rms_m = 0.0;         // before-scan's TD along the rays vs the job's, RMS
  double before_td_miss_share = 0.0;    // share of cells beyond kRescanMatchTd_m
  Comparison comparison;                // measured - predicted per cell
  std::optional<Calibration> calibration;
  std::string calibration_error;        // why there is no calibration (too few sprayed cells)
  // With a robot and a calibration: the calibrated config (deposition rate x factor), the config
  // the corrective round was planned with (that one with grid.bay whole: the measured wall is the
  // bay already), its surface (the after-scan's wall points) and the round planned for the arm.
  std::optional<Config> calibrated, correction_config;
  std::optional<Surface> correction_surface;
  std::optional<ArmPlan> correction;
  double register_s = 0.0, measure_s = 0.0, correction_s = 0.0;
};

/// The re-scan of a job: `before` (the scan the job planned on, with its surroundings) and `after`
/// (any frame near before's) checked (check_cloud, "before-scan: ..." / "after-scan: ...") and
/// scaled by io.unit_scale; `after` registered to `before` on config.rescan.reference (dry: what
/// `predicted_deposit_m` left unsprayed; box; mask: near `mask`, before frame) from `initial`
/// (after -> before); the layer per cell of `grid` (the job's, TD before per cell) by M3C2, checked
/// against the job (the before-scan's TD must match the job's, at least half the cells measured);
/// measured vs `predicted_deposit_m` (per cell, NaN: none); the flow factor; and with a `robot` the
/// corrective round: plan_for_arm on the after-scan's wall points (wall_points, kRescanWallBand_m)
/// with the calibrated rate. Throws std::invalid_argument / std::runtime_error, one line, for
/// unusable input (empty or NaN clouds, another bay, too little overlap, no reference area).
RescanOutcome rescan_job(const Grid& grid, const Eigen::VectorXd& predicted_deposit_m, const Cloud& before,
                         const Cloud& after, const Config& config, const Cloud* mask = nullptr,
                         const Eigen::Matrix4d& initial = Eigen::Matrix4d::Identity(), const Robot* robot = nullptr,
                         const ProgressFn& progress = {});

}  // namespace shotcrete
