#pragma once
// The one deposit of the core: a layer of concrete put on the scanned wall. The planner's rounds,
// the Python API and the ROS node's execution all move the wall through deposit_layer, so the
// report's numbers and the executed wall agree.
#include <vector>

#include "shotcrete/surface/surface.hpp"

namespace shotcrete {

/// The wall as it is sprayed: the scan's surface with its cloud moved by every layer so far; the
/// grid's cell means, TD and normals and the levels follow the moved points. Every point keeps the
/// cell the scan gave it, so a layer never moves a point into another cell.
struct SprayedWall {
  Surface surface;                 // cloud, grid and levels of the wall as sprayed so far
  std::vector<int> cell_of_point;  // the scan's cell of every point (-1: outside the grid band)
};

/// The wall before any spraying: the surface's cloud on its grid. The points the grid was built
/// from (surface.in_grid) keep their cells; the rest (the face, a floor, the lining, points farther
/// than max_deviation_m from the design line when in_grid is not set) belong to no cell; the cell
/// means and TD are those of the points assigned here. Throws std::invalid_argument without normals.
SprayedWall unsprayed_wall(const Surface& surface, double max_deviation_m);

/// Puts a layer on the wall: every point of a cell moves toward the axis along its ray (d and theta
/// stay, so the point keeps its cell) by thickness_m[i] / cos(tilt); points of no cell (the face,
/// a floor, the lining, a ventilation duct) stay where the scan has them -- a layer measured along the normal
/// fills that much radially (tilt: between the normal and the ray, counted at most 60 degrees).
/// Moving along the scan normals instead makes points in deep pits cross each other and corrupt
/// the cell means. Then the cells are re-averaged, their levels re-graded, and every cell that
/// gained more than 2 mm gets the normal of its new TD map (the scan's no longer describes it).
/// thickness_m: one entry per point of wall.surface.cloud (std::invalid_argument otherwise).
void deposit_layer(SprayedWall& wall, const Eigen::VectorXd& thickness_m);

}  // namespace shotcrete
