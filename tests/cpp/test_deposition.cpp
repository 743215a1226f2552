// Deposition model: stroke fit vs the measured CSV and an exhaustive grid, eq. 2-13 on planes and a
// cylinder vs independent quadrature, mass balance, spatial index vs brute force, pass spacing vs
// an exhaustive scan, bad inputs.
#ifdef _OPENMP
#include <omp.h>
#endif
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iostream>
#include <limits>
#include <random>
#include <string>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/io/synth.hpp"

using namespace shotcrete;

namespace {

constexpr double kPi = 3.14159265358979323846;
const std::string kCsv = std::string(SHOTCRETE_DATA_DIR) + "/deposition_stroke.csv";

StrokeFit measured_fit() {
  static const StrokeFit fit = fit_stroke(read_stroke_csv(kCsv, 1.0, 0.15, 0.08));
  return fit;
}

std::string write_tmp(const std::string& name, const std::string& text) {
  // Prefixed: other test binaries write their own bad.csv into TempDir at the same time (ctest -j).
  const std::string path = ::testing::TempDir() + "/deposition_" + name;
  std::ofstream(path) << text;
  return path;
}

// Lattice on the plane through `origin` spanned by unit u, v, normal n = unit(u x v) flipped to
// `toward`; spacing h, extents [-a, a] x [-b, b]. Each point stands for an area h^2.
Cloud plane_lattice(const Eigen::Vector3d& origin, const Eigen::Vector3d& u, const Eigen::Vector3d& v, double a, double b,
                    double h, const Eigen::Vector3d& toward) {
  Eigen::Vector3d n = u.cross(v).normalized();
  if (n.dot(toward) < 0) n = -n;
  const int nu = static_cast<int>(std::round(2 * a / h)), nv = static_cast<int>(std::round(2 * b / h));
  Cloud c;
  c.xyz.resize(static_cast<Eigen::Index>(nu) * nv, 3);
  c.normals.resize(c.xyz.rows(), 3);
  Eigen::Index k = 0;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      c.xyz.row(k) = (origin + (-a + (i + 0.5) * h) * u + (-b + (j + 0.5) * h) * v).transpose();
      c.normals.row(k++) = n.transpose();
    }
  return c;
}

// Independent eq. 2-13: r_proj from the intersection of the ray with the reference plane at H0,
// angles from acos, q0 from the spot formula.
double reference_rate(const SpotModel& m, const Eigen::Vector3d& c, const Eigen::Vector3d& axis, const Eigen::Vector3d& p,
                      const Eigen::Vector3d& n) {
  const Eigen::Vector3d a = axis.normalized(), d = p - c;
  const double L = d.norm();
  if (d.dot(a) <= 0) return 0;
  const Eigen::Vector3d hit = c + d * (m.reference_standoff_m / d.dot(a));
  const double r_proj = (hit - (c + m.reference_standoff_m * a)).norm();
  const double theta = std::acos(std::min(1.0, d.dot(a) / L));
  const double gamma = std::acos(std::clamp(n.normalized().dot(-d / L), -1.0, 1.0));
  if (r_proj >= m.radius_m || gamma >= kPi / 2) return 0;
  const double q0 = m.peak_rate_mps * std::pow(1 - r_proj * r_proj / (m.radius_m * m.radius_m), m.beta - 1);
  return q0 * std::pow(m.reference_standoff_m / L, 2) * std::cos(gamma) / std::pow(std::cos(theta), 3);
}

// Composite Simpson over the straight pass c(s) = c0 + s e, s in [0, len], at speed v.
double reference_pass(const SpotModel& m, const Eigen::Vector3d& c0, const Eigen::Vector3d& e, double len,
                      const Eigen::Vector3d& axis, double v, double rebound, const Eigen::Vector3d& p,
                      const Eigen::Vector3d& n, int intervals = 20000) {
  const double h = len / intervals;
  double sum = 0;
  for (int k = 0; k <= intervals; ++k) {
    const double w = (k == 0 || k == intervals) ? 1 : (k % 2 ? 4 : 2);
    sum += w * reference_rate(m, c0 + k * h * e, axis, p, n);
  }
  return sum * h / 3 / v * (1 - rebound);
}

SpotModel default_model() { return spot_model_from_config(DepositionConfig{}); }

}  // namespace

// ------------------------------------------------------------------ fit

TEST(Fit, BeatsPublishedStrokeMse) {
  const StrokeFit fit = measured_fit();
  std::cout << "fit: R = " << fit.model.radius_m * 1e3 << " mm, cone half-angle = "
            << fit.model.cone_half_angle_rad() * 180 / kPi << " deg, beta = " << fit.model.beta
            << ", stroke exponent = " << fit.stroke_exponent << ", q_max = " << fit.model.peak_rate_mps * 1e3
            << " mm/s, peak = " << fit.peak_thickness_m * 1e3 << " mm, offset = " << fit.center_offset_m * 1e3
            << " mm, MSE = " << fit.mse_mm2 << " mm^2, flow = " << fit.flow_m3ph << " m^3/h sprayed, "
            << fit.deposited_flow_m3ph << " m^3/h deposited, " << fit.evaluations << " evaluations\n";
  EXPECT_LT(fit.mse_mm2, 1.2);
  // The published parameters (stroke exponent 1.7, R 201 mm, peak 39.6 mm) on the same data.
  const StrokeData d = read_stroke_csv(kCsv);
  double pub = 0, ours = 0;
  for (size_t i = 0; i < d.position_m.size(); ++i) {
    const double x = d.position_m[i] * 1e3, u = x / 201.0;
    const double tp = u * u < 1 ? 39.6 * std::pow(1 - u * u, 1.7) : 0.0;
    pub += std::pow(tp - d.thickness_m[i] * 1e3, 2);
    ours += std::pow(fit.stroke_at_m(d.position_m[i]) * 1e3 - d.thickness_m[i] * 1e3, 2);
  }
  pub /= d.position_m.size();
  ours /= d.position_m.size();
  EXPECT_NEAR(ours, fit.mse_mm2, 1e-9);  // the reported MSE is the MSE of the reported profile
  EXPECT_LT(fit.mse_mm2, pub);
}

