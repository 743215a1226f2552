#pragma once
// Re-scan after spraying (docs/architecture.md §12): the after-scan registered to the before-scan on
// areas the job left unsprayed, the layer measured along the wall normal (M3C2, Lague et al. 2013),
// and the flow calibrated from measured vs predicted thickness.
#include <Eigen/Core>
#include <functional>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

/// The job's grid rebuilt from its cells (cells.csv: row, col, theta and d of each valid cell centre)
/// on the lattice of build_grid: cell edge `cell_size_m` along d and of arc at the design radius.
/// td_before_m (per listed cell) fills td_m; the other cells are invalid. Throws
/// std::invalid_argument, one line, when the cells are not on one such lattice (another cell size or
/// radius) or a value is not finite.
Grid grid_from_cells(const TunnelAxis& axis, const DesignProfile& profile, double cell_size_m,
                     const std::vector<int>& rows, const std::vector<int>& cols,
                     const std::vector<double>& theta_rad, const std::vector<double>& d_m,
                     const std::vector<double>& td_before_m);

/// Which points (in the before frame) are reference areas: unsprayed and unchanged between scans.
/// Called from several threads at once (register_scans): it must only read its state.
using ReferenceTest = std::function<bool(const Eigen::Vector3d& p_m)>;

/// rescan.reference dry: a point is reference unless it lies within profile band max_deviation_m of
/// the design line and within reference_margin_m (on the unrolled wall) of a cell whose predicted
/// deposit is at least dry_threshold_m (NaN counts as sprayed). Context off the grid is reference.
ReferenceTest dry_reference(const Grid& grid, const Eigen::VectorXd& predicted_deposit_m,
                            const RescanConfig& config, double max_deviation_m);
/// rescan.reference box: inside [reference_box_min_m, reference_box_max_m].
ReferenceTest box_reference(const RescanConfig& config);
/// rescan.reference mask: within mask_radius_m of a point of `mask` (throws for an empty mask).
ReferenceTest mask_reference(const Cloud& mask, const RescanConfig& config);

struct Registration {
  Eigen::Matrix4d transform = Eigen::Matrix4d::Identity();  // after -> before: p_before = T p_after
  double rms_m = 0.0;        // RMS distance of the matched after reference points to the before-scan's local plane
                             // (8 nearest points): scanner noise plus what registration left
  double overlap = 0.0;      // share of after reference points with a before point within fine_correspondence_m
  int iterations = 0;        // GICP iterations, both stages
  long target_points = 0;    // before reference points (voxelled)
  long source_points = 0;    // after reference points (voxelled, last stage)
  double time_s = 0.0;
};

/// Registers `after` to `before` on the reference areas: starts from `initial` (the known rig pose;
/// identity when the scanner frame did not change), keeps the points the test accepts (after points
/// through the current estimate), thins both (as many random points as voxels of voxel_size_m),
/// then GICP (PCL, covariances from 20 neighbours) twice: coarse_correspondence_m on clouds thinned
/// at twice the voxel edge, then fine_correspondence_m with the reference of the after-scan
/// re-selected through the coarse estimate. Throws std::invalid_argument for too few
/// reference points (min_reference_points) and std::runtime_error when GICP does not converge or the
/// overlap is below min_overlap (not the same place, or a wrong initial pose).
Registration register_scans(const Cloud& before, const Cloud& after, const ReferenceTest& reference,
                            const RescanConfig& config,
                            const Eigen::Matrix4d& initial = Eigen::Matrix4d::Identity());

/// Applies a rigid transform to every point (normals rotated).
Cloud transform_cloud(const Cloud& cloud, const Eigen::Matrix4d& transform);

/// M3C2 (Lague, Brodu, Leroux 2013): per core point i, the points of each cloud inside the cylinder
/// of radius cylinder_radius_m around the line through core[i] along normal[i], within
/// cylinder_half_length_m of core[i] along it; distance = mean projection of `after` minus that of
/// `before` onto the normal (each cloud's points first reduced to its wall: the densest stretch of
/// one cylinder radius along the axis whose points centre in the cross-section, trimmed to 3.5
/// robust std devs of its median; a surface crossing the cylinder, like the face where the wall
/// ends, lies spread along it on one side and is not the wall); its 95 % level of detection 1.96 sqrt(s1^2 / n1 + s2^2 / n2)
/// (s: std dev of the projections, the local roughness; n: counts). NaN where either cloud has
/// fewer than min_cylinder_points points.
struct M3C2Result {
  Eigen::VectorXd distance_m, lod95_m, before_std_m, after_std_m;
  Eigen::VectorXi before_count, after_count;
};
M3C2Result m3c2(const Points& core, const Points& normals, const Cloud& before, const Cloud& after,
                const RescanConfig& config);

/// m3c2 at wall points (per point on request): each core point's normal is the design line's
/// normal toward `axis` (the radial direction on a circle; as per cell).
M3C2Result measure_points(const TunnelAxis& axis, const Points& core, const Cloud& before, const Cloud& after,
                          const RescanConfig& config, const DesignProfile& profile = DesignProfile::circle(1.0));

/// The layer per grid cell: M3C2 along the cell's ray (the design surface's normal at the cell
/// centre: radial, the wall normal at the scale of the bay), the cylinder centred on the wall as
/// scanned before (design radius + the cell's TD). thickness = before - after projection (positive:
/// concrete toward the axis); residual = TD before - thickness. Points are binned on the grid's
/// lattice, so a measurement costs O(points). NaN where not measurable. before_td_m: the before
/// points' mean along the ray less the design radius (the TD the before-scan shows there: it must
/// match the job's, or the before-scan is not the one the job planned on).
struct CellThickness {
  Eigen::VectorXd thickness_m, lod95_m, residual_td_m, before_std_m, after_std_m, before_td_m;
  Eigen::VectorXi before_count, after_count;
  int measured = 0;  // cells with a thickness
};
CellThickness measure_cells(const Grid& grid, const Cloud& before, const Cloud& after_registered,
                            const RescanConfig& config);

/// The points of `cloud` on the measured wall: in a valid cell of `grid` with a finite `wall_td_m`
/// (per cell, e.g. the measured residual TD) and within band_m of it radially. The bay as the
/// corrective round sees it, without the context or a surface crossing the bay's ends (the face);
/// with the normals when the cloud has them (the corrective round estimates its own).
Cloud wall_points(const Grid& grid, const Cloud& cloud, const Eigen::VectorXd& wall_td_m, double band_m);

/// Measured vs predicted per cell over the cells where both are finite [m]: measured - predicted.
struct Comparison {
  double bias_m = 0.0, rms_m = 0.0, max_abs_m = 0.0;
  int cells = 0;
};
Comparison compare_cells(const Eigen::VectorXd& measured_m, const Eigen::VectorXd& predicted_m);

/// The flow (deposition) scale factor: measured = factor x predicted, least squares through the
/// origin over the cells predicted to get at least calibration_min_deposit_m, refitted without the
/// cells beyond 3 robust std devs (1.4826 MAD) of the fit until none is dropped (at most 5 times).
/// Throws std::invalid_argument when fewer than 10 cells qualify.
struct Calibration {
  double factor = 1.0;
  double std_error = 0.0;   // standard error of the factor
  int cells = 0;            // cells in the final fit
  int rejected = 0;         // cells dropped as outliers
  double residual_rms_m = 0.0;  // RMS of measured - factor x predicted over the fit's cells
};
Calibration calibrate_flow(const Eigen::VectorXd& measured_m, const Eigen::VectorXd& predicted_m,
                           const RescanConfig& config);

}  // namespace shotcrete
