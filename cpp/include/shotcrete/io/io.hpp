#pragma once
// Point cloud files through PCL (PCD, PLY) and plain text (XYZ: x y z [nx ny nz] per line).
// LAS/LAZ and E57 are read by the Python layer (laspy, pye57) and handed over as arrays.
#include <string>

#include "shotcrete/types.hpp"

namespace shotcrete {

/// Reads .pcd, .ply, .xyz/.txt/.csv in double precision (float or double fields); normals are
/// read when the file has them. Throws std::invalid_argument "<path>: <problem>" for a missing,
/// unknown or malformed file, and for a header that disagrees with the data (docs/architecture.md §3).
Cloud read_cloud(const std::string& path);

/// Writes .pcd (binary), .ply (binary) or .xyz; x/y/z as float32, or float64 when a coordinate
/// exceeds 1 km (survey coordinates); `scalar` (optional, one value per point) is
/// stored as the intensity field (PCD/PLY) or a 4th/7th column (XYZ).
void write_cloud(const std::string& path, const Cloud& cloud, const Eigen::VectorXd& scalar = {});

}  // namespace shotcrete