TEST(Fit, OptimumNotBeatenByExhaustiveGrid) {
  // Independent brute force: grid over (R, p, x0) with the amplitude by linear least squares.
  const StrokeData d = read_stroke_csv(kCsv);
  const StrokeFit fit = measured_fit();
  double best = 1e300;
  for (double R = 150; R <= 260; R += 0.5)
    for (double p = 0.8; p <= 3.0; p += 0.01)
      for (double x0 = -10; x0 <= 10; x0 += 1.0) {
        double ft = 0, ff = 0;
        std::vector<double> f(d.position_m.size());
        for (size_t i = 0; i < f.size(); ++i) {
          const double u = (d.position_m[i] * 1e3 - x0) / R;
          f[i] = u * u < 1 ? std::pow(1 - u * u, p) : 0;
          ft += f[i] * d.thickness_m[i] * 1e3;
          ff += f[i] * f[i];
        }
        double s = 0;
        for (size_t i = 0; i < f.size(); ++i) s += std::pow(ft / ff * f[i] - d.thickness_m[i] * 1e3, 2);
        best = std::min(best, s / f.size());
      }
  EXPECT_LE(fit.mse_mm2, best + 1e-9);
  EXPECT_GT(fit.mse_mm2, best - 0.02);  // a 0.5 mm / 0.01 / 1 mm grid lands close to the optimum
}

TEST(Fit, RecoversKnownParameters) {
  SpotModel truth;
  truth.radius_m = 0.23;
  truth.beta = 2.7;
  truth.peak_rate_mps = 0.03;
  StrokeData d;
  d.speed_mps = 0.2;
  d.rebound_fraction = 0.1;
  for (double x = -0.3; x <= 0.3001; x += 0.015) {
    d.position_m.push_back(x + 0.004);
    d.thickness_m.push_back(stroke_thickness_m(truth, x, d.speed_mps) * (1 - d.rebound_fraction));
  }
  const StrokeFit fit = fit_stroke(d);
  EXPECT_NEAR(fit.model.radius_m, truth.radius_m, 1e-5);
  EXPECT_NEAR(fit.model.beta, truth.beta, 1e-4);
  EXPECT_NEAR(fit.model.peak_rate_mps / truth.peak_rate_mps, 1.0, 1e-4);
  EXPECT_NEAR(fit.center_offset_m, 0.004, 1e-6);
  EXPECT_LT(fit.mse_mm2, 1e-8);
}

// Issue 17: one thickness of 1e300 made every error infinite and fit_stroke read best_x[0] of an
// empty vector (segfault). Values outside the physical range are refused at the boundary.
TEST(Fit, OutOfRangeOrNonFiniteSamplesAreRefused) {
  const StrokeData good = read_stroke_csv(kCsv);
  auto expect_refused = [&](size_t i, double x, double t, const std::string& fragment) {
    StrokeData d = good;
    d.position_m[i] = x;
    d.thickness_m[i] = t;
    try {
      fit_stroke(d);
      ADD_FAILURE() << "no error for x = " << x << ", t = " << t;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("sample " + std::to_string(i)), std::string::npos) << e.what();
    }
  };
  expect_refused(3, good.position_m[3], 1e297, "outside the physical range");  // 1e300 mm
  expect_refused(3, good.position_m[3], 1.0001, "outside the physical range");
  expect_refused(0, 1e297, 0.001, "outside the physical range");
  expect_refused(0, -10.5, 0.001, "outside the physical range");
  expect_refused(5, good.position_m[5], std::numeric_limits<double>::quiet_NaN(), "not finite");
  expect_refused(5, std::numeric_limits<double>::infinity(), 0.001, "not finite");
  // The limits themselves are accepted: a 1 m thick stroke still fits (as a spike) and is finite.
  StrokeData edge = good;
  edge.thickness_m[3] = 1.0;
  const StrokeFit f = fit_stroke(edge);
  EXPECT_TRUE(std::isfinite(f.mse_mm2) && std::isfinite(f.model.radius_m) && std::isfinite(f.model.peak_rate_mps));
}

TEST(Fit, FlowAgreesWithNominalWithinRebound) {
  // The stroke is what stayed on the wall, so the deposited flow must lie between the nominal
  // pump flow (nothing lost) and the nominal flow minus the assumed rebound share (8%).
  const StrokeFit fit = measured_fit();
  const DepositionConfig cfg;
  EXPECT_LE(fit.deposited_flow_m3ph, cfg.nominal_flow_m3ph);
  EXPECT_GE(fit.deposited_flow_m3ph, cfg.nominal_flow_m3ph * (1 - cfg.rebound_fraction));
  // Second method: trapezoid area of the measured points times the speed.
  const StrokeData d = read_stroke_csv(kCsv);
  double area = 0;
  for (size_t i = 1; i < d.position_m.size(); ++i)
    area += 0.5 * (d.thickness_m[i] + d.thickness_m[i - 1]) * (d.position_m[i] - d.position_m[i - 1]);
  EXPECT_NEAR(area * d.speed_mps * 3600 / fit.deposited_flow_m3ph, 1.0, 0.03);
  EXPECT_NEAR(fit.flow_m3ph * (1 - 0.08), fit.deposited_flow_m3ph, 1e-12);
}

TEST(Fit, ConfigDefaultsMatchFreshFit) {
  const StrokeFit fit = measured_fit();
  const DepositionConfig cfg;
  EXPECT_NEAR(cfg.spot_radius_m, fit.model.radius_m, 1e-4);
  EXPECT_NEAR(cfg.spot_beta, fit.model.beta, 1e-3);
  EXPECT_NEAR(cfg.peak_rate_mps / fit.model.peak_rate_mps, 1.0, 1e-3);
  EXPECT_EQ(cfg.reference_standoff_m, 1.0);
  const SpotModel m = spot_model_from_config(cfg);
  EXPECT_NEAR(m.volume_rate_m3ps() * 3600, fit.flow_m3ph, 0.01);
}

TEST(Fit, ZeroPeakRateInConfigIsRejected) {
  DepositionConfig cfg;
  cfg.peak_rate_mps = 0;
  try {
    spot_model_from_config(cfg);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("peak_rate_mps"), std::string::npos);
  }
}

