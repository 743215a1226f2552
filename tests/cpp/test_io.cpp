// Readers and writers of the core (docs/architecture.md §3, "Readers"): files written byte by byte
// here, independently of PCL, read back exactly; header/data mismatches are one-line errors naming
// the file; survey coordinates survive a write/read round trip in double.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

#include "shotcrete/io/io.hpp"

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
