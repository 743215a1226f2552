"""Exact distances of a robot's collision shapes to points, in numpy (every point): the independent
reference the clearance tests check the core's octree and exact queries against. Cylinders along
their z axis and boxes (the rig's carrier); nothing else is in the bundled URDF."""
from __future__ import annotations

import numpy as np

from shotcrete import _core


def shape_distance(shape, link_pose: np.ndarray, points: np.ndarray) -> float:
    """Least distance [m] of `points` (n x 3) to `shape` at its link's 4x4 world pose (0 inside)."""
    T = np.asarray(link_pose) @ np.asarray(shape.origin)
    local = (np.asarray(points) - T[:3, 3]) @ T[:3, :3]
    if shape.kind == _core.CollisionShape.Kind.box:
        return float(np.min(np.linalg.norm(np.maximum(0.0, np.abs(local) - 0.5 * np.asarray(shape.size_m)), axis=1)))
    assert shape.kind == _core.CollisionShape.Kind.cylinder
    radial = np.maximum(0.0, np.hypot(local[:, 0], local[:, 1]) - shape.radius_m)
    axial = np.maximum(0.0, np.abs(local[:, 2]) - 0.5 * shape.length_m)
    return float(np.min(np.hypot(radial, axial)))
