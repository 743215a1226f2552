#include "ros_conversions.hpp"

#include <ros/param.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <set>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "shotcrete/config_fields.hpp"

namespace shotcrete_ros {
namespace {

bool host_is_big_endian() {
  const std::uint16_t one = 1;
  std::uint8_t first = 0;
  std::memcpy(&first, &one, 1);
  return first == 0;
}

const sensor_msgs::PointField* find_field(const sensor_msgs::PointCloud2& msg, const std::string& name) {
  for (const auto& f : msg.fields)
    if (f.name == name) return &f;
  return nullptr;
}

double read_value(const std::uint8_t* p, std::uint8_t datatype) {
  if (datatype == sensor_msgs::PointField::FLOAT32) {
    float v;
    std::memcpy(&v, p, sizeof v);
    return v;
  }
  double v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

}  // namespace

std::string cloud_from_msg(const sensor_msgs::PointCloud2& msg, const std::string& expected_frame,
                           shotcrete::Cloud& out, std::size_t max_points) {
  // No tf lookup: the planner works in the tunnel frame, so any other frame is refused rather
  // than silently misplaced.
  if (msg.header.frame_id != expected_frame) {
    const std::string& f = msg.header.frame_id;  // a hostile name can be megabytes long, or binary
    return "frame '" + shotcrete::printable(f, 64) + "'" + (f.size() > 64 ? " (" + std::to_string(f.size()) + " bytes)" : "") +
           " is not the tunnel frame '" + expected_frame + "'";
  }
  const std::size_t n = static_cast<std::size_t>(msg.width) * msg.height;
  if (n == 0) return "empty cloud (width * height = 0)";
  if (n > max_points)
    return "cloud of " + std::to_string(n) + " points is larger than ~max_points (" + std::to_string(max_points) + ")";
  if (msg.is_bigendian != host_is_big_endian()) return "byte order differs from this machine's";
  const sensor_msgs::PointField* xyz[3];
  const char* names[3] = {"x", "y", "z"};
  for (int k = 0; k < 3; ++k) {
    xyz[k] = find_field(msg, names[k]);
    if (!xyz[k]) return std::string("missing field '") + names[k] + "'";
    if (xyz[k]->datatype != sensor_msgs::PointField::FLOAT32 && xyz[k]->datatype != sensor_msgs::PointField::FLOAT64)
      return std::string("field '") + names[k] + "' is not float32/float64";
    const std::size_t size = xyz[k]->datatype == sensor_msgs::PointField::FLOAT32 ? 4 : 8;
    if (xyz[k]->offset + size > msg.point_step)
      return std::string("field '") + names[k] + "' lies outside point_step";
  }
  if (static_cast<std::size_t>(msg.row_step) < static_cast<std::size_t>(msg.width) * msg.point_step)
    return "row_step smaller than width * point_step";
  if (msg.data.size() < static_cast<std::size_t>(msg.row_step) * msg.height)
    return "data holds " + std::to_string(msg.data.size()) + " bytes, header promises " +
           std::to_string(static_cast<std::size_t>(msg.row_step) * msg.height);

  shotcrete::Cloud cloud;
  cloud.xyz.resize(static_cast<Eigen::Index>(n), 3);
  std::size_t bad = 0, i = 0;
  for (std::uint32_t row = 0; row < msg.height; ++row) {
    for (std::uint32_t col = 0; col < msg.width; ++col, ++i) {
      // In size_t: row * row_step can pass 2^32 on a legal multi-GB message.
      const std::uint8_t* p = msg.data.data() + static_cast<std::size_t>(row) * msg.row_step +
                              static_cast<std::size_t>(col) * msg.point_step;
      bool finite = true;
      for (int k = 0; k < 3; ++k) {
        const double v = read_value(p + xyz[k]->offset, xyz[k]->datatype);
        finite = finite && std::isfinite(v);
        cloud.xyz(static_cast<Eigen::Index>(i), k) = v;
      }
      if (!finite) ++bad;
    }
  }
  if (bad > 0)
    return std::to_string(bad) + " of " + std::to_string(n) + " points have NaN/Inf coordinates";
  out = std::move(cloud);
  return {};
}

std_msgs::ColorRGBA colormap(double t, float alpha) {
  t = std::clamp(std::isfinite(t) ? t : 0.0, 0.0, 1.0);
  // Piecewise-linear through blue, cyan, green, yellow, red.
  static const double stops[5][3] = {{0.1, 0.2, 1.0}, {0.0, 0.9, 1.0}, {0.1, 0.9, 0.1}, {1.0, 0.9, 0.0}, {1.0, 0.1, 0.0}};
  const double x = t * 4.0;
  const int k = std::min(3, static_cast<int>(x));
  const double u = x - k;
  std_msgs::ColorRGBA c;
  c.r = static_cast<float>(stops[k][0] + u * (stops[k + 1][0] - stops[k][0]));
  c.g = static_cast<float>(stops[k][1] + u * (stops[k + 1][1] - stops[k][1]));
  c.b = static_cast<float>(stops[k][2] + u * (stops[k + 1][2] - stops[k][2]));
  c.a = alpha;
  return c;
}

sensor_msgs::PointCloud2 cloud_to_msg(const shotcrete::Points& xyz, const Eigen::VectorXd& td_m,
                                      double td_color_max_m, const std::string& frame_id,
                                      const ros::Time& stamp) {
  if (td_m.size() != xyz.rows())
    throw std::invalid_argument("cloud_to_msg: " + std::to_string(td_m.size()) + " TD values for " +
                                std::to_string(xyz.rows()) + " points");
  sensor_msgs::PointCloud2 msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  sensor_msgs::PointCloud2Modifier mod(msg);
  mod.setPointCloud2Fields(5, "x", 1, sensor_msgs::PointField::FLOAT32, "y", 1, sensor_msgs::PointField::FLOAT32,
                           "z", 1, sensor_msgs::PointField::FLOAT32, "intensity", 1,
                           sensor_msgs::PointField::FLOAT32, "rgb", 1, sensor_msgs::PointField::FLOAT32);
  mod.resize(static_cast<std::size_t>(xyz.rows()));
  sensor_msgs::PointCloud2Iterator<float> x(msg, "x"), y(msg, "y"), z(msg, "z"), in(msg, "intensity");
  sensor_msgs::PointCloud2Iterator<std::uint8_t> rgb(msg, "rgb");
  const double scale = td_color_max_m > 0 ? 1.0 / td_color_max_m : 1.0;
  for (Eigen::Index i = 0; i < xyz.rows(); ++i, ++x, ++y, ++z, ++in, ++rgb) {
    *x = static_cast<float>(xyz(i, 0));
    *y = static_cast<float>(xyz(i, 1));
    *z = static_cast<float>(xyz(i, 2));
    *in = static_cast<float>(td_m[i]);
    std_msgs::ColorRGBA c;
    if (td_m[i] <= 0.0) {
      c.r = c.g = c.b = 0.6f;  // at or inside the design line: done
    } else {
      c = colormap(td_m[i] * scale);
    }
    // packed rgb float: bytes b, g, r, a in memory (PCL convention)
    rgb[0] = static_cast<std::uint8_t>(std::lround(c.b * 255));
    rgb[1] = static_cast<std::uint8_t>(std::lround(c.g * 255));
    rgb[2] = static_cast<std::uint8_t>(std::lround(c.r * 255));
    rgb[3] = 255;
  }
  return msg;
}

sensor_msgs::PointCloud2 cells_to_msg(const shotcrete::Points& xyz, const Eigen::VectorXd& thickness_m,
                                      const Eigen::VectorXd& lod95_m, const std::vector<int>& cells,
                                      double color_max_m, const std::string& frame_id, const ros::Time& stamp) {
  const auto n = static_cast<std::size_t>(xyz.rows());
  if (static_cast<std::size_t>(thickness_m.size()) != n || static_cast<std::size_t>(lod95_m.size()) != n ||
      cells.size() != n)
    throw std::invalid_argument("cells_to_msg: " + std::to_string(n) + " points with " +
                                std::to_string(thickness_m.size()) + " thicknesses, " +
                                std::to_string(lod95_m.size()) + " lod95, " + std::to_string(cells.size()) + " cells");
  sensor_msgs::PointCloud2 msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  sensor_msgs::PointCloud2Modifier mod(msg);
  using F = sensor_msgs::PointField;
  mod.setPointCloud2Fields(7, "x", 1, F::FLOAT32, "y", 1, F::FLOAT32, "z", 1, F::FLOAT32, "intensity", 1, F::FLOAT32,
                           "rgb", 1, F::FLOAT32, "lod95", 1, F::FLOAT32, "cell", 1, F::FLOAT32);
  mod.resize(n);
  sensor_msgs::PointCloud2Iterator<float> x(msg, "x"), y(msg, "y"), z(msg, "z"), in(msg, "intensity"),
      lod(msg, "lod95"), cell(msg, "cell");
  sensor_msgs::PointCloud2Iterator<std::uint8_t> rgb(msg, "rgb");
  const double scale = color_max_m > 0 ? 1.0 / color_max_m : 1.0;
  for (std::size_t i = 0; i < n; ++i, ++x, ++y, ++z, ++in, ++rgb, ++lod, ++cell) {
    *x = static_cast<float>(xyz(i, 0));
    *y = static_cast<float>(xyz(i, 1));
    *z = static_cast<float>(xyz(i, 2));
    *in = static_cast<float>(thickness_m[i]);
    *lod = static_cast<float>(lod95_m[i]);
    *cell = static_cast<float>(cells[i]);
    const std_msgs::ColorRGBA c = colormap(thickness_m[i] * scale);
    rgb[0] = static_cast<std::uint8_t>(std::lround(c.b * 255));
    rgb[1] = static_cast<std::uint8_t>(std::lround(c.g * 255));
    rgb[2] = static_cast<std::uint8_t>(std::lround(c.r * 255));
    rgb[3] = 255;
  }
  return msg;
}

namespace {

std::string type_name(XmlRpc::XmlRpcValue::Type t) {
  switch (t) {
    case XmlRpc::XmlRpcValue::TypeBoolean: return "bool";
    case XmlRpc::XmlRpcValue::TypeInt: return "int";
    case XmlRpc::XmlRpcValue::TypeDouble: return "double";
    case XmlRpc::XmlRpcValue::TypeString: return "string";
    case XmlRpc::XmlRpcValue::TypeArray: return "list";
    case XmlRpc::XmlRpcValue::TypeStruct: return "dict";
    default: return "other";
  }
}

double as_number(XmlRpc::XmlRpcValue& v, const std::string& name) {
  if (v.getType() == XmlRpc::XmlRpcValue::TypeDouble) return static_cast<double>(v);
  if (v.getType() == XmlRpc::XmlRpcValue::TypeInt) return static_cast<int>(v);
  throw std::invalid_argument("parameter " + name + ": expected a number, got " + type_name(v.getType()));
}

template <class T>
void assign(T& member, XmlRpc::XmlRpcValue& v, const std::string& name) {
  if constexpr (std::is_same_v<T, bool>) {
    if (v.getType() != XmlRpc::XmlRpcValue::TypeBoolean)
      throw std::invalid_argument("parameter " + name + ": expected a bool, got " + type_name(v.getType()));
    member = static_cast<bool>(v);
  } else if constexpr (std::is_same_v<T, std::string>) {
    if (v.getType() != XmlRpc::XmlRpcValue::TypeString)
      throw std::invalid_argument("parameter " + name + ": expected a string, got " + type_name(v.getType()));
    member = static_cast<std::string>(v);
  } else if constexpr (shotcrete::is_named_enum_v<T>) {  // by name, as in the YAML config
    if (v.getType() != XmlRpc::XmlRpcValue::TypeString)
      throw std::invalid_argument("parameter " + name + ": expected one of " + shotcrete::enum_choices<T>() + ", got " +
                                  type_name(v.getType()));
    member = shotcrete::parse_enum<T>(static_cast<std::string>(v), "parameter " + name);
  } else if constexpr (std::is_same_v<T, double>) {
    member = as_number(v, name);
  } else if constexpr (std::is_integral_v<T>) {
    if (v.getType() != XmlRpc::XmlRpcValue::TypeInt)
      throw std::invalid_argument("parameter " + name + ": expected an integer, got " + type_name(v.getType()));
    const int i = static_cast<int>(v);
    if (std::is_unsigned_v<T> && i < 0)
      throw std::invalid_argument("parameter " + name + ": must not be negative, got " + std::to_string(i));
    member = static_cast<T>(i);
  } else if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
    if (v.getType() != XmlRpc::XmlRpcValue::TypeArray || v.size() != 3)
      throw std::invalid_argument("parameter " + name + ": expected a list of 3 numbers");
    for (int k = 0; k < 3; ++k) member[k] = as_number(v[k], name);
  } else {
    static_assert(sizeof(T) == 0, "config field type without a ROS parameter mapping");
  }
}

}  // namespace

std::vector<std::string> apply_param_overrides(const ros::NodeHandle& pnh, shotcrete::Config& config) {
  std::vector<std::string> applied;
  std::set<std::string> known;
  shotcrete::fields::visit_sections([&](const char* section_name, auto shotcrete::Config::*section_ptr) {
    auto& section = config.*section_ptr;
    using Section = std::decay_t<decltype(section)>;
    shotcrete::fields::visit(static_cast<Section*>(nullptr),
                             [&](const char* key, auto Section::*member, double, double, const char*) {
                               const std::string name = std::string(section_name) + "/" + key;
                               known.insert(pnh.resolveName(name));
                               XmlRpc::XmlRpcValue value;
                               if (!pnh.getParam(name, value)) return;
                               assign(section.*member, value, pnh.resolveName(name));
                               applied.push_back(name);
                             });
  });
  // A typo in a key must not be ignored silently (the YAML loader refuses unknown keys too).
  std::set<std::string> sections;
  shotcrete::fields::visit_sections([&](const char* s, auto) { sections.insert(pnh.resolveName(s) + "/"); });
  std::vector<std::string> all;
  ros::param::getParamNames(all);
  for (const auto& p : all) {
    for (const auto& s : sections) {
      if (p.rfind(s, 0) == 0 && !known.count(p))
        throw std::invalid_argument("unknown config parameter " + p);
    }
  }
  try {
    shotcrete::validate(config);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("after parameter overrides: ") + e.what());
  }
  return applied;
}

}  // namespace shotcrete_ros
