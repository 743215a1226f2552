"""What the spot allows (shotcrete.bound): the placement matrix against the deposition model point by
point, a wall the family can lay exactly is reached, a one-cell spike is not (with an excess no
smaller than a bound worked out from the matrix alone), and the reported figures agree with the
dwells the programme returns."""
import numpy as np
import pytest

import shotcrete
from shotcrete import _core
from shotcrete.bound import band_programme, deposit_bound, path_family, placement_family, placement_matrix

SMALL_BAY = """
synth: {theta_min_rad: 1.2, theta_max_rad: 1.6, length_m: 0.8, points_per_cell: 6, pit_count: 3}
"""


@pytest.fixture(scope="module")
def bay():
    cfg = shotcrete.Config.from_yaml(SMALL_BAY)
    surface = _core.build_surface(shotcrete.synthetic_cloud(cfg), cfg)
    family = placement_family(surface, cfg)
    a_mm = (placement_matrix(surface, cfg, family) * 1000.0).tocsc()
    return cfg, surface, family, a_mm


def test_matrix_is_the_cells_mean_of_the_deposition_model(bay):
    cfg, surface, family, a_mm = bay
    grid = surface.grid
    model = _core.spot_model_from_config(cfg.deposition)
    keep = 1.0 - cfg.deposition.rebound_fraction
    xyz = np.asarray(surface.cloud.xyz)
    normals = np.asarray(surface.cloud.normals)
    valid = np.asarray(grid.valid).reshape(-1)
    # Cells by the grid's lattice arithmetic (theta rows from theta0, d columns from d0).
    cyl = np.array([grid.axis.to_cylindrical(p) for p in xyz])
    row = np.floor((cyl[:, 1] - grid.theta0_rad) / grid.dtheta_rad).astype(int)
    col = np.floor((cyl[:, 2] - grid.d0_m) / grid.cell_size_m).astype(int)
    inside = (row >= 0) & (row < grid.n_theta) & (col >= 0) & (col < grid.n_d)
    cell = np.where(inside, row * grid.n_d + col, -1)
    inside &= valid[np.maximum(cell, 0)] & np.asarray(surface.in_grid, bool)
    # The same points the grid counts per cell.
    assert np.array_equal(np.bincount(cell[inside], minlength=valid.size)[valid], np.asarray(grid.count).reshape(-1)[valid])
    valid_cells = np.flatnonzero(valid)
    rng = np.random.default_rng(4)
    # Placements of both kinds, in the bay and past its edges.
    picks = list(rng.choice(np.flatnonzero(family.kind == 0), 3, replace=False))
    picks += list(rng.choice(np.flatnonzero(family.kind == 1), 5, replace=False))
    checked = 0
    for j in picks:
        pose = _core.NozzlePose(family.positions_m[j], family.axes[j])
        rate = np.array([_core.point_rate_mps(model, pose, p, n) for p, n in zip(xyz, normals)]) * keep * 1000.0
        expect = np.array([rate[inside & (cell == c)].mean() for c in valid_cells])
        got = a_mm[:, j].toarray().ravel()
        assert np.allclose(got, expect, rtol=1e-9, atol=1e-9)
        checked += int((expect > 0).sum())
    assert checked > 50  # the placements reached cells: the comparison is not of zeros


def test_a_wall_the_family_can_lay_exactly_is_reached(bay):
    _, _, _, a_mm = bay
    rng = np.random.default_rng(7)
    w0 = np.where(rng.random(a_mm.shape[1]) < 0.05, rng.uniform(0.5, 3.0, a_mm.shape[1]), 0.0)
    td = a_mm @ w0
    r = band_programme(a_mm, td, band_mm=0.5)
    assert r.reached and r.cells_past_band == 0
    assert np.allclose(r.residual_mm, td - a_mm @ r.dwell)  # residual = TD - laid (positive: short)
    assert np.abs(r.residual_mm).max() <= 0.5 + 1e-6 and r.dwell.min() >= -1e-6
    # The nearest-flush pattern: no farther from flush than the pattern that laid it exactly.
    assert np.abs(r.residual_mm).sum() <= 1e-3 * len(td)


