// Re-scan after spraying: synthetic context and after-scan, registration on reference areas (and the
// bias of whole-cloud registration), M3C2 thickness (closed forms on a plane and a cylinder, a second
// implementation), calibration, refusals.
#include <gtest/gtest.h>

#include <pcl/filters/voxel_grid.h>

#include <cmath>
#include <random>

#include "shotcrete/config.hpp"
#include "shotcrete/io/synth.hpp"
#include "shotcrete/pipeline/rescan_job.hpp"
#include "shotcrete/rescan/rescan.hpp"
#include "../../cpp/src/rescan/gicp_parts.hpp"

using namespace shotcrete;

namespace {

constexpr double kPi = 3.14159265358979323846;

// The lattice of the synthetic bay's grid (as build_grid lays it): every cell valid, TD from the bay.
Grid bay_lattice(const SyntheticBay& bay, double cs = 0.05) {
  const double R = bay.config.design_radius_m, dth = cs / R;
  const int n_theta = static_cast<int>(std::floor(bay.config.theta_max_rad / dth)) + 1;
  const int n_d = static_cast<int>(std::round(bay.config.length_m / cs));
  std::vector<int> rows, cols;
  std::vector<double> th, d, td;
  for (int i = 0; i < n_theta; ++i)
    for (int j = 0; j < n_d; ++j) {
      rows.push_back(i);
      cols.push_back(j);
      th.push_back((i + 0.5) * dth);
      d.push_back((j + 0.5) * cs);
      td.push_back(bay.td_at(d.back(), th.back()));
    }
  DesignProfile prof;
  prof.radius_m = R;
  return grid_from_cells(bay.axis, prof, cs, rows, cols, th, d, td);
}

Config small_config() {
  Config c;
  c.synth.points_per_cell = 20;  // ~16 points per 25 mm cylinder and scan
  c.synth.after_points_per_cell = 20;
  c.synth.context_enabled = true;
  c.synth.context_previous_bay_m = 1.0;
  return c;
}

// Rotation angle [deg] and translation [m] of T_est^-1 T_true.
std::pair<double, double> pose_error(const Eigen::Matrix4d& est, const Eigen::Matrix4d& truth) {
  const Eigen::Matrix4d E = est.inverse() * truth;
  const double angle = Eigen::AngleAxisd(Eigen::Matrix3d(E.topLeftCorner<3, 3>())).angle() * 180.0 / kPi;
  return {angle, E.topRightCorner<3, 1>().norm()};
}

// Largest displacement [m] a pose error causes on the bay's wall (the measurement's error).
double wall_error(const Eigen::Matrix4d& est, const Eigen::Matrix4d& truth, const SyntheticBay& bay) {
  const Eigen::Matrix4d E = est * truth.inverse();
  double worst = 0;
  for (double th = 0; th <= kPi; th += 0.1)
    for (double d : {0.0, bay.config.length_m}) {
      const Eigen::Vector3d p = bay.axis.to_cartesian(bay.config.design_radius_m, th, d);
      worst = std::max(worst, (E.topLeftCorner<3, 3>() * p + E.topRightCorner<3, 1>() - p).norm());
    }
  return worst;
}

struct Pair {
  Config config;
  SyntheticBay bay;
  Grid grid;
  Eigen::VectorXd deposit;
  Cloud before;
  AfterScan after;
};

// A bay sprayed flush (deposit = TD) except a dry band of rows, seen after from a pose 1 deg / 0.1 m off.
Pair make_pair(double flow_scale = 0.85) {
  Pair p;
  p.config = small_config();
  p.config.synth.after_flow_scale = flow_scale;
  p.config.synth.after_pose_rpy_rad = Eigen::Vector3d(0.3, -0.5, 0.8) * (kPi / 180.0);
  p.config.synth.after_pose_translation_m = Eigen::Vector3d(0.06, -0.05, 0.06);
  p.bay = make_synthetic_bay(p.config.synth);
  p.grid = bay_lattice(p.bay);
  p.deposit = p.grid.td_m;
  p.before = p.bay.sample_scan(0.05);
  p.after = make_after_scan(p.bay, p.grid, p.deposit, p.config);
  return p;
}

}  // namespace

