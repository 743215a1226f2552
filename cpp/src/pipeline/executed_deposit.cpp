// The executed deposit: the flow-weighted dwell of every trajectory sample laid round by round on
// the moved wall (see executed_deposit.hpp; the pump's flow schedule is in deposition/flow.cpp).
#include "shotcrete/pipeline/executed_deposit.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "shotcrete/deposition/deposition.hpp"

namespace shotcrete {

namespace {

// The round of every sample: that of its region, or of the last region before it.
std::vector<int> sample_rounds(const TimedTrajectory& tr, const std::vector<int>& regions_per_round) {
  std::vector<int> round_of_region;
  for (std::size_t k = 0; k < regions_per_round.size(); ++k)
    round_of_region.insert(round_of_region.end(), static_cast<std::size_t>(std::max(0, regions_per_round[k])),
                           static_cast<int>(k));
  std::vector<int> out(tr.size(), 0);
  int current = 0;
  for (std::size_t i = 0; i < tr.size(); ++i) {
    const int r = tr.region_index[i];
    if (r >= static_cast<int>(round_of_region.size()))
      throw std::invalid_argument("execute_deposit: sample " + std::to_string(i) + " is in region " + std::to_string(r) +
                                  " but the rounds have " + std::to_string(round_of_region.size()) + " regions");
    if (r >= 0) current = round_of_region[static_cast<std::size_t>(r)];
    out[i] = current;
  }
  return out;
}

// Concrete on the valid cells of the wall [m^3]: every point of a cell stands for an equal share
// of the cell's footprint on the cylinder through it (the design-line area scaled to the cell's
// radius), tilted by the point's own normal against the radial direction (the surface it samples
// is that much larger; the deposit's thickness is measured along that normal).
double on_wall_m3(const SprayedWall& wall, const Eigen::VectorXd& thickness_m) {
  const Grid& g = wall.surface.grid;
  const Cloud& cloud = wall.surface.cloud;
  std::vector<double> sum(static_cast<std::size_t>(g.size()), 0.0);
  std::vector<int> count(static_cast<std::size_t>(g.size()), 0);
  for (Eigen::Index i = 0; i < thickness_m.size(); ++i) {
    const int c = wall.cell_of_point[static_cast<std::size_t>(i)];
    if (c < 0 || !g.valid[static_cast<std::size_t>(c)]) continue;
    const Eigen::Vector3d radial = design_normal(g.axis, g.profile, g.theta_center(g.row_of(c)));
    const double cos_tilt = std::max(0.5, std::abs(cloud.normals.row(i).dot(radial.transpose())));
    sum[static_cast<std::size_t>(c)] += thickness_m[i] / cos_tilt;
    ++count[static_cast<std::size_t>(c)];
  }
  double volume = 0.0;
  for (int c = 0; c < g.size(); ++c) {
    const auto k = static_cast<std::size_t>(c);
    if (count[k] == 0) continue;
    const double theta = g.theta_center(g.row_of(c)), radius = g.profile.radius_at(theta);
    volume += g.cell_size_m * g.cell_size_m * (radius + g.profile.radial_offset_m(g.td_m[c], theta)) / radius * sum[k] / count[k];
  }
  return volume;
}

// Distance along a ray from c (relative to the axis origin) along u to the cylinder of radius R
// about the axis; NaN when it meets none ahead.
double ray_to_cylinder(const TunnelAxis& ax, const Eigen::Vector3d& c, const Eigen::Vector3d& u, double R) {
  const Eigen::Vector3d c_perp = c - c.dot(ax.ex) * ax.ex, u_perp = u - u.dot(ax.ex) * ax.ex;
  const double A = u_perp.squaredNorm(), B = 2.0 * c_perp.dot(u_perp), C = c_perp.squaredNorm() - R * R;
  const double disc = B * B - 4.0 * A * C;
  if (!(A > 1e-12) || disc < 0.0) return std::numeric_limits<double>::quiet_NaN();
  const double t = (-B + std::sqrt(disc)) / (2.0 * A);
  return t > 0.0 ? t : std::numeric_limits<double>::quiet_NaN();
}

// Cell a ray from c (relative to the axis origin) along u meets on the surface td_m outside the
// design line (along its normal); -1 when it meets none of the grid's cells. A circle's offset
// surface is a cylinder (closed form); a section's is found by secant steps from the cylinder of
// its mean radius.
int cell_on_wall(const Grid& grid, const Eigen::Vector3d& c, const Eigen::Vector3d& u, double td_m) {
  const TunnelAxis& ax = grid.axis;
  const DesignProfile& prof = grid.profile;
  double t = ray_to_cylinder(ax, c, u, prof.radius_m + td_m);
  if (!std::isfinite(t)) return -1;
  if (!prof.is_circle()) {
    auto f = [&](double s) {
      const Eigen::Vector3d cyl = ax.to_cylindrical(ax.origin_m + c + s * u);
      return cyl[0] - prof.radius_at(cyl[1]) - prof.radial_offset_m(td_m, cyl[1]);  // NaN off the span
    };
    double t0 = t, f0 = f(t0), t1 = t0 + 0.01, f1 = f(t1);
    for (int it = 0; it < 12 && std::isfinite(f0) && std::isfinite(f1) && std::abs(f1) > 1e-6 && f1 != f0; ++it) {
      const double t2 = t1 - f1 * (t1 - t0) / (f1 - f0);
      t0 = t1, f0 = f1, t1 = t2, f1 = f(t1);
    }
    if (!std::isfinite(f1) || std::abs(f1) > 1e-4 || !(t1 > 0.0)) return -1;
    t = t1;
  }
  const Eigen::Vector3d cyl = ax.to_cylindrical(ax.origin_m + c + t * u);
  return grid.cell_at(cyl[1], cyl[2]);
}

// Share of the spot's volume whose rays meet the wall off every valid cell: the disc at H0 split
// into rings of equal volume (1 - (1 - r^2/R^2)^beta = (k + 1/2) / rings) and directions; each ray
// meets the design surface, then the surface through the TD of the cell it met there.
double miss_fraction(const SpotModel& model, const Grid& grid, const NozzlePose& nozzle) {
  constexpr int kRings = 8, kDirections = 16;
  const Eigen::Vector3d a = nozzle.axis.normalized();
  const Eigen::Vector3d e1 = a.unitOrthogonal(), e2 = a.cross(e1);
  const Eigen::Vector3d c = nozzle.position_m - grid.axis.origin_m;
  int missed = 0;
  for (int k = 0; k < kRings; ++k) {
    const double f = (k + 0.5) / kRings;
    const double rho = model.radius_m * std::sqrt(1.0 - std::pow(1.0 - f, 1.0 / model.beta));
    for (int j = 0; j < kDirections; ++j) {
      const double phi = 2.0 * M_PI * (j + 0.5 * (k % 2)) / kDirections;
      const Eigen::Vector3d u = (model.reference_standoff_m * a + rho * (std::cos(phi) * e1 + std::sin(phi) * e2)).normalized();
      int cell = cell_on_wall(grid, c, u, 0.0);
      if (cell >= 0 && grid.valid[static_cast<std::size_t>(cell)])
        cell = cell_on_wall(grid, c, u, grid.td_m[cell]);
      if (cell < 0 || !grid.valid[static_cast<std::size_t>(cell)]) ++missed;
    }
  }
  return static_cast<double>(missed) / (kRings * kDirections);
}

}  // namespace

ExecutedDeposit execute_deposit(const Surface& surface, const std::vector<int>& regions_per_round,
                                const TimedTrajectory& tr, const Config& config) {
  validate(config);
  if (!surface.cloud.has_normals()) throw std::invalid_argument("execute_deposit: the surface cloud has no normals");
  const SpotModel model = spot_model_from_config(config.deposition);
  const double rebound = config.deposition.rebound_fraction, rate = model.volume_rate_m3ps();
  const std::vector<int> round_of = sample_rounds(tr, regions_per_round);
  ExecutedDeposit out{Eigen::VectorXd::Zero(surface.cloud.size()), {}, {}, {},
                      unsprayed_wall(surface, config.profile.max_deviation_m),
                      flow_schedule(tr.t_s, tr.spraying, config.flow, joint_move_samples(tr), /*ends_blocked=*/true), {}};
  const std::vector<double> dwell = flow_dwells(out.flow, tr.t_s);
  double missed = 0.0;  // full-flow seconds whose spray lands off the scanned cells
  for (std::size_t k = 0; k < regions_per_round.size(); ++k) {
    std::vector<NozzlePose> poses;
    std::vector<double> dwells;
    for (std::size_t i = 0; i < tr.size(); ++i)
      if (round_of[i] == static_cast<int>(k) && dwell[i] > 0.0) poses.push_back(tr.nozzle[i]), dwells.push_back(dwell[i]);
    Eigen::VectorXd deposit = Eigen::VectorXd::Zero(out.wall.surface.cloud.size());
    std::vector<double> miss(poses.size());  // per pose, summed in order below: the same sum on any thread count
#pragma omp parallel for schedule(static)
    for (long j = 0; j < static_cast<long>(poses.size()); ++j)
      miss[static_cast<std::size_t>(j)] = miss_fraction(model, out.wall.surface.grid, poses[static_cast<std::size_t>(j)]);
    for (std::size_t j = 0; j < poses.size(); ++j) missed += dwells[j] * miss[j];
    if (!poses.empty()) {
      const SurfaceIndex index(out.wall.surface.cloud, 0.05);  // the wall as moved so far, as plan_bay
      accumulate_dwells(model, index, poses, dwells, rebound, deposit);
      out.volumes.on_wall_m3 += on_wall_m3(out.wall, deposit);
      deposit_layer(out.wall, deposit);
      out.deposited_m += deposit;
    }
    out.round_deposited_m.push_back(std::move(deposit));
    out.round_td_after_m.push_back(out.wall.surface.grid.td_m);
  }
  out.td_after_m = out.wall.surface.grid.td_m;
  out.volumes.sprayed_m3 = rate * out.flow.on_time_s();
  out.volumes.rebound_m3 = rebound * out.volumes.sprayed_m3;
  out.volumes.outside_m3 = rate * (1.0 - rebound) * missed;
  out.bridged_volume_m3 = rate * out.flow.bridged_s;
  out.extended_volume_m3 = rate * out.flow.extended_s;
  return out;
}

ExecutedDeposit execute_deposit(const Surface& surface, const Plan& plan, const TimedTrajectory& trajectory,
                                const Config& config) {
  std::vector<int> regions_per_round;
  for (const auto& round : plan.rounds) regions_per_round.push_back(static_cast<int>(round.regions.size()));
  return execute_deposit(surface, regions_per_round, trajectory, config);
}

double DepositVolumes::balance_error() const {
  return sprayed_m3 > 0.0 ? (sprayed_m3 - rebound_m3 - on_wall_m3 - outside_m3) / sprayed_m3 : 0.0;
}

DepositDifferenceMm deposit_difference_mm(const Eigen::VectorXd& a_m, const Eigen::VectorXd& b_m,
                                          const std::vector<bool>& valid) {
  if (a_m.size() != b_m.size() || a_m.size() != static_cast<Eigen::Index>(valid.size()))
    throw std::invalid_argument("deposit_difference_mm: maps of " + std::to_string(a_m.size()) + " and " +
                                std::to_string(b_m.size()) + " cells on a grid of " + std::to_string(valid.size()));
  DepositDifferenceMm d;
  double sum = 0.0, sum2 = 0.0;
  int n = 0;
  for (std::size_t c = 0; c < valid.size(); ++c) {
    if (!valid[c]) continue;
    const double x = 1000.0 * (a_m[static_cast<Eigen::Index>(c)] - b_m[static_cast<Eigen::Index>(c)]);
    sum += x, sum2 += x * x, ++n;
    d.max_abs = std::max(d.max_abs, std::abs(x));
  }
  if (n > 0) d.mean = sum / n, d.rms = std::sqrt(sum2 / n);
  return d;
}

}  // namespace shotcrete
