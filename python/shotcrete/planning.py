"""The planning of ``shotcrete.plan()``, ``shotcrete demo`` / ``shotcrete plan`` and the ROS node:
the bay planned for the arm (``_core.plan_for_arm``), or on request without it (``_core.plan_bay``)."""
from __future__ import annotations

from . import _core
from .robot import load_robot


def plan_surface(surface, config, progress=None, *, arm: bool = True, robot=None):
    """Plan and simulate a bay on a built surface (``build_surface``).

    ``arm=True`` (the default, as the CLI jobs and the ROS node plan): every pass within the speeds
    the arm's joints can follow, the plan timed, re-planned where the timed passes still break a
    joint limit. Returns an ``ArmPlan``: ``.plan`` (the ``Plan``), ``.trajectory`` (a
    ``TimedTrajectory``, or None with the reason in ``.timing_error``), ``.replans``, and the timing
    swarm's results. ``robot`` defaults to ``load_robot(config)``.

    ``arm=False``: the plan without the arm (no speed bounds from its joints, no trajectory).
    Returns the ``Plan`` of ``plan_bay``.
    """
    if not arm:
        if robot is not None:
            raise ValueError("robot is only used when planning for the arm (arm=True)")
        return _core.plan_bay(surface, config, progress)
    robot = robot if robot is not None else load_robot(config)
    return _core.plan_for_arm(surface, config, robot, progress)
