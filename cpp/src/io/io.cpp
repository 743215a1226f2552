#include "shotcrete/io/io.hpp"

#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace shotcrete {
namespace {

std::string extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext;
}

bool has_field(const pcl::PCLPointCloud2& blob, const std::string& name) {
  return std::any_of(blob.fields.begin(), blob.fields.end(), [&](const auto& f) { return f.name == name; });
}

Cloud from_blob(const pcl::PCLPointCloud2& blob, const std::string& path) {
  if (!has_field(blob, "x") || !has_field(blob, "y") || !has_field(blob, "z"))
    throw std::invalid_argument(path + ": the cloud has no x/y/z fields");
  Cloud cloud;
  const bool normals = has_field(blob, "normal_x") && has_field(blob, "normal_y") && has_field(blob, "normal_z");
  if (normals) {
    pcl::PointCloud<pcl::PointNormal> pc;
    pcl::fromPCLPointCloud2(blob, pc);
    cloud.xyz.resize(pc.size(), 3);
    cloud.normals.resize(pc.size(), 3);
    for (std::size_t i = 0; i < pc.size(); ++i) {
      cloud.xyz.row(i) << pc[i].x, pc[i].y, pc[i].z;
      cloud.normals.row(i) << pc[i].normal_x, pc[i].normal_y, pc[i].normal_z;
    }
  } else {
    pcl::PointCloud<pcl::PointXYZ> pc;
    pcl::fromPCLPointCloud2(blob, pc);
    cloud.xyz.resize(pc.size(), 3);
    for (std::size_t i = 0; i < pc.size(); ++i) cloud.xyz.row(i) << pc[i].x, pc[i].y, pc[i].z;
  }
  return cloud;
}

// PCL's readers can crash on a file that is not what its extension says: check the header first.
void check_header(const std::string& path, const std::string& ext) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  if (ext == ".ply") {
    std::getline(in, line);
    if (line.rfind("ply", 0) != 0) throw std::invalid_argument(path + ": not a PLY file (no 'ply' magic line)");
    return;
  }
  bool fields = false, data = false, points = false;
  for (int i = 0; i < 30 && std::getline(in, line); ++i) {
    if (line.rfind("FIELDS", 0) == 0) fields = true;
    if (line.rfind("POINTS", 0) == 0) points = true;
    if (line.rfind("DATA", 0) == 0) {
      data = true;
      break;
    }
  }
  if (!(fields && points && data))
    throw std::invalid_argument(path + ": not a PCD file (header without FIELDS/POINTS/DATA)");
}

Cloud read_text(const std::string& path) {
  std::ifstream in(path);
  std::vector<double> values;
  std::string line;
  int columns = -1, line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    for (char& c : line)
      if (c == ',' || c == ';' || c == '\t') c = ' ';
    const auto first = line.find_first_not_of(' ');
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ss(line);
    std::vector<double> row;
    std::string token;
    while (ss >> token) {
      try {
        std::size_t used = 0;
        row.push_back(std::stod(token, &used));
        if (used != token.size()) throw std::invalid_argument(token);
      } catch (const std::exception&) {
        if (values.empty() && row.empty() && std::isalpha(static_cast<unsigned char>(token[0]))) {
          row.clear();  // a header line such as "x y z"
          break;
        }
        throw std::invalid_argument(path + ":" + std::to_string(line_no) + ": '" + token + "' is not a number");
      }
    }
    if (row.empty()) continue;
    if (row.size() < 3)
      throw std::invalid_argument(path + ":" + std::to_string(line_no) + ": expected at least 3 columns (x y z)");
    const int use = row.size() >= 6 ? 6 : 3;
    if (columns < 0) columns = use;
    if (use != columns)
      throw std::invalid_argument(path + ":" + std::to_string(line_no) + ": inconsistent number of columns");
    values.insert(values.end(), row.begin(), row.begin() + use);
  }
  Cloud cloud;
  const Eigen::Index n = columns > 0 ? static_cast<Eigen::Index>(values.size()) / columns : 0;
  cloud.xyz.resize(n, 3);
  if (columns == 6) cloud.normals.resize(n, 3);
  for (Eigen::Index i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) {
      cloud.xyz(i, k) = values[i * columns + k];
      if (columns == 6) cloud.normals(i, k) = values[i * columns + 3 + k];
    }
  return cloud;
}

}  // namespace

Cloud read_cloud(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) throw std::invalid_argument(path + ": no such file");
  const std::string ext = extension(path);
  if (ext == ".xyz" || ext == ".txt" || ext == ".csv" || ext == ".pts") return read_text(path);
  if (ext == ".pcd" || ext == ".ply") check_header(path, ext);
  pcl::PCLPointCloud2 blob;
  int rc = -1;
  // PCL prints its own complaints on failure; the exception below carries the message the user needs.
  if (ext == ".pcd") {
    pcl::PCDReader reader;
    rc = reader.read(path, blob);
  } else if (ext == ".ply") {
    pcl::PLYReader reader;
    rc = reader.read(path, blob);
  } else {
    throw std::invalid_argument(path + ": unknown cloud format '" + ext +
                                "' (supported: .pcd .ply .xyz .txt .csv; .las .laz .e57 through Python)");
  }
  if (rc < 0) throw std::invalid_argument(path + ": not a valid " + ext.substr(1) + " point cloud");
  return from_blob(blob, path);
}

void write_cloud(const std::string& path, const Cloud& cloud, const Eigen::VectorXd& scalar) {
  const Eigen::Index n = cloud.size();
  if (scalar.size() != 0 && scalar.size() != n)
    throw std::invalid_argument("write_cloud: scalar has " + std::to_string(scalar.size()) + " values for " +
                                std::to_string(n) + " points");
  const std::string ext = extension(path);
  const bool normals = cloud.has_normals();
  if (ext == ".xyz" || ext == ".txt") {
    std::ofstream out(path);
    if (!out) throw std::invalid_argument(path + ": cannot write");
    out.precision(9);
    for (Eigen::Index i = 0; i < n; ++i) {
      out << cloud.xyz(i, 0) << ' ' << cloud.xyz(i, 1) << ' ' << cloud.xyz(i, 2);
      if (normals) out << ' ' << cloud.normals(i, 0) << ' ' << cloud.normals(i, 1) << ' ' << cloud.normals(i, 2);
      if (scalar.size()) out << ' ' << scalar[i];
      out << '\n';
    }
    if (!out) throw std::runtime_error(path + ": write failed");
    return;
  }
  if (ext != ".pcd" && ext != ".ply")
    throw std::invalid_argument(path + ": unknown cloud format '" + ext + "' (write .pcd, .ply or .xyz)");
  pcl::PointCloud<pcl::PointXYZINormal> pc;
  pc.resize(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    auto& p = pc[i];
    p.x = cloud.xyz(i, 0);
    p.y = cloud.xyz(i, 1);
    p.z = cloud.xyz(i, 2);
    p.intensity = scalar.size() ? static_cast<float>(scalar[i]) : 0.f;
    p.normal_x = normals ? cloud.normals(i, 0) : 0.f;
    p.normal_y = normals ? cloud.normals(i, 1) : 0.f;
    p.normal_z = normals ? cloud.normals(i, 2) : 0.f;
    p.curvature = 0.f;
  }
  int rc = ext == ".pcd" ? pcl::io::savePCDFileBinary(path, pc) : pcl::io::savePLYFileBinary(path, pc);
  if (rc < 0) throw std::runtime_error(path + ": write failed");
}

}  // namespace shotcrete