TEST(Synth, ContextOffKeepsTheBayAndOnAddsTheSurroundingsOnTheirSurfaces) {
  Config c = small_config();
  c.synth.context_enabled = false;
  const SyntheticBay off = make_synthetic_bay(c.synth);
  EXPECT_EQ(off.sample_scan(0.05).xyz, off.sample(0.05).xyz);
  c.synth.context_enabled = true;
  c.synth.noise_m = 0.0;
  const SyntheticBay on = make_synthetic_bay(c.synth);
  const Cloud ctx = on.sample_context(0.05, 6, 0.0, 1);  // 6 points per cell area
  ASSERT_GT(ctx.size(), 1000);
  const double R = c.synth.design_radius_m, h = c.synth.context_invert_depth_m, L = c.synth.length_m;
  int lining = 0, floor = 0, face = 0;
  for (Eigen::Index i = 0; i < ctx.size(); ++i) {
    const Eigen::Vector3d p = ctx.xyz.row(i).transpose();
    const double r = std::hypot(p.y(), p.z());
    if (std::abs(p.z() + h) < 1e-9 && std::abs(p.y()) <= R) ++floor;
    else if (std::abs(p.x() - L) < 1e-9 && r <= R && p.z() >= -h) ++face;
    else if (std::abs(r - R) < 1e-9 && p.x() < 0 && p.x() >= -c.synth.context_previous_bay_m && p.z() >= -1e-9) ++lining;
    else ADD_FAILURE() << "point off every context surface: " << p.transpose();
  }
  // Uniform density: counts in proportion to the areas (pi R x 1 m, 2R x 2.2 m, half disc + 2R h).
  const double dens = 6 / 0.0025;
  EXPECT_NEAR(lining, kPi * R * 1.0 * dens, 0.03 * kPi * R * dens);
  EXPECT_NEAR(floor, 2 * R * (1.0 + L) * dens, 0.03 * 2 * R * (1.0 + L) * dens);
  const double face_area = 0.5 * kPi * R * R + 2 * (0.5 * h * std::sqrt(R * R - h * h) + 0.5 * R * R * std::asin(h / R));
  EXPECT_NEAR(face, face_area * dens, 0.03 * face_area * dens);
}

