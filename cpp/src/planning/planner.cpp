#include "shotcrete/planning/planner.hpp"

#include <nlopt.hpp>

#include <algorithm>
#include <chrono>
#include <functional>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/ordering/ordering.hpp"

namespace shotcrete {

// ---------------------------------------------------------------------------------------------
// Pass helpers

double Pass::duration_s() const {
  double t = 0;
  const auto dw = dwell_s();
  for (double d : dw) t += d;
  return t;
}

std::vector<double> Pass::dwell_s() const {
  // Each waypoint stands for half of each neighbouring interval (trapezoid rule along the path).
  const std::size_t n = waypoints.size();
  std::vector<double> dwell(n, 0.0);
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const double len = (waypoints[i + 1].position_m - waypoints[i].position_m).norm();
    dwell[i] += 0.5 * len / speed_at(i);
    dwell[i + 1] += 0.5 * len / speed_at(i + 1);
  }
  return dwell;
}

namespace {

void reverse_pass(Pass& p) {
  std::reverse(p.waypoints.begin(), p.waypoints.end());
  std::reverse(p.speed_profile_mps.begin(), p.speed_profile_mps.end());
}

double polyline_length(const std::vector<NozzlePose>& w) {
  double len = 0;
  for (std::size_t i = 0; i + 1 < w.size(); ++i) len += (w[i + 1].position_m - w[i].position_m).norm();
  return len;
}

// Clamped cubic spline of a vector-valued function through knots (t_i, y_i); evaluated at `ts`.
Eigen::MatrixXd spline_eval(const std::vector<double>& t, const Eigen::MatrixXd& y, const Eigen::RowVectorXd& d0,
                            const Eigen::RowVectorXd& dn, const std::vector<double>& ts) {
  const int n = static_cast<int>(t.size());
  const int dim = static_cast<int>(y.cols());
  Eigen::MatrixXd out(ts.size(), dim);
  if (n == 2) {
    for (std::size_t k = 0; k < ts.size(); ++k) {
      const double u = (ts[k] - t[0]) / (t[1] - t[0]);
      out.row(k) = (1 - u) * y.row(0) + u * y.row(1);
    }
    return out;
  }
  std::vector<double> h(n - 1);
  for (int i = 0; i + 1 < n; ++i) h[i] = t[i + 1] - t[i];
  // Tridiagonal system for the second derivatives M (Thomas algorithm), clamped ends.
  std::vector<double> a(n, 0), b(n, 0), c(n, 0);
  Eigen::MatrixXd r(n, dim);
  b[0] = 2 * h[0];
  c[0] = h[0];
  r.row(0) = 6 * ((y.row(1) - y.row(0)) / h[0] - d0);
  for (int i = 1; i + 1 < n; ++i) {
    a[i] = h[i - 1];
    b[i] = 2 * (h[i - 1] + h[i]);
    c[i] = h[i];
    r.row(i) = 6 * ((y.row(i + 1) - y.row(i)) / h[i] - (y.row(i) - y.row(i - 1)) / h[i - 1]);
  }
  a[n - 1] = h[n - 2];
  b[n - 1] = 2 * h[n - 2];
  r.row(n - 1) = 6 * (dn - (y.row(n - 1) - y.row(n - 2)) / h[n - 2]);
  for (int i = 1; i < n; ++i) {
    const double m = a[i] / b[i - 1];
    b[i] -= m * c[i - 1];
    r.row(i) -= m * r.row(i - 1);
  }
  Eigen::MatrixXd M(n, dim);
  M.row(n - 1) = r.row(n - 1) / b[n - 1];
  for (int i = n - 2; i >= 0; --i) M.row(i) = (r.row(i) - c[i] * M.row(i + 1)) / b[i];
  int seg = 0;
  for (std::size_t k = 0; k < ts.size(); ++k) {
    const double x = ts[k];
    while (seg < n - 2 && x > t[seg + 1]) ++seg;
    const double hs = h[seg], A = t[seg + 1] - x, B = x - t[seg];
    out.row(k) = M.row(seg) * A * A * A / (6 * hs) + M.row(seg + 1) * B * B * B / (6 * hs) +
                 (y.row(seg) / hs - M.row(seg) * hs / 6) * A + (y.row(seg + 1) / hs - M.row(seg + 1) * hs / 6) * B;
  }
  return out;
}

// End derivatives of the clamped spline: slope of the parabola through the first (last) three
// knots (Bessel's end condition), or of the chord when there are only two.
std::pair<Eigen::RowVectorXd, Eigen::RowVectorXd> end_slopes(const std::vector<double>& t, const Eigen::MatrixXd& y) {
  const int n = static_cast<int>(t.size());
  if (n < 3) {
    const Eigen::RowVectorXd d = (y.row(1) - y.row(0)) / (t[1] - t[0]);
    return {d, d};
  }
  auto slope_at_first = [](double h0, double h1, const Eigen::RowVectorXd& y0, const Eigen::RowVectorXd& y1,
                           const Eigen::RowVectorXd& y2) -> Eigen::RowVectorXd {
    return -(2 * h0 + h1) / (h0 * (h0 + h1)) * y0 + (h0 + h1) / (h0 * h1) * y1 - h0 / (h1 * (h0 + h1)) * y2;
  };
  const Eigen::RowVectorXd d0 = slope_at_first(t[1] - t[0], t[2] - t[1], y.row(0), y.row(1), y.row(2));
  // Mirror the last three knots (parameter running backwards) and flip the sign.
  const Eigen::RowVectorXd dn =
      -slope_at_first(t[n - 1] - t[n - 2], t[n - 2] - t[n - 3], y.row(n - 1), y.row(n - 2), y.row(n - 3));
  return {d0, dn};
}

std::vector<double> chord_knots(const std::vector<Eigen::Vector3d>& pts) {
  std::vector<double> t(pts.size(), 0.0);
  for (std::size_t i = 1; i < pts.size(); ++i) t[i] = t[i - 1] + (pts[i] - pts[i - 1]).norm();
  return t;
}

std::vector<double> sample_params(double total, double step) {
  const int n = std::max(1, static_cast<int>(std::ceil(total / step - 1e-9)));
  std::vector<double> ts(n + 1);
  for (int k = 0; k <= n; ++k) ts[k] = total * k / n;
  return ts;
}

// Spline through nozzle positions, with the spray axes splined on the same knots and renormalised.
std::vector<NozzlePose> spline_poses(const std::vector<NozzlePose>& knots, double step_m) {
  std::vector<Eigen::Vector3d> pts;
  for (const auto& k : knots) pts.push_back(k.position_m);
  const auto t = chord_knots(pts);
  const int n = static_cast<int>(pts.size());
  Eigen::MatrixXd y(n, 6);
  for (int i = 0; i < n; ++i) y.row(i) << pts[i].transpose(), knots[i].axis.transpose();
  const auto [d0, dn] = end_slopes(t, y);
  const auto ts = sample_params(t.back(), step_m);
  const Eigen::MatrixXd s = spline_eval(t, y, d0, dn, ts);
  std::vector<NozzlePose> out(ts.size());
  for (std::size_t k = 0; k < ts.size(); ++k) {
    out[k].position_m = s.row(k).head<3>().transpose();
    out[k].axis = s.row(k).tail<3>().transpose().normalized();
  }
  return out;
}

}  // namespace

