#include "shotcrete/planning/passes.hpp"

#include <algorithm>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

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

void reverse_pass(Pass& p) {
  std::reverse(p.waypoints.begin(), p.waypoints.end());
  std::reverse(p.speed_profile_mps.begin(), p.speed_profile_mps.end());
  std::swap(p.tight_start, p.tight_end);
}

Eigen::Vector3d square_axis(const TunnelAxis& axis, const DesignProfile& profile, const Eigen::Vector3d& p) {
  const Eigen::Vector3d q = p - axis.origin_m;
  const Eigen::Vector3d radial = (q - q.dot(axis.ex) * axis.ex).normalized();
  if (profile.is_circle()) return radial;
  const Eigen::Vector3d n = design_normal(axis, profile, axis.to_cylindrical(p)[1]);
  return n.allFinite() ? n : radial;
}

Eigen::Vector3d leaned_axis(const Eigen::Vector3d& square_axis, const Eigen::Vector3d& lean) {
  const Eigen::Vector3d t = lean - lean.dot(square_axis) * square_axis;
  const double angle = t.norm();
  if (!(angle > 1e-9)) return square_axis;
  return (std::cos(angle) * square_axis + std::sin(angle) * t / angle).normalized();
}

double polyline_length(const std::vector<NozzlePose>& w) {
  double len = 0;
  for (std::size_t i = 0; i + 1 < w.size(); ++i) len += (w[i + 1].position_m - w[i].position_m).norm();
  return len;
}

// ---------------------------------------------------------------------------------------------
// Clamped cubic spline

namespace {

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

namespace {

// The unrolled wall as the passes see it: u runs along a pass, w across the passes; positions in
// metres of wall (s = theta * R, or d).
struct PassFrame {
  const Grid& grid;
  const std::vector<Eigen::Vector3d>* lean;  // per cell, or null: every pose square
  bool axial;
  double R, cs;
  int n_u, n_w;
  double w0;  // lower edge of w index 0
  double u0;  // lower edge of u index 0