TEST(Csv, BadInputsGiveClearErrors) {
  auto expect_error = [](const std::string& text, const std::string& fragment) {
    const std::string path = write_tmp("bad.csv", text);
    try {
      read_stroke_csv(path);
      ADD_FAILURE() << "no error for:\n" << text;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
  };
  expect_error("position_mm,thickness_mm\n0,1\n10,2\n20,3\n30,1\n", "at least 5");
  expect_error("position_mm,thickness_mm\n0,1\n10,abc\n20,3\n30,1\n40,1\n", "non-numeric thickness 'abc'");
  expect_error("position_mm,thickness_mm\n0,1\nx,2\n20,3\n30,1\n40,1\n", "non-numeric position");
  expect_error("position_mm,thickness_mm\n0,1\n10,-2\n20,3\n30,1\n40,1\n", "negative thickness");
  expect_error("position_mm,thickness_mm\n0,0\n10,0\n20,0\n30,0\n40,0\n", "all thickness values are zero");
  expect_error("position_mm,thickness_mm\n0,1,3\n10,2\n20,3\n30,1\n40,1\n", "expected 2 columns");
  expect_error("position_mm,thickness_mm\n0,1\n10,\n20,3\n30,1\n40,1\n", "non-numeric thickness");
  expect_error("position_mm,thickness_mm\n0,1\n10,1e300\n20,3\n30,1\n40,1\n",
               "line 3: thickness 1e300 mm is above the physical limit of 1000 mm");
  expect_error("position_mm,thickness_mm\n0,1\n1e300,1\n20,3\n30,1\n40,1\n",
               "line 3: position 1e300 mm is outside the physical range +-10000 mm");
  expect_error("position_mm,thickness_mm\n0,1\n10,1e400\n20,3\n30,1\n40,1\n", "non-numeric thickness '1e400'");
  // Fuzz findings (the core alone): a cell with non-UTF-8 bytes or a CR was quoted raw (pybind11
  // then raised an empty ValueError; a CR broke the line). Quoted cells are printable ASCII now.
  expect_error("position_mm,thickness_mm\n0,1\n10,24\xc1\xb1J\n20,3\n30,1\n40,1\n", "line 3: non-numeric thickness '24??J'");
  expect_error("position_mm,thickness_mm\n0,1\n10,3\r8\n20,3\n30,1\n40,1\n", "line 3: non-numeric thickness '3?8'");
  EXPECT_THROW(read_stroke_csv("/nonexistent/stroke.csv"), std::invalid_argument);
  // A valid file without header parses.
  const StrokeData ok = read_stroke_csv(write_tmp("ok.csv", "0,1\n10,2\n20,3\n30,1\n40,1\n"));
  EXPECT_EQ(ok.position_m.size(), 5u);
  EXPECT_DOUBLE_EQ(ok.thickness_m[2], 0.003);
}

// ------------------------------------------------------------------ eq. 2-13

TEST(PointRate, ReducesToSpotOnReferencePlaneAndCuts) {
  const SpotModel m = default_model();
  const NozzlePose nz{Eigen::Vector3d(0.3, -0.2, 0.1), Eigen::Vector3d(0, 0, 2)};
  const Eigen::Vector3d n(0, 0, -1);
  for (double r : {0.0, 0.05, 0.1, 0.15, 0.19}) {
    const Eigen::Vector3d p = nz.position_m + Eigen::Vector3d(r * 0.6, r * 0.8, 1.0);
    EXPECT_NEAR(point_rate_mps(m, nz, p, n), m.rate_at(r), 1e-12);
    EXPECT_NEAR(point_rate_mps(m, nz, p, n), reference_rate(m, nz.position_m, nz.axis, p, n), 1e-12);
  }
  // Twice the standoff: r_proj halves, rate falls with (H0 / L)^2 cos(gamma) / cos^3(theta).
  const Eigen::Vector3d p2 = nz.position_m + Eigen::Vector3d(0.2, 0, 2.0);
  EXPECT_NEAR(point_rate_mps(m, nz, p2, n), m.rate_at(0.1) / 4, 1e-12);
  EXPECT_EQ(point_rate_mps(m, nz, nz.position_m + Eigen::Vector3d(0.25, 0, 1.0), n), 0.0);  // outside the cone
  EXPECT_EQ(point_rate_mps(m, nz, nz.position_m + Eigen::Vector3d(0, 0, 1.0), -n), 0.0);     // faces away
  EXPECT_EQ(point_rate_mps(m, nz, nz.position_m + Eigen::Vector3d(0, 0, -1.0), n), 0.0);     // behind
  // gamma just below / above 90 deg on a steep wall inside the cone.
  const Eigen::Vector3d p3 = nz.position_m + Eigen::Vector3d(0.1, 0, 1.0);
  const Eigen::Vector3d ray = (p3 - nz.position_m).normalized(), perp = ray.cross(Eigen::Vector3d::UnitY());
  EXPECT_GT(point_rate_mps(m, nz, p3, perp * (perp.dot(ray) > 0 ? -1 : 1) - 1e-3 * ray), 0.0);
  EXPECT_EQ(point_rate_mps(m, nz, p3, perp * (perp.dot(ray) > 0 ? -1 : 1) + 1e-3 * ray), 0.0);
}

// ------------------------------------------------------------------ index

TEST(SurfaceIndex, WithinMatchesBruteForce) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  Cloud c;
  c.xyz.resize(5000, 3);
  c.normals.resize(5000, 3);
  for (int i = 0; i < 5000; ++i) {
    c.xyz.row(i) << u(rng), 2 * u(rng), 0.3 * u(rng);
    c.normals.row(i) << 0, 0, 1;
  }
  const SurfaceIndex idx(c, 0.07);
  std::vector<int> got;
  for (int q = 0; q < 50; ++q) {
    const Eigen::Vector3d center(1.2 * u(rng), 2.2 * u(rng), 0.5 * u(rng));
    const double r = 0.05 + 0.5 * std::abs(u(rng));
    idx.within(center, r, got);
    std::vector<int> want;
    for (int i = 0; i < 5000; ++i)
      if ((c.xyz.row(i).transpose() - center).norm() <= r) want.push_back(i);
    ASSERT_EQ(got, want) << "query " << q;
  }
  EXPECT_THROW(SurfaceIndex(Cloud{c.xyz, Points()}), std::invalid_argument);
}

// The default synthetic bay (pits, roughness) sampled with radial normals toward the axis, each
// tilted by up to tilt_rad at random (0: exact-enough radial normals).
static Cloud synthetic_bay_cloud(int points_per_cell, double tilt_rad, std::mt19937& rng) {
  SynthConfig sc;
  sc.points_per_cell = points_per_cell;
  Cloud c = make_synthetic_bay(sc).sample(0.05);
  c.normals.resize(c.size(), 3);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (Eigen::Index i = 0; i < c.size(); ++i) {
    const Eigen::Vector3d p = c.xyz.row(i);
    Eigen::Vector3d n = -Eigen::Vector3d(0, p.y(), p.z()).normalized();
    if (tilt_rad > 0) n = (n + tilt_rad * Eigen::Vector3d(u(rng), u(rng), u(rng))).normalized();
    c.normals.row(i) = n.transpose();
  }
  return c;
}