std::vector<Eigen::Vector3d> clamped_cubic_spline(const std::vector<Eigen::Vector3d>& points, double step_m) {
  if (points.size() < 2) throw std::invalid_argument("spline: need at least 2 points");
  if (!(step_m > 0)) throw std::invalid_argument("spline: step_m must be > 0");
  const auto t = chord_knots(points);
  for (std::size_t i = 1; i < t.size(); ++i)
    if (!(t[i] > t[i - 1])) throw std::invalid_argument("spline: consecutive points coincide");
  const int n = static_cast<int>(points.size());
  Eigen::MatrixXd y(n, 3);
  for (int i = 0; i < n; ++i) y.row(i) = points[i].transpose();
  const auto [d0, dn] = end_slopes(t, y);
  const auto ts = sample_params(t.back(), step_m);
  const Eigen::MatrixXd s = spline_eval(t, y, d0, dn, ts);
  std::vector<Eigen::Vector3d> out(ts.size());
  for (std::size_t k = 0; k < ts.size(); ++k) out[k] = s.row(k).transpose();
  return out;
}

// ---------------------------------------------------------------------------------------------
// Pass geometry

std::vector<Pass> plan_passes(const Grid& grid, const std::vector<int>& cells, double spacing_m,
                              const PlannerConfig& config) {
  if (cells.empty()) return {};
  if (!(spacing_m > 0)) throw std::invalid_argument("plan_passes: spacing_m must be > 0");
  const bool axial = config.pass_direction == PassDirection::axial;
  const double R = grid.profile.radius_m, cs = grid.cell_size_m;
  // u runs along a pass, w across the passes; positions in metres of wall (s = theta * R, or d).
  const int n_u = axial ? grid.n_d : grid.n_theta, n_w = axial ? grid.n_theta : grid.n_d;
  auto cell_of = [&](int iu, int iw) { return axial ? grid.index(iw, iu) : grid.index(iu, iw); };
  const double w0 = axial ? grid.theta0_rad * R : grid.d0_m;  // lower edge of w index 0
  auto w_center = [&](int iw) { return w0 + (iw + 0.5) * cs; };
  int w_lo = n_w, w_hi = -1;
  double theta_sum = 0;
  for (int c : cells) {
    const int iw = axial ? grid.row_of(c) : grid.col_of(c);
    w_lo = std::min(w_lo, iw);
    w_hi = std::max(w_hi, iw);
    theta_sum += grid.theta_center(grid.row_of(c));
  }
  const double e0 = w0 + w_lo * cs, e1 = w0 + (w_hi + 1) * cs;
  const int n_lines = std::max(1, static_cast<int>(std::ceil((e1 - e0) / spacing_m - 1e-6)));
  const double mid = 0.5 * (e0 + e1);
  // Step up the wall: from the right springline toward the crown on the right side, from the left
  // springline toward the crown on the left side (theta > pi/2).
  const bool left_side = theta_sum / cells.size() > M_PI / 2;
  const bool step_down_w = axial && left_side;

  std::vector<char> in_set(grid.size(), 0);
  for (int c : cells) in_set[c] = 1;
  std::vector<Pass> passes;
  for (int k = 0; k < n_lines; ++k) {
    const int line = step_down_w ? n_lines - 1 - k : k;
    const double wk = mid + (line - 0.5 * (n_lines - 1)) * spacing_m;
    // Along-pass extent: the set's cells within half a spacing of this line.
    int u_lo = n_u, u_hi = -1;
    for (int c : cells) {
      const int iw = axial ? grid.row_of(c) : grid.col_of(c), iu = axial ? grid.col_of(c) : grid.row_of(c);
      if (std::abs(w_center(iw) - wk) <= 0.5 * spacing_m + 0.5 * cs) {
        u_lo = std::min(u_lo, iu);
        u_hi = std::max(u_hi, iu);
      }
    }
    if (u_hi < 0) continue;
    // Crossing points of the slicing plane with the wall, one per u, from the pair of cells that
    // straddle the plane (segment-plane intersection); the nearest valid cell where one is missing.
    std::vector<NozzlePose> knots;
    std::vector<double> knot_u;
    for (int iu = u_lo; iu <= u_hi; ++iu) {
      const int below = static_cast<int>(std::floor((wk - w0) / cs - 0.5));
      const int above = below + 1;
      const bool vb = below >= 0 && below < n_w && grid.valid[cell_of(iu, below)];
      const bool va = above >= 0 && above < n_w && grid.valid[cell_of(iu, above)];
      Eigen::Vector3d p, nrm;
      const double theta_k = wk / R;
      if (vb && va) {
        const Eigen::Vector3d p1 = grid.mean_xyz.row(cell_of(iu, below)).transpose();
        const Eigen::Vector3d p2 = grid.mean_xyz.row(cell_of(iu, above)).transpose();
        // Signed distances to the plane: theta = theta_k through the axis, or d = wk across it.
        auto side = [&](const Eigen::Vector3d& q) {
          if (!axial) return (q - grid.axis.origin_m).dot(grid.axis.ex) - wk;
          const Eigen::Vector3d tangent = -std::sin(theta_k) * grid.axis.ey + std::cos(theta_k) * grid.axis.ez;
          return (q - grid.axis.origin_m).dot(tangent);
        };
        const double s1 = side(p1), s2 = side(p2);
        const double u = std::abs(s1 - s2) > 1e-12 ? std::clamp(s1 / (s1 - s2), 0.0, 1.0) : 0.5;
        p = (1 - u) * p1 + u * p2;
        nrm = ((1 - u) * grid.mean_normal.row(cell_of(iu, below)) + u * grid.mean_normal.row(cell_of(iu, above)))
                  .transpose()
                  .normalized();
      } else if (vb || va) {
        const int c = cell_of(iu, vb ? below : above);
        const Eigen::Vector3d cyl = grid.axis.to_cylindrical(grid.mean_xyz.row(c).transpose());
        // Move the lone cell's point onto the plane, keeping its radius.
        p = axial ? grid.axis.to_cartesian(cyl[0], theta_k, cyl[2]) : grid.axis.to_cartesian(cyl[0], cyl[1], wk);
        nrm = grid.mean_normal.row(c).transpose();
      } else {
        continue;  // no data on either side of the plane here: the spline bridges the gap
      }
      NozzlePose pose;
      const Eigen::Vector3d q = p - grid.axis.origin_m;
      const Eigen::Vector3d radial = (q - q.dot(grid.axis.ex) * grid.axis.ex).normalized();
      if (config.offset_along_normal && nrm.allFinite() && nrm.norm() > 0.5) {
        pose.axis = -nrm;
        pose.position_m = p + config.standoff_m * nrm;
      } else {
        pose.axis = radial;
        pose.position_m = p - config.standoff_m * radial;
      }
      knots.push_back(pose);
      knot_u.push_back(iu);
    }
    if (knots.empty()) continue;
    if (knots.size() == 1) {
      // A one-cell-long line: a pass over that cell, from edge to edge.
      const Eigen::Vector3d dir = axial ? grid.axis.ex : Eigen::Vector3d(grid.axis.ex.cross(knots[0].axis).normalized());
      NozzlePose a = knots[0], b = knots[0];
      a.position_m -= 0.5 * cs * dir;
      b.position_m += 0.5 * cs * dir;
      knots = {a, b};
      knot_u = {knot_u[0], knot_u[0]};
    }
    // The nozzle keeps the standoff on average but does not follow every 5 cm bump of the rough
    // wall: the knots' distance from the axis is smoothed along the pass (binomial weights over
    // +-2 knots). Without it the path wiggles by up to 9 degrees per centimetre and the boom's
    // joint accelerations explode; on a smooth wall nothing changes.
    if (knots.size() >= 3) {
      const std::size_t m = knots.size();
      std::vector<Eigen::Vector3d> cyl(m);
      for (std::size_t i = 0; i < m; ++i) cyl[i] = grid.axis.to_cylindrical(knots[i].position_m);
      const double wts[5] = {1, 4, 6, 4, 1};
      for (std::size_t i = 0; i < m; ++i) {
        double sum = 0, wsum = 0;
        for (int o = -2; o <= 2; ++o) {
          const long j = static_cast<long>(i) + o;
          if (j < 0 || j >= static_cast<long>(m)) continue;
          sum += wts[o + 2] * cyl[j][0];
          wsum += wts[o + 2];
        }
        knots[i].position_m = grid.axis.to_cartesian(sum / wsum, cyl[i][1], cyl[i][2]);
      }
    }
    // At the bay's ends (the arches) run on past the last cell, so the end cells see the whole
    // spot like the others instead of half of it.
    if (axial && config.edge_overrun_m > 0) {
      if (knot_u.front() == 0) {
        NozzlePose extra = knots.front();
        extra.position_m -= config.edge_overrun_m * (knots[1].position_m - knots[0].position_m).normalized();
        knots.insert(knots.begin(), extra);
      }
      if (knot_u.back() == n_u - 1) {
        const std::size_t m = knots.size();
        NozzlePose extra = knots.back();
        extra.position_m += config.edge_overrun_m * (knots[m - 1].position_m - knots[m - 2].position_m).normalized();
        knots.push_back(extra);
      }
    }
    Pass pass;
    pass.line = line;
    pass.waypoints = spline_poses(knots, config.sample_step_m);
    pass.length_m = polyline_length(pass.waypoints);
    passes.push_back(std::move(pass));
  }
  for (std::size_t i = 0; i < passes.size(); ++i)
    if (i % 2 == 1) reverse_pass(passes[i]);  // serpentine
  return passes;
}

