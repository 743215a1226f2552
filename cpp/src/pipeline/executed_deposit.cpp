// The executed deposit: the flow-weighted dwell of every trajectory sample laid round by round on
// the moved wall (see executed_deposit.hpp; the pump's flow schedule is in deposition/flow.cpp).
#include "shotcrete/pipeline/executed_deposit.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/timing/region_spray.hpp"

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

// Where a sample lies in its region, as slot + fraction. Slots: 0 the lead-in, 4j + 1 pass j, and
// the join after pass j (the last join is the lead-out) as 4j + 2 up to a joint move, 4j + 3 the
// move (blocked: a stop-and-go middle) and 4j + 4 after it; the move's path and length are the
// arm's own, the runs before and after it keep their places. The fraction is the share of the
// slot's nozzle path before the sample (of its time where the nozzle hardly moves), each slot
// running from the midpoint with the sample before its first to the midpoint with the sample
// after its last, so the position grows across a slot's end too. local_pass never decreases.
std::vector<double> slot_positions(const std::vector<int>& local_pass, const std::vector<char>& blocked,
                                   const std::vector<Eigen::Vector3d>& position, const std::vector<double>& t_s) {
  const std::size_t n = local_pass.size();
  std::vector<int> slot(n, 0);
  std::vector<double> x(n, 0.0);
  int last = -1, phase = 0;  // the last pass; in the join after it: 0 before a joint move, 1 in it, 2 after
  for (std::size_t k = 0; k < n; ++k) {
    if (local_pass[k] >= 0) {
      last = local_pass[k], phase = 0;
      slot[k] = 4 * last + 1;
    } else if (last >= 0) {
      phase = blocked[k] ? 1 : (phase == 1 ? 2 : phase);
      slot[k] = 4 * last + 2 + phase;
    }
  }
  for (std::size_t a = 0; a < n;) {
    std::size_t b = a + 1;
    while (b < n && slot[b] == slot[a]) ++b;
    const double d0 = a > 0 ? 0.5 * (position[a] - position[a - 1]).norm() : 0.0;
    const double t0 = a > 0 ? 0.5 * (t_s[a] - t_s[a - 1]) : 0.0;
    std::vector<double> d(b - a, d0), t(b - a, t0);
    for (std::size_t k = a + 1; k < b; ++k) {
      d[k - a] = d[k - a - 1] + (position[k] - position[k - 1]).norm();
      t[k - a] = t[k - a - 1] + (t_s[k] - t_s[k - 1]);
    }
    const double length = d.back() + (b < n ? 0.5 * (position[b] - position[b - 1]).norm() : 0.0);
    const double span = t.back() + (b < n ? 0.5 * (t_s[b] - t_s[b - 1]) : 0.0);
    for (std::size_t k = a; k < b; ++k)
      x[k] = slot[k] + (length > 1e-4 ? d[k - a] / length : (span > 0.0 ? t[k - a] / span : 0.0));
    a = b;
  }
  return x;
}

// y at x on the polyline (xs, ys), xs non-decreasing: the first point reaching x, held beyond the ends.
double interpolate(const std::vector<double>& xs, const std::vector<double>& ys, double x) {
  const auto it = std::lower_bound(xs.begin(), xs.end(), x);
  if (it == xs.begin()) return ys.front();
  if (it == xs.end()) return ys.back();
  const auto i = static_cast<std::size_t>(it - xs.begin());  // xs[i - 1] < x <= xs[i]
  return ys[i - 1] + (ys[i] - ys[i - 1]) * (x - xs[i - 1]) / (xs[i] - xs[i - 1]);
}

}  // namespace