TEST(Synth, AfterScanAppliesTheScaledDepositAndMovesToItsPose) {
  Config c = small_config();
  c.synth.context_enabled = false;
  c.synth.after_noise_m = 0.0;
  c.synth.after_thickness_noise = 0.0;
  c.synth.after_flow_scale = 0.85;
  c.synth.after_rebound_fraction = 0.16;  // real rebound double the model's 0.08
  const SyntheticBay bay = make_synthetic_bay(c.synth);
  const Grid grid = bay_lattice(bay);
  const Eigen::VectorXd dep = Eigen::VectorXd::Constant(grid.size(), 0.1);
  const AfterScan a = make_after_scan(bay, grid, dep, c);
  const double scale = 0.85 * (1 - 0.16) / (1 - 0.08);
  EXPECT_NEAR(a.layer_scale, scale, 1e-12);
  for (int i = 0; i < grid.size(); ++i) EXPECT_NEAR(a.true_thickness_m[i], 0.1 * scale, 1e-12);
  EXPECT_TRUE(a.pose.isIdentity());
  for (Eigen::Index i = 0; i < a.cloud.size(); i += 97) {
    const Eigen::Vector3d cyl = bay.axis.to_cylindrical(a.cloud.xyz.row(i).transpose());
    EXPECT_NEAR(cyl.x(), 5.6 + bay.td_at(cyl.z(), cyl.y()) - 0.1 * scale, 1e-9);
  }
  // A pose: the cloud is the same wall seen from it.
  c.synth.after_pose_rpy_rad = Eigen::Vector3d(0.01, 0.02, -0.03);
  c.synth.after_pose_translation_m = Eigen::Vector3d(0.1, -0.2, 0.3);
  const AfterScan moved = make_after_scan(bay, grid, dep, c);
  const Cloud back = transform_cloud(moved.cloud, moved.pose);
  EXPECT_LT((back.xyz - a.cloud.xyz).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_THROW(make_after_scan(bay, grid, Eigen::VectorXd::Zero(3), c), std::invalid_argument);
}

// The registration's own covariances and voxel count against the PCL steps they replace, on a
// noisy cylinder patch several metres from the origin (as the centred reference clouds are).
class PclGicp : public detail::GicpBase {
 public:
  MatricesVector covariances(const detail::PclCloud::ConstPtr& cloud) {
    auto tree = std::make_shared<detail::Tree>();
    tree->setInputCloud(cloud);
    MatricesVector out;
    computeCovariances<pcl::PointXYZ>(cloud, tree, out);
    return out;
  }
  double epsilon() const { return gicp_epsilon_; }
};

TEST(Registration, CovariancesAndVoxelCountMatchPcl) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.005);
  auto cloud = std::make_shared<detail::PclCloud>();
  for (int i = 0; i < 6000; ++i) {
    const double th = 1.2 * u(rng), x = -3.0 + 6.0 * u(rng), r = 5.0 + noise(rng);
    cloud->push_back(pcl::PointXYZ(static_cast<float>(x), static_cast<float>(r * std::cos(th) - 4.0),
                                   static_cast<float>(r * std::sin(th) - 2.0)));
  }
  PclGicp pcl_gicp;
  const auto expected = pcl_gicp.covariances(cloud);
  auto tree = std::make_shared<detail::Tree>();
  tree->setInputCloud(cloud);
  const auto got = detail::gicp_covariances(*cloud, *tree, 20, pcl_gicp.epsilon());
  ASSERT_EQ(got->size(), expected.size());
  double worst = 0.0;
  for (size_t i = 0; i < got->size(); ++i) worst = std::max(worst, ((*got)[i] - expected[i]).cwiseAbs().maxCoeff());
  RecordProperty("covariance_max_difference", std::to_string(worst));
  // PCL squares the coordinates in float: ~2e-5 apart here; a wrong formula is ~1 apart.
  EXPECT_LT(worst, 1e-3);
  // A plane's covariance: unit in-plane, epsilon along the normal (the cylinder's radial direction).
  const Eigen::Vector3d p0 = (*cloud)[0].getVector3fMap().cast<double>() + Eigen::Vector3d(0, 4, 2);
  const Eigen::Vector3d radial = Eigen::Vector3d(0, p0.y(), p0.z()).normalized();
  EXPECT_NEAR(radial.dot((*got)[0] * radial), pcl_gicp.epsilon(), 0.01);
  EXPECT_NEAR((*got)[0].trace(), 2.0 + pcl_gicp.epsilon(), 1e-9);
  for (const double voxel_m : {0.02, 0.05, 0.1, 0.37}) {
    pcl::VoxelGrid<pcl::PointXYZ> grid;
    grid.setInputCloud(cloud);
    grid.setLeafSize(static_cast<float>(voxel_m), static_cast<float>(voxel_m), static_cast<float>(voxel_m));
    detail::PclCloud voxels;
    grid.filter(voxels);
    EXPECT_EQ(detail::occupied_voxels(*cloud, voxel_m), voxels.size()) << voxel_m;
  }
}

TEST(Registration, RecoversAKnownPoseOnTheReferenceAreas) {
  const Pair p = make_pair();
  Config c = p.config;
  const auto ref = dry_reference(p.grid, p.deposit, c.rescan, c.profile.max_deviation_m);
  const Registration reg = register_scans(p.before, p.after.cloud, ref, c.rescan);
  const auto [deg, m] = pose_error(reg.transform, p.after.pose);
  RecordProperty("rotation_error_deg", std::to_string(deg));
  RecordProperty("translation_error_m", std::to_string(m));
  EXPECT_LT(deg, 0.05);
  EXPECT_LT(wall_error(reg.transform, p.after.pose, p.bay), 0.005);
  // Overlap: the share of after points with a before point within 0.05 m; both are thinned to one
  // point per 0.06 m voxel at random, so ~10 % fall in the gaps.
  EXPECT_GT(reg.overlap, 0.85);
  EXPECT_GT(reg.iterations, 0);
  // Point-to-plane RMS: the 5 mm scanner noise (of the point and of the plane's 8 points), no more.
  EXPECT_GT(reg.rms_m, 0.004);
  EXPECT_LT(reg.rms_m, 0.008);
  // The layer then reads true within a few mm on average (its own noise: 5 mm scanner noise, 6 points per cell).
  const CellThickness t = measure_cells(p.grid, p.before, transform_cloud(p.after.cloud, reg.transform), c.rescan);
  const Comparison cmp = compare_cells(t.thickness_m, p.after.true_thickness_m);
  RecordProperty("thickness_bias_mm", std::to_string(cmp.bias_m * 1000));
  RecordProperty("thickness_rms_mm", std::to_string(cmp.rms_m * 1000));
  EXPECT_GT(cmp.cells, 0.99 * p.grid.size());
  EXPECT_LT(std::abs(cmp.bias_m), 0.001);
  EXPECT_LT(cmp.rms_m, 0.003);
}

