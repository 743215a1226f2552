"""shotcrete-planner: shotcrete spraying plans for an 8-DOF manipulator from a tunnel bay scan.

The numerical work lives in the C++ core (``shotcrete._core``); this package adds file formats
that surveyors deliver (LAS/LAZ, E57), configuration files, the CLI and the reports.

Quick start::

    import shotcrete
    config = shotcrete.load_config()            # config/default.yaml
    cloud = shotcrete.synthetic_cloud(config)    # or shotcrete.read_cloud("bay.pcd")
    surface = shotcrete.build_surface(cloud, config)
    surface.grid.td_m                            # (rows along the arc, cols along the axis), metres
    result = shotcrete.plan(cloud, config)       # rounds, passes, speeds, simulated residual
"""
from ._core import *  # noqa: F401,F403  (the public C++ API)
from ._core import Cloud, Config, build_surface, make_synthetic_bay, plan_bay  # noqa: F401
from .config import default_config_path, load_config  # noqa: F401
from .io import read_cloud, write_cloud  # noqa: F401


def plan(cloud, config=None, progress=None):
    """Plan and simulate a bay from a raw cloud (metres): surface stage, then rounds until flush.

    ``config.planner.mode`` picks the thesis' graded rounds ("graded") or the levelling planner
    that optimises the final residual and spray time ("optimal"). ``progress(stage, fraction)``
    is called between stages. Returns a ``Plan``: rounds -> regions (in spraying order) -> passes
    (waypoints in m, speeds in m/s), the simulated TD per cell (``td_after_m``), the sprayed cloud,
    spray time and the physical limit. Raises ValueError for unusable input.
    """
    config = config or load_config()
    surface = build_surface(cloud, config)
    return plan_bay(surface, config, progress)


def synthetic_cloud(config=None):
    """The seeded synthetic bay of ``config.synth`` sampled as a Cloud (metres)."""
    config = config or load_config()
    return make_synthetic_bay(config.synth).sample(config.grid.cell_size_m)


__version__ = "0.1.0"
