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

ORIGIN_STEP_M = 100.0
FAR_M = 1000.0  # a config point farther than this from a shifted cloud was not given in its frame


def local_origin(xyz_m: np.ndarray) -> np.ndarray:
    """The bounding box centre of ``xyz_m`` (N, 3) in metres, rounded to whole ORIGIN_STEP_M
    (non-finite points ignored; (0, 0, 0) for a cloud without finite points)."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    finite = xyz[np.isfinite(xyz).all(axis=1)] if len(xyz) else xyz
    if len(finite) == 0:
        return np.zeros(3)
    centre = (finite.min(axis=0) + finite.max(axis=0)) / 2.0
    return np.round(centre / ORIGIN_STEP_M) * ORIGIN_STEP_M + 0.0  # + 0.0: no -0.0 in reports


@dataclass(frozen=True)
class LocalFrame:
    """input frame (metres) = local frame + origin_m."""

    origin_m: np.ndarray

    @staticmethod
    def of(cloud: _core.Cloud, config: _core.Config) -> "LocalFrame":
        """The local frame of a cloud in its input units (config.io.unit_scale); none (origin 0)
        for a cloud wider than io.max_extent_m, which the surface stage refuses with a units hint."""
        xyz_m = np.asarray(cloud.xyz) * config.io.unit_scale
        finite = xyz_m[np.isfinite(xyz_m).all(axis=1)] if len(xyz_m) else xyz_m
        if len(finite) and np.ptp(finite, axis=0).max() > config.io.max_extent_m:
            return LocalFrame(np.zeros(3))
        return LocalFrame(local_origin(xyz_m))

    @property
    def shifted(self) -> bool:
        return bool(np.any(self.origin_m != 0.0))

    def to_local(self, cloud: _core.Cloud, config: _core.Config) -> tuple[_core.Cloud, _core.Config]:
        """The cloud (in its input units) and a copy of the config, both moved into the local frame."""
        if not self.shifted:
            return cloud, config
        self._check_config_near(config)
        local = _moved(cloud, -self.origin_m / config.io.unit_scale)
        cfg = config.copy()
        cfg.profile.axis_origin_m = np.asarray(config.profile.axis_origin_m) - self.origin_m
        cfg.preprocess.crop_min_m = np.asarray(config.preprocess.crop_min_m) - self.origin_m
        cfg.preprocess.crop_max_m = np.asarray(config.preprocess.crop_max_m) - self.origin_m
        cfg.robot.base_position_m = np.asarray(config.robot.base_position_m) - self.origin_m
        return local, cfg

    def _check_config_near(self, config: _core.Config) -> None:
        """ValueError when the robot base, or the given axis, is far from a cloud in survey coordinates."""
        where = ", ".join(f"{v:,.0f}" for v in self.origin_m)
        base = np.asarray(config.robot.base_position_m, dtype=float)
        axis_o = np.asarray(config.profile.axis_origin_m, dtype=float)
        axis_d = np.asarray(config.profile.axis_direction, dtype=float)
        axis_d = axis_d / np.linalg.norm(axis_d)
        rel = self.origin_m - axis_o
        checks = [("robot.base_position_m", np.linalg.norm(base - self.origin_m))]
        if not config.profile.estimate_axis:
            checks.append(("profile.axis_origin_m", np.linalg.norm(rel - rel.dot(axis_d) * axis_d)))
        elif not config.profile.estimate_axis_origin:  # a surveyed origin kept, the direction fitted
            checks.append(("profile.axis_origin_m", np.linalg.norm(rel)))
        for key, dist in checks:
            if dist > FAR_M:
                raise ValueError(f"the cloud lies in survey coordinates around ({where}) m but {key} is "
                                 f"{dist / 1000:,.1f} km from it: give {key} in the cloud's frame "
                                 "(docs/architecture.md §3, survey coordinates)")

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
