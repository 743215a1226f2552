#pragma once
// Deposition model (docs/architecture.md §4): spot model fitted to the measured stroke, closed-form
// stroke profile, free-form thickness rate on a cloud with normals, accumulation along nozzle
// paths, rebound, and the golden-section pass spacing.
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/types.hpp"  // Cloud, NozzlePose

namespace shotcrete {

/// Spot model at the reference standoff H0: q(r) = q_max (1 - r^2/R^2)^(beta - 1) for r <= R.
/// Rates are thickness per second in m/s (sprayed, before rebound).
/// Defaults are the config defaults (the fit of data/deposition_stroke.csv).
struct SpotModel {
  double reference_standoff_m = DepositionConfig{}.reference_standoff_m;  // H0
  double radius_m = DepositionConfig{}.spot_radius_m;                     // R at H0
  double beta = DepositionConfig{}.spot_beta;                             // spot exponent
  double peak_rate_mps = DepositionConfig{}.peak_rate_mps;                // q_max

  double rate_at(double r_m) const;
  double cone_half_angle_rad() const;  // atan(R / H0)
  /// Sprayed volume per second: integral of q over the disc = q_max * pi R^2 / beta [m^3/s].
  double volume_rate_m3ps() const;
};

/// The spot model of the config (deposition section). Throws std::invalid_argument if
/// peak_rate_mps <= 0 (there is no implicit fit: run `shotcrete deposition fit` and set it), if
/// spot_radius_m <= 0 or spot_beta < 1.
SpotModel spot_model_from_config(const DepositionConfig& config);

/// Closed-form cross profile of a straight pass at speed v over a plane at H0:
/// T(x) = (q_max / v) R B(1/2, beta) (1 - x^2/R^2)^(beta - 1/2)   [m].
double stroke_thickness_m(const SpotModel& model, double x_m, double speed_mps);

/// A measured stroke: thickness across one pass (metres), with its standoff and speed. The stroke
/// is what stayed on the wall, i.e. after a rebound of `rebound_fraction`.
struct StrokeData {
  std::vector<double> position_m;
  std::vector<double> thickness_m;
  double standoff_m = 1.0;
  double speed_mps = 0.15;
  double rebound_fraction = 0.08;
};
/// Reads position_mm,thickness_mm CSV (header line optional); throws std::invalid_argument for
/// < 5 rows, non-numeric cells, negative or all-zero thickness, non-positive standoff/speed.
StrokeData read_stroke_csv(const std::string& path, double standoff_m = 1.0, double speed_mps = 0.15,
                           double rebound_fraction = 0.08);

struct StrokeFit {
  SpotModel model;               // sprayed rates: q_max = deposited fit / (1 - rebound)
  double stroke_exponent = 0.0;  // beta - 1/2
  double peak_thickness_m = 0.0; // deposited T(0) at the test speed (the measured quantity)
  double mse_mm2 = 0.0;          // mean squared error of the stroke profile [mm^2]
  double flow_m3ph = 0.0;        // implied sprayed flow at the test speed [m^3/h]
  double deposited_flow_m3ph = 0.0;  // what stayed on the wall: flow * (1 - rebound) [m^3/h]
  double center_offset_m = 0.0;  // fitted pass centre in the CSV's position frame
  double speed_mps = 0.15;
  double rebound_fraction = 0.08;
  int evaluations = 0;           // objective evaluations of the optimiser
  /// Fitted deposited stroke at CSV position x [m].
  double stroke_at_m(double x_m) const;
};
/// Least-squares fit of (R, beta, q_max, centre offset) to a measured stroke through the closed
/// form: q_max in closed form (linear), (R, beta, offset) by multi-start NLopt BOBYQA.
StrokeFit fit_stroke(const StrokeData& data);

/// Free-form thickness rate (thesis eq. 2-13) at point p with unit normal n [m/s]:
/// q0(r_proj) (H0/L)^2 cos(gamma) / cos^3(theta) inside the cone and facing the nozzle, else 0.
double point_rate_mps(const SpotModel& model, const NozzlePose& nozzle, const Eigen::Vector3d& p,
                      const Eigen::Vector3d& n);

/// Spatial index over a cloud with normals, answering "which points can this nozzle reach"
/// without scanning the whole cloud. Build once per cloud; rebuild after moving points.
class SurfaceIndex {
 public:
  /// Cloud must have finite points and unit normals toward the side the nozzle sprays from.
  /// cell_size_m: edge of the dense voxel grid (grown automatically to cap memory).
  explicit SurfaceIndex(const Cloud& cloud, double cell_size_m = 0.05);
  ~SurfaceIndex();
  SurfaceIndex(SurfaceIndex&&) noexcept;
  SurfaceIndex& operator=(SurfaceIndex&&) noexcept;
  const Cloud& cloud() const;
  /// Indices of points within `radius_m` of `center`.
  void within(const Eigen::Vector3d& center, double radius_m, std::vector<int>& out) const;
  double cell_size_m() const;
  /// Ball (centre, radius) that contains every point of the cloud this nozzle can reach (inside
  /// the cone) on the first surface along its axis; see deposition.cpp for the bound.
  std::pair<Eigen::Vector3d, double> reach_ball(const SpotModel& model, const NozzlePose& nozzle) const;