// ---------------------------------------------------------------------------------------------
// Round loop

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Lower TD bound (mm) of a level: a cell leaves level L once its TD falls below this.
double level_floor_mm(int level) {
  if (level >= 2) return 70.0 * level;
  if (level == 1) return 50.0;
  return -50.0;
}

// Thickness per grid cell left by a path at unit dwell weights, on the current cell surface.
struct CellSurface {
  std::vector<int> cell_ids;  // valid cells, in index order
  std::vector<int> slot;      // grid cell -> position in cell_ids (-1 if invalid)
  std::unique_ptr<SurfaceIndex> index;

  explicit CellSurface(const Grid& g) : slot(g.size(), -1) {
    Cloud c;
    for (int i = 0; i < g.size(); ++i)
      if (g.valid[i]) {
        slot[i] = static_cast<int>(cell_ids.size());
        cell_ids.push_back(i);
      }
    c.xyz.resize(cell_ids.size(), 3);
    c.normals.resize(cell_ids.size(), 3);
    for (std::size_t k = 0; k < cell_ids.size(); ++k) {
      c.xyz.row(k) = g.mean_xyz.row(cell_ids[k]);
      c.normals.row(k) = g.mean_normal.row(cell_ids[k]);
    }
    index = std::make_unique<SurfaceIndex>(c, g.cell_size_m * 2);
  }
};