TEST(SurfaceIndex, ConeCulledSumsEqualTheBruteForce) {
  // add_rates_sorted skips the voxels wholly outside the spray cone. On a rough bay with pits,
  // nozzles tilted along and across, near and far (and past the bay's end, where the fallback ball
  // holds the whole cone), with fine and coarse voxels, every point's deposit equals the sum of
  // point_rate_mps over the whole cloud: the skipped points would have added exactly 0.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  const Cloud c = synthetic_bay_cloud(4, 0.3, rng);
  const SpotModel m = default_model();
  std::vector<NozzlePose> poses;
  std::vector<double> dwell;
  for (int q = 0; q < 60; ++q) {
    const double th = 0.2 + 2.7 * u(rng), d = -0.3 + 1.8 * u(rng), tilt = 1.2 * (u(rng) - 0.5);
    const Eigen::Vector3d radial(0, std::cos(th), std::sin(th)), along(1, 0, 0);
    poses.push_back({Eigen::Vector3d(d, 0, 0) + (5.6 + 0.15 - 0.4 - 1.2 * u(rng)) * radial,
                     (radial + tilt * along + 0.8 * (u(rng) - 0.5) * radial.cross(along)).normalized()});
    dwell.push_back(0.1 + u(rng));
  }
  Eigen::VectorXd brute = Eigen::VectorXd::Zero(c.size());
  for (std::size_t k = 0; k < poses.size(); ++k)
    for (Eigen::Index i = 0; i < c.size(); ++i)
      brute[i] += point_rate_mps(m, poses[k], c.xyz.row(i).transpose(), c.normals.row(i).transpose()) * dwell[k];
  ASSERT_GT((brute.array() > 0).count(), 5000);
  for (double voxel_m : {0.02, 0.05, 0.3}) {
    const SurfaceIndex idx(c, voxel_m);
    Eigen::VectorXd got = Eigen::VectorXd::Zero(c.size());
    accumulate_dwells(m, idx, poses, dwell, 0.0, got);
    ASSERT_EQ((got.array() > 0).count(), (brute.array() > 0).count()) << "voxel " << voxel_m;
    EXPECT_LT((got - brute).cwiseAbs().maxCoeff(), 1e-14 * brute.maxCoeff()) << "voxel " << voxel_m;
  }
}

TEST(SurfaceIndex, ReachBallHoldsEveryReachablePoint) {
  // Synthetic bay with pits: for random nozzle poses, every point with a non-zero rate
  // (brute force over the whole cloud) lies inside the query ball.
  std::mt19937 no_tilt(0);
  const Cloud c = synthetic_bay_cloud(6, 0.0, no_tilt);
  const SurfaceIndex idx(c);
  const SpotModel m = default_model();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  int reached_total = 0;
  for (int q = 0; q < 40; ++q) {
    const double th = 0.2 + 2.7 * u(rng), d = 1.2 * u(rng), tilt = 0.5 * (u(rng) - 0.5);
    const Eigen::Vector3d radial(0, std::cos(th), std::sin(th)), along(1, 0, 0);
    NozzlePose nz{Eigen::Vector3d(d, 0, 0) + (5.6 + 0.15 - 1.0 - 0.3 * u(rng)) * radial,
                  (radial + tilt * along + 0.3 * (u(rng) - 0.5) * radial.cross(along)).normalized()};
    const auto [center, radius] = idx.reach_ball(m, nz);
    for (Eigen::Index i = 0; i < c.size(); ++i) {
      if (point_rate_mps(m, nz, c.xyz.row(i).transpose(), c.normals.row(i).transpose()) <= 0) continue;
      ++reached_total;
      ASSERT_LE((c.xyz.row(i).transpose() - center).norm(), radius) << "pose " << q;
    }
  }
  EXPECT_GT(reached_total, 1000);
  // Axis past the end of the bay (d < 0): only the cone rim reaches the wall, via the fallback ball.
  for (double d : {-0.05, -0.12}) {
    const Eigen::Vector3d radial(0, 0, 1);
    const NozzlePose nz{Eigen::Vector3d(d, 0, 4.75), radial};
    const auto [center, radius] = idx.reach_ball(m, nz);
    int reached = 0;
    for (Eigen::Index i = 0; i < c.size(); ++i) {
      if (point_rate_mps(m, nz, c.xyz.row(i).transpose(), c.normals.row(i).transpose()) <= 0) continue;
      ++reached;
      ASSERT_LE((c.xyz.row(i).transpose() - center).norm(), radius) << "edge pose d = " << d;
    }
    EXPECT_GT(reached, 10);
  }
}

// ------------------------------------------------------------------ passes vs closed form / quadrature

TEST(Pass, PlaneReproducesMeasuredStroke) {
  // Nozzle 1 m below the plane z = 1, passing along x at y = the fitted centre; the deposited
  // cross profile at x = 0 must match the CSV within the fit's own error.
  const StrokeFit fit = measured_fit();
  const StrokeData d = read_stroke_csv(kCsv);
  Cloud c;
  c.xyz.resize(d.position_m.size(), 3);
  c.normals.resize(d.position_m.size(), 3);
  for (size_t i = 0; i < d.position_m.size(); ++i) {
    c.xyz.row(i) << 0.0, d.position_m[i], 1.0;
    c.normals.row(i) << 0, 0, -1;
  }
  const SurfaceIndex idx(c);
  const std::vector<NozzlePose> line{{Eigen::Vector3d(-0.6, fit.center_offset_m, 0), Eigen::Vector3d::UnitZ()},
                                     {Eigen::Vector3d(0.6, fit.center_offset_m, 0), Eigen::Vector3d::UnitZ()}};
  Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
  accumulate_pass(fit.model, idx, line, 0.15, 0.005, 0.08, t);
  double mse = 0;
  for (size_t i = 0; i < d.position_m.size(); ++i) {
    mse += std::pow((t[i] - d.thickness_m[i]) * 1e3, 2);
    EXPECT_NEAR(t[i], fit.stroke_at_m(d.position_m[i]), 2e-5) << "closed form at " << d.position_m[i];
  }
  mse /= d.position_m.size();
  EXPECT_LT(mse, fit.mse_mm2 * 1.02 + 1e-3);
}

