#pragma once
// Stage 1 of the pipeline: raw scan -> checked, preprocessed cloud with normals -> axis ->
// graded 50 mm grid with priority levels.
#include <map>
#include <optional>
#include <string>

#include "shotcrete/config.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/types.hpp"

namespace shotcrete {

struct Surface {
  Cloud cloud;              // preprocessed, with normals toward the axis
  TunnelAxis axis;
  DesignProfile profile;
  double axis_fit_rms_m = 0.0;  // 0 when the axis came from the config
  std::optional<AxisFit> axis_fit;  // when profile.estimate_axis
  Grid grid;                // the bay's grid
  BaySelectionResult bay;   // how the bay was chosen from the scan
  std::vector<char> in_grid;  // per cloud point: 1 when gridded (near the line, wall, in the bay)
  std::vector<int> levels;  // per cell
  std::map<std::string, double> timings_s;  // per stage
};

/// Throws std::invalid_argument with the reason for unusable input (empty, NaN, units, radius).
Surface build_surface(const Cloud& raw, const Config& config);

/// Re-grids a cloud that already has normals (after deposition moved its points), over the bay
/// chosen when the surface was built.
void regrid(Surface& surface, const Config& config);

}  // namespace shotcrete
