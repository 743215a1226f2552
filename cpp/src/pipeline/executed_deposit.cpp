// The executed deposit: the pump's flow schedule from the trajectory's spraying flags, the
// flow-weighted dwell of every sample, and the deposit laid round by round on the moved wall
// (see executed_deposit.hpp).
#include "shotcrete/pipeline/executed_deposit.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "shotcrete/deposition/deposition.hpp"

namespace shotcrete {

namespace {

// Integral from -infinity to t of a unit step at c smoothed into a linear ramp of width r centred
// on c: 0 before the ramp, (t - c + r/2)^2 / (2 r) on it, t - c after it.
double ramp_integral(double t, double c, double r) {
  if (!(r > 0.0)) return std::max(0.0, t - c);
  if (t <= c - 0.5 * r) return 0.0;
  if (t >= c + 0.5 * r) return t - c;
  const double u = t - c + 0.5 * r;
  return u * u / (2.0 * r);
}

double ramp_value(double t, double c, double r) {
  if (!(r > 0.0)) return t >= c ? 1.0 : 0.0;
  return std::clamp((t - c + 0.5 * r) / r, 0.0, 1.0);
}

// Spells [on, off] the flags ask for: a flagged sample stands for the time between the midpoints
// with its neighbours (the first and last samples reach the trajectory's ends).
void commanded_spells(const std::vector<double>& t, const std::vector<char>& spraying, FlowSchedule& s) {
  const std::size_t n = t.size();
  for (std::size_t i = 0; i < n; ++i) {
    if (!spraying[i] || (i > 0 && spraying[i - 1])) continue;
    std::size_t j = i;
    while (j + 1 < n && spraying[j + 1]) ++j;
    s.on_s.push_back(i == 0 ? t[0] : 0.5 * (t[i - 1] + t[i]));
    s.off_s.push_back(j + 1 == n ? t[n - 1] : 0.5 * (t[j] + t[j + 1]));
  }
}

// Merges spells separated by less than min_off; returns whether any were merged.
bool bridge_gaps(FlowSchedule& s, double min_off) {
  std::vector<double> on, off;
  bool merged = false;
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    if (!on.empty() && s.on_s[k] - off.back() < min_off) {
      s.bridged_s += std::max(0.0, s.on_s[k] - off.back());
      off.back() = std::max(off.back(), s.off_s[k]);
      merged = true;
      continue;
    }
    on.push_back(s.on_s[k]);
    off.push_back(s.off_s[k]);
  }
  s.on_s = std::move(on);
  s.off_s = std::move(off);
  return merged;
}

// Extends spells shorter than min_on about their middle, within [t0, t1]; returns whether any grew.
bool extend_spells(FlowSchedule& s, double min_on, double t0, double t1) {
  bool grown = false;
  const double target = std::min(min_on, t1 - t0);
  for (std::size_t k = 0; k < s.on_s.size(); ++k) {
    double& a = s.on_s[k];
    double& b = s.off_s[k];
    const double need = target - (b - a);
    if (!(need > 1e-12)) continue;
    a -= 0.5 * need;
    b += 0.5 * need;
    if (a < t0) b += t0 - a, a = t0;
    if (b > t1) a = std::max(t0, a - (b - t1)), b = t1;
    grown = true;
  }
  return grown;
}

void check_times(const std::vector<double>& t_s) {
  for (std::size_t i = 0; i < t_s.size(); ++i) {
    if (!std::isfinite(t_s[i])) throw std::invalid_argument("flow_schedule: t_s[" + std::to_string(i) + "] is not finite");
    if (i > 0 && !(t_s[i] > t_s[i - 1]))
      throw std::invalid_argument("flow_schedule: t_s must increase strictly (t_s[" + std::to_string(i) +
                                  "] = " + std::to_string(t_s[i]) + ")");
  }
}

}  // namespace

double FlowSchedule::shortest_on_s() const {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < on_s.size(); ++k) best = std::min(best, off_s[k] - on_s[k]);
  return on_s.empty() ? 0.0 : best;
}

