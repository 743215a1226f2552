"""Survey coordinates (docs/architecture.md §3, "Survey coordinates").

Scans arrive in survey coordinates (x = 500,000, y = 4,000,000): float32, which PCL's filters and
normals use, keeps only ~0.25 m there. A job therefore runs in a local frame: the input (read in
double precision) minus a local origin, the centre of its bounding box rounded to whole 100 m,
(0, 0, 0) for any cloud within 50 m of its own origin, so such clouds run unchanged. The config's
coordinates (axis origin, crop box, robot base) are in the input's frame too and move with it.
Every output that carries coordinates is written back in the input's frame (the origin added
back), and report.json records the origin as ``local_origin_m``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core


def local_origin(xyz_m: np.ndarray) -> np.ndarray:
    """The bounding box centre of ``xyz_m`` (N, 3) in metres, rounded to whole 100 m (the core's
    kLocalOriginStepM; non-finite points ignored; (0, 0, 0) for a cloud without finite points)."""
    xyz = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    return np.asarray(_core.local_origin(xyz))


@dataclass(frozen=True)
class LocalFrame:
    """input frame (metres) = local frame + origin_m. The origin and the shift are the core's
    (``_core.local_frame_origin``, ``_core.to_local_frame``), which the ROS node calls too."""

    origin_m: np.ndarray

    @staticmethod
    def of(cloud: _core.Cloud, config: _core.Config) -> "LocalFrame":
        """The local frame of a cloud in its input units (config.io.unit_scale); none (origin 0)
        for a cloud wider than io.max_extent_m, which the surface stage refuses with a units hint."""
        return LocalFrame(np.asarray(_core.local_frame_origin(cloud.xyz, config.io)))

    @property
    def shifted(self) -> bool:
        return bool(np.any(self.origin_m != 0.0))

    def to_local(self, cloud: _core.Cloud, config: _core.Config) -> tuple[_core.Cloud, _core.Config]:
        """The cloud (in its input units) and a copy of the config, both moved into the local frame;
        ValueError naming the key when the robot base or the given axis lies far from the cloud."""
        if not self.shifted:
            return cloud, config
        return _core.to_local_frame(self.origin_m, cloud, config)

    def points_to_input(self, points_m: np.ndarray) -> np.ndarray:
        """(..., 3) local points [m] in the input's frame."""
        return np.asarray(points_m, dtype=np.float64) + self.origin_m

    def cloud_to_input(self, cloud: _core.Cloud) -> _core.Cloud:
        """A local cloud in the input's frame (normals unchanged)."""
        if not self.shifted:
            return cloud
        return _moved(cloud, self.origin_m)


def _moved(cloud: _core.Cloud, offset: np.ndarray) -> _core.Cloud:
    normals = np.asarray(cloud.normals) if cloud.has_normals() else None
    return _core.Cloud(np.ascontiguousarray(np.asarray(cloud.xyz) + offset), normals)