TEST(Registration, WholeCloudRegistrationExplainsTheLayerAwayButReferenceAreasDoNot) {
  Pair p = make_pair();
  // The bay alone (no context), a 0.12 m layer: the whole-cloud GICP pulls the after-scan outward.
  Config c = p.config;
  c.synth.context_enabled = false;
  p.bay = make_synthetic_bay(c.synth);
  p.before = p.bay.sample_scan(0.05);
  const Eigen::VectorXd dep = Eigen::VectorXd::Constant(p.grid.size(), 0.12);
  const AfterScan a = make_after_scan(p.bay, p.grid, dep, c);
  c.rescan.reference = ReferenceArea::box;  // the whole cloud
  c.rescan.coarse_correspondence_m = 0.5;
  c.rescan.fine_correspondence_m = 0.3;
  c.rescan.min_overlap = 0.0;
  const Registration whole = register_scans(p.before, a.cloud, box_reference(c.rescan), c.rescan);
  const CellThickness tw = measure_cells(p.grid, p.before, transform_cloud(a.cloud, whole.transform), c.rescan);
  const Comparison cw = compare_cells(tw.thickness_m, a.true_thickness_m);
  // With the context and the dry reference the same layer reads true.
  const Pair q = make_pair();
  const AfterScan aq = make_after_scan(q.bay, q.grid, dep, q.config);
  const Registration good = register_scans(q.before, aq.cloud, dry_reference(q.grid, dep, q.config.rescan, 1.0), q.config.rescan);
  const CellThickness tg = measure_cells(q.grid, q.before, transform_cloud(aq.cloud, good.transform), q.config.rescan);
  const Comparison cg = compare_cells(tg.thickness_m, aq.true_thickness_m);
  RecordProperty("whole_cloud_bias_mm", std::to_string(cw.bias_m * 1000));
  RecordProperty("reference_bias_mm", std::to_string(cg.bias_m * 1000));
  EXPECT_GT(wall_error(whole.transform, a.pose, p.bay), 0.03);  // centimetres off
  EXPECT_LT(cw.bias_m, -0.02);                                   // the layer reads thinner
  EXPECT_GT(cw.rms_m, 5 * cg.rms_m);
  EXPECT_LT(std::abs(cg.bias_m), 0.002);
}

TEST(Registration, RefusesNoReferenceAreaAnotherBayAndBadClouds) {
  const Pair p = make_pair();
  RescanConfig rc = p.config.rescan;
  rc.reference = ReferenceArea::box;
  rc.reference_box_min_m = Eigen::Vector3d(100, 100, 100);
  rc.reference_box_max_m = Eigen::Vector3d(101, 101, 101);
  EXPECT_THROW(register_scans(p.before, p.after.cloud, box_reference(rc), rc), std::invalid_argument);
  // An after-scan of another bay (50 m along): none of its points fall in the reference areas.
  Eigen::Matrix4d far = Eigen::Matrix4d::Identity();
  far(0, 3) = 50;
  const auto ref = dry_reference(p.grid, p.deposit, p.config.rescan, 1.0);
  try {
    register_scans(p.before, transform_cloud(p.after.cloud, far), ref, p.config.rescan);
    ADD_FAILURE() << "another bay was registered";
  } catch (const std::exception& e) {
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
  }
  // Overlapping only in part (the after-scan shifted 0.6 m along the axis): refused by the overlap test.
  Eigen::Matrix4d shift = Eigen::Matrix4d::Identity();
  shift(0, 3) = 0.6;
  EXPECT_ANY_THROW(register_scans(p.before, transform_cloud(p.after.cloud, shift), ref, p.config.rescan));
  Cloud empty;
  EXPECT_THROW(register_scans(empty, p.after.cloud, ref, p.config.rescan), std::invalid_argument);
  Cloud nan = p.after.cloud;
  nan.xyz(3, 1) = std::nan("");
  EXPECT_THROW(register_scans(p.before, nan, ref, p.config.rescan), std::invalid_argument);
  EXPECT_THROW(mask_reference(Cloud{}, p.config.rescan), std::invalid_argument);
  // A reference test that throws (it runs on every thread): its exception reaches the caller.
  const ReferenceTest throwing = [](const Eigen::Vector3d& q) -> bool {
    if (q.x() > 1.0) throw std::domain_error("reference test failed");
    return true;
  };
  EXPECT_THROW(register_scans(p.before, p.after.cloud, throwing, p.config.rescan), std::domain_error);
}