 private:
  friend void accumulate_dwells(const SpotModel&, const SurfaceIndex&, const std::vector<NozzlePose>&,
                                const std::vector<double>&, double, Eigen::VectorXd&);
  // accumulate_dwells' inner steps: adds rate_mps(point) * weight for every point reachable from
  // `nozzle` (eq. 2-13; only the points in reach_ball are visited) to a buffer of cloud-size
  // entries in the index's internal point order (no size check, no allocation); add_sorted adds
  // such a buffer to a vector in cloud order.
  void add_rates_sorted(const SpotModel& model, const NozzlePose& nozzle, double weight, double* sorted) const;
  void add_sorted(const std::vector<double>& sorted, Eigen::VectorXd& out) const;

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Adds to `thickness_m` (one entry per point of the index's cloud) the concrete that stays on the
/// wall while the nozzle dwells dwell_s[i] at poses[i]: sum_i q_s(pose_i) * dwell_i * (1 - rebound).
void accumulate_dwells(const SpotModel& model, const SurfaceIndex& surface, const std::vector<NozzlePose>& poses,
                       const std::vector<double>& dwell_s, double rebound_fraction, Eigen::VectorXd& thickness_m);

/// The samples of a pass: the polyline resampled at the midpoints of n = ceil(length / step_m)
/// equal intervals (step <= step_m, midpoint rule), each dwelling step / speed.
struct PassSamples {
  std::vector<NozzlePose> poses;
  std::vector<double> dwell_s;
  double length_m = 0.0;
};
PassSamples resample_pass(const std::vector<NozzlePose>& polyline, double speed_mps, double step_m);

/// Same for a nozzle moving along a polyline of poses at constant speed: the path is resampled at
/// `step_m` (poses interpolated, axes renormalised) and each sample dwells step / speed.
void accumulate_pass(const SpotModel& model, const SurfaceIndex& surface, const std::vector<NozzlePose>& polyline,
                     double speed_mps, double step_m, double rebound_fraction, Eigen::VectorXd& thickness_m);

// The sprayed wall (a deposit put on the cloud and its grid): deposit_layer in deposition/wall.hpp.

/// Golden-section pass spacing (thesis 3.5): the overlap in [0, R] (design; widened if the optimum
/// sits on the bound) of two parallel strokes that
/// minimises sum_x (Td - T(x))^2 on a 1 mm grid, each stroke peaking at Td; spacing = 2R - overlap.
struct PassSpacing {
  double spacing_m = 0.0;
  double overlap_m = 0.0;
  double band_min_m = 0.0;  // thickness range between the two pass centres, for peak Td
  double band_max_m = 0.0;
};
PassSpacing pass_spacing(const SpotModel& model, double target_thickness_m);

/// Many parallel strokes of equal dwell at pitch p lay a layer that ripples across them with period
/// p; how much depends on p non-monotonically (default spot: 5.6 % peak to peak at 0.114 m, 0.9 %
/// at 0.103 m). The pitch in [lo_m, hi_m] of least ripple, (max - min) / mean of the sum of the
/// strokes' cross profiles (1 - (x/R)^2)^(beta - 1/2) (a flat wall at H0; the design's curvature
/// moves the optimum by < 1 mm), scanned in 0.1 mm steps (0.2 % of lo_m where that is finer, at most
/// 2e4 steps); lo_m >= 0.05 R.
struct LinePitch {
  double pitch_m = 0.0;
  double ripple = 0.0;  // (max - min) / mean across the lines [-]
};
LinePitch least_ripple_pitch(const SpotModel& model, double lo_m, double hi_m);
/// The ripple of equal strokes at pitch_m (least_ripple_pitch's measure).
double line_ripple(const SpotModel& model, double pitch_m);

}  // namespace shotcrete
