import numpy as np
import pytest

import shotcrete


@pytest.fixture(scope="session")
def small_config():
    """A quick bay: a 1 rad slice of the default wall, 0.6 m long."""
    cfg = shotcrete.load_config()
    cfg.synth.theta_min_rad = 1.0
    cfg.synth.theta_max_rad = 2.0
    cfg.synth.length_m = 0.6
    cfg.synth.points_per_cell = 8
    return cfg


@pytest.fixture(scope="session")
def small_cloud(small_config):
    return shotcrete.synthetic_cloud(small_config)


@pytest.fixture()
def run_cli():
    from typer.testing import CliRunner

    from shotcrete.cli import app

    runner = CliRunner()

    def run(*args):
        return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)

    return run


def cylinder_points(n=2000, radius=5.6, seed=0):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.5, 2.5, n)
    d = rng.uniform(0, 1.2, n)
    return np.column_stack([d, radius * np.cos(theta), radius * np.sin(theta)])