TEST(Thickness, M3C2OnNoisyPlanesMatchesTheLayerAndItsOwnUncertainty) {
  // Before: z = 0; after: z = 0.07 (a 70 mm layer toward +z), 4 mm noise, 40,000 points each per m^2.
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.0, 2.0);
  std::normal_distribution<double> g(0.0, 0.004);
  auto plane = [&](double z, int n) {
    Cloud c;
    c.xyz.resize(n, 3);
    for (int i = 0; i < n; ++i) c.xyz.row(i) << u(rng), u(rng), z + g(rng);
    return c;
  };
  const Cloud before = plane(0.0, 160000), after = plane(0.07, 160000);
  Points core(100, 3), normals(100, 3);
  for (int i = 0; i < 100; ++i) {
    core.row(i) << 0.5 + 0.1 * (i % 10), 0.5 + 0.1 * (i / 10), 0.0;
    normals.row(i) << 0, 0, 1;
  }
  RescanConfig rc;
  rc.cylinder_radius_m = 0.05;
  rc.cylinder_half_length_m = 0.2;
  const M3C2Result r = m3c2(core, normals, before, after, rc);
  double sum = 0, sum2 = 0, lod = 0;
  for (int i = 0; i < 100; ++i) {
    ASSERT_TRUE(std::isfinite(r.distance_m[i]));
    // Expected count: density x pi r^2 = 40,000 x 0.00785 = 314.
    EXPECT_NEAR(r.before_count[i], 314, 70);
    sum += r.distance_m[i];
    sum2 += r.distance_m[i] * r.distance_m[i];
    lod += r.lod95_m[i];
  }
  const double mean = sum / 100, sd = std::sqrt(sum2 / 100 - mean * mean);
  EXPECT_NEAR(mean, 0.07, 0.0003);
  // The LoD95 of each core point is 1.96 x the spread of the distances over the core points.
  EXPECT_NEAR(lod / 100, 1.96 * sd, 0.3 * 1.96 * sd);
  EXPECT_NEAR(lod / 100, 1.96 * 0.004 * std::sqrt(2.0 / 314), 0.1 * 1.96 * 0.004 * std::sqrt(2.0 / 314));
  // A tilted normal (30 deg) reads the layer times cos(30 deg): measured along the normal, not vertically.
  Points tilted = normals;
  for (int i = 0; i < 100; ++i) tilted.row(i) << std::sin(kPi / 6), 0, std::cos(kPi / 6);
  const M3C2Result t = m3c2(core, tilted, before, after, rc);
  EXPECT_NEAR(t.distance_m.mean(), 0.07 / std::cos(kPi / 6), 0.001);  // the plane at 0.07 is met farther along
  // Too few points: NaN.
  rc.min_cylinder_points = 100000;
  EXPECT_TRUE(std::isnan(m3c2(core, normals, before, after, rc).distance_m[0]));
}