TEST(Pass, InclinedPlaneMatchesQuadrature) {
  const SpotModel m = default_model();
  const double tilt = 30 * kPi / 180;
  const Eigen::Vector3d u(1, 0, 0), v(0, std::cos(tilt), std::sin(tilt));
  const Cloud c = plane_lattice(Eigen::Vector3d(0, 0, 1.0), u, v, 0.5, 0.5, 0.01, -Eigen::Vector3d::UnitZ());
  const SurfaceIndex idx(c);
  const Eigen::Vector3d c0(-0.4, 0.05, 0.0), e(1, 0, 0), axis(0, 0.2, 1);
  const std::vector<NozzlePose> line{{c0, axis}, {c0 + 0.8 * e, axis}};
  Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
  accumulate_pass(m, idx, line, 0.2, 0.001, 0.08, t);
  const double peak = t.maxCoeff();
  ASSERT_GT(peak, 0.005);
  int checked = 0;
  for (Eigen::Index i = 0; i < c.size(); i += 37) {
    const double ref = reference_pass(m, c0, e, 0.8, axis, 0.2, 0.08, c.xyz.row(i).transpose(), c.normals.row(i).transpose());
    ASSERT_NEAR(t[i], ref, 2e-3 * peak) << "point " << i;
    if (ref > 0.1 * peak) ++checked;
  }
  EXPECT_GT(checked, 50);
}

TEST(Pass, CylinderInsideMatchesQuadrature) {
  // Inside of a cylinder of radius 5.6 around x; nozzle 1 m inside, axis tilted off radial.
  const SpotModel m = default_model();
  const double Rc = 5.6, h = 0.01;
  Cloud c;
  std::vector<Eigen::Vector3d> pts, nrm;
  for (double x = -0.5; x <= 0.5; x += h)
    for (double th = 1.3; th <= 1.85; th += h / Rc) {
      pts.emplace_back(x, Rc * std::cos(th), Rc * std::sin(th));
      nrm.emplace_back(0, -std::cos(th), -std::sin(th));
    }
  c.xyz.resize(pts.size(), 3);
  c.normals.resize(pts.size(), 3);
  for (size_t i = 0; i < pts.size(); ++i) {
    c.xyz.row(i) = pts[i].transpose();
    c.normals.row(i) = nrm[i].transpose();
  }
  const SurfaceIndex idx(c);
  const double th0 = 1.55;
  const Eigen::Vector3d radial(0, std::cos(th0), std::sin(th0));
  const Eigen::Vector3d c0 = Eigen::Vector3d(-0.35, 0, 0) + (Rc - 1.0) * radial, e(1, 0, 0);
  const Eigen::Vector3d axis = (radial + 0.15 * Eigen::Vector3d(0, -std::sin(th0), std::cos(th0))).normalized();
  const std::vector<NozzlePose> line{{c0, axis}, {c0 + 0.7 * e, axis}};
  Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
  accumulate_pass(m, idx, line, 0.15, 0.001, 0.08, t);
  const double peak = t.maxCoeff();
  ASSERT_GT(peak, 0.01);
  int checked = 0;
  for (Eigen::Index i = 0; i < c.size(); i += 23) {
    const double ref = reference_pass(m, c0, e, 0.7, axis, 0.15, 0.08, c.xyz.row(i).transpose(), c.normals.row(i).transpose());
    ASSERT_NEAR(t[i], ref, 2e-3 * peak) << "point " << i;
    if (ref > 0.1 * peak) ++checked;
  }
  EXPECT_GT(checked, 50);
}

TEST(Pass, ConvergesWithStep) {
  // Halving the step changes the thickness by less than 0.5% of the peak (10 mm -> 5 mm), and
  // the change shrinks with the step (midpoint rule).
  const SpotModel m = default_model();
  const double tilt = 20 * kPi / 180;
  const Cloud c = plane_lattice(Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d(1, 0, 0),
                                Eigen::Vector3d(0, std::cos(tilt), std::sin(tilt)), 0.6, 0.4, 0.01, -Eigen::Vector3d::UnitZ());
  const SurfaceIndex idx(c);
  const std::vector<NozzlePose> line{{Eigen::Vector3d(-0.4, 0, 0), Eigen::Vector3d(0, 0, 1)},
                                     {Eigen::Vector3d(0.0, 0.1, 0.05), Eigen::Vector3d(0.1, 0, 1)},
                                     {Eigen::Vector3d(0.4, 0.0, 0), Eigen::Vector3d(0, -0.1, 1)}};
  std::vector<Eigen::VectorXd> t;
  for (double step : {0.02, 0.01, 0.005, 0.0025}) {
    t.emplace_back(Eigen::VectorXd::Zero(c.size()));
    accumulate_pass(m, idx, line, 0.15, step, 0.08, t.back());
  }
  const double peak = t.back().maxCoeff();
  const double d1 = (t[1] - t[0]).cwiseAbs().maxCoeff(), d2 = (t[2] - t[1]).cwiseAbs().maxCoeff(),
               d3 = (t[3] - t[2]).cwiseAbs().maxCoeff();
  std::cout << "step convergence (max change / peak): 20->10 mm " << d1 / peak << ", 10->5 mm " << d2 / peak
            << ", 5->2.5 mm " << d3 / peak << "\n";
  EXPECT_LT(d2, 0.005 * peak);
  EXPECT_LT(d3, d2);
  EXPECT_LT(d2, d1);
}

TEST(Pass, MassBalanceOnLargePlane) {
  // Volume left on a large inclined plane = q-integral x time x (1 - rebound), within 1%.
  const SpotModel m = default_model();
  const double tilt = 25 * kPi / 180, h = 0.005;
  const Cloud c = plane_lattice(Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d(1, 0, 0),
                                Eigen::Vector3d(0, std::cos(tilt), std::sin(tilt)), 1.0, 0.6, h, -Eigen::Vector3d::UnitZ());
  const SurfaceIndex idx(c);
  const double len = 1.0, v = 0.25, rebound = 0.08;
  const std::vector<NozzlePose> line{{Eigen::Vector3d(-0.5, 0, 0.1), Eigen::Vector3d(0, 0.1, 1)},
                                     {Eigen::Vector3d(0.5, 0, 0.1), Eigen::Vector3d(0, 0.1, 1)}};
  Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
  accumulate_pass(m, idx, line, v, 0.005, rebound, t);
  const double volume = t.sum() * h * h;
  const double expected = m.volume_rate_m3ps() * (len / v) * (1 - rebound);
  std::cout << "mass balance: deposited / expected = " << volume / expected << "\n";
  EXPECT_NEAR(volume / expected, 1.0, 0.01);
}

