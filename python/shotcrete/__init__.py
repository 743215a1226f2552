"""shotcrete-planner: shotcrete spraying plans for an 8-DOF manipulator from a tunnel bay scan.

The numerical work lives in the C++ core (``shotcrete._core``); this package adds file formats
that surveyors deliver (LAS/LAZ, E57), configuration files, the CLI and the reports.

Quick start::

    import shotcrete
    config = shotcrete.load_config()            # config/default.yaml
    cloud = shotcrete.synthetic_cloud(config)    # or shotcrete.read_cloud("bay.pcd")
    surface = shotcrete.build_surface(cloud, config)
    surface.grid.td_m                            # (rows along the arc, cols along the axis), metres
"""
from ._core import *  # noqa: F401,F403  (the public C++ API)
from ._core import Cloud, Config, build_surface, make_synthetic_bay  # noqa: F401
from .config import default_config_path, load_config  # noqa: F401
from .io import read_cloud, write_cloud  # noqa: F401


def synthetic_cloud(config=None):
    """The seeded synthetic bay of ``config.synth`` sampled as a Cloud (metres)."""
    config = config or load_config()
    return make_synthetic_bay(config.synth).sample(config.grid.cell_size_m)


__version__ = "0.1.0"
