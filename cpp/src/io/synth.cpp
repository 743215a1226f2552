#include "shotcrete/io/synth.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

namespace shotcrete {

SyntheticBay make_synthetic_bay(const SynthConfig& c) {
  if (!(c.design_radius_m > 0)) throw std::invalid_argument("synth: design_radius_m must be > 0");
  if (!(c.length_m > 0)) throw std::invalid_argument("synth: length_m must be > 0");
  if (!(c.theta_max_rad > c.theta_min_rad)) throw std::invalid_argument("synth: theta_max_rad must exceed theta_min_rad");
  SyntheticBay bay;
  bay.config = c;
  ProfileConfig pc;
  pc.design_radius_m = c.design_radius_m;
  pc.section_path = c.section_path;
  bay.profile = design_profile_from_config(pc);
  if (const auto [th0, th1] = bay.wall_theta_span(); !bay.profile.is_circle() && !(th0 < th1))
    throw std::invalid_argument("synth: synth.theta_min_rad..theta_max_rad misses the section's span");
  std::mt19937_64 rng(c.seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double s0 = c.theta_min_rad * bay.profile.radius_m, s1 = c.theta_max_rad * bay.profile.radius_m;
  for (int i = 0; i < c.pit_count; ++i) {
    DigPit p;
    p.d_m = u(rng) * c.length_m;
    p.s_m = s0 + u(rng) * (s1 - s0);
    p.depth_m = c.pit_depth_min_m + u(rng) * (c.pit_depth_max_m - c.pit_depth_min_m);
    p.radius_m = c.pit_radius_min_m + u(rng) * (c.pit_radius_max_m - c.pit_radius_min_m);
    bay.pits.push_back(p);
  }
  return bay;
}

std::pair<double, double> SyntheticBay::wall_theta_span() const {
  return {std::max(config.theta_min_rad, profile.theta_min_rad()), std::min(config.theta_max_rad, profile.theta_max_rad())};
}

double SyntheticBay::td_at(double d_m, double theta_rad) const {
  const double s = theta_rad * profile.radius_m;
  double td = config.base_overbreak_m;
  for (const auto& p : pits) {
    const double q = ((d_m - p.d_m) * (d_m - p.d_m) + (s - p.s_m) * (s - p.s_m)) / (p.radius_m * p.radius_m);
    if (q < 1.0) td += p.depth_m * std::pow(1.0 - q, config.pit_shape_alpha);
  }
  if (config.protrusion_height_m > 0.0) {
    const double ds = s - config.protrusion_theta_rad * profile.radius_m, dd = d_m - config.protrusion_d_m;
    const double q = (dd * dd + ds * ds) / (config.protrusion_radius_m * config.protrusion_radius_m);
    if (q < 1.0) td -= config.protrusion_height_m * std::pow(1.0 - q, config.pit_shape_alpha);
  }
  return td;
}

Cloud SyntheticBay::sample(double cell_size_m) const {
  const auto& c = config;
  const auto [th0, th1] = wall_theta_span();
  const double arc = (th1 - th0) * profile.radius_m;
  const auto n = static_cast<Eigen::Index>(std::llround(arc * c.length_m / (cell_size_m * cell_size_m) * c.points_per_cell));
  if (n < 1) throw std::invalid_argument("synth: the bay would have no points");
  // A second stream, so the pits do not change when only the sampling density does.
  std::mt19937_64 rng(c.seed * 0x9E3779B97F4A7C15ULL + 17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, c.noise_m > 0 ? c.noise_m : 1.0);
  Cloud cloud;
  cloud.xyz.resize(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double d = u(rng) * c.length_m;
    const double theta = th0 + u(rng) * (th1 - th0);
    const double r = profile.radius_at(theta) + profile.radial_offset_m(td_at(d, theta), theta) + (c.noise_m > 0 ? noise(rng) : 0.0);
    cloud.xyz.row(i) = axis.to_cartesian(r, theta, d).transpose();
  }
  return cloud;
}

}  // namespace shotcrete

namespace shotcrete {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Appends n uniform samples of a surface: at(u1, u2) -> (point, unit normal) for u in [0, 1)^2,
// each point moved along its normal by Gaussian noise.
template <class At>
void sample_surface(std::vector<Eigen::Vector3d>& out, long n, double noise_m, std::mt19937_64& rng, At at) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, noise_m > 0 ? noise_m : 1.0);
  for (long i = 0; i < n; ++i) {
    Eigen::Vector3d p, nrm;
    if (!at(u(rng), u(rng), p, nrm)) continue;
    out.push_back(p + nrm * (noise_m > 0 ? noise(rng) : 0.0));
  }
}