def test_a_one_cell_spike_is_not_reached_and_the_excess_is_consistent(bay):
    _, _, _, a_mm = bay
    a = a_mm.toarray()
    # The spike sits on the cell with the most neighbours' share around it (an interior cell).
    c = int(np.argmax(a.sum(axis=1)))
    td = np.zeros(a.shape[0])
    spike, band = 200.0, 5.0
    td[c] = spike
    r = band_programme(a_mm, td, band_mm=band)
    assert not r.reached and r.cells_past_band >= 1
    # The reported excess and count are those of the returned residual.
    over = np.maximum(np.abs(r.residual_mm) - band, 0.0)
    assert r.excess_mm == pytest.approx(over.sum(), abs=1e-4)
    assert r.least_excess_mm <= r.excess_mm + 1e-4 and r.excess_mm <= r.least_excess_mm + 1e-3 * len(td) + 1e-4
    # Programme 1 alone finds the same least excess, and its own solution has it.
    quick = band_programme(a_mm, td, band_mm=band, nearest_flush=False)
    assert quick.least_excess_mm == pytest.approx(r.least_excess_mm, abs=1e-3)
    assert quick.excess_mm == pytest.approx(quick.least_excess_mm, abs=1e-3)
    assert r.cells_past_band == int((over > 1e-6).sum())
    # Independent lower bound: every placement lays on c at most rho times what it lays on the other
    # cells it reaches, so D_c <= rho * sum(D_others) and the others cannot exceed band + their excess.
    others = np.ones(a.shape[0], bool)
    others[c] = False
    reach = a[c] > 0
    rho = (a[c, reach] / a[others][:, reach].sum(axis=0)).max()
    # With N the cells those placements reach besides c: D_c <= rho * sum_N D_n <= rho * (|N| band + E)
    # (E their excess), and the spike's own excess is at least spike - band - D_c; so the total excess
    # is at least spike - band - rho |N| band + (1 - rho) E >= spike - band - rho |N| band.
    n_near = int((a[others][:, reach].sum(axis=1) > 0).sum())
    floor = spike - band - rho * n_near * band
    assert rho < 1.0 and floor > 0.0, (rho, n_near)
    assert r.excess_mm >= floor - 1e-6


def test_deposit_bound_on_the_bay_reports_each_band(bay):
    cfg, surface, family, _ = bay
    b = deposit_bound(surface, cfg, bands_mm=[25.0, 10.0], family=family)
    assert [x.band_mm for x in b.bands] == [25.0, 10.0]
    assert b.cells == int(np.asarray(surface.grid.valid).sum()) and b.placements == len(family.kind)
    assert b.bands[0].reached and b.bands[1].reached  # this small bay is within reach of both
    # Nearest flush within +-25 is at least as near as within +-10 (the +-10 pattern is a candidate).
    assert np.abs(b.bands[0].residual_mm).sum() <= np.abs(b.bands[1].residual_mm).sum() + 1e-3 * b.cells
    for x in b.bands:
        assert x.cells_past_band == int((np.abs(x.residual_mm) > x.band_mm + 1e-6).sum())


class _Trajectory:
    """A hand-made trajectory: two spraying stretches along a line 1 m inside the bay, nozzle off between."""

    def __init__(self, surface, cfg):
        grid = surface.grid
        theta = grid.theta0_rad + 0.5 * grid.n_theta * grid.dtheta_rad
        r = cfg.profile.design_radius_m - cfg.planner.standoff_m
        d = np.linspace(grid.d0_m, grid.d0_m + grid.n_d * grid.cell_size_m, 161)
        pts = np.array([grid.axis.to_cartesian(r, theta, x) for x in d])
        out = np.array([grid.axis.to_cartesian(r + 1.0, theta, x) for x in d]) - pts
        self.positions = pts
        self.axes = out / np.linalg.norm(out, axis=1, keepdims=True)
        self.spraying = np.ones(len(d), bool)
        self.spraying[70:90] = False