// Deposit on the cells (per valid-cell slot) of a run of waypoints, each dwelling `dwell`.
Eigen::VectorXd unit_deposit(const SpotModel& model, const CellSurface& cs, const std::vector<NozzlePose>& poses,
                             const std::vector<double>& dwell, double rebound) {
  Eigen::VectorXd out = Eigen::VectorXd::Zero(cs.cell_ids.size());
  accumulate_dwells(model, *cs.index, poses, dwell, rebound, out);
  return out;
}

struct Sparse {
  std::vector<int> idx;
  std::vector<double> val;
};

Sparse sparsify(const Eigen::VectorXd& v) {
  Sparse s;
  for (Eigen::Index i = 0; i < v.size(); ++i)
    if (v[i] > 1e-9) {
      s.idx.push_back(static_cast<int>(i));
      s.val.push_back(v[i]);
    }
  return s;
}

// BOBYQA speeds of the passes of one region: minimise sum |Td - T_c(v)| over the region's cells.
// v_max: per pass upper bound (the machine's speed cap, at most max_speed_mps, above min_speed_mps).
std::vector<double> optimise_speeds(const std::vector<Eigen::VectorXd>& unit_per_pass, const std::vector<int>& slots,
                                    double target_m, const PlannerConfig& cfg, const std::vector<double>& v_max,
                                    std::string& note) {
  const int n = static_cast<int>(unit_per_pass.size());
  const int m = static_cast<int>(slots.size());
  // A (m x n): thickness on region cell i from pass j at 1 m/s; T = A * (1 / v).
  Eigen::MatrixXd A(m, n);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < m; ++i) A(i, j) = unit_per_pass[j][slots[i]];
  std::function<double(const std::vector<double>&)> objective = [&](const std::vector<double>& v) {
    Eigen::VectorXd w(n);
    for (int j = 0; j < n; ++j) w[j] = 1.0 / v[j];
    return ((A * w).array() - target_m).abs().sum() / m;
  };
  // Start: one common speed that gives the target on the median cell.
  std::vector<double> sums(m);
  for (int i = 0; i < m; ++i) sums[i] = A.row(i).sum();
  std::nth_element(sums.begin(), sums.begin() + m / 2, sums.end());
  double v0 = sums[m / 2] > 0 ? sums[m / 2] / target_m : cfg.min_speed_mps;
  std::vector<double> v(n), step(n);
  for (int j = 0; j < n; ++j) {
    v[j] = std::clamp(v0, cfg.min_speed_mps, v_max[j]);
    step[j] = std::min(0.25 * v[j], 0.45 * (v_max[j] - cfg.min_speed_mps));
  }
  if (n >= 2) {
    nlopt::opt opt(nlopt::LN_BOBYQA, n);
    opt.set_lower_bounds(std::vector<double>(n, cfg.min_speed_mps));
    opt.set_upper_bounds(v_max);
    opt.set_min_objective(
        [](const std::vector<double>& x, std::vector<double>&, void* data) {
          return (*static_cast<std::function<double(const std::vector<double>&)>*>(data))(x);
        },
        &objective);
    opt.set_xtol_rel(1e-4);
    opt.set_maxeval(400 * n);
    // BOBYQA needs its first step within half the bound gap.
    opt.set_initial_step(step);
    double best = 0;
    try {
      opt.optimize(v, best);
    } catch (const nlopt::roundoff_limited&) {
      // BOBYQA stopped on rounding: v holds its best point, which is what we want.
    } catch (const std::exception& e) {
      throw std::runtime_error(std::string("speed optimisation (BOBYQA) failed: ") + e.what());
    }
  } else {
    // One pass: the 1-D problem is solved exactly by a golden-section search on 1/v.
    double lo = 1.0 / v_max[0], hi = 1.0 / cfg.min_speed_mps;
    const double g = (std::sqrt(5.0) - 1) / 2;
    auto f = [&](double w) { return objective({1.0 / w}); };
    double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
    double f1 = f(x1), f2 = f(x2);
    for (int it = 0; it < 80; ++it) {
      if (f1 < f2) {
        hi = x2;
        x2 = x1;
        f2 = f1;
        x1 = hi - g * (hi - lo);
        f1 = f(x1);
      } else {
        lo = x1;
        x1 = x2;
        f1 = f2;
        x2 = lo + g * (hi - lo);
        f2 = f(x2);
      }
    }
    v[0] = 1.0 / (0.5 * (lo + hi));
  }
  for (int j = 0; j < n; ++j) v[j] = std::clamp(v[j], cfg.min_speed_mps, v_max[j]);
  // Can the slowest passes reach the target at all?
  Eigen::VectorXd slowest = A * Eigen::VectorXd::Constant(n, 1.0 / cfg.min_speed_mps);
  if (m > 0 && slowest.maxCoeff() < target_m) {
    std::ostringstream msg;
    msg << "target " << std::round(target_m * 1000) << " mm exceeds the " << std::round(slowest.maxCoeff() * 1000)
        << " mm that passes at the slowest speed " << cfg.min_speed_mps << " m/s leave; the cells need more rounds";
    note = msg.str();
  }
  return v;
}

