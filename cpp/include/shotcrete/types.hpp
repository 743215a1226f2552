#pragma once
// Plain data types shared by every stage. SI units: metres, seconds, radians.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

namespace shotcrete {

/// N x 3 row-major: maps one-to-one onto a C-contiguous numpy (N, 3) float64 array.
using Points = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// A point cloud in metres; `normals` is either empty (0 rows) or one unit normal per point.
struct Cloud {
  Points xyz;
  Points normals;

  Eigen::Index size() const { return xyz.rows(); }
  bool has_normals() const { return normals.rows() == xyz.rows() && xyz.rows() > 0; }
};

}  // namespace shotcrete