def test_path_family_thins_the_spraying_samples_and_the_floor_holds(bay):
    cfg, surface, _, _ = bay
    tr = _Trajectory(surface, cfg)
    family, length = path_family(tr, step_m=0.02)
    pos = tr.positions
    sp = tr.spraying
    # Every placement is a spraying sample; consecutive ones in a stretch are >= 2 cm apart.
    idx = [int(np.flatnonzero((pos == p).all(axis=1))[0]) for p in family.positions_m]
    assert all(sp[i] for i in idx)
    for i, j in zip(idx[:-1], idx[1:]):
        if sp[i:j + 1].all():  # same stretch
            assert np.linalg.norm(pos[j] - pos[i]) >= 0.02 - 1e-12
    assert idx[0] == 0 and 90 in idx and len(idx) < sp.sum() / 3  # each stretch starts a placement; thinned
    # Each placement stands for the path from it to the next one kept, or to its stretch's end.
    seg = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    for k, i in enumerate(idx):
        e = i
        while e + 1 < len(pos) and sp[e + 1]:
            e += 1  # the last sample of i's stretch
        j = idx[k + 1] if k + 1 < len(idx) and idx[k + 1] <= e else e
        assert length[k] == pytest.approx(seg[i:j].sum(), abs=1e-12), k
    # The lengths add up to the spraying stretches' own lengths (independent: segment sums).
    sprayed = seg[sp[1:] & sp[:-1]].sum()
    assert length.sum() == pytest.approx(sprayed, rel=1e-12)
    a_mm = (placement_matrix(surface, cfg, family) * 1000.0).tocsc()
    valid = np.asarray(surface.grid.valid).reshape(-1)
    td = np.asarray(surface.grid.td_m).reshape(-1)[valid] * 1000.0
    floor = length / cfg.planner.max_speed_mps
    r = band_programme(a_mm, td, 25.0, min_dwell_s=floor)
    # The dwells respect the floor, placement by placement.
    assert np.all(r.dwell >= floor - 1e-7)
    # One line cannot level a bay 0.4 rad high: the cells farthest from it stay short.
    assert not r.reached and r.residual_mm.max() > 25.0 and r.least_excess_mm > 0
    with pytest.raises(ValueError, match="min_dwell_s"):
        band_programme(a_mm, td, 25.0, min_dwell_s=floor[:-1])
    tr.spraying[:] = False
    with pytest.raises(ValueError, match="never sprays"):
        path_family(tr)


def test_a_dwell_ceiling_holds_and_can_make_a_band_unreachable(bay):
    _, _, _, a_mm = bay
    rng = np.random.default_rng(11)
    w0 = np.where(rng.random(a_mm.shape[1]) < 0.05, rng.uniform(0.5, 3.0, a_mm.shape[1]), 0.0)
    td = a_mm @ w0
    assert band_programme(a_mm, td, band_mm=0.5).reached
    # With every dwell at most `cap`, the deepest cell gets at most cap * sum_j A_cj (closed form);
    # a cap at half of what it needs leaves it that short at least.
    c = int(np.argmax(td))
    row_sum = float(a_mm[c, :].sum())
    cap = 0.5 * (td[c] - 0.5) / row_sum
    capped = band_programme(a_mm, td, band_mm=0.5, max_dwell_s=np.full(a_mm.shape[1], cap))
    assert not capped.reached
    assert capped.residual_mm[c] >= td[c] - cap * row_sum - 1e-6
    assert np.all(capped.dwell <= cap + 1e-7)
    with pytest.raises(ValueError, match="max_dwell_s"):
        band_programme(a_mm, td, 0.5, min_dwell_s=np.full(a_mm.shape[1], 1.0), max_dwell_s=np.full(a_mm.shape[1], 0.5))