// Share of the spot's volume whose rays meet the wall off every valid cell: the disc at H0 split
// into rings of equal volume (1 - (1 - r^2/R^2)^beta = (k + 1/2) / rings) and directions; each ray
// meets the design surface, then the surface through the TD of the cell it met there.
double spot_miss_fraction(const SpotModel& model, const Grid& grid, const NozzlePose& nozzle) {
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

SpotOnGridBound::SpotOnGridBound(const SpotModel& model, const Grid& grid) : grid_(&grid) {
  const int nt = grid.n_theta, nd = grid.n_d;
  invalid_sum_.assign(static_cast<std::size_t>((nt + 1) * (nd + 1)), 0);
  double td_lo = 0.0, td_hi = 0.0;
  for (int r = 0; r < nt; ++r)
    for (int c = 0; c < nd; ++c) {
      const int cell = grid.index(r, c);
      const bool ok = grid.valid[static_cast<std::size_t>(cell)];
      if (ok) td_lo = std::min(td_lo, grid.td_m[cell]), td_hi = std::max(td_hi, grid.td_m[cell]);
      invalid_sum_[static_cast<std::size_t>((r + 1) * (nd + 1) + c + 1)] =
          (ok ? 0 : 1) + invalid_sum_[static_cast<std::size_t>(r * (nd + 1) + c + 1)] +
          invalid_sum_[static_cast<std::size_t>((r + 1) * (nd + 1) + c)] - invalid_sum_[static_cast<std::size_t>(r * (nd + 1) + c)];
    }
  cone_rad_ = model.cone_half_angle_rad();
  rho_lo_ = grid.profile.radius_m + td_lo;
  rho_hi_ = grid.profile.radius_m + td_hi;
  usable_ = grid.profile.is_circle() && nt > 0 && nd > 0 && rho_lo_ > 0.0 && std::isfinite(rho_hi_) && cone_rad_ < 0.5;
}

bool SpotOnGridBound::surely_on_grid(const NozzlePose& nozzle) const {
  if (!usable_) return false;
  const Grid& g = *grid_;
  const TunnelAxis& ax = g.axis;
  const Eigen::Vector3d cyl = ax.to_cylindrical(nozzle.position_m);  // the nozzle's (r, theta, d)
  const double r_c = cyl[0], theta_c = cyl[1], cx = cyl[2];
  const Eigen::Vector3d a = nozzle.axis.normalized();
  if (!(r_c > 1e-6 && r_c < rho_lo_ - 1e-6)) return false;
  // Elevation e (out of the cross-section) of the rays: within the cone of a, |e - e_a| <= cone.
  const double e_a = std::asin(std::clamp(a.dot(ax.ex), -1.0, 1.0)), cone = cone_rad_;
  const double e_max = std::abs(e_a) + cone;
  if (e_max >= 0.5 * M_PI - 0.05) return false;
  const double ux_lo = std::sin(e_a - cone), ux_hi = std::sin(e_a + cone), perp_min = std::cos(e_max);
  // Azimuth about the axis, against the outward radial at the nozzle: two directions at angle
  // <= cone with elevations e1, e2 differ in azimuth by dpsi, sin(dpsi / 2) <= sin(cone / 2) /
  // sqrt(cos e1 cos e2).
  const double s = std::sin(0.5 * cone) / std::sqrt(std::cos(e_a) * perp_min);
  if (s >= 1.0) return false;
  const double dpsi = 2.0 * std::asin(s);
  const Eigen::Vector2d radial(std::cos(theta_c), std::sin(theta_c)), a_perp(a.dot(ax.ey), a.dot(ax.ez));
  if (a_perp.norm() < 1e-9) return false;
  const double phi_a = std::acos(std::clamp(radial.dot(a_perp.normalized()), -1.0, 1.0));
  const double phi_max = phi_a + dpsi;
  if (phi_max >= 0.5 * M_PI) return false;  // a ray may run along the wall: cast them
  // Travel in the cross-section from the nozzle to the circle of radius rho at azimuth phi grows
  // with both: d = -r_c cos phi + sqrt(rho^2 - r_c^2 sin^2 phi); the ray's length is d / cos e.
  const double sp = std::sin(phi_max);
  const double d_max = -r_c * std::cos(phi_max) + std::sqrt(rho_hi_ * rho_hi_ - r_c * r_c * sp * sp);
  const double t_min = rho_lo_ - r_c, t_max = d_max / perp_min;
  const double dx_lo = std::min(t_min * ux_lo, t_max * ux_lo), dx_hi = std::max(t_min * ux_hi, t_max * ux_hi);
  // The hit's angle about the axis from the nozzle's: sin(dtheta) = d sin(phi) / rho.
  const double sin_dt = d_max * sp / rho_lo_;
  if (sin_dt >= 1.0) return false;
  const double dt = std::asin(sin_dt);
  if (theta_c - dt < -0.5 * M_PI || theta_c + dt >= 1.5 * M_PI) return false;  // across the cut
  // The window's rows and columns, one more each side for rounding.
  const int r0 = static_cast<int>(std::floor((theta_c - dt - g.theta0_rad) / g.dtheta_rad)) - 1;
  const int r1 = static_cast<int>(std::floor((theta_c + dt - g.theta0_rad) / g.dtheta_rad)) + 1;
  const int c0 = static_cast<int>(std::floor((cx + dx_lo - g.d0_m) / g.cell_size_m)) - 1;
  const int c1 = static_cast<int>(std::floor((cx + dx_hi - g.d0_m) / g.cell_size_m)) + 1;
  if (r0 < 0 || c0 < 0 || r1 >= g.n_theta || c1 >= g.n_d) return false;
  const int w = g.n_d + 1;
  const auto at = [&](int r, int col) { return invalid_sum_[static_cast<std::size_t>(r * w + col)]; };
  return at(r1 + 1, c1 + 1) - at(r0, c1 + 1) - at(r1 + 1, c0) + at(r0, c0) == 0;
}

PumpProgram planned_pump_program(const Plan& plan, const TimedTrajectory& tr, const Config& config) {
  std::vector<const std::vector<Pass>*> regions;
  for (const auto& round : plan.rounds)
    for (const auto& region : round.regions) regions.push_back(&region.passes);
  std::vector<std::vector<std::size_t>> samples(regions.size());  // the trajectory's samples of each region
  for (std::size_t i = 0; i < tr.size(); ++i) {
    const int r = tr.region_index[i];
    if (r < 0) continue;
    if (r >= static_cast<int>(regions.size()))
      throw std::invalid_argument("planned_pump_program: sample " + std::to_string(i) + " is in region " +
                                  std::to_string(r) + " but the plan has " + std::to_string(regions.size()) + " regions");
    samples[static_cast<std::size_t>(r)].push_back(i);
  }
  PumpProgram out;
  int pass_offset = 0;
  for (std::size_t r = 0; r < regions.size(); ++r) {
    const std::vector<Pass>& passes = *regions[r];
    const int n_passes = static_cast<int>(passes.size());
    const std::vector<std::size_t>& idx = samples[r];
    pass_offset += n_passes;
    if (idx.empty() || passes.empty()) continue;
    // The plan's program: the region's spells as the planner sprays it, and where they lie.
    const RegionSpray spray = region_spray(passes, config);
    std::vector<Eigen::Vector3d> plan_pos;
    for (const auto& p : spray.nozzle) plan_pos.push_back(p.position_m);
    const std::vector<double> plan_x = slot_positions(spray.pass_index, spray.blocked, plan_pos, spray.t_s);
    // The same places on the trajectory.
    std::vector<int> local(idx.size());
    std::vector<char> moving(idx.size());
    std::vector<Eigen::Vector3d> pos(idx.size());
    std::vector<double> t(idx.size());
    const int first_pass = pass_offset - n_passes;
    int last = -1;
    for (std::size_t k = 0; k < idx.size(); ++k) {
      const int p = tr.pass_index[idx[k]];
      if (p >= 0 && (p < first_pass || p >= pass_offset || p < last))
        throw std::invalid_argument("planned_pump_program: sample " + std::to_string(idx[k]) + " of region " +
                                    std::to_string(r) + " is on pass " + std::to_string(p) +
                                    (p < last ? ", after pass " + std::to_string(last) + " (out of order)"
                                              : ", not one of its " + std::to_string(n_passes) + " passes from " +
                                                    std::to_string(first_pass)));
      last = std::max(last, p);
      local[k] = p < 0 ? -1 : p - first_pass;
      moving[k] = tr.kind[idx[k]] == static_cast<char>(SegmentKind::Transit);
      pos[k] = tr.nozzle[idx[k]].position_m;
      t[k] = tr.t_s[idx[k]];
    }
    const std::vector<double> x = slot_positions(local, moving, pos, t);
    // A switch on a pass keeps its place on the pass. One off the passes (a spell the pump
    // lengthened to its minimum into a join or lead, a bridged gap's end) keeps its time from the
    // nearer pass end, within its join: the pump's rules are in time, and the arm runs joins at
    // speeds of its own (an eased start run 2.1 s where the plan's took 1.4 s: by place, a spell
    // lengthened 0.3 s into it started 0.5 s before the pass, 3.3 mm more on a cell).
    const auto plan_t_at = [&](double xp) { return interpolate(plan_x, spray.t_s, xp); };
    const auto arm_t_at = [&](double xp) { return interpolate(x, t, xp); };
    const auto to_arm = [&](double ts) {
      const double xs = interpolate(spray.t_s, plan_x, ts);
      const int slot = static_cast<int>(std::floor(xs));
      if (slot % 4 == 1) return arm_t_at(xs);
      const int before = slot < 2 ? -1 : (slot - 2) / 4;  // the pass before (-1: the lead-in)
      const int after = before + 1;                       // the pass after (n_passes: the lead-out)
      const double x_lo = before < 0 ? plan_x.front() : 4.0 * before + 2.0;  // the join's ends
      const double x_hi = after < n_passes ? 4.0 * after + 1.0 : plan_x.back();
      const bool from_before =
          before >= 0 && (after >= n_passes || ts - plan_t_at(x_lo) <= plan_t_at(x_hi) - ts);
      const double x_end = from_before ? x_lo : x_hi;
      return std::clamp(arm_t_at(x_end) + (ts - plan_t_at(x_end)), arm_t_at(x_lo), arm_t_at(x_hi));
    };
    const FlowSchedule& f = spray.flow;
    for (std::size_t k = 0; k < f.on_s.size(); ++k) {
      const double on = to_arm(f.on_s[k]);
      const double off = to_arm(f.off_s[k]);
      if (!(off > on)) continue;  // the trajectory stands still there
      if (!out.on_s.empty() && on <= out.off_s.back()) {
        out.off_s.back() = std::max(out.off_s.back(), off);
        continue;
      }
      out.on_s.push_back(on);
      out.off_s.push_back(off);
    }
  }
  return out;
}

namespace {

ExecutedDeposit execute_schedule(const Surface& surface, const std::vector<int>& regions_per_round,
                                 const TimedTrajectory& tr, FlowSchedule flow, const Config& config) {
  if (!surface.cloud.has_normals()) throw std::invalid_argument("execute_deposit: the surface cloud has no normals");
  const SpotModel model = spot_model_from_config(config.deposition);
  const double rebound = config.deposition.rebound_fraction, rate = model.volume_rate_m3ps();
  const std::vector<int> round_of = sample_rounds(tr, regions_per_round);
  ExecutedDeposit out{Eigen::VectorXd::Zero(surface.cloud.size()), {}, {}, {},
                      unsprayed_wall(surface, config.profile.max_deviation_m),
                      std::move(flow), {}};
  const std::vector<double> dwell = flow_dwells(out.flow, tr.t_s);
  double missed = 0.0;  // full-flow seconds whose spray lands off the scanned cells
  for (std::size_t k = 0; k < regions_per_round.size(); ++k) {
    std::vector<NozzlePose> poses;
    std::vector<double> dwells;
    for (std::size_t i = 0; i < tr.size(); ++i)
      if (round_of[i] == static_cast<int>(k) && dwell[i] > 0.0) poses.push_back(tr.nozzle[i]), dwells.push_back(dwell[i]);
    Eigen::VectorXd deposit = Eigen::VectorXd::Zero(out.wall.surface.cloud.size());
    std::vector<double> miss(poses.size());  // per pose, summed in order below: the same sum on any thread count
    const SpotOnGridBound on_grid(model, out.wall.surface.grid);
#pragma omp parallel for schedule(dynamic, 256)
    for (long j = 0; j < static_cast<long>(poses.size()); ++j) {
      const NozzlePose& p = poses[static_cast<std::size_t>(j)];
      miss[static_cast<std::size_t>(j)] = on_grid.surely_on_grid(p) ? 0.0 : spot_miss_fraction(model, out.wall.surface.grid, p);
    }
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

}  // namespace

ExecutedDeposit execute_deposit(const Surface& surface, const std::vector<int>& regions_per_round,
                                const TimedTrajectory& trajectory, const Config& config) {
  validate(config);
  return execute_schedule(surface, regions_per_round, trajectory,
                          flow_schedule(trajectory.t_s, trajectory.spraying, config.flow, joint_move_samples(trajectory),
                                        /*ends_blocked=*/true),
                          config);
}

ExecutedDeposit execute_deposit(const Surface& surface, const Plan& plan, const TimedTrajectory& trajectory,
                                const Config& config) {
  validate(config);
  std::vector<int> regions_per_round;
  for (const auto& round : plan.rounds) regions_per_round.push_back(static_cast<int>(round.regions.size()));
  const PumpProgram program = planned_pump_program(plan, trajectory, config);
  return execute_schedule(surface, regions_per_round, trajectory,
                          program_schedule(program.on_s, program.off_s, trajectory.t_s, config.flow,
                                           joint_move_samples(trajectory), /*ends_blocked=*/true),
                          config);
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