Cloud to_cloud(const std::vector<Eigen::Vector3d>& pts) {
  Cloud c;
  c.xyz.resize(static_cast<Eigen::Index>(pts.size()), 3);
  for (size_t i = 0; i < pts.size(); ++i) c.xyz.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
  return c;
}

// A unit-variance Gaussian random field on the unrolled wall (d, s): sum of random Fourier modes
// with wave vectors ~ N(0, I / l^2), which gives the covariance exp(-h^2 / (2 l^2)).
struct RandomField {
  std::vector<Eigen::Vector2d> k;
  std::vector<double> phase;
  RandomField(double length_m, std::uint64_t seed, int modes = 64) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> g(0.0, 1.0 / length_m);
    std::uniform_real_distribution<double> u(0.0, 2.0 * kPi);
    for (int i = 0; i < modes; ++i) {
      k.emplace_back(g(rng), g(rng));
      phase.push_back(u(rng));
    }
  }
  double operator()(double d_m, double s_m) const {
    double sum = 0.0;
    for (size_t i = 0; i < k.size(); ++i) sum += std::cos(k[i].x() * d_m + k[i].y() * s_m + phase[i]);
    return sum * std::sqrt(2.0 / static_cast<double>(k.size()));
  }
};

}  // namespace

double SyntheticBay::muck_height_at(double d_m, double y_m) const {
  const auto& c = config;
  if (!(c.context_enabled && c.context_muck_height_m > 0 && c.context_invert_depth_m > 0)) return 0.0;
  const double u = (c.length_m - d_m) / c.context_muck_length_m, v = 2.0 * y_m / c.context_muck_width_m;
  if (u < 0.0 || u > 1.0 || std::abs(v) > 1.0) return 0.0;
  return c.context_muck_height_m * (1.0 - u) * (1.0 - v * v);
}

bool SyntheticBay::scanner_sees(const Eigen::Vector3d& p) const {
  const auto& c = config;
  if (!(c.context_enabled && c.context_scanner_shadow)) return true;
  // Both ends in the bay's frame: (d, y, z).
  const Eigen::Vector3d rel = p - axis.origin_m;
  const Eigen::Vector3d q(rel.dot(axis.ex), rel.dot(axis.ey), rel.dot(axis.ez));
  const Eigen::Vector3d& s = c.context_scanner_position_m;
  const Eigen::Vector3d dir = q - s;
  const double len = dir.norm();
  if (!(len > 0)) return true;
  // A surface point is its own first hit: anything the ray meets more than kTol short of it hides
  // it (kTol: 6 sigma of the default 5 mm noise along the normal; a noisy point may lie inside).
  constexpr double kTol = 0.03;
  const double t_max = 1.0 - kTol / len;
  if (t_max <= 0) return true;
  const double d_lo = -c.context_previous_bay_m;
  if (c.context_duct_diameter_m > 0) {  // the duct: a cylinder along d up to its outlet
    const double d_hi = std::min(c.length_m, c.context_duct_outlet_d_m);
    const double a = c.context_duct_diameter_m / 2, R = c.design_radius_m, yc = c.context_duct_y_m;
    const double zc = std::sqrt(R * R - yc * yc) - c.context_duct_gap_m - a;
    const double oy = s.y() - yc, oz = s.z() - zc, dy = dir.y(), dz = dir.z();
    const double A = dy * dy + dz * dz, B = 2 * (oy * dy + oz * dz), C = oy * oy + oz * oz - a * a;
    const double disc = B * B - 4 * A * C;
    if (A > 0 && disc > 0) {
      // The duct is a tube (its round, no ends): the ray is stopped where it crosses the round
      // within the duct's chainage, going in or coming out.
      for (const double t : {(-B - std::sqrt(disc)) / (2 * A), (-B + std::sqrt(disc)) / (2 * A)}) {
        if (!(t > 0 && t < t_max)) continue;
        const double d_hit = s.x() + t * dir.x();
        if (d_hit >= d_lo && d_hit <= d_hi) return false;
      }
    }
  }
  if (c.context_rig_length_m > 0 && c.context_invert_depth_m > 0) {  // the carrier: slab test on its box
    const Eigen::Vector3d lo(c.context_rig_front_d_m - c.context_rig_length_m, -c.context_rig_width_m / 2,
                             -c.context_invert_depth_m);
    const Eigen::Vector3d hi(c.context_rig_front_d_m, c.context_rig_width_m / 2,
                             -c.context_invert_depth_m + c.context_rig_height_m);
    double t_in = 0.0, t_out = t_max;
    bool hit = true;
    for (int k = 0; k < 3 && hit; ++k) {
      if (std::abs(dir[k]) < 1e-15) {
        if (s[k] < lo[k] || s[k] > hi[k]) hit = false;
        continue;
      }
      double ta = (lo[k] - s[k]) / dir[k], tb = (hi[k] - s[k]) / dir[k];
      if (ta > tb) std::swap(ta, tb);
      t_in = std::max(t_in, ta);
      t_out = std::min(t_out, tb);
      if (t_in > t_out) hit = false;
    }
    if (hit) return false;
  }
  if (c.context_muck_height_m > 0 && c.context_invert_depth_m > 0) {  // the muck: march the ray at 2 cm
    const double h = c.context_invert_depth_m;
    const int n = std::max(2, static_cast<int>(std::ceil(len * t_max / 0.02)));
    for (int i = 1; i < n; ++i) {
      const double t = t_max * i / n;
      const Eigen::Vector3d x = s + t * dir;
      if (x.z() < -h + muck_height_at(x.x(), x.y())) return false;
    }
  }
  return true;
}