double FlowSchedule::shortest_off_s() const {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t k = 1; k < on_s.size(); ++k) best = std::min(best, on_s[k] - off_s[k - 1]);
  return on_s.size() < 2 ? 0.0 : best;
}

double FlowSchedule::on_time_s() const {
  double sum = 0.0;
  for (std::size_t k = 0; k < on_s.size(); ++k) sum += off_s[k] - on_s[k];
  return sum;
}

double FlowSchedule::flow_at(double t) const {
  double f = 0.0;
  for (std::size_t k = 0; k < on_s.size(); ++k) f += ramp_value(t, on_s[k], ramp_s) - ramp_value(t, off_s[k], ramp_s);
  return std::clamp(f, 0.0, 1.0);
}

double FlowSchedule::integral_to(double t) const {
  double sum = 0.0;
  for (std::size_t k = 0; k < on_s.size(); ++k) sum += ramp_integral(t, on_s[k], ramp_s) - ramp_integral(t, off_s[k], ramp_s);
  return sum;
}

FlowSchedule flow_schedule(const std::vector<double>& t_s, const std::vector<char>& spraying, const FlowConfig& flow) {
  Config c;
  c.flow = flow;
  validate(c);
  if (t_s.size() != spraying.size())
    throw std::invalid_argument("flow_schedule: " + std::to_string(t_s.size()) + " times but " +
                                std::to_string(spraying.size()) + " spraying flags");
  check_times(t_s);
  FlowSchedule s;
  s.ramp_s = flow.ramp_s;
  if (t_s.empty()) return s;
  commanded_spells(t_s, spraying, s);
  s.commanded_on_s = s.on_time_s();
  s.commanded_switches = s.switches();
  // Bridging only merges and extending only lengthens, so this settles; the cap is a safeguard.
  for (int pass = 0; pass < 1000; ++pass) {
    const bool merged = bridge_gaps(s, flow.min_off_s);
    const bool grown = extend_spells(s, flow.min_on_s, t_s.front(), t_s.back());
    if (!merged && !grown) break;
  }
  s.extended_s = s.on_time_s() - s.commanded_on_s - s.bridged_s;
  return s;
}

std::vector<double> flow_dwells(const FlowSchedule& s, const std::vector<double>& t_s) {
  const std::size_t n = t_s.size();
  std::vector<double> dwell(n, 0.0);
  if (n == 0 || s.on_s.empty()) return dwell;
  const double half = 0.5 * s.ramp_s;
  std::size_t first = 0;  // first spell whose off-ramp has not ended by t
  double done = 0.0;      // flow-on time of the spells before `first`
  // Integral to t for increasing t: the ended spells summed once, the others (at most a few, the
  // spells being ramp_s or more apart) integrated.
  auto cumulative = [&](double t) {
    while (first < s.on_s.size() && s.off_s[first] + half <= t) done += s.off_s[first] - s.on_s[first], ++first;
    double sum = done;
    for (std::size_t k = first; k < s.on_s.size() && s.on_s[k] - half < t; ++k)
      sum += ramp_integral(t, s.on_s[k], s.ramp_s) - ramp_integral(t, s.off_s[k], s.ramp_s);
    return sum;
  };
  double prev = 0.0;  // integral to the lower edge of sample i's share (-infinity for the first)
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const double cur = cumulative(0.5 * (t_s[i] + t_s[i + 1]));
    dwell[i] = cur - prev;
    prev = cur;
  }
  dwell[n - 1] = s.on_time_s() - prev;
  return dwell;
}

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
    const Eigen::Vector3d radial = g.axis.radial(g.theta_center(g.row_of(c)));
    const double cos_tilt = std::max(0.5, std::abs(cloud.normals.row(i).dot(radial.transpose())));
    sum[static_cast<std::size_t>(c)] += thickness_m[i] / cos_tilt;
    ++count[static_cast<std::size_t>(c)];
  }
  double volume = 0.0;
  for (int c = 0; c < g.size(); ++c) {
    const auto k = static_cast<std::size_t>(c);
    if (count[k] == 0) continue;
    const double radius = g.profile.radius_at(g.theta_center(g.row_of(c)));
    volume += g.cell_size_m * g.cell_size_m * (radius + g.td_m[c]) / radius * sum[k] / count[k];
  }
  return volume;
}