TEST(Thickness, CellsOnACylinderWithAKnownLayerAgreeWithTheGenericM3C2) {
  Config c = small_config();
  c.synth.context_enabled = false;
  c.synth.pit_count = 0;  // a cylinder at R + 0.15
  c.synth.points_per_cell = 20;
  c.synth.after_points_per_cell = 20;
  c.synth.after_thickness_noise = 0.0;
  const SyntheticBay bay = make_synthetic_bay(c.synth);
  const Grid grid = bay_lattice(bay);
  const Eigen::VectorXd dep = Eigen::VectorXd::Constant(grid.size(), 0.09);
  const AfterScan a = make_after_scan(bay, grid, dep, c);
  const Cloud before = bay.sample(0.05);
  const CellThickness t = measure_cells(grid, before, a.cloud, c.rescan);
  EXPECT_GE(t.measured, grid.size() - 3) << "every cell measured but a few sparse ones";
  const Comparison cmp = compare_cells(t.thickness_m, Eigen::VectorXd::Constant(grid.size(), 0.09));
  EXPECT_LT(std::abs(cmp.bias_m), 0.0003);
  // Noise alone: 5 mm scanner noise over ~ pi 25^2 / 50^2 x 20 = 15.7 points per cylinder and scan.
  const double expected_sd = 0.005 * std::sqrt(2.0 / 15.7);
  EXPECT_NEAR(cmp.rms_m, expected_sd, 0.25 * expected_sd);
  for (int i = 0; i < grid.size(); i += 37)
    EXPECT_NEAR(t.residual_td_m[i], grid.td_m[i] - t.thickness_m[i], 1e-12);
  // The generic M3C2 (kd-tree, float) along the cells' rays reads the same numbers.
  Points core(grid.size(), 3), normals(grid.size(), 3);
  for (int i = 0; i < grid.size(); ++i) {
    const double th = grid.theta_center(grid.row_of(i));
    core.row(i) = bay.axis.to_cartesian(5.6 + grid.td_m[i], th, grid.d_center(grid.col_of(i))).transpose();
    normals.row(i) = -bay.axis.radial(th).transpose();
  }
  const M3C2Result g = m3c2(core, normals, before, a.cloud, c.rescan);
  int compared = 0;
  for (int i = 0; i < grid.size(); ++i) {
    if (t.before_count[i] != g.before_count[i] || t.after_count[i] != g.after_count[i]) continue;  // float edge cases
    if (!std::isfinite(t.thickness_m[i]) || !std::isfinite(g.distance_m[i])) {
      EXPECT_EQ(std::isfinite(t.thickness_m[i]), std::isfinite(g.distance_m[i]));
      continue;
    }
    EXPECT_NEAR(t.thickness_m[i], g.distance_m[i], 1e-5);
    EXPECT_NEAR(t.lod95_m[i], g.lod95_m[i], 1e-5);
    ++compared;
  }
  EXPECT_GT(compared, 0.9 * grid.size());
  // measure_points takes the same radial normals itself.
  const M3C2Result mp = measure_points(bay.axis, core, before, a.cloud, c.rescan);
  for (int i = 0; i < grid.size(); i += 101)
    if (std::isfinite(g.distance_m[i])) EXPECT_DOUBLE_EQ(mp.distance_m[i], g.distance_m[i]);
}

TEST(Calibration, RobustFactorFromMeasuredVsPredicted) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0.0, 0.3);
  std::normal_distribution<double> g(0.0, 0.002);
  const int n = 2000;
  Eigen::VectorXd pred(n), meas(n);
  for (int i = 0; i < n; ++i) {
    pred[i] = u(rng);
    meas[i] = 0.85 * pred[i] + g(rng);
  }
  for (int i = 0; i < 40; ++i) meas[i * 50] += 0.2;  // rebound pockets, a loose block: outliers
  pred[1] = std::nan("");
  RescanConfig rc;
  const Calibration cal = calibrate_flow(meas, pred, rc);
  EXPECT_NEAR(cal.factor, 0.85, 0.002);
  EXPECT_GE(cal.rejected, 35);
  EXPECT_NEAR(cal.residual_rms_m, 0.002, 0.0005);
  // Independent: least squares on the clean cells.
  double mp = 0, pp = 0;
  for (int i = 0; i < n; ++i)
    if (i % 50 != 0 && i != 1 && pred[i] >= rc.calibration_min_deposit_m) {
      mp += meas[i] * pred[i];
      pp += pred[i] * pred[i];
    }
  EXPECT_NEAR(cal.factor, mp / pp, 2e-4);
  rc.calibration_min_deposit_m = 0.5;
  EXPECT_THROW(calibrate_flow(meas, pred, rc), std::invalid_argument);
}