Cloud SyntheticBay::sample_context(double cell_size_m, double points_per_cell, double noise_m,
                                   std::uint64_t seed) const {
  const auto& c = config;
  if (!c.context_enabled) return Cloud{};
  if (!profile.is_circle())
    throw std::invalid_argument("synth: the scene context (synth.context_enabled) is built around a circle; "
                                "it cannot be used with synth.section_path");
  const double density = points_per_cell / (cell_size_m * cell_size_m);  // points per m^2
  const double R = c.design_radius_m, h = c.context_invert_depth_m;
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ULL + 29);
  std::vector<Eigen::Vector3d> pts;
  if (c.context_previous_bay_m > 0) {  // lined: on the design line
    const double dth = c.theta_max_rad - c.theta_min_rad, len = c.context_previous_bay_m;
    sample_surface(pts, std::lround(dth * R * len * density), noise_m, rng,
                   [&](double u1, double u2, Eigen::Vector3d& p, Eigen::Vector3d& n) {
                     const double th = c.theta_min_rad + u1 * dth;
                     p = axis.to_cartesian(R, th, -len + u2 * len);
                     n = -axis.radial(th);
                     return true;
                   });
  }
  if (h > 0) {  // invert: under the previous bay and the new one
    const double d0 = -c.context_previous_bay_m, len = c.context_previous_bay_m + c.length_m;
    sample_surface(pts, std::lround(2 * R * len * density), noise_m, rng,
                   [&](double u1, double u2, Eigen::Vector3d& p, Eigen::Vector3d& n) {
                     const double d = d0 + u2 * len, y = -R + 2 * R * u1;
                     if (muck_height_at(d, y) > 0) return false;  // under the muck
                     p = axis.origin_m + axis.ex * d + axis.ey * y - axis.ez * h;
                     n = axis.ez;
                     return true;
                   });
  }
  if (c.context_face) {  // the face: inside the design circle, above the invert (or the springlines)
    const double zmin = h > 0 ? -h : 0.0;
    const double area_box = 2 * R * (R - zmin);
    sample_surface(pts, std::lround(area_box * density), noise_m, rng,
                   [&](double u1, double u2, Eigen::Vector3d& p, Eigen::Vector3d& n) {
                     const double y = -R + 2 * R * u1, z = zmin + (R - zmin) * u2;
                     if (y * y + z * z > R * R) return false;  // rejection: only the disc's part
                     if (h > 0 && z < -h + muck_height_at(c.length_m, y)) return false;  // behind the muck
                     p = axis.origin_m + axis.ex * c.length_m + axis.ey * y + axis.ez * z;
                     n = -axis.ex;
                     return true;
                   });
  }
  if (c.context_duct_diameter_m > 0) {  // the duct: its whole round, from the lined bay's start to its outlet
    const double a = c.context_duct_diameter_m / 2, y = c.context_duct_y_m;
    if (!(std::abs(y) < R)) throw std::invalid_argument("synth: context_duct_y_m puts the duct outside the design circle");
    const double zc = std::sqrt(R * R - y * y) - c.context_duct_gap_m - a;
    const double d0 = -c.context_previous_bay_m, len = std::min(c.length_m, c.context_duct_outlet_d_m) - d0;
    if (!(len > 0))
      throw std::invalid_argument("synth: context_duct_outlet_d_m (" + std::to_string(c.context_duct_outlet_d_m) +
                                  " m) ends the duct before the lined bay's start (d = " + std::to_string(d0) + " m)");
    sample_surface(pts, std::lround(2 * kPi * a * len * density), noise_m, rng,
                   [&](double u1, double u2, Eigen::Vector3d& p, Eigen::Vector3d& n) {
                     const double phi = 2 * kPi * u1;
                     n = axis.ey * std::cos(phi) + axis.ez * std::sin(phi);
                     p = axis.origin_m + axis.ex * (d0 + u2 * len) + axis.ey * y + axis.ez * zc + a * n;
                     return true;
                   });
  }
  if (c.context_muck_height_m > 0) {  // the muck: z = -h + muck_height_at(d, y) over its footprint
    if (!(h > 0)) throw std::invalid_argument("synth: the muck (context_muck_height_m) lies on the invert; set context_invert_depth_m > 0");
    const double H = c.context_muck_height_m, L = c.context_muck_length_m, W = c.context_muck_width_m;
    // Uniform on the surface: footprint samples kept with probability (area element) / (its maximum).
    const double gmax = std::hypot(H / L, 2.0 * H / (W / 2)), smax = std::sqrt(1 + gmax * gmax);
    std::uniform_real_distribution<double> keep(0.0, smax);
    sample_surface(pts, std::lround(L * W * smax * density), noise_m, rng,
                   [&](double u1, double u2, Eigen::Vector3d& p, Eigen::Vector3d& n) {
                     const double d = c.length_m - L * u2, y = -W / 2 + W * u1;
                     const double u = (c.length_m - d) / L, v = 2 * y / W;
                     const double gd = H / L * (1 - v * v);             // dz/dd
                     const double gy = -H * (1 - u) * 2 * v * 2 / W;    // dz/dy
                     const double area = std::sqrt(1 + gd * gd + gy * gy);
                     if (keep(rng) > area) return false;
                     n = (-gd * axis.ex - gy * axis.ey + axis.ez).normalized();
                     p = axis.origin_m + axis.ex * d + axis.ey * y + axis.ez * (-h + muck_height_at(d, y));
                     return true;
                   });
  }
  if (c.context_rig_length_m > 0) {  // the carrier: a box on the invert, its five faces above it
    if (!(h > 0)) throw std::invalid_argument("synth: the rig (context_rig_length_m) stands on the invert; set context_invert_depth_m > 0");
    const double L = c.context_rig_length_m, W = c.context_rig_width_m, H = c.context_rig_height_m;
    const Eigen::Vector3d lo = axis.origin_m + axis.ex * (c.context_rig_front_d_m - L) - axis.ey * (W / 2) - axis.ez * h;
    // Face k: corner + u1 * e1 + u2 * e2, outward normal.
    const std::array<std::array<Eigen::Vector3d, 4>, 5> faces{{
        {lo + axis.ez * H, axis.ex * L, axis.ey * W, axis.ez},         // top
        {lo, axis.ex * L, axis.ez * H, -axis.ey},                      // right side
        {lo + axis.ey * W, axis.ex * L, axis.ez * H, axis.ey},         // left side
        {lo, axis.ey * W, axis.ez * H, -axis.ex},                      // back
        {lo + axis.ex * L, axis.ey * W, axis.ez * H, axis.ex}}};       // front, toward the face
    for (const auto& f : faces)
      sample_surface(pts, std::lround(f[1].norm() * f[2].norm() * density), noise_m, rng,
                     [&](double u1, double u2, Eigen::Vector3d& p, Eigen::Vector3d& n) {
                       p = f[0] + u1 * f[1] + u2 * f[2];
                       n = f[3];
                       return true;
                     });
  }
  return to_cloud(pts);
}

