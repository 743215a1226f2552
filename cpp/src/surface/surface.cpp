#include "shotcrete/surface/surface.hpp"

#include <chrono>

#include "shotcrete/surface/preprocess.hpp"

namespace shotcrete {
namespace {

class StageTimer {
 public:
  explicit StageTimer(std::map<std::string, double>& out) : out_(out) {}
  void lap(const std::string& stage) {
    const auto now = std::chrono::steady_clock::now();
    out_[stage] += std::chrono::duration<double>(now - last_).count();
    last_ = now;
  }

 private:
  std::map<std::string, double>& out_;
  std::chrono::steady_clock::time_point last_ = std::chrono::steady_clock::now();
};

}  // namespace

Surface build_surface(const Cloud& raw, const Config& config) {
  validate(config);
  Surface s;
  StageTimer timer(s.timings_s);
  Cloud cloud = config.io.unit_scale != 1.0 ? scale_cloud(raw, config.io.unit_scale) : raw;
  check_cloud(cloud, config.io);
  timer.lap("check");
  cloud = preprocess(cloud, config.preprocess);
  timer.lap("preprocess");
  s.axis = axis_from_config(config.profile);
  s.profile.radius_m = config.profile.design_radius_m;
  cloud = estimate_normals(cloud, config.normals.k_neighbors, s.axis);
  timer.lap("normals");
  if (config.profile.estimate_axis) {
    const AxisFit fit = fit_axis(cloud, config.profile);
    s.axis = fit.axis;
    s.axis_fit_rms_m = fit.rms_m;
    s.axis_fit = fit;
    orient_normals_toward_axis(cloud, s.axis);  // orientation depends on where the axis is
    timer.lap("axis_fit");
  }
  s.cloud = std::move(cloud);
  regrid(s, config);
  timer.lap("grid");
  return s;
}

void regrid(Surface& s, const Config& config) {
  s.grid = build_grid(s.cloud, s.axis, s.profile, config.grid, config.profile.max_deviation_m);
  s.levels = cell_levels(s.grid);
}

}  // namespace shotcrete