// Box-constrained least squares for the dwell per unit length of every segment (optimal mode):
// min 1/2 |U w - t|^2 + lambda L.w,  w in {0} u [w_min, w_max]; coordinate descent.
// w_floor[j] > 0 forces segment j to spray with at least that dwell (speed caps from the limiter).
// w_min[j]: dwell at the segment's fastest allowed speed (max speed, or the machine's cap there).
std::vector<double> optimise_dwell(const std::vector<Sparse>& U, const std::vector<double>& seg_len,
                                   const Eigen::VectorXd& target, double lambda, const std::vector<double>& w_min,
                                   double w_max, const std::vector<double>& w_floor) {
  const std::size_t n = U.size();
  std::vector<double> w(n, 0.0), h(n, 0.0);
  Eigen::VectorXd res = -target;  // U w - t
  for (std::size_t j = 0; j < n; ++j)
    for (double v : U[j].val) h[j] += v * v;
  auto set = [&](std::size_t j, double value) {
    const double d = value - w[j];
    if (d == 0) return;
    for (std::size_t k = 0; k < U[j].idx.size(); ++k) res[U[j].idx[k]] += d * U[j].val[k];
    w[j] = value;
  };
  auto grad = [&](std::size_t j) {
    double g = lambda * seg_len[j];
    for (std::size_t k = 0; k < U[j].idx.size(); ++k) g += U[j].val[k] * res[U[j].idx[k]];
    return g;
  };
  for (int sweep = 0; sweep < 300; ++sweep) {
    double change = 0;
    for (std::size_t j = 0; j < n; ++j) {
      if (h[j] <= 0) continue;
      const double next = std::clamp(w[j] - grad(j) / h[j], w_floor[j], w_max);
      change = std::max(change, std::abs(next - w[j]));
      set(j, next);
    }
    if (change < 1e-4 * w_max) break;
  }
  // The nozzle cannot move faster than max speed while spraying: below w_min, either stop
  // spraying there or spray at max speed, whichever leaves the smaller objective; then polish.
  for (int pass = 0; pass < 3; ++pass) {
    for (std::size_t j = 0; j < n; ++j) {
      if (w[j] <= 0 || w[j] >= w_min[j] || w_floor[j] > 0) continue;
      auto objective_delta = [&](double value) {
        const double d = value - w[j];
        double delta = lambda * seg_len[j] * d;
        for (std::size_t k = 0; k < U[j].idx.size(); ++k) {
          const double r = res[U[j].idx[k]];
          delta += 0.5 * ((r + d * U[j].val[k]) * (r + d * U[j].val[k]) - r * r);
        }
        return delta;
      };
      set(j, objective_delta(0.0) <= objective_delta(w_min[j]) ? 0.0 : w_min[j]);
    }
    for (std::size_t j = 0; j < n; ++j) {
      if (w[j] <= 0 || h[j] <= 0) continue;  // skipped segments stay skipped
      set(j, std::clamp(w[j] - grad(j) / h[j], std::max(w_min[j], w_floor[j]), w_max));
    }
  }
  return w;
}

// The arm cannot change the nozzle speed at will: a cycloidal change from v0 to v1 over a length
// D peaks at |v1^2 - v0^2| / D. Along every pass line, cap the speeds (forward, then backward) so
// that this stays within accel_mps2; D is the shorter neighbouring segment (the timing changes
// speed across segment boundaries) or the spray-off gap between two sprayed segments. The nozzle
// crosses a gap at speeds between those of the segments on either side, so first both are capped
// by the slowest speed the machine allows in the gap (v_cap per segment, +inf: no cap).
template <class Seg>
std::vector<double> limit_speed_changes(const std::vector<Seg>& segs, std::vector<double> w, double accel_mps2,
                                        const std::vector<double>& v_cap) {
  auto same_line = [&](std::size_t a, std::size_t b) { return segs[a].side == segs[b].side && segs[a].pass == segs[b].pass; };
  for (std::size_t j = 0; j < segs.size(); ++j) {
    if (w[j] <= 0 || j + 1 >= segs.size() || w[j + 1] > 0 || !same_line(j, j + 1)) continue;
    std::size_t k = j + 1;
    double gap_cap = std::numeric_limits<double>::infinity();
    for (; k < segs.size() && same_line(j, k) && w[k] <= 0; ++k) gap_cap = std::min(gap_cap, v_cap[k]);
    if (k >= segs.size() || !same_line(j, k)) continue;  // the line ends: no gap to cross
    for (std::size_t e : {j, k})
      if (1.0 / w[e] > gap_cap) w[e] = 1.0 / gap_cap;
  }
  auto sweep = [&](bool forward) {
    const std::size_t n = segs.size();
    int prev = -1;
    double gap = 0.0;
    for (std::size_t k = 0; k < n; ++k) {
      const std::size_t j = forward ? k : n - 1 - k;
      if (prev >= 0 && (segs[j].side != segs[prev].side || segs[j].pass != segs[prev].pass)) prev = -1;
      if (w[j] <= 0) {
        if (prev >= 0) gap += segs[j].length_m;
        continue;
      }
      if (prev >= 0) {
        const double d = gap > 0 ? gap : std::min(segs[j].length_m, segs[prev].length_m);
        const double v_prev = 1.0 / w[prev], v_cap = std::sqrt(v_prev * v_prev + accel_mps2 * d);
        if (1.0 / w[j] > v_cap) w[j] = 1.0 / v_cap;
      }
      prev = static_cast<int>(j);
      gap = 0.0;
    }
  };
  sweep(true);
  sweep(false);
  return w;
}

// Volume of concrete missing from the cells (TD > 0), m^3, on the design-line cell area.
double missing_volume_m3(const Grid& g) {
  double v = 0;
  for (int c = 0; c < g.size(); ++c)
    if (g.valid[c] && g.td_m[c] > 0) v += g.td_m[c] * g.cell_size_m * g.cell_size_m;
  return v;
}

void order_regions(Round& round, const OrderingConfig& ocfg, const std::optional<Eigen::Vector3d>& start) {
  if (round.regions.empty()) return;
  OrderingProblem problem;
  for (const auto& r : round.regions) {
    problem.a_m.push_back(r.entry_m());
    problem.b_m.push_back(r.exit_m());
  }
  problem.start_m = start;
  const OrderingResult res = solve_ordering(problem, ocfg);
  std::vector<RegionPlan> ordered;
  for (int i : res.order) {
    RegionPlan r = round.regions[i];
    if (res.reversed[i]) {
      std::reverse(r.passes.begin(), r.passes.end());
      for (auto& p : r.passes) reverse_pass(p);
      r.reversed = true;
    }
    ordered.push_back(std::move(r));
  }
  round.regions = std::move(ordered);
  round.order = res.order;
  round.link_length_m = res.link_length_m;
  round.order_method = res.method;
}