Cloud SyntheticBay::sample_scan(double cell_size_m) const {
  Cloud bay = sample(cell_size_m);
  if (!config.context_enabled) return bay;
  const Cloud ctx = sample_context(cell_size_m, config.points_per_cell, config.noise_m, config.seed);
  Cloud out;
  out.xyz.resize(bay.size() + ctx.size(), 3);
  out.xyz << bay.xyz, ctx.xyz;
  return drop_shadowed(out);
}

Cloud SyntheticBay::drop_shadowed(const Cloud& cloud) const {
  if (!(config.context_enabled && config.context_scanner_shadow)) return cloud;
  const auto& c = config;
  const Eigen::Vector3d& sp = c.context_scanner_position_m;
  const double R = c.design_radius_m, h = c.context_invert_depth_m;
  if (!(std::hypot(sp.y(), sp.z()) < R) || (h > 0 && !(sp.z() > -h + muck_height_at(sp.x(), sp.y()))))
    throw std::invalid_argument("synth: context_scanner_position_m lies outside the tunnel (beyond the design circle, "
                                "under the invert or in the muck)");
  if (c.context_duct_diameter_m > 0) {
    const double a = c.context_duct_diameter_m / 2, zc = std::sqrt(R * R - c.context_duct_y_m * c.context_duct_y_m) -
                                                         c.context_duct_gap_m - a;
    if (std::hypot(sp.y() - c.context_duct_y_m, sp.z() - zc) <= a && sp.x() >= -c.context_previous_bay_m &&
        sp.x() <= std::min(c.length_m, c.context_duct_outlet_d_m))
      throw std::invalid_argument("synth: context_scanner_position_m lies inside the duct");
  }
  if (c.context_rig_length_m > 0 && h > 0 && sp.x() >= c.context_rig_front_d_m - c.context_rig_length_m &&
      sp.x() <= c.context_rig_front_d_m && std::abs(sp.y()) <= c.context_rig_width_m / 2 &&
      sp.z() <= -h + c.context_rig_height_m)
    throw std::invalid_argument("synth: context_scanner_position_m lies inside the rig's carrier");
  std::vector<Eigen::Vector3d> kept;
  kept.reserve(static_cast<size_t>(cloud.size()));
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    const Eigen::Vector3d p = cloud.xyz.row(i).transpose().cast<double>();
    if (scanner_sees(p)) kept.push_back(p);
  }
  return to_cloud(kept);
}