TEST(Pass, DwellsEqualResampledPass) {
  const SpotModel m = default_model();
  const Cloud c = plane_lattice(Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0), 0.5,
                                0.3, 0.02, -Eigen::Vector3d::UnitZ());
  const SurfaceIndex idx(c);
  const std::vector<NozzlePose> line{{Eigen::Vector3d(-0.3, 0, 0), Eigen::Vector3d(0, 0, 1)},
                                     {Eigen::Vector3d(0.3, 0, 0), Eigen::Vector3d(0, 0, 1)}};
  const PassSamples s = resample_pass(line, 0.2, 0.007);
  ASSERT_EQ(s.poses.size(), 86u);  // ceil(0.6 / 0.007)
  EXPECT_NEAR(s.dwell_s[0] * s.poses.size(), 0.6 / 0.2, 1e-12);
  EXPECT_NEAR(s.poses.front().position_m.x(), -0.3 + 0.5 * 0.6 / 86, 1e-12);
  Eigen::VectorXd a = Eigen::VectorXd::Zero(c.size()), b = Eigen::VectorXd::Zero(c.size());
  accumulate_pass(m, idx, line, 0.2, 0.007, 0.1, a);
  accumulate_dwells(m, idx, s.poses, s.dwell_s, 0.1, b);
  EXPECT_EQ(a, b);
  // Brute force over the whole cloud with point_rate_mps gives the same sums.
  Eigen::VectorXd brute = Eigen::VectorXd::Zero(c.size());
  for (size_t k = 0; k < s.poses.size(); ++k)
    for (Eigen::Index i = 0; i < c.size(); ++i)
      brute[i] += point_rate_mps(m, s.poses[k], c.xyz.row(i).transpose(), c.normals.row(i).transpose()) * s.dwell_s[k] * 0.9;
  EXPECT_LT((brute - a).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_THROW(accumulate_pass(m, idx, {line[0]}, 0.2, 0.01, 0.1, a), std::invalid_argument);
  EXPECT_THROW(accumulate_pass(m, idx, line, 0.0, 0.01, 0.1, a), std::invalid_argument);
  EXPECT_THROW(accumulate_pass(m, idx, line, 0.2, 0.01, 1.0, a), std::invalid_argument);
  Eigen::VectorXd wrong = Eigen::VectorXd::Zero(3);
  EXPECT_THROW(accumulate_pass(m, idx, line, 0.2, 0.01, 0.1, wrong), std::invalid_argument);
}

TEST(Pass, ManyDwellsAreSummedInChunksIndependentOfThreads) {
  // Over 256 dwells accumulate_dwells splits them into chunks run in parallel: the sums equal the
  // brute force over the whole cloud, and are the same bits on one thread as on several.
  const SpotModel m = default_model();
  const Cloud c = plane_lattice(Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0), 1.2,
                                0.4, 0.02, -Eigen::Vector3d::UnitZ());
  const SurfaceIndex idx(c);
  const std::vector<NozzlePose> line{{Eigen::Vector3d(-0.5, -0.05, 0), Eigen::Vector3d(0, 0.1, 1)},
                                     {Eigen::Vector3d(0.5, 0.05, 0), Eigen::Vector3d(0, -0.1, 1)}};
  const PassSamples s = resample_pass(line, 0.2, 0.0005);
  ASSERT_EQ(s.poses.size(), 2010u);  // 8 chunks
  Eigen::VectorXd brute = Eigen::VectorXd::Zero(c.size());
  for (size_t k = 0; k < s.poses.size(); ++k)
    for (Eigen::Index i = 0; i < c.size(); ++i)
      brute[i] += point_rate_mps(m, s.poses[k], c.xyz.row(i).transpose(), c.normals.row(i).transpose()) * s.dwell_s[k] * 0.9;
  Eigen::VectorXd a = Eigen::VectorXd::Zero(c.size());
  accumulate_dwells(m, idx, s.poses, s.dwell_s, 0.1, a);
  ASSERT_GT(brute.maxCoeff(), 1e-3);
  EXPECT_LT((brute - a).cwiseAbs().maxCoeff(), 1e-12 * brute.maxCoeff());
#ifdef _OPENMP
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  Eigen::VectorXd one = Eigen::VectorXd::Zero(c.size());
  accumulate_dwells(m, idx, s.poses, s.dwell_s, 0.1, one);
  omp_set_num_threads(3);
  Eigen::VectorXd three = Eigen::VectorXd::Zero(c.size());
  accumulate_dwells(m, idx, s.poses, s.dwell_s, 0.1, three);
  omp_set_num_threads(threads);
  EXPECT_EQ(one, a);
  EXPECT_EQ(three, a);
#endif
  // A bad dwell or pose among many is still refused before anything is added.
  std::vector<double> dwell = s.dwell_s;
  dwell[1500] = std::nan("");
  Eigen::VectorXd untouched = Eigen::VectorXd::Zero(c.size());
  EXPECT_THROW(accumulate_dwells(m, idx, s.poses, dwell, 0.1, untouched), std::invalid_argument);
  EXPECT_EQ(untouched, Eigen::VectorXd::Zero(c.size()));
  std::vector<NozzlePose> poses = s.poses;
  poses[1700].axis = Eigen::Vector3d::Zero();
  EXPECT_THROW(accumulate_dwells(m, idx, poses, s.dwell_s, 0.1, untouched), std::invalid_argument);
  poses[1700] = s.poses[1700];
  poses[900].position_m.x() = std::numeric_limits<double>::infinity();
  EXPECT_THROW(accumulate_dwells(m, idx, poses, s.dwell_s, 0.1, untouched), std::invalid_argument);
  EXPECT_EQ(untouched, Eigen::VectorXd::Zero(c.size()));
}

namespace {

// Points of a cylinder wall of radius r (normals toward the axis) over x in [0, x_max) and
// theta in [1, th_max), 10 mm apart, as a Surface on the design radius R.
Surface cylinder_wall(double R, double r, double x_max, double th_max) {
  Surface s;
  std::vector<Eigen::Vector3d> pts;
  for (double x = 0.005; x < x_max; x += 0.01)
    for (double th = 1.0; th < th_max; th += 0.01 / r) pts.emplace_back(x, r * std::cos(th), r * std::sin(th));
  s.cloud.xyz.resize(pts.size(), 3);
  s.cloud.normals.resize(pts.size(), 3);
  for (size_t i = 0; i < pts.size(); ++i) {
    s.cloud.xyz.row(i) = pts[i].transpose();
    s.cloud.normals.row(i) = -Eigen::Vector3d(0, pts[i].y(), pts[i].z()).normalized().transpose();
  }
  s.profile = DesignProfile{R};
  s.grid = build_grid(s.cloud, s.axis, s.profile, GridConfig{}, 1.0);
  s.levels = cell_levels(s.grid);
  return s;
}

}  // namespace

