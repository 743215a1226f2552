#pragma once
// Point cloud files through PCL (PCD, PLY) and plain text (XYZ: x y z [nx ny nz] per line).
// LAS/LAZ and E57 are read by the Python layer (laspy, pye57) and handed over as arrays.
#include <string>

#include "shotcrete/types.hpp"

namespace shotcrete {

/// Reads .pcd, .ply, .xyz/.txt/.csv; normals are read when the file has them.
/// Throws std::invalid_argument for a missing, unknown or malformed file.
Cloud read_cloud(const std::string& path);

/// Writes .pcd (binary), .ply (binary) or .xyz; `scalar` (optional, one value per point) is
/// stored as the intensity field (PCD/PLY) or a 4th/7th column (XYZ).
void write_cloud(const std::string& path, const Cloud& cloud, const Eigen::VectorXd& scalar = {});

}  // namespace shotcrete
