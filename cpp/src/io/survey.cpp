#include "shotcrete/io/survey.hpp"

#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>

namespace shotcrete {

namespace {

// 4031.2 -> "4,031.2" (digits grouped by three, `decimals` after the point).
std::string grouped(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, std::abs(v));
  std::string s(buf);
  const std::size_t dot = s.find('.');
  std::string head = s.substr(0, dot), tail = dot == std::string::npos ? "" : s.substr(dot);
  for (int i = static_cast<int>(head.size()) - 3; i > 0; i -= 3) head.insert(static_cast<std::size_t>(i), ",");
  return (v < 0 && std::round(std::abs(v) * std::pow(10.0, decimals)) != 0 ? "-" : "") + head + tail;
}

}  // namespace

namespace {

// The bounding box of the finite points of `xyz` x unit_scale [m]; false when there is none.
bool finite_box(const Points& xyz, double unit_scale, Eigen::Vector3d& lo, Eigen::Vector3d& hi) {
  const double inf = std::numeric_limits<double>::infinity();
  lo = Eigen::Vector3d::Constant(inf);
  hi = Eigen::Vector3d::Constant(-inf);
  bool any = false;
  for (Eigen::Index i = 0; i < xyz.rows(); ++i) {
    const Eigen::Vector3d p = xyz.row(i).transpose() * unit_scale;
    if (!p.allFinite()) continue;
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    any = true;
  }
  return any;
}

// The box's centre rounded to whole kLocalOriginStepM.
Eigen::Vector3d rounded_centre(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  Eigen::Vector3d o;
  // std::nearbyint: halves to even, as numpy's round; + 0.0: no -0.0 in reports.
  for (int k = 0; k < 3; ++k) o[k] = std::nearbyint((lo[k] + hi[k]) / 2.0 / kLocalOriginStepM) * kLocalOriginStepM + 0.0;
  return o;
}

}  // namespace

Eigen::Vector3d local_origin(const Points& xyz, double unit_scale) {
  Eigen::Vector3d lo, hi;
  return finite_box(xyz, unit_scale, lo, hi) ? rounded_centre(lo, hi) : Eigen::Vector3d::Zero();
}

Eigen::Vector3d local_frame_origin(const Points& xyz, const IoConfig& io) {
  Eigen::Vector3d lo, hi;
  if (!finite_box(xyz, io.unit_scale, lo, hi) || (hi - lo).maxCoeff() > io.max_extent_m) return Eigen::Vector3d::Zero();
  return rounded_centre(lo, hi);
}

void to_local_frame(const Eigen::Vector3d& origin_m, Cloud& cloud, Config& config) {
  if (!origin_m.allFinite()) throw std::invalid_argument("local frame: the origin is not finite");
  if ((origin_m.array() == 0.0).all()) return;
  const std::string where = grouped(origin_m.x(), 0) + ", " + grouped(origin_m.y(), 0) + ", " + grouped(origin_m.z(), 0);
  auto far = [&](const char* key, double dist_m) {
    if (dist_m > kFarFromCloudM)
      throw std::invalid_argument("the cloud lies in survey coordinates around (" + where + ") m but " + key + " is " +
                                  grouped(dist_m / 1000.0, 1) + " km from it: give " + key +
                                  " in the cloud's frame (docs/architecture.md §3, survey coordinates)");
  };
  const ProfileConfig& p = config.profile;
  far("robot.base_position_m", (config.robot.base_position_m - origin_m).norm());
  const Eigen::Vector3d rel = origin_m - p.axis_origin_m;
  if (!p.estimate_axis) {  // the distance of the cloud's origin from the axis line
    const Eigen::Vector3d dir = p.axis_direction.normalized();
    far("profile.axis_origin_m", (rel - rel.dot(dir) * dir).norm());
  } else if (!p.estimate_axis_origin) {  // a surveyed origin kept, the direction fitted
    far("profile.axis_origin_m", rel.norm());
  }
  const Eigen::RowVector3d shift = (-origin_m / config.io.unit_scale).transpose();
  cloud.xyz.rowwise() += shift;
  config.profile.axis_origin_m -= origin_m;
  config.preprocess.crop_min_m -= origin_m;
  config.preprocess.crop_max_m -= origin_m;
  config.robot.base_position_m -= origin_m;
}

}  // namespace shotcrete