TEST(Wall, LayerMovesPointsAlongTheirRaysAndLowersEveryCell) {
  // Cylinder wall 0.1 m outside a 5.6 m design line; a uniform 20 mm layer moves every point
  // 20 mm toward the axis (radial normals: no tilt), lowers the TD of every cell by 20 mm, and
  // re-gridding the moved cloud agrees.
  const double r = 5.7;
  const Surface s = cylinder_wall(5.6, r, 0.6, 2.0);
  const Cloud& c = s.cloud;
  SprayedWall wall = unsprayed_wall(s, 1.0);
  const Eigen::VectorXd before = wall.surface.grid.td_m;
  const Eigen::VectorXd t = Eigen::VectorXd::Constant(c.size(), 0.02);
  deposit_layer(wall, t);
  const Cloud& moved = wall.surface.cloud;
  for (Eigen::Index i = 0; i < c.size(); i += 97) {
    EXPECT_NEAR(Eigen::Vector3d(0, moved.xyz(i, 1), moved.xyz(i, 2)).norm(), r - 0.02, 1e-12);
    EXPECT_NEAR(std::atan2(moved.xyz(i, 2), moved.xyz(i, 1)), std::atan2(c.xyz(i, 2), c.xyz(i, 1)), 1e-12);
    EXPECT_EQ(moved.xyz(i, 0), c.xyz(i, 0));
    // The sprayed cells get the normal of their TD map: still radial, at the cell's centre angle.
    EXPECT_GT(-moved.normals.row(i).dot(Eigen::RowVector3d(0, moved.xyz(i, 1), moved.xyz(i, 2)).normalized()),
              std::cos(0.005));
  }
  const Grid after = build_grid(moved, s.axis, s.profile, GridConfig{}, 1.0);
  const Grid& g = wall.surface.grid;
  int checked = 0;
  for (int cell = 0; cell < g.size(); ++cell) {
    if (!g.valid[cell]) continue;
    EXPECT_NEAR(g.td_m[cell], before[cell] - 0.02, 1e-12);
    if (after.valid[cell]) {
      EXPECT_NEAR(g.td_m[cell], after.td_m[cell], 1e-3);
      ++checked;
    }
  }
  EXPECT_GT(checked, 100);
  EXPECT_EQ(wall.surface.levels, cell_levels(g));
  EXPECT_THROW(deposit_layer(wall, Eigen::VectorXd::Zero(2)), std::invalid_argument);
  Surface bare = s;
  bare.cloud.normals.resize(0, 3);
  EXPECT_THROW(unsprayed_wall(bare, 1.0), std::invalid_argument);
}

TEST(Wall, PointsOfNoCellStayWhereTheScanHasThem) {
  // A duct's point 1.2 m inside the wall (out of the grid's band) that a nozzle passed closely
  // gets a huge "layer"; it stays put (it moved 33 m across the axis in a scene's plan), the wall's
  // points move.
  Surface s = cylinder_wall(5.6, 5.7, 0.3, 1.2);
  const Eigen::Index n = s.cloud.size();
  s.cloud.xyz.conservativeResize(n + 1, 3);
  s.cloud.normals.conservativeResize(n + 1, 3);
  s.cloud.xyz.row(n) << 0.1, 0.0, 4.5;
  s.cloud.normals.row(n) << 0.0, 0.0, -1.0;
  SprayedWall wall = unsprayed_wall(s, 1.0);
  ASSERT_EQ(wall.cell_of_point[static_cast<std::size_t>(n)], -1);
  const Eigen::VectorXd before = wall.surface.grid.td_m;
  deposit_layer(wall, Eigen::VectorXd::Constant(n + 1, 5.0));
  EXPECT_EQ(wall.surface.cloud.xyz.row(n), s.cloud.xyz.row(n));
  EXPECT_NEAR(Eigen::Vector3d(0, wall.surface.cloud.xyz(0, 1), wall.surface.cloud.xyz(0, 2)).norm(), 0.7, 1e-9);
  for (int c = 0; c < wall.surface.grid.size(); ++c)
    if (wall.surface.grid.valid[c]) EXPECT_NEAR(wall.surface.grid.td_m[c], before[c] - 5.0, 1e-9);
}

TEST(Wall, TiltedNormalFillsRadiallyAndKeepsTheCell) {
  // A layer measured along a normal tilted 45 degrees from the ray fills t / cos(45) along the
  // ray; beyond 60 degrees the fill is capped at 2 t. The point stays on its ray (d, theta).
  const double r = 5.7;
  Surface s = cylinder_wall(5.6, r, 0.3, 1.2);
  Cloud& c = s.cloud;
  const Eigen::Vector3d inward0 = c.normals.row(0).transpose(), inward1 = c.normals.row(1).transpose();
  c.normals.row(0) = (std::cos(kPi / 4) * inward0 + std::sin(kPi / 4) * Eigen::Vector3d::UnitX()).transpose();
  c.normals.row(1) = (std::cos(1.4) * inward1 + std::sin(1.4) * Eigen::Vector3d::UnitX()).transpose();
  SprayedWall wall = unsprayed_wall(s, 1.0);
  const std::vector<int> cells = wall.cell_of_point;
  Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
  t[0] = t[1] = 0.01;
  deposit_layer(wall, t);
  const Points& q = wall.surface.cloud.xyz;
  EXPECT_NEAR(r - Eigen::Vector3d(0, q(0, 1), q(0, 2)).norm(), 0.01 / std::cos(kPi / 4), 1e-12);
  EXPECT_NEAR(r - Eigen::Vector3d(0, q(1, 1), q(1, 2)).norm(), 0.02, 1e-12);
  EXPECT_EQ(q(0, 0), c.xyz(0, 0));
  EXPECT_EQ(q.bottomRows(c.size() - 2), c.xyz.bottomRows(c.size() - 2));  // no thickness: not moved
  EXPECT_EQ(wall.cell_of_point, cells);
}

// ------------------------------------------------------------------ pass spacing

