#include "shotcrete/io/io.hpp"

#include "cloud_header.hpp"

#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstring>
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

const pcl::PCLPointField* find_field(const pcl::PCLPointCloud2& blob, const std::string& name) {
  for (const auto& f : blob.fields)
    if (f.name == name) return &f;
  return nullptr;
}

template <class T> double load_as_double(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return static_cast<double>(v);
}

/// One value of `field` per point, converted to double by the field's own datatype (FLOAT32,
/// FLOAT64 or an integer type), never through a float32 PCL point type.
void read_column(const pcl::PCLPointCloud2& blob, const pcl::PCLPointField& field, Points& out, int column) {
  double (*load)(const std::uint8_t*) = nullptr;
  switch (field.datatype) {
    case pcl::PCLPointField::INT8: load = load_as_double<std::int8_t>; break;
    case pcl::PCLPointField::UINT8: load = load_as_double<std::uint8_t>; break;
    case pcl::PCLPointField::INT16: load = load_as_double<std::int16_t>; break;
    case pcl::PCLPointField::UINT16: load = load_as_double<std::uint16_t>; break;
    case pcl::PCLPointField::INT32: load = load_as_double<std::int32_t>; break;
    case pcl::PCLPointField::UINT32: load = load_as_double<std::uint32_t>; break;
    case pcl::PCLPointField::FLOAT32: load = load_as_double<float>; break;
    case pcl::PCLPointField::FLOAT64: load = load_as_double<double>; break;
    default: throw std::invalid_argument("field '" + field.name + "' has an unsupported datatype");
  }
  const std::size_t n = static_cast<std::size_t>(out.rows());
  for (std::size_t i = 0; i < n; ++i) out(i, column) = load(blob.data.data() + i * blob.point_step + field.offset);
}

Cloud from_blob(const pcl::PCLPointCloud2& blob, const std::string& path) {
  const char* names[2][3] = {{"x", "y", "z"}, {"normal_x", "normal_y", "normal_z"}};
  const pcl::PCLPointField* fields[2][3];
  for (int k = 0; k < 3; ++k) {
    fields[0][k] = find_field(blob, names[0][k]);
    fields[1][k] = find_field(blob, names[1][k]);
  }
  if (!fields[0][0] || !fields[0][1] || !fields[0][2]) throw std::invalid_argument(path + ": the cloud has no x/y/z fields");
  const std::size_t n = static_cast<std::size_t>(blob.width) * blob.height;
  if (blob.data.size() < n * blob.point_step)
    throw std::invalid_argument(path + ": the reader returned " + std::to_string(blob.data.size()) + " bytes for " +
                                std::to_string(n) + " points of " + std::to_string(blob.point_step) + " bytes");
  Cloud cloud;
  cloud.xyz.resize(static_cast<Eigen::Index>(n), 3);
  for (int k = 0; k < 3; ++k) read_column(blob, *fields[0][k], cloud.xyz, k);
  if (fields[1][0] && fields[1][1] && fields[1][2]) {
    cloud.normals.resize(static_cast<Eigen::Index>(n), 3);
    for (int k = 0; k < 3; ++k) read_column(blob, *fields[1][k], cloud.normals, k);
  }
  return cloud;
}

Cloud read_text(const std::string& path) {
  std::ifstream in(path);
  std::vector<double> values;
  std::string line;
  int columns = -1, line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    for (char& c : line) {
      const unsigned char u = static_cast<unsigned char>(c);
      if (u < 32 && c != '\t' && c != '\r' && c != '\f' && c != '\v')
        throw std::invalid_argument(path + ":" + std::to_string(line_no) +
                                    ": binary data (control byte " + std::to_string(u) +
                                    "); .xyz/.txt/.csv/.pts must be text, x y z [nx ny nz] per line");
      if (c == ',' || c == ';' || c == '\t' || c == '\r' || c == '\f' || c == '\v') c = ' ';
    }
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
        throw std::invalid_argument(path + ":" + std::to_string(line_no) + ": '" + detail::printable(token) + "' is not a number");
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

/// Coordinates beyond this magnitude are written as float64: float32 keeps only ~6 cm at 500 km.
constexpr double kFloat32CoordinateLimitM = 1000.0;

void add_field(pcl::PCLPointCloud2& blob, const std::string& name, std::uint8_t datatype, std::uint32_t size) {
  pcl::PCLPointField f;
  f.name = name;
  f.offset = blob.point_step;
  f.datatype = datatype;
  f.count = 1;
  blob.fields.push_back(f);
  blob.point_step += size;
}

template <class T> void store(std::uint8_t* p, double v) {
  const T t = static_cast<T>(v);
  std::memcpy(p, &t, sizeof(T));
}

/// x, y, z (float32, or float64 beyond kFloat32CoordinateLimitM), normal_x/y/z and intensity (float32).
pcl::PCLPointCloud2 to_blob(const Cloud& cloud, const Eigen::VectorXd& scalar) {
  const Eigen::Index n = cloud.size();
  const bool wide = n > 0 && cloud.xyz.cwiseAbs().maxCoeff() > kFloat32CoordinateLimitM;
  const bool normals = cloud.has_normals();
  pcl::PCLPointCloud2 blob;
  const std::uint32_t coord = wide ? 8 : 4;
  for (const char* name : {"x", "y", "z"})
    add_field(blob, name, wide ? pcl::PCLPointField::FLOAT64 : pcl::PCLPointField::FLOAT32, coord);
  for (const char* name : {"normal_x", "normal_y", "normal_z", "intensity"})
    add_field(blob, name, pcl::PCLPointField::FLOAT32, 4);
  blob.width = static_cast<std::uint32_t>(n);
  blob.height = 1;
  blob.is_dense = false;
  blob.row_step = blob.point_step * blob.width;
  blob.data.assign(static_cast<std::size_t>(blob.row_step), 0);
  for (Eigen::Index i = 0; i < n; ++i) {
    std::uint8_t* p = blob.data.data() + static_cast<std::size_t>(i) * blob.point_step;
    for (int k = 0; k < 3; ++k) {
      wide ? store<double>(p + k * coord, cloud.xyz(i, k)) : store<float>(p + k * coord, cloud.xyz(i, k));
      store<float>(p + 3 * coord + 4 * k, normals ? cloud.normals(i, k) : 0.0);
    }
    store<float>(p + 3 * coord + 12, scalar.size() ? scalar[i] : 0.0);
  }
  return blob;
}

}  // namespace

Cloud read_cloud(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) throw std::invalid_argument(path + ": no such file");
  const std::string ext = extension(path);
  if (ext == ".xyz" || ext == ".txt" || ext == ".csv" || ext == ".pts") return read_text(path);
  // Every count in the header is checked against the data before PCL allocates anything.
  if (ext == ".pcd") detail::check_pcd_header(path);
  if (ext == ".ply") detail::check_ply_header(path);
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
    out.precision(12);  // micrometres at survey coordinates
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
  const pcl::PCLPointCloud2 blob = to_blob(cloud, scalar);
  int rc = -1;
  if (ext == ".pcd") {
    rc = pcl::PCDWriter().writeBinary(path, blob);
  } else {
    rc = pcl::PLYWriter().writeBinary(path, blob, Eigen::Vector4f::Zero(), Eigen::Quaternionf::Identity(), false);
  }
  if (rc < 0) throw std::runtime_error(path + ": write failed");
}

}  // namespace shotcrete