Eigen::Matrix4d after_pose(const SynthConfig& c) {
  const Eigen::Vector3d& rpy = c.after_pose_rpy_rad;
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                             Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                             Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX())).toRotationMatrix();
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = R;
  T.topRightCorner<3, 1>() = c.after_pose_translation_m;
  return T;
}

AfterScan make_after_scan(const SyntheticBay& bay, const Grid& lattice, const Eigen::VectorXd& deposit_m,
                          const Config& config) {
  const auto& c = bay.config;
  if (deposit_m.size() != lattice.size())
    throw std::invalid_argument("synth --after: " + std::to_string(deposit_m.size()) + " deposit values for a grid of " +
                                std::to_string(lattice.size()) + " cells");
  if (std::abs(lattice.profile.radius_m - bay.profile.radius_m) > 1e-6 ||
      lattice.profile.polyline_m.size() != bay.profile.polyline_m.size())
    throw std::invalid_argument("synth --after: the job's design profile (radius " + std::to_string(lattice.profile.radius_m) +
                                " m) is not the synthetic bay's (radius " + std::to_string(bay.profile.radius_m) +
                                " m; another bay or another config)");
  AfterScan out;
  out.layer_scale = c.after_flow_scale * (1.0 - c.after_rebound_fraction) / (1.0 - config.deposition.rebound_fraction);
  const RandomField field(c.after_noise_length_m, c.after_seed * 0x9E3779B97F4A7C15ULL + 5);
  const int nt = lattice.n_theta, nd = lattice.n_d;
  auto dep = [&](int row, int col) {
    row = std::clamp(row, 0, nt - 1);
    col = std::clamp(col, 0, nd - 1);
    const int cell = lattice.index(row, col);
    const double v = deposit_m[cell];
    return lattice.valid[static_cast<size_t>(cell)] && std::isfinite(v) ? v : 0.0;
  };
  const DesignProfile& prof = bay.profile;
  const double R = prof.radius_m;
  auto layer = [&](double d, double theta) {
    // Bilinear between cell centres (clamped at the lattice's edges).
    const double fr = (theta - lattice.theta0_rad) / lattice.dtheta_rad - 0.5;
    const double fc = (d - lattice.d0_m) / lattice.cell_size_m - 0.5;
    const int r0 = static_cast<int>(std::floor(fr)), c0 = static_cast<int>(std::floor(fc));
    const double a = fr - r0, b = fc - c0;
    const double D = (1 - a) * ((1 - b) * dep(r0, c0) + b * dep(r0, c0 + 1)) +
                     a * ((1 - b) * dep(r0 + 1, c0) + b * dep(r0 + 1, c0 + 1));
    return std::max(0.0, out.layer_scale * D * (1.0 + c.after_thickness_noise * field(d, theta * R)));
  };
  // Ground truth: the layer's mean over each cell (8 x 8 midpoints).
  out.true_thickness_m = Eigen::VectorXd::Constant(lattice.size(), std::numeric_limits<double>::quiet_NaN());
  for (int cell = 0; cell < lattice.size(); ++cell) {
    if (!lattice.valid[static_cast<size_t>(cell)]) continue;
    const int row = lattice.row_of(cell), col = lattice.col_of(cell);
    double sum = 0;
    for (int i = 0; i < 8; ++i)
      for (int j = 0; j < 8; ++j)
        sum += layer(lattice.d0_m + (col + (j + 0.5) / 8.0) * lattice.cell_size_m,
                     lattice.theta0_rad + (row + (i + 0.5) / 8.0) * lattice.dtheta_rad);
    out.true_thickness_m[cell] = sum / 64.0;
  }
  // The sprayed bay, sampled afresh.
  const auto [th0, th1] = bay.wall_theta_span();
  const double arc = (th1 - th0) * R;
  const double cs = config.grid.cell_size_m;
  const long n = std::lround(arc * c.length_m / (cs * cs) * c.after_points_per_cell);
  std::mt19937_64 rng(c.after_seed * 0x9E3779B97F4A7C15ULL + 17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, c.after_noise_m > 0 ? c.after_noise_m : 1.0);
  std::vector<Eigen::Vector3d> pts;
  pts.reserve(static_cast<size_t>(n));
  for (long i = 0; i < n; ++i) {
    const double d = u(rng) * c.length_m;
    const double theta = th0 + u(rng) * (th1 - th0);
    const double r = prof.radius_at(theta) + prof.radial_offset_m(bay.td_at(d, theta) - layer(d, theta), theta) +
                     (c.after_noise_m > 0 ? noise(rng) : 0.0);
    pts.push_back(bay.axis.to_cartesian(r, theta, d));
  }
  const Cloud ctx = bay.sample_context(cs, c.after_points_per_cell, c.after_noise_m, c.after_seed);
  for (Eigen::Index i = 0; i < ctx.size(); ++i) pts.push_back(ctx.xyz.row(i).transpose());
  if (c.context_enabled && c.context_scanner_shadow)
    pts.erase(std::remove_if(pts.begin(), pts.end(), [&](const Eigen::Vector3d& p) { return !bay.scanner_sees(p); }),
              pts.end());
  // Seen from the after-scan's pose: p_after = R^T (p_before - t).
  out.pose = after_pose(c);
  const Eigen::Matrix3d Rt = out.pose.topLeftCorner<3, 3>().transpose();
  const Eigen::Vector3d t = out.pose.topRightCorner<3, 1>();
  for (auto& p : pts) p = Rt * (p - t);
  out.cloud = to_cloud(pts);
  return out;
}

}  // namespace shotcrete
