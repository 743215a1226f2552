// Readers and writers of the core (docs/architecture.md §3, "Readers"): files written byte by byte
// here, independently of PCL, read back exactly; header/data mismatches are one-line errors naming
// the file; survey coordinates survive a write/read round trip in double.
#include <gtest/gtest.h>

#include <cstring>
#include <limits>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

#include "shotcrete/io/io.hpp"
#include "shotcrete/io/survey.hpp"

namespace fs = std::filesystem;
using shotcrete::Cloud;

namespace {

fs::path temp_file(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("shotcrete_test_io_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return dir / name;
}

fs::path write_bytes(const std::string& name, const std::string& bytes) {
  const fs::path p = temp_file(name);
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

std::vector<double> survey_points(int n) {  // x y z per point, ~ (500 km, 4000 km, 300 m)
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  std::vector<double> v;
  for (int i = 0; i < 3 * n; ++i) v.push_back(u(rng) + (i % 3 == 0 ? 500000.0 : i % 3 == 1 ? 4000000.0 : 300.0));
  return v;
}

template <class T> std::string raw(const T& value) { return std::string(reinterpret_cast<const char*>(&value), sizeof(T)); }

/// A binary little-endian PLY: double x, float intensity, double z, double y (scrambled order, extra property).
std::string double_ply(const std::vector<double>& xyz, std::size_t declared) {
  std::string s = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(declared) +
                  "\nproperty double x\nproperty float intensity\nproperty double z\nproperty double y\nend_header\n";
  for (std::size_t i = 0; i < xyz.size() / 3; ++i)
    s += raw(xyz[3 * i]) + raw(float(i)) + raw(xyz[3 * i + 2]) + raw(xyz[3 * i + 1]);
  return s;
}

std::string ascii_pcd(const std::vector<double>& xyz, long declared) {
  std::string s = "VERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\nWIDTH " + std::to_string(declared) +
                  "\nHEIGHT 1\nPOINTS " + std::to_string(declared) + "\nDATA ascii\n";
  char buf[128];
  for (std::size_t i = 0; i < xyz.size() / 3; ++i) {
    std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g\n", xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    s += buf;
  }
  return s;
}

std::string error_of(const fs::path& p) {
  try {
    shotcrete::read_cloud(p.string());
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

void expect_exact(const Cloud& c, const std::vector<double>& xyz) {
  ASSERT_EQ(static_cast<std::size_t>(c.size()), xyz.size() / 3);
  for (Eigen::Index i = 0; i < c.size(); ++i)
    for (int k = 0; k < 3; ++k) ASSERT_EQ(c.xyz(i, k), xyz[3 * i + k]) << "point " << i << " axis " << k;
}

}  // namespace

TEST(Readers, DoublePlyInAnyPropertyOrderIsReadExactly) {
  const auto xyz = survey_points(100);
  expect_exact(shotcrete::read_cloud(write_bytes("d.ply", double_ply(xyz, 100)).string()), xyz);
}

TEST(Readers, DoubleAsciiPcdIsReadExactly) {
  const auto xyz = survey_points(50);
  expect_exact(shotcrete::read_cloud(write_bytes("d.pcd", ascii_pcd(xyz, 50)).string()), xyz);
}

TEST(Readers, HeaderDisagreeingWithDataIsAnErrorNamingFileAndCounts) {
  const auto xyz = survey_points(100);
  const fs::path half = write_bytes("half.pcd", ascii_pcd(xyz, 50));
  std::string msg = error_of(half);
  EXPECT_NE(msg.find(half.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("POINTS 50"), std::string::npos) << msg;
  EXPECT_NE(msg.find("100 points"), std::string::npos) << msg;
  msg = error_of(write_bytes("neg.pcd", ascii_pcd(xyz, -5)));
  EXPECT_NE(msg.find("whole number"), std::string::npos) << msg;
  msg = error_of(write_bytes("short.ply", double_ply(xyz, 60)));
  EXPECT_NE(msg.find("understates"), std::string::npos) << msg;
  msg = error_of(write_bytes("huge.ply", double_ply(xyz, 4000000000u)));
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  EXPECT_EQ(msg.find('\n'), std::string::npos);
}

TEST(Writers, SurveyCoordinatesRoundTripInDouble) {
  const auto xyz = survey_points(64);
  Cloud c;
  c.xyz.resize(64, 3);
  for (int i = 0; i < 64; ++i) c.xyz.row(i) << xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2];
  for (const char* name : {"w.pcd", "w.ply"}) {
    const fs::path p = temp_file(name);
    shotcrete::write_cloud(p.string(), c);
    expect_exact(shotcrete::read_cloud(p.string()), xyz);
  }
}

// ---------------------------------------------------------------------------------------------
// Survey coordinates: the local frame (io/survey.hpp), shared by the CLI and the ROS node.
// ---------------------------------------------------------------------------------------------

using namespace shotcrete;

TEST(LocalFrame, OriginIsTheBoxCentreRoundedToWhole100m) {
  const Eigen::Vector3d survey(500000.0, 4000000.0, 300.0);
  Points xyz(2, 3);
  xyz << 0.0, -5.0, 0.0, 1.2, 5.0, 5.6;
  EXPECT_EQ(local_origin(xyz), Eigen::Vector3d::Zero());  // near its own origin: unshifted
  EXPECT_EQ(local_origin(xyz.rowwise() + survey.transpose()), survey);
  EXPECT_EQ(local_origin(xyz.rowwise() + Eigen::RowVector3d(149.0, -251.0, 45.0)), Eigen::Vector3d(100.0, -300.0, 0.0));
  Points nan = Points::Constant(3, 3, std::numeric_limits<double>::quiet_NaN());
  EXPECT_EQ(local_origin(nan), Eigen::Vector3d::Zero());
  EXPECT_EQ(local_origin(Points(0, 3)), Eigen::Vector3d::Zero());
  // A NaN row is ignored, not a reason to stay unshifted.
  Points mixed(3, 3);
  mixed << xyz.rowwise() + survey.transpose(), nan.row(0);
  EXPECT_EQ(local_origin(mixed), survey);
  // Input units: millimetres scale to metres first; a cloud wider than io.max_extent_m stays put
  // (the surface stage refuses it with a units hint).
  IoConfig io;
  io.unit_scale = 0.001;
  EXPECT_EQ(local_frame_origin((xyz.rowwise() + survey.transpose()) * 1000.0, io), survey);
  io.unit_scale = 1.0;
  EXPECT_EQ(local_frame_origin((xyz.rowwise() + survey.transpose()) * 1000.0, io), Eigen::Vector3d::Zero());
}

TEST(LocalFrame, MovesCloudAndConfigByTheSameOriginKeepingMillimetresInFloat32) {
  const Eigen::Vector3d survey(500000.0, 4000000.0, 300.0);
  Config cfg;
  cfg.profile.axis_origin_m = survey + Eigen::Vector3d(0, 0, 1);
  cfg.robot.base_position_m = survey + Eigen::Vector3d(0.6, 0, -1.2);
  const Eigen::Vector3d crop_span = cfg.preprocess.crop_max_m - cfg.preprocess.crop_min_m;
  Cloud c;
  c.xyz.resize(2, 3);
  c.xyz << 0.5004, 0.0007, 5.0003, 0.7, 1.0, 5.5;
  const Points local_truth = c.xyz;
  c.xyz.rowwise() += survey.transpose();
  c.normals = Points::Constant(2, 3, 0.5);
  const Eigen::Vector3d origin = local_frame_origin(c.xyz, cfg.io);
  ASSERT_EQ(origin, survey);
  Config local = cfg;
  to_local_frame(origin, c, local);
  EXPECT_LT((c.xyz - local_truth).cwiseAbs().maxCoeff(), 1e-9);
  // float32 keeps 0.1 mm in the local frame (~0.25 m at y = 4,000 km).
  EXPECT_LT((c.xyz.cast<float>().cast<double>() - local_truth).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_EQ(c.normals, Points::Constant(2, 3, 0.5));
  EXPECT_LT((local.profile.axis_origin_m - Eigen::Vector3d(0, 0, 1)).norm(), 1e-9);
  EXPECT_LT((local.robot.base_position_m - Eigen::Vector3d(0.6, 0, -1.2)).norm(), 1e-9);
  EXPECT_LT((local.preprocess.crop_max_m - local.preprocess.crop_min_m - crop_span).norm(), 1e-6);
  // Millimetres: the cloud moves in its input units, the config in metres.
  Cloud mm;
  mm.xyz = (local_truth.rowwise() + survey.transpose()) * 1000.0;
  Config mm_cfg = cfg;
  mm_cfg.io.unit_scale = 0.001;
  to_local_frame(local_frame_origin(mm.xyz, mm_cfg.io), mm, mm_cfg);
  EXPECT_LT((mm.xyz - local_truth * 1000.0).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT((mm_cfg.robot.base_position_m - Eigen::Vector3d(0.6, 0, -1.2)).norm(), 1e-9);
  // A zero origin moves nothing.
  Cloud same = c;
  Config same_cfg = local;
  to_local_frame(Eigen::Vector3d::Zero(), same, same_cfg);
  EXPECT_EQ(same.xyz, c.xyz);
  EXPECT_EQ(same_cfg.robot.base_position_m, local.robot.base_position_m);
}

TEST(LocalFrame, ConfigLeftInAnotherFrameIsRefusedNamingTheKey) {
  const Eigen::Vector3d survey(500000.0, 4000000.0, 300.0);
  Cloud c;
  c.xyz.resize(2, 3);
  c.xyz << 0.5, 0.0, 5.0, 0.7, 1.0, 5.5;
  c.xyz.rowwise() += survey.transpose();
  Config cfg;  // robot and axis at the origin, 4,031 km away
  auto refusal = [&](const Config& k) -> std::string {
    Cloud cc = c;
    Config kk = k;
    try {
      to_local_frame(survey, cc, kk);
    } catch (const std::invalid_argument& e) {
      EXPECT_EQ(cc.xyz, c.xyz) << "a refused shift must leave the cloud";
      return e.what();
    }
    return "";
  };
  const char* expected = "robot.base_position_m is 4,031.1 km from it: give robot.base_position_m in the cloud's frame";
  EXPECT_EQ(refusal(cfg).rfind("the cloud lies in survey coordinates around (500,000, 4,000,000, 300) m but ", 0), 0u)
      << refusal(cfg);
  EXPECT_NE(refusal(cfg).find(expected), std::string::npos) << refusal(cfg);
  cfg.robot.base_position_m = survey;
  EXPECT_NE(refusal(cfg).find("profile.axis_origin_m"), std::string::npos);
  cfg.profile.axis_origin_m = survey + Eigen::Vector3d(-900.0, 0.0, 0.0);  // along the axis: on its line
  EXPECT_EQ(refusal(cfg), "");
  cfg.profile.axis_origin_m = Eigen::Vector3d::Zero();
  cfg.profile.estimate_axis = true;  // fitted: the given origin is not used ...
  EXPECT_EQ(refusal(cfg), "");
  cfg.profile.estimate_axis_origin = false;  // ... unless it is kept (a surveyed point on the axis)
  EXPECT_NE(refusal(cfg).find("profile.axis_origin_m"), std::string::npos);
}