// Many equal lines: the ripple of their sum from the closed-form cross profile against the deposit
// integrated along real passes (accumulate_pass over a plane at H0, eq. 2-13); the least-ripple
// pitch lays a flatter layer than the optimal mode's former 0.5 x two-pass spacing.
TEST(Spacing, LeastRipplePitchLaysTheFlattestLayerOfManyLines) {
  const SpotModel m = default_model();
  // A strip of wall points across the lines, 1 mm apart, at H0 below the nozzles.
  const Cloud c = plane_lattice(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), 0.6, 0.0005,
                                0.001, Eigen::Vector3d::UnitZ());
  const SurfaceIndex idx(c, 0.05);
  const Eigen::Vector3d axis(0, 0, -1);
  auto integrated_ripple = [&](double pitch_m) {
    Eigen::VectorXd t = Eigen::VectorXd::Zero(c.size());
    const int k_max = static_cast<int>(std::ceil((0.6 - m.radius_m) / pitch_m)) - 1;
    for (int k = -k_max; k <= k_max; ++k) {
      const double x = k * pitch_m;
      const std::vector<NozzlePose> line{{Eigen::Vector3d(x, -0.5, m.reference_standoff_m), axis},
                                         {Eigen::Vector3d(x, 0.5, m.reference_standoff_m), axis}};
      accumulate_pass(m, idx, line, 0.2, 0.001, 0.0, t);
    }
    double lo = 1e300, hi = -1e300, sum = 0;
    int n = 0;
    for (Eigen::Index i = 0; i < c.size(); ++i)
      if (std::abs(c.xyz(i, 0)) <= pitch_m) lo = std::min(lo, t[i]), hi = std::max(hi, t[i]), sum += t[i], ++n;
    return (hi - lo) / (sum / n);
  };
  const double two_pass_m = pass_spacing(m, 0.07).spacing_m;
  for (double ratio : {0.42, 0.45, 0.5, 0.55}) {
    const double p = ratio * two_pass_m;
    EXPECT_NEAR(line_ripple(m, p), integrated_ripple(p), 0.004) << "pitch " << p;
  }
  const double nominal = 0.5 * two_pass_m;
  const LinePitch best = least_ripple_pitch(m, 0.85 * nominal, 1.15 * nominal);
  std::cout << "lines at " << nominal * 1e3 << " mm: ripple " << 100 * line_ripple(m, nominal) << " %; least at "
            << best.pitch_m * 1e3 << " mm: " << 100 * best.ripple << " %\n";
  EXPECT_GE(best.pitch_m, 0.85 * nominal);
  EXPECT_LE(best.pitch_m, 1.15 * nominal);
  EXPECT_NEAR(best.ripple, line_ripple(m, best.pitch_m), 1e-12);
  // The integrated layer: flatter at the chosen pitch than at the nominal one, and than 1 mm either side.
  const double at_best = integrated_ripple(best.pitch_m);
  EXPECT_LT(at_best, 0.5 * integrated_ripple(nominal));
  EXPECT_LT(at_best, 0.025);
  EXPECT_LE(at_best, integrated_ripple(best.pitch_m - 0.002) + 0.002);
  EXPECT_LE(at_best, integrated_ripple(best.pitch_m + 0.002) + 0.002);
  // A window of one pitch is that pitch.
  EXPECT_EQ(least_ripple_pitch(m, nominal, nominal).pitch_m, nominal);
  EXPECT_THROW(least_ripple_pitch(m, 0.0, 0.1), std::invalid_argument);
  EXPECT_THROW(least_ripple_pitch(m, 0.2, 0.1), std::invalid_argument);
  EXPECT_THROW(line_ripple(m, -0.1), std::invalid_argument);
  EXPECT_THROW(line_ripple(m, 1e-12), std::invalid_argument);  // below 0.001 R: a loop over 1e11 strokes
  EXPECT_THROW(least_ripple_pitch(m, 0.001, 0.1), std::invalid_argument);  // below 0.05 R: 40+ strokes a ripple
  const LinePitch wide = least_ripple_pitch(m, 0.1, 1e6);  // 1e10 steps of 0.1 mm: 2e4 steps instead
  EXPECT_GE(wide.pitch_m, 0.1);
  EXPECT_LE(wide.pitch_m, 1e6);
  EXPECT_THROW(least_ripple_pitch(m, 0.1, std::numeric_limits<double>::quiet_NaN()), std::invalid_argument);
}

TEST(Spacing, GoldenMatchesExhaustiveScanAndIsScaleFree) {
  const SpotModel m = default_model();
  const double R = m.radius_m, p = m.beta - 0.5;
  // Independent cost: two strokes of peak 1 at 0 and s, squared deviation from 1 on a 1 mm grid.
  auto cost = [&](double overlap) {
    const double s = 2 * R - overlap;
    double j = 0;
    for (int k = 0; k * 1e-3 <= s + 1e-12; ++k) {
      double t = 0;
      for (double x : {k * 1e-3, k * 1e-3 - s}) t += std::abs(x) < R ? std::pow(1 - x * x / (R * R), p) : 0;
      j += (1 - t) * (1 - t);
    }
    return j;
  };
  double best_o = 0, best = 1e300;
  for (double o = 0; o <= R; o += 0.0005)
    if (const double j = cost(o); j < best) best = j, best_o = o;
  const PassSpacing ps = pass_spacing(m, 0.05);
  std::cout << "spacing: " << ps.spacing_m * 1e3 << " mm, overlap " << ps.overlap_m * 1e3 << " mm, band "
            << ps.band_min_m * 1e3 << " .. " << ps.band_max_m * 1e3 << " mm for Td 50 mm (scan: overlap "
            << best_o * 1e3 << " mm)\n";
  EXPECT_NEAR(ps.overlap_m, best_o, 0.0005);
  EXPECT_NEAR(ps.spacing_m, 2 * R - ps.overlap_m, 1e-12);
  EXPECT_LE(cost(ps.overlap_m), best + 1e-9);
  EXPECT_LT(ps.band_min_m, 0.05);
  EXPECT_GT(ps.band_max_m, 0.05 * 0.9);
  for (double td : {0.005, 0.02, 0.2}) {
    const PassSpacing q = pass_spacing(m, td);
    EXPECT_NEAR(q.overlap_m, ps.overlap_m, 1e-6);
    EXPECT_NEAR(q.band_min_m / td, ps.band_min_m / 0.05, 1e-9);
    EXPECT_NEAR(q.band_max_m / td, ps.band_max_m / 0.05, 1e-9);
  }
  EXPECT_THROW(pass_spacing(m, 0.0), std::invalid_argument);
}