// Split the passes of the levelling round into segments, one dwell variable each.
struct Segment {
  std::size_t side = 0, pass = 0;   // which region (wall side) and which of its passes
  std::size_t first = 0, last = 0;  // waypoint range [first, last]
  double length_m = 0;
};

}  // namespace

Plan plan_bay(const Surface& surface, const Config& config, const ProgressFn& progress, const SpeedCapFn& speed_cap) {
  validate(config);
  const auto t_start = Clock::now();
  auto report = [&](const std::string& stage, double f) {
    if (progress) progress(stage, f);
  };
  const PlannerConfig& pc = config.planner;
  const SpotModel model = spot_model_from_config(config.deposition);
  const double rebound = config.deposition.rebound_fraction;
  const double spacing = pass_spacing(model, 0.07).spacing_m;  // scale-free in the target
  if (!surface.cloud.has_normals()) throw std::invalid_argument("plan_bay: the surface cloud has no normals");

  Plan plan;
  plan.grid_before = surface.grid;
  // The bay as it is sprayed: the moved cloud and the per-cell view of it on the scan's grid.
  SprayedWall wall = unsprayed_wall(surface, config.profile.max_deviation_m);
  Cloud& cloud = wall.surface.cloud;
  Grid& grid = wall.surface.grid;
  std::vector<int>& levels = wall.surface.levels;
  plan.deposited_m = Eigen::VectorXd::Zero(surface.cloud.size());
  std::optional<Eigen::Vector3d> nozzle_at;
  const bool optimal = pc.mode == PlannerMode::optimal;
  plan.timings_s["setup"] = seconds_since(t_start);
  // Per waypoint: the fastest speed the machine allows there, within [min, max] speed (a cap below
  // the slowest speed is reported once per pass and sprayed at the slowest speed).
  double cap_seconds = 0.0;
  auto waypoint_caps = [&](const Pass& pass, const std::string& where) {
    std::vector<double> cap(pass.waypoints.size(), pc.max_speed_mps);
    if (!speed_cap) return cap;
    const auto t0 = Clock::now();
    const std::vector<double> c = speed_cap(pass.waypoints);
    cap_seconds += seconds_since(t0);
    if (c.size() != cap.size())
      throw std::runtime_error("plan_bay: the speed cap returned " + std::to_string(c.size()) + " values for " +
                               std::to_string(cap.size()) + " waypoints");
    double lowest = pc.max_speed_mps;
    for (std::size_t k = 0; k < cap.size(); ++k) {
      if (std::isnan(c[k])) throw std::runtime_error("plan_bay: the speed cap is NaN at waypoint " + std::to_string(k) + " of " + where);
      lowest = std::min(lowest, c[k]);
      cap[k] = std::clamp(c[k], pc.min_speed_mps, pc.max_speed_mps);
    }
    if (lowest < pc.min_speed_mps) {
      std::ostringstream msg;
      msg << where << ": the machine allows only " << lowest << " m/s on part of the pass, below planner.min_speed_mps "
          << pc.min_speed_mps << " m/s; sprayed at the slowest speed there";
      plan.warnings.push_back(msg.str());
    }
    return cap;
  };

  // Graded mode: cells whose level a round could not lower are set aside (reported), so the
  // rest of the bay still gets finished.
  std::vector<char> stuck(grid.size(), 0);
  auto active_levels = [&]() {
    std::vector<int> lv = levels;
    for (int c = 0; c < grid.size(); ++c)
      if (stuck[c]) lv[c] = kNoDataLevel;
    return lv;
  };
  std::optional<StopReason> stop;  // settled after the loop when no round gives a reason
  for (int round_no = 0; round_no < pc.max_rounds; ++round_no) {
    const auto counts_before = level_counts(levels);
    const std::vector<int> graded_levels = active_levels();
    int top = std::numeric_limits<int>::min();
    for (auto [lv, n] : level_counts(graded_levels)) top = std::max(top, lv);
    double max_td = -std::numeric_limits<double>::infinity();
    for (int c = 0; c < grid.size(); ++c)
      if (grid.valid[c]) max_td = std::max(max_td, grid.td_m[c]);
    const bool flush = optimal ? (top <= 0 && max_td <= pc.finish_tolerance_m) : top <= 0;
    if (flush) break;  // the reason is settled after the loop
    report("round " + std::to_string(round_no + 1), 0.0);
    const auto t_round = Clock::now();
    Round round;
    round.levels_before = counts_before;
    CellSurface cells(grid);
    const int n_slots = static_cast<int>(cells.cell_ids.size());

    if (!optimal) {
      round.kind = RoundKind::graded;
      round.level = top;
      const auto regions = find_regions(grid, graded_levels, top, config.regions.min_region_cells);
      for (std::size_t ri = 0; ri < regions.size(); ++ri) {
        RegionPlan rp;
        rp.region = regions[ri];
        // Thesis rule: the largest drop that takes every cell one level down (5 mm margin). For the
        // last step (level 1 -> 0) aim at the band's centre instead: the mean TD, so cells end near
        // flush rather than just inside +50 mm.
        rp.target_thickness_m = top == 1 ? std::max(rp.region.td_mean_m, rp.region.td_max_m - 0.045)
                                         : rp.region.td_max_m - level_floor_mm(top) / 1000.0 + 0.005;
        rp.spacing_m = spacing;
        rp.passes = plan_passes(grid, rp.region.cells, spacing, pc);
        if (rp.passes.empty()) continue;
        std::vector<Eigen::VectorXd> unit;
        for (const auto& p : rp.passes) {
          Pass unit_pass = p;
          unit_pass.speed_mps = 1.0;
          unit.push_back(unit_deposit(model, cells, p.waypoints, unit_pass.dwell_s(), rebound));
        }
        std::vector<int> slots;
        for (int c : rp.region.cells) slots.push_back(cells.slot[c]);
        const std::string where = "round " + std::to_string(round_no + 1) + ", region " + std::to_string(ri);
        std::vector<double> v_max;
        for (std::size_t j = 0; j < rp.passes.size(); ++j) {
          const auto cap = waypoint_caps(rp.passes[j], where + ", pass " + std::to_string(j));
          v_max.push_back(*std::min_element(cap.begin(), cap.end()));
          // BOBYQA needs lower < upper; a pass capped at the slowest speed keeps a hair of room.
          v_max.back() = std::max(v_max.back(), pc.min_speed_mps * (1.0 + 1e-6));
          if (v_max.back() < pc.max_speed_mps) ++plan.speed_capped;
        }
        std::vector<double> v;
        try {
          v = optimise_speeds(unit, slots, rp.target_thickness_m, pc, v_max, rp.note);
        } catch (const std::runtime_error& e) {
          throw std::runtime_error("round " + std::to_string(round_no + 1) + ", region " + std::to_string(ri) + ": " +
                                   e.what());
        }
        for (std::size_t j = 0; j < v.size(); ++j) rp.passes[j].speed_mps = v[j];
        if (!rp.note.empty())
          plan.warnings.push_back("round " + std::to_string(round_no + 1) + ", region " + std::to_string(ri) + ": " +
                                  rp.note);
        report("round " + std::to_string(round_no + 1), 0.6 * (ri + 1) / regions.size());
        round.regions.push_back(std::move(rp));
      }
    } else {
      round.kind = RoundKind::levelling;
      round.level = top;
      // Cells to cover: every cell that still misses more than the tolerance, split into the right
      // and left walls so each side is sprayed bottom-up.
      // One set of pass lines over every cell still short of flush (even spacing across the
      // crown), then split into the right and left walls so each side is sprayed bottom-up.
      std::vector<int> open_cells;
      Eigen::VectorXd target = Eigen::VectorXd::Zero(n_slots);
      for (int k = 0; k < n_slots; ++k) {
        const int c = cells.cell_ids[k];
        target[k] = std::max(0.0, grid.td_m[c]) * 1000.0;  // mm
        if (grid.td_m[c] > pc.finish_tolerance_m) open_cells.push_back(c);
      }
      std::vector<RegionPlan> sides;
      std::vector<Segment> segs;
      std::vector<Sparse> U;
      std::vector<double> seg_len;
      {
        // Closer lines than the two-pass spacing: the per-segment speeds then shape the layer
        // across the lines too (measured: RMS 6.5 mm instead of 10 mm on the default bay).
        const auto all = plan_passes(grid, open_cells, pc.levelling_spacing_ratio * spacing, pc);
        RegionPlan side[2];
        for (const auto& p : all) {
          const Eigen::Vector3d mid = p.waypoints[p.waypoints.size() / 2].position_m;
          const bool left = pc.pass_direction == PassDirection::axial && grid.axis.to_cylindrical(mid)[1] > M_PI / 2;
          side[left ? 1 : 0].passes.push_back(p);
        }
        std::reverse(side[1].passes.begin(), side[1].passes.end());  // left wall: springline up
        for (auto& c : open_cells)
          side[pc.pass_direction == PassDirection::axial && grid.theta_center(grid.row_of(c)) > M_PI / 2 ? 1 : 0]
              .region.cells.push_back(c);
        for (auto& rp : side) {
          if (rp.passes.empty()) continue;
          rp.region.level = top;
          rp.spacing_m = pc.levelling_spacing_ratio * spacing;
          sides.push_back(std::move(rp));
        }
      }
      std::vector<double> seg_cap;  // fastest speed the machine allows on each segment [m/s]
      for (std::size_t s = 0; s < sides.size(); ++s)
        for (std::size_t p = 0; p < sides[s].passes.size(); ++p) {
          const Pass& pass = sides[s].passes[p];
          const std::size_t nw = pass.waypoints.size();
          const auto cap = waypoint_caps(pass, "round " + std::to_string(round_no + 1) + ", side " + std::to_string(s) +
                                                   ", line " + std::to_string(pass.line));
          const std::size_t per = std::max<std::size_t>(1, std::llround(pc.segment_length_m / pc.sample_step_m));
          for (std::size_t a = 0; a + 1 < nw; a += per) {
            Segment seg;
            seg.side = s;
            seg.pass = p;
            seg.first = a;
            seg.last = std::min(nw - 1, a + per);
            std::vector<NozzlePose> poses(pass.waypoints.begin() + seg.first, pass.waypoints.begin() + seg.last + 1);
            Pass piece;
            piece.waypoints = poses;
            piece.speed_mps = 1.0;
            seg.length_m = polyline_length(poses);
            // thickness in mm per (s/m) of dwell: speed 1 m/s means dwell 1 s per metre.
            U.push_back(sparsify(unit_deposit(model, cells, poses, piece.dwell_s(), rebound) * 1000.0));
            seg_len.push_back(seg.length_m);
            segs.push_back(seg);
            seg_cap.push_back(*std::min_element(cap.begin() + seg.first, cap.begin() + seg.last + 1));
            if (seg_cap.back() < pc.max_speed_mps) ++plan.speed_capped;
          }
        }
      report("round " + std::to_string(round_no + 1), 0.3);
      // Least squares, then the arm's speed-change limit; the capped segments become floors of
      // the next solve so the others can compensate; the limiter has the last word.
      std::vector<double> floor(segs.size(), 0.0), w_min(segs.size());
      for (std::size_t j = 0; j < segs.size(); ++j) w_min[j] = 1.0 / seg_cap[j];
      std::vector<double> w;
      for (int it = 0; it < 3; ++it) {
        w = optimise_dwell(U, seg_len, target, pc.time_weight_mm2_per_s, w_min, 1.0 / pc.min_speed_mps, floor);
        const auto limited = limit_speed_changes(segs, w, config.timing.speed_change_accel_mps2, seg_cap);
        for (std::size_t j = 0; j < w.size(); ++j)
          if (limited[j] > w[j] * (1 + 1e-9)) floor[j] = std::max(floor[j], limited[j]);
        w = limited;
      }
      // Rebuild the passes: runs of sprayed segments become passes with a per-waypoint speed.
      for (std::size_t s = 0; s < sides.size(); ++s) {
        RegionPlan out = sides[s];
        out.passes.clear();
        for (std::size_t p = 0; p < sides[s].passes.size(); ++p) {
          const Pass& pass = sides[s].passes[p];
          Pass cur;
          auto flush_cur = [&]() {
            if (cur.waypoints.size() >= 2) {
              cur.length_m = polyline_length(cur.waypoints);
              cur.speed_mps = cur.length_m / cur.duration_s();
              out.passes.push_back(cur);
            }
            cur = Pass();
          };
          for (std::size_t j = 0; j < segs.size(); ++j) {
            if (segs[j].side != s || segs[j].pass != p) continue;
            if (w[j] <= 0) {
              flush_cur();
              continue;
            }
            const double v = 1.0 / w[j];
            const std::size_t from = cur.waypoints.empty() ? segs[j].first : segs[j].first + 1;
            if (cur.waypoints.empty()) cur.line = pass.line;
            for (std::size_t a = from; a <= segs[j].last; ++a) {
              cur.waypoints.push_back(pass.waypoints[a]);
              cur.speed_profile_mps.push_back(v);
            }
          }
          flush_cur();
        }
        if (!out.passes.empty()) round.regions.push_back(std::move(out));
      }
    }
    if (round.regions.empty()) {
      // Optimal mode: every segment was skipped, i.e. no spraying pays off at the time weight.
      stop = optimal && top <= 0
                 ? StopReason{StopKind::levelled, "no further pass pays off at planner.time_weight_mm2_per_s"}
                 : StopReason{StopKind::no_progress, "no pass could be planned over the remaining cells"};
      break;
    }
    order_regions(round, config.ordering, nozzle_at);
    nozzle_at = round.regions.back().exit_m();
    report("round " + std::to_string(round_no + 1), 0.7);

    // Simulate the round on the full cloud, then re-grade.
    SurfaceIndex index(cloud, 0.05);
    Eigen::VectorXd deposit = Eigen::VectorXd::Zero(cloud.size());
    for (const auto& r : round.regions)
      for (const auto& p : r.passes) {
        accumulate_dwells(model, index, p.waypoints, p.dwell_s(), rebound, deposit);
        round.spray_time_s += p.duration_s();
      }
    deposit_layer(wall, deposit);
    plan.deposited_m += deposit;
    round.levels_after = level_counts(levels);
    round.td_after_m = grid.td_m;
    plan.spray_time_s += round.spray_time_s;

    // Progress: did the sprayed cells leave their level (graded), or the largest TD fall (levelling)?
    double max_after = -std::numeric_limits<double>::infinity();
    for (int c = 0; c < grid.size(); ++c)
      if (grid.valid[c]) max_after = std::max(max_after, grid.td_m[c]);
    std::vector<int> not_lowered;
    if (!optimal)
      for (const auto& r : round.regions)
        for (int c : r.region.cells)
          if (levels[c] >= top) not_lowered.push_back(c);
    plan.timings_s["round_" + std::to_string(round_no + 1)] = seconds_since(t_round);
    plan.rounds.push_back(std::move(round));
    report("round " + std::to_string(plan.rounds.size()), 1.0);
    if (optimal && max_td - max_after <= 0.001) {
      // With the time weight, the last cells off flush are not worth another round.
      int top_now = std::numeric_limits<int>::min();
      for (auto [lv, n] : level_counts(levels)) top_now = std::max(top_now, lv);
      stop = top_now <= 0
                 ? StopReason{StopKind::levelled, "another round would lower the largest TD by less than 1 mm"}
                 : StopReason{StopKind::no_progress, "a levelling round lowered the largest TD by less than 1 mm"};
      break;
    }
    if (!optimal) {
      std::size_t sprayed = 0;
      for (const auto& r : plan.rounds.back().regions) sprayed += r.region.cells.size();
      if (not_lowered.size() == sprayed) {
        // Nothing moved down: set these cells aside and go on with the rest of the bay.
        for (int c : not_lowered) stuck[c] = 1;
        plan.warnings.push_back("round " + std::to_string(plan.rounds.size()) + ": " +
                                std::to_string(not_lowered.size()) + " cells of level " + std::to_string(top) +
                                " did not go down a level (too small a region or at the edge of the scan); set aside");
      }
    }
  }
  if (stop) {
    plan.stop_reason = *stop;
  } else {
    int top = std::numeric_limits<int>::min(), top_active = top;
    for (auto [lv, n] : level_counts(levels)) top = std::max(top, lv);
    for (auto [lv, n] : level_counts(active_levels())) top_active = std::max(top_active, lv);
    if (top <= 0)
      plan.stop_reason = {StopKind::flush, ""};
    else if (top_active <= 0)
      plan.stop_reason = {StopKind::no_progress, "the cells set aside stay above level 0"};
    else
      plan.stop_reason = {StopKind::max_rounds, ""};
  }
  for (int c = 0; c < grid.size(); ++c)
    if (grid.valid[c] && levels[c] > 0) plan.unreachable_cells.push_back(c);
  plan.td_after_m = grid.td_m;
  plan.sprayed_cloud = cloud;
  if (speed_cap) plan.timings_s["speed_caps"] = cap_seconds;
  plan.timings_s["total"] = seconds_since(t_start);
  plan.required_volume_m3 = missing_volume_m3(surface.grid);
  plan.deposition_rate_m3ps = model.volume_rate_m3ps() * (1.0 - rebound);
  plan.physical_limit_s = plan.required_volume_m3 / plan.deposition_rate_m3ps;
  return plan;
}

}  // namespace shotcrete