  PassFrame(const Grid& g, const std::vector<Eigen::Vector3d>* lean_per_cell, bool along_axis)
      : grid(g),
        lean(lean_per_cell && !lean_per_cell->empty() ? lean_per_cell : nullptr),
        axial(along_axis),
        R(g.profile.radius_m),
        cs(g.cell_size_m),
        n_u(along_axis ? g.n_d : g.n_theta),
        n_w(along_axis ? g.n_theta : g.n_d),
        w0(along_axis ? g.theta0_rad * g.profile.radius_m : g.d0_m),
        u0(along_axis ? g.d0_m : g.theta0_rad * g.profile.radius_m) {}
  int cell_of(int iu, int iw) const { return axial ? grid.index(iw, iu) : grid.index(iu, iw); }
  int u_of(int c) const { return axial ? grid.col_of(c) : grid.row_of(c); }
  int w_of(int c) const { return axial ? grid.row_of(c) : grid.col_of(c); }
  double w_center(int iw) const { return w0 + (iw + 0.5) * cs; }
  Eigen::Vector3d lean_of(int c) const { return lean ? (*lean)[static_cast<std::size_t>(c)] : Eigen::Vector3d::Zero(); }
  bool leans(int c) const { return lean_of(c).norm() > 1e-9; }  // the cell's own lean, not a neighbour's
  // Where wall point p lies along the passes [m of wall].
  double u_at(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d cyl = grid.axis.to_cylindrical(p);
    return axial ? cyl[2] : cyl[1] * R;
  }
  // The lean over a wall point at u_m on cell (iu, iw): linear between the centres of that cell and
  // its neighbour along the pass (its own where that one holds no data). A knot stands at its
  // cell's mean point, which lies up to half a cell off the centre: with the cell's lean alone, a
  // lean fading 0.025 rad a cell along a pass turned the axis up to 3x faster or slower from knot
  // to knot, and the spline through those knots swung the boom's telescope at 3x its
  // acceleration limit (the face scene).
  Eigen::Vector3d lean_at(int iu, int iw, double u_m) const {
    const Eigen::Vector3d own = lean_of(cell_of(iu, iw));
    if (!lean) return own;
    const double t = (u_m - (u0 + (iu + 0.5) * cs)) / cs;
    const int next = t >= 0.0 ? iu + 1 : iu - 1;
    if (!std::isfinite(t) || next < 0 || next >= n_u || !grid.valid[cell_of(next, iw)]) return own;
    const double a = std::min(1.0, std::abs(t));
    const Eigen::Vector3d other = lean_of(cell_of(next, iw));
    const double n_own = own.norm(), n_other = other.norm();
    if (n_own < 1e-9 || n_other < 1e-9) return (1.0 - a) * own + a * other;  // a lean fading out
    // Two obstacles' leans meeting (beside a duct, toward the face): the angle and the direction
    // blended apart, so the knot never leans less than the smaller of the two (a blend of the
    // vectors leant less than either); leans pointing apart keep the cell's own.
    if (own.dot(other) <= 0.0) return own;
    return ((1.0 - a) * n_own + a * n_other) * ((1.0 - a) * own / n_own + a * other / n_other).normalized();
  }
};

// A wall point on a pass line: where, its normal, and the nozzle's lean over it.
struct Crossing {
  Eigen::Vector3d point, normal, lean;
  bool leaned = false;  // a cell it is read from leans (its own lean, not a neighbour's blended in)
};

// A pass line's knots before the spline: nozzle poses and the u index each came from.
struct LineKnots {
  std::vector<NozzlePose> poses;
  std::vector<int> u;
  std::vector<char> leaned;  // the knot's pose leans off square
  std::vector<Eigen::Vector3d> lean;  // by this (the lean field's vector: toward it, length = angle)
};

// Where the slicing plane at w = wk crosses the wall at u = iu: from the pair of cells that
// straddle the plane (segment-plane intersection), or the nearest valid cell where one is missing;
// nothing where there is no data on either side (the spline bridges the gap).
std::optional<Crossing> crossing_point(const PassFrame& f, int iu, double wk) {
  const Grid& grid = f.grid;
  const int below = static_cast<int>(std::floor((wk - f.w0) / f.cs - 0.5));
  const int above = below + 1;
  const bool vb = below >= 0 && below < f.n_w && grid.valid[f.cell_of(iu, below)];
  const bool va = above >= 0 && above < f.n_w && grid.valid[f.cell_of(iu, above)];
  const double theta_k = wk / f.R;
  if (vb && va) {
    const Eigen::Vector3d p1 = grid.mean_xyz.row(f.cell_of(iu, below)).transpose();
    const Eigen::Vector3d p2 = grid.mean_xyz.row(f.cell_of(iu, above)).transpose();
    // Signed distances to the plane: theta = theta_k through the axis, or d = wk across it.
    auto side = [&](const Eigen::Vector3d& q) {
      if (!f.axial) return (q - grid.axis.origin_m).dot(grid.axis.ex) - wk;
      const Eigen::Vector3d tangent = -std::sin(theta_k) * grid.axis.ey + std::cos(theta_k) * grid.axis.ez;
      return (q - grid.axis.origin_m).dot(tangent);
    };
    const double s1 = side(p1), s2 = side(p2);
    const double u = std::abs(s1 - s2) > 1e-12 ? std::clamp(s1 / (s1 - s2), 0.0, 1.0) : 0.5;
    const Eigen::Vector3d p = (1 - u) * p1 + u * p2;
    const Eigen::Vector3d nrm =
        ((1 - u) * grid.mean_normal.row(f.cell_of(iu, below)) + u * grid.mean_normal.row(f.cell_of(iu, above)))
            .transpose()
            .normalized();
    const double at = f.u_at(p);
    const Eigen::Vector3d lean = (1 - u) * f.lean_at(iu, below, at) + u * f.lean_at(iu, above, at);
    const bool leaned = f.leans(f.cell_of(iu, below)) || f.leans(f.cell_of(iu, above));
    return Crossing{p, nrm, lean, leaned};
  }
  if (!vb && !va) return std::nullopt;
  const int c = f.cell_of(iu, vb ? below : above);
  const Eigen::Vector3d cyl = grid.axis.to_cylindrical(grid.mean_xyz.row(c).transpose());
  // Move the lone cell's point onto the plane, keeping its radius.
  const Eigen::Vector3d p =
      f.axial ? grid.axis.to_cartesian(cyl[0], theta_k, cyl[2]) : grid.axis.to_cartesian(cyl[0], cyl[1], wk);
  return Crossing{p, Eigen::Vector3d(grid.mean_normal.row(c).transpose()), f.lean_at(iu, vb ? below : above, f.u_at(p)),
                  f.leans(c)};
}

// The nozzle pose over wall point p: the standoff along the normal nrm, or toward the axis; with a
// lean (tangent vector, length = angle [rad]) the spray axis tips toward it and the nozzle stands
// the standoff back along the tipped axis.
NozzlePose standoff_pose(const TunnelAxis& axis, const DesignProfile& profile, const Eigen::Vector3d& p,
                         const Eigen::Vector3d& nrm, const Eigen::Vector3d& lean, const PlannerConfig& config) {
  NozzlePose pose;
  const Eigen::Vector3d radial = square_axis(axis, profile, p);
  if (config.offset_along_normal && nrm.allFinite() && nrm.norm() > 0.5) {
    pose.axis = -nrm;
    pose.position_m = p + config.standoff_m * nrm;
  } else {
    pose.axis = radial;
    pose.position_m = p - config.standoff_m * radial;
  }
  const Eigen::Vector3d tipped = leaned_axis(pose.axis, lean);
  if (tipped != pose.axis) {
    pose.axis = tipped;
    pose.position_m = p - config.standoff_m * pose.axis;
  }
  return pose;
}

// The nozzle keeps the standoff on average but does not follow every 5 cm bump of the rough
// wall: the knots' distance from the axis is smoothed along the pass (binomial weights over
// +-2 knots). Without it the path wiggles by up to 9 degrees per centimetre and the boom's
// joint accelerations explode; on a smooth wall nothing changes.
// A leaning nozzle's distance from the axis changes with its lean: there the radii smoothed are
// those of the wall points it aims at (the standoff along the axis), and the nozzle stands back
// from the smoothed point along its own axis.
void smooth_knot_radii(const TunnelAxis& axis, std::vector<NozzlePose>& knots, bool leaned, double standoff_m) {
  if (knots.size() < 3) return;
  const std::size_t m = knots.size();
  std::vector<Eigen::Vector3d> cyl(m);
  for (std::size_t i = 0; i < m; ++i)
    cyl[i] = axis.to_cylindrical(leaned ? Eigen::Vector3d(knots[i].position_m + standoff_m * knots[i].axis) : knots[i].position_m);
  const double wts[5] = {1, 4, 6, 4, 1};
  for (std::size_t i = 0; i < m; ++i) {
    double sum = 0, wsum = 0;
    for (int o = -2; o <= 2; ++o) {
      const long j = static_cast<long>(i) + o;
      if (j < 0 || j >= static_cast<long>(m)) continue;
      sum += wts[o + 2] * cyl[j][0];
      wsum += wts[o + 2];
    }
    knots[i].position_m = axis.to_cartesian(sum / wsum, cyl[i][1], cyl[i][2]);
    if (leaned) knots[i].position_m -= standoff_m * knots[i].axis;
  }
}

// At the bay's ends (the arches) run on past the last cell, so the end cells see the whole
// spot like the others instead of half of it. Where the nozzle leans at that end (to keep clear of
// a face past it) it runs on at most leaned_edge_overrun_m with the lean held: a leaned spot lays most
// of its concrete on the side nearer the nozzle, so without a run-on the end cell gets only the
// far tail and the cells behind it the peak. obstructed_cells keeps that much room for it, and no
// more: an end whose lean points out past it (the obstacle lies beyond) and is no less than its
// neighbour's is tight (Pass::tight_*). Returns whether the front and the back end are.
std::pair<bool, bool> add_edge_overrun(LineKnots& k, int n_u, const PlannerConfig& config, const Eigen::Vector3d& ex) {
  const double overrun_m = config.edge_overrun_m;
  auto& knots = k.poses;
  // Knots past `end` (its neighbour `inner`) over `run` metres, outward along `out` (the lines are
  // built with u, i.e. d, increasing: -ex at the front, +ex at the back). A leaned nozzle's place
  // also moves toward or off the wall as its lean changes: there the run-on goes along the
  // tunnel's axis, which keeps the held spray axis on the wall, in steps no longer than the last
  // knots' (the axes are splined on the nozzle's path: one long step after short ones would
  // overshoot the lean).
  // At an end whose lean fades outward (its lean less than the knot's before it, the same way;
  // not tight: the obstacle lies the other way) the lean goes on fading and eases to a halt over
  // the run-on, by w (s - s^2 / 2F) at distance s (w the fade per metre of nozzle travel between
  // the last two knots, 0 at F = min(run, 2 lean / w) and held from there: square at most): held
  // from the last knot on, the turn stopped within one knot step (2.5 cm of nozzle travel on a
  // lean fading 0.5 rad/m) and the boom's telescope jerked at 1.7x its acceleration limit there
  // (the face scene). Read from the lean field, not the axes: the wall's normals turn from knot
  // to knot as well, and that is not carried on.
  auto run_on = [&](const NozzlePose& end, const NozzlePose& inner, bool leaned, const Eigen::Vector3d& out_dir,
                    const Eigen::Vector3d& lean_end, const Eigen::Vector3d& lean_inner, bool carry) {
    const Eigen::Vector3d along = end.position_m - inner.position_m;
    const double run = leaned ? leaned_edge_overrun_m(config, overrun_m) : overrun_m;
    std::vector<NozzlePose> out;
    if (!(run > 0)) return out;
    if (!leaned) {
      out.push_back(end);
      out.back().position_m += run * along.normalized();
      return out;
    }
    const double last = std::max(std::abs(along.dot(ex)), 1e-3);
    const int n = std::min(50, static_cast<int>(std::ceil(run / last - 1e-9)));
    const Eigen::Vector3d b = end.axis.normalized();
    const double l_end = lean_end.norm(), l_inner = lean_inner.norm();
    double w = 0.0;  // rad per metre of the nozzle's travel
    Eigen::Vector3d about = Eigen::Vector3d::Zero();  // lean direction x axis: tips the axis back
    if (carry && l_end > 1e-9 && l_inner > l_end && lean_end.dot(lean_inner) > 0.0 && along.norm() > 1e-9) {
      const Eigen::Vector3d c = (lean_end / l_end).cross(b);
      if (c.norm() > 1e-9 && c.allFinite()) {
        about = c.normalized();
        w = (l_inner - l_end) / along.norm();
      }
    }
    const double F = w > 0.0 ? std::min(run, 2.0 * l_end / w) : run;
    for (int i = 1; i <= n; ++i) {
      const double s = run * i / n, e = std::min(s, F);
      out.push_back(end);
      out.back().position_m += s * out_dir;
      if (w > 0.0) out.back().axis = (Eigen::AngleAxisd(w * (e - e * e / (2.0 * F)), about) * b).normalized();
    }
    return out;
  };
  // (k.u and k.leaned keep describing the cells' knots only: nothing reads them after this.)
  const std::size_t m = k.lean.size();
  // (Leans come in 0.05 rad steps up to a cap: the last two cells often lean alike by a face.)
  auto tight_at = [&](std::size_t end, std::size_t inner, const Eigen::Vector3d& out) {
    const Eigen::Vector3d& l = k.lean[end];
    return k.leaned[end] != 0 && l.dot(out) > 0.5 * l.norm() && l.norm() >= k.lean[inner].norm() - 1e-9;
  };
  std::pair<bool, bool> tight{false, false};
  if (k.u.front() == 0) {
    tight.first = m >= 2 && tight_at(0, 1, -ex);
    auto extra = run_on(knots.front(), knots[1], k.leaned.front() != 0, -ex, k.lean.front(), k.lean[std::min<std::size_t>(1, m - 1)],
                        m >= 2 && !tight.first);
    knots.insert(knots.begin(), extra.rbegin(), extra.rend());
  }
  if (k.u.back() == n_u - 1) {
    tight.second = m >= 2 && tight_at(m - 1, m - 2, ex);
    auto extra = run_on(knots.back(), knots[knots.size() - 2], k.leaned.back() != 0, ex, k.lean.back(),
                        k.lean[m >= 2 ? m - 2 : 0], m >= 2 && !tight.second);
    knots.insert(knots.end(), extra.begin(), extra.end());
  }
  return tight;
}

// The u ranges of a pass line over the cells within half a spacing of the slicing plane w = wk:
// one range from the first such cell to the last, or, with split_gap_m > 0, one per run of them,
// cut where more than split_gap_m of wall holds none of them (the line would otherwise spray the
// cells between, which need nothing, as much as its own).
std::vector<std::pair<int, int>> line_ranges(const PassFrame& f, const std::vector<int>& cells, double wk,
                                             double spacing_m, double split_gap_m) {
  std::vector<int> us;
  for (int c : cells)
    if (std::abs(f.w_center(f.w_of(c)) - wk) <= 0.5 * spacing_m + 0.5 * f.cs) us.push_back(f.u_of(c));
  if (us.empty()) return {};
  std::sort(us.begin(), us.end());
  std::vector<std::pair<int, int>> ranges{{us.front(), us.front()}};
  for (int u : us) {
    if (split_gap_m > 0 && (u - ranges.back().second - 1) * f.cs > split_gap_m + 1e-9) ranges.push_back({u, u});
    ranges.back().second = u;
  }
  return ranges;
}

// Knots of the pass on the slicing plane w = wk over u = u_lo..u_hi (none when no cell there has
// data on the plane).
LineKnots line_knots(const PassFrame& f, int u_lo, int u_hi, double wk, const PlannerConfig& config) {
  LineKnots k;
  for (int iu = u_lo; iu <= u_hi; ++iu) {
    const auto crossing = crossing_point(f, iu, wk);
    if (!crossing) continue;
    k.poses.push_back(standoff_pose(f.grid.axis, f.grid.profile, crossing->point, crossing->normal, crossing->lean, config));
    k.u.push_back(iu);
    k.leaned.push_back(crossing->leaned);
    k.lean.push_back(crossing->lean);
  }
  if (k.poses.size() == 1) {
    // A one-cell-long line: a pass over that cell, from edge to edge.
    const auto& axis = f.grid.axis;
    const Eigen::Vector3d dir = f.axial ? axis.ex : Eigen::Vector3d(axis.ex.cross(k.poses[0].axis).normalized());
    NozzlePose a = k.poses[0], b = k.poses[0];
    a.position_m -= 0.5 * f.cs * dir;
    b.position_m += 0.5 * f.cs * dir;
    k.poses = {a, b};
    k.u = {k.u[0], k.u[0]};
    k.leaned = {k.leaned[0], k.leaned[0]};
    k.lean = {k.lean[0], k.lean[0]};
  }
  return k;
}

}  // namespace

double longest_edge_overrun_m(const PlannerConfig& config) {
  const double own = config.mode == PlannerMode::optimal ? config.levelling_late_edge_overrun_m : config.graded_last_edge_overrun_m;
  return std::max(config.edge_overrun_m, own);
}

double leaned_edge_overrun_m(const PlannerConfig& config, double overrun_m) {
  return std::min(overrun_m, config.leaned_edge_overrun_m);
}

std::vector<Pass> plan_passes(const Grid& grid, const std::vector<int>& cells, double spacing_m,
                              const PlannerConfig& config, const std::vector<Eigen::Vector3d>* lean,
                              double split_gap_m) {
  if (cells.empty()) return {};
  if (!(spacing_m > 0)) throw std::invalid_argument("plan_passes: spacing_m must be > 0");
  if (!(split_gap_m >= 0)) throw std::invalid_argument("plan_passes: split_gap_m must be >= 0");
  if (lean && !lean->empty() && lean->size() != static_cast<std::size_t>(grid.size()))
    throw std::invalid_argument("plan_passes: lean has " + std::to_string(lean->size()) + " entries for " +
                                std::to_string(grid.size()) + " grid cells");
  const PassFrame f(grid, lean, config.pass_direction == PassDirection::axial);
  double theta_sum = 0;
  std::vector<int> ws;
  for (int c : cells) {
    ws.push_back(f.w_of(c));
    theta_sum += grid.theta_center(grid.row_of(c));
  }
  std::sort(ws.begin(), ws.end());
  ws.erase(std::unique(ws.begin(), ws.end()), ws.end());
  // The slicing planes: spacing_m apart, centred on the cells' extent across the lines. With
  // split_gap_m > 0 the cells are first parted where more than split_gap_m (and a spacing) of wall
  // across the lines holds none of them, and each part gets planes of its own: one lattice over
  // streaks metres apart puts the plane nearest a streak up to half a spacing off it, and the pass
  // then lays its peak on the flush wall beside the streak.
  std::vector<std::pair<int, int>> parts{{ws.front(), ws.front()}};
  const double part_gap_m = std::max(split_gap_m, spacing_m);
  for (int w : ws) {
    if (split_gap_m > 0 && (w - parts.back().second - 1) * f.cs > part_gap_m + 1e-9) parts.push_back({w, w});
    parts.back().second = w;
  }
  std::vector<double> planes;
  for (const auto& [w_lo, w_hi] : parts) {
    const double e0 = f.w0 + w_lo * f.cs, e1 = f.w0 + (w_hi + 1) * f.cs;
    const int n = std::max(1, static_cast<int>(std::ceil((e1 - e0) / spacing_m - 1e-6)));
    for (int k = 0; k < n; ++k) planes.push_back(0.5 * (e0 + e1) + (k - 0.5 * (n - 1)) * spacing_m);
  }
  const int n_lines = static_cast<int>(planes.size());
  // Step up the wall: from the right springline toward the crown on the right side, from the left
  // springline toward the crown on the left side (theta > pi/2).
  const bool left_side = theta_sum / cells.size() > M_PI / 2;
  const bool step_down_w = f.axial && left_side;

  std::vector<Pass> passes;
  int n_sprayed_lines = 0;
  for (int k = 0; k < n_lines; ++k) {
    const int line = step_down_w ? n_lines - 1 - k : k;
    const double wk = planes[line];
    std::vector<Pass> pieces;
    for (const auto& [u_lo, u_hi] : line_ranges(f, cells, wk, spacing_m, split_gap_m)) {
      LineKnots knots = line_knots(f, u_lo, u_hi, wk, config);
      if (knots.poses.empty()) continue;
      const bool leaned = std::any_of(knots.leaned.begin(), knots.leaned.end(), [](char l) { return l != 0; });
      smooth_knot_radii(grid.axis, knots.poses, leaned, config.standoff_m);
      std::pair<bool, bool> tight{false, false};
      if (f.axial && config.edge_overrun_m > 0) tight = add_edge_overrun(knots, f.n_u, config, grid.axis.ex);
      Pass pass;
      pass.line = line;
      pass.tight_start = tight.first;
      pass.tight_end = tight.second;
      pass.waypoints = spline_poses(knots.poses, config.sample_step_m);
      pass.length_m = polyline_length(pass.waypoints);
      pieces.push_back(std::move(pass));
    }
    if (pieces.empty()) continue;
    // Serpentine: every other line runs back, its pieces in reverse order.
    if (n_sprayed_lines++ % 2 == 1) {
      std::reverse(pieces.begin(), pieces.end());
      for (auto& p : pieces) reverse_pass(p);
    }
    for (auto& p : pieces) passes.push_back(std::move(p));
  }
  return passes;
}

}  // namespace shotcrete