TEST(Rescan, GridFromCellsRefusesAnotherLattice) {
  Config c;
  const SyntheticBay bay = make_synthetic_bay(c.synth);
  const Grid g = bay_lattice(bay);
  EXPECT_EQ(g.valid_count(), g.size());
  EXPECT_NEAR(g.theta_center(3), 3.5 * 0.05 / 5.6, 1e-12);
  DesignProfile prof;
  prof.radius_m = 5.6;
  EXPECT_THROW(grid_from_cells(bay.axis, prof, 0.04, {0, 1}, {0, 0}, {0.025 / 5.6, 0.075 / 5.6}, {0.025, 0.025}, {0.1, 0.1}),
               std::invalid_argument);
  EXPECT_THROW(grid_from_cells(bay.axis, prof, 0.05, {0}, {0}, {std::nan("")}, {0.025}, {0.1}), std::invalid_argument);
}

// rescan_job (the CLI's and the ROS node's one loop) is the stage functions composed: the same pose,
// layer, comparison and factor as calling them one by one; its refusals name the scan at fault.
TEST(RescanJob, ComposesTheStagesAndRefusesScansThatAreNotTheJobs) {
  const Pair p = make_pair();
  const RescanOutcome out = rescan_job(p.grid, p.deposit, p.before, p.after.cloud, p.config);
  const auto ref = dry_reference(p.grid, p.deposit, p.config.rescan, p.config.profile.max_deviation_m);
  const Registration reg = register_scans(p.before, p.after.cloud, ref, p.config.rescan);
  EXPECT_TRUE(out.registration.transform.isApprox(reg.transform, 1e-12));
  const CellThickness th = measure_cells(p.grid, p.before, transform_cloud(p.after.cloud, reg.transform), p.config.rescan);
  EXPECT_EQ(out.thickness.measured, th.measured);
  EXPECT_TRUE(out.thickness.thickness_m.array().isNaN().matrix() == th.thickness_m.array().isNaN().matrix());
  EXPECT_LT((out.thickness.thickness_m - th.thickness_m).array().isNaN().select(0.0, (out.thickness.thickness_m -
            th.thickness_m).array()).abs().maxCoeff(), 1e-12);
  const Comparison cmp = compare_cells(th.thickness_m, p.deposit);
  EXPECT_DOUBLE_EQ(out.comparison.rms_m, cmp.rms_m);
  ASSERT_TRUE(out.calibration.has_value()) << out.calibration_error;
  EXPECT_DOUBLE_EQ(out.calibration->factor, calibrate_flow(th.thickness_m, p.deposit, p.config.rescan).factor);
  EXPECT_NEAR(out.calibration->factor / p.after.layer_scale, 1.0, 0.02);
  EXPECT_LT(out.before_td_rms_m, 0.005);  // the before-scan's TD along the rays is the grid's
  EXPECT_FALSE(out.correction.has_value());  // no robot: no corrective round
  const Config cal = calibrated_config(p.config, 0.9);
  EXPECT_DOUBLE_EQ(cal.deposition.peak_rate_mps, 0.9 * p.config.deposition.peak_rate_mps);

  auto message = [&](const Grid& g, const Eigen::VectorXd& dep, const Cloud& before, const Cloud& after) {
    try {
      rescan_job(g, dep, before, after, p.config);
    } catch (const std::exception& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_EQ(message(p.grid, Eigen::VectorXd::Zero(3), p.before, p.after.cloud).rfind("rescan: predicted deposit", 0), 0u);
  EXPECT_EQ(message(p.grid, p.deposit, p.before, Cloud{}).rfind("after-scan: ", 0), 0u);
  Cloud nan = p.before;
  nan.xyz(5, 2) = std::nan("");
  EXPECT_EQ(message(p.grid, p.deposit, nan, p.after.cloud).rfind("before-scan: ", 0), 0u);
  // A job whose TD is 50 mm off the before-scan's everywhere: not the scan it planned on.
  Grid other = p.grid;
  other.td_m.array() += 0.05;
  const std::string m = message(other, p.deposit, p.before, p.after.cloud);
  EXPECT_NE(m.find("not the scan the job planned on"), std::string::npos) << m;
}
