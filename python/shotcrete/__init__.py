"""shotcrete-planner: shotcrete spraying plans for an 8-DOF manipulator from a tunnel bay scan.

The numerical work lives in the C++ core (``shotcrete._core``); this package adds file formats
that surveyors deliver (LAS/LAZ, E57), configuration files, the CLI and the reports.

Quick start::

    import shotcrete
    config = shotcrete.load_config()            # config/default.yaml
    cloud = shotcrete.synthetic_cloud(config)    # or shotcrete.read_cloud("bay.pcd")
    surface = shotcrete.build_surface(cloud, config)
    surface.grid.td_m                            # (rows along the arc, cols along the axis), metres
    job = shotcrete.plan(cloud, config)          # planned for the arm, as `shotcrete plan` does
    job.plan.rounds, job.trajectory              # rounds, passes, speeds, residual; timed joints
    shotcrete.plan(cloud, config, arm=False)     # the Plan alone, without the arm's speed bounds
"""
from ._core import *  # noqa: F401,F403  (the public C++ API)
from ._core import Cloud, Config, build_surface, make_synthetic_bay, plan_bay  # noqa: F401
from .config import default_config_path, load_config  # noqa: F401
from .io import read_cloud, write_cloud  # noqa: F401
from .planning import plan_surface
from .robot import load_robot  # noqa: F401


def plan(cloud, config=None, progress=None, *, arm=True, robot=None):
    """Plan and simulate a bay from a raw cloud (metres): the surface stage, then the planning of
    ``shotcrete plan`` and ``shotcrete demo`` (``planning.plan_surface``).

    ``config.planner.mode`` picks the thesis' graded rounds ("graded") or the levelling planner
    that optimises the final residual and spray time ("optimal"). ``progress(stage, fraction)``
    is called between stages.

    ``arm=True`` (default): planned for the arm (``robot``, default ``load_robot(config)``), every
    pass within the speeds its joints can follow, timed, re-planned where needed. Returns an
    ``ArmPlan``: ``.plan`` and ``.trajectory`` (None with ``.timing_error`` when the timing failed).
    ``arm=False``: planned without the arm. Returns the ``Plan`` alone.

    A ``Plan`` holds rounds -> regions (in spraying order) -> passes (waypoints in m, speeds in
    m/s), the simulated TD per cell (``td_after_m``), the sprayed cloud, spray time and the
    physical limit. ``summarise_job(surface, job, robot, config)`` gives report.json's figures.
    Raises ValueError for unusable input.
    """
    config = config or load_config()
    surface = build_surface(cloud, config)
    return plan_surface(surface, config, progress, arm=arm, robot=robot)


def synthetic_cloud(config=None):
    """The seeded synthetic bay of ``config.synth`` sampled as a Cloud (metres)."""
    config = config or load_config()
    return make_synthetic_bay(config.synth).sample(config.grid.cell_size_m)


__version__ = "0.1.0"