// Cell a ray from c (relative to the axis origin) along u meets on the cylinder of radius R about
// the axis; -1 when it meets none of the grid's cells.
int cell_on_cylinder(const Grid& grid, const Eigen::Vector3d& c, const Eigen::Vector3d& u, double R) {
  const TunnelAxis& ax = grid.axis;
  const Eigen::Vector3d c_perp = c - c.dot(ax.ex) * ax.ex, u_perp = u - u.dot(ax.ex) * ax.ex;
  const double A = u_perp.squaredNorm(), B = 2.0 * c_perp.dot(u_perp), C = c_perp.squaredNorm() - R * R;
  const double disc = B * B - 4.0 * A * C;
  if (!(A > 1e-12) || disc < 0.0) return -1;
  const double t = (-B + std::sqrt(disc)) / (2.0 * A);
  if (!(t > 0.0)) return -1;
  const Eigen::Vector3d cyl = ax.to_cylindrical(ax.origin_m + c + t * u);
  return grid.cell_at(cyl[1], cyl[2]);
}

// Share of the spot's volume whose rays meet the wall off every valid cell: the disc at H0 split
// into rings of equal volume (1 - (1 - r^2/R^2)^beta = (k + 1/2) / rings) and directions; each ray
// meets the design surface, then the cylinder through the TD of the cell it met there.
double miss_fraction(const SpotModel& model, const Grid& grid, const NozzlePose& nozzle) {
  constexpr int kRings = 8, kDirections = 16;
  const Eigen::Vector3d a = nozzle.axis.normalized();
  const Eigen::Vector3d e1 = a.unitOrthogonal(), e2 = a.cross(e1);
  const Eigen::Vector3d c = nozzle.position_m - grid.axis.origin_m;
  const double R = grid.profile.radius_m;
  int missed = 0;
  for (int k = 0; k < kRings; ++k) {
    const double f = (k + 0.5) / kRings;
    const double rho = model.radius_m * std::sqrt(1.0 - std::pow(1.0 - f, 1.0 / model.beta));
    for (int j = 0; j < kDirections; ++j) {
      const double phi = 2.0 * M_PI * (j + 0.5 * (k % 2)) / kDirections;
      const Eigen::Vector3d u = (model.reference_standoff_m * a + rho * (std::cos(phi) * e1 + std::sin(phi) * e2)).normalized();
      int cell = cell_on_cylinder(grid, c, u, R);
      if (cell >= 0 && grid.valid[static_cast<std::size_t>(cell)])
        cell = cell_on_cylinder(grid, c, u, R + grid.td_m[cell]);
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
                      unsprayed_wall(surface, config.profile.max_deviation_m), flow_schedule(tr.t_s, tr.spraying, config.flow), {}};
  const std::vector<double> dwell = flow_dwells(out.flow, tr.t_s);
  double missed = 0.0;  // full-flow seconds whose spray lands off the scanned cells
  for (std::size_t k = 0; k < regions_per_round.size(); ++k) {
    std::vector<NozzlePose> poses;
    std::vector<double> dwells;
    for (std::size_t i = 0; i < tr.size(); ++i)
      if (round_of[i] == static_cast<int>(k) && dwell[i] > 0.0) poses.push_back(tr.nozzle[i]), dwells.push_back(dwell[i]);
    Eigen::VectorXd deposit = Eigen::VectorXd::Zero(out.wall.surface.cloud.size());
    for (std::size_t j = 0; j < poses.size(); ++j)
      missed += dwells[j] * miss_fraction(model, out.wall.surface.grid, poses[j]);
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
