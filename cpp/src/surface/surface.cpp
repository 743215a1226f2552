#include "shotcrete/surface/surface.hpp"

#include <algorithm>
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

/// The points of `cloud` that build_grid grids inside `range`, with their normals.
Cloud bay_wall_points(const Cloud& cloud, const TunnelAxis& axis, const DesignProfile& profile, const Config& config,
                      const BayRange& range) {
  std::vector<char> kept;
  build_grid(cloud, axis, profile, config.grid, config.profile.max_deviation_m, range, &kept);
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < cloud.size(); ++i)
    if (kept[static_cast<std::size_t>(i)]) keep.push_back(i);
  return select_points(cloud, keep);
}

}  // namespace

Surface build_surface(const Cloud& raw, const Config& config) {
  validate(config);
  Surface s;
  StageTimer timer(s.timings_s);
  s.profile = design_profile_from_config(config.profile);  // a bad section file fails before any work
  Cloud cloud = config.io.unit_scale != 1.0 ? scale_cloud(raw, config.io.unit_scale) : raw;
  check_cloud(cloud, config.io);
  timer.lap("check");
  cloud = preprocess(cloud, config.preprocess);
  timer.lap("preprocess");
  s.axis = axis_from_config(config.profile);
  cloud = estimate_normals(cloud, config.normals.k_neighbors, s.axis);
  timer.lap("normals");
  if (config.profile.estimate_axis) {
    const AxisFit fit = fit_axis(cloud, config.profile, config.grid);
    s.axis = fit.axis;
    s.axis_fit_rms_m = fit.rms_m;
    s.axis_fit = fit;
    orient_normals_toward_axis(cloud, s.axis);  // orientation depends on where the axis is
    timer.lap("axis_fit");
  }
  s.cloud = std::move(cloud);
  // The whole scan's wall first; the bay is a stretch of it (the rest stays in s.cloud).
  Grid scan_grid = build_grid(s.cloud, s.axis, s.profile, config.grid, config.profile.max_deviation_m);
  s.bay = select_bay(scan_grid, config.grid);
  const bool other_wall = config.grid.bay == BaySelection::detect ? s.bay.lined_columns > 0
                                                                   : s.bay.range.start_m != s.bay.scan_start_m || s.bay.range.end_m != s.bay.scan_end_m;
  if (config.profile.estimate_axis && other_wall && config.grid.bay == BaySelection::detect) {
    // A lined bay beside the new one: the fit held both (each at its own radius; the lining, on
    // the design line, pins the axis best), but its origin lies where the scan's wall starts, so
    // the columns fall across the seam and the bay's first one is part lining. The origin moves to
    // where the bay's own wall starts (the 0.1 % axial quantile of its points off the design line
    // by more than lined_td_m: the 0.5 % one lay 6 mm in, and that strip of the bay made the column
    // before it not lined) and the bay is selected again on columns from there.
    const Cloud bay_wall = bay_wall_points(s.cloud, s.axis, s.profile, config, s.bay.range);
    std::vector<double> d;
    for (Eigen::Index i = 0; i < bay_wall.size(); ++i) {
      const Eigen::Vector3d c = s.axis.to_cylindrical(bay_wall.xyz.row(i).transpose());
      if (s.profile.td_m(c[0], c[1]) > config.grid.lined_td_m) d.push_back(c[2]);
    }
    if (static_cast<long>(d.size()) >= kMinAxisFitPoints) {
      const auto k = static_cast<std::ptrdiff_t>(0.001 * static_cast<double>(d.size()));
      std::nth_element(d.begin(), d.begin() + k, d.end());
      s.axis.origin_m += d[static_cast<std::size_t>(k)] * s.axis.ex;
      s.axis_fit->axis = s.axis;
      scan_grid = build_grid(s.cloud, s.axis, s.profile, config.grid, config.profile.max_deviation_m);
      s.bay = select_bay(scan_grid, config.grid);
    }
  } else if (config.profile.estimate_axis && other_wall) {
    // The chainage range given: the axis again from the bay's own wall. (Not for a bay whose sparse end
    // column was only trimmed: the whole wall fits better than a shorter one.) One cross-section
    // less at each end, where a column may hold a strip of other wall.
    const double cs = config.grid.cell_size_m;
    const BayRange inner{s.bay.range.start_m + cs, s.bay.range.end_m - cs};
    const Cloud bay_wall = inner.start_m < inner.end_m ? bay_wall_points(s.cloud, s.axis, s.profile, config, inner) : Cloud{};
    if (bay_wall.size() >= kMinAxisFitPoints) {
      const AxisFit fit = fit_axis(bay_wall, config.profile, config.grid);
      s.axis = fit.axis;
      s.axis_fit_rms_m = fit.rms_m;
      s.axis_fit = fit;
      orient_normals_toward_axis(s.cloud, s.axis);
      scan_grid = build_grid(s.cloud, s.axis, s.profile, config.grid, config.profile.max_deviation_m);
      s.bay = select_bay(scan_grid, config.grid);
    }
  }
  regrid(s, config);
  timer.lap("grid");
  return s;
}

void regrid(Surface& s, const Config& config) {
  // The bay chosen on the scan, not re-detected: a sprayed bay looks like lining.
  // (A surface assembled by hand, with no bay chosen, grids the whole cloud.)
  const bool chosen = s.bay.range.start_m < s.bay.range.end_m;
  s.grid = build_grid(s.cloud, s.axis, s.profile, config.grid, config.profile.max_deviation_m,
                      chosen ? std::optional<BayRange>(s.bay.range) : std::nullopt, &s.in_grid);
  s.levels = cell_levels(s.grid);
}

}  // namespace shotcrete
