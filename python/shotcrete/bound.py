"""What any spray plan could reach on a bay: the spot model's own limit, as a linear programme.

Every plan sprays the wall as a sum of the nozzle's spot, each placement weighted by how long it
dwells there (``accumulate_dwells``). Over a family of placements (the nozzle at the standoff,
facing the wall, on a lattice over the bay and past its edges; ``placement_family``), the question
"can every cell end within +-band of flush?" is a linear programme in the dwells w >= 0:

    TD_c - band <= sum_j A_cj w_j <= TD_c + band   for every valid cell c,

with A_cj the layer placement j lays on cell c per second (the core's deposition model, rebound
included, averaged over the cell's points as the grid averages TD). ``band_programme`` solves it
with elastic excess variables (least total excess past the band, then least dwell), so it always
has a solution: zero excess means some dwell pattern reaches the band; a positive excess means no
pattern over the family does. Paths, speeds, ordering, the pump's spells and the arm's limits
only restrict which dwell patterns a plan can spray, so a plan whose poses lie in the family can
never beat this; where the programme reaches a band the planner does not, the planner's
constraints (not the spot's width) are what is left. Its dwell is the least spraying time any
such plan needs for that band.

Needs scipy (HiGHS); docs/architecture.md §5 ("What the spot allows").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core


@dataclass
class PlacementFamily:
    """Nozzle placements: positions [m] (K, 3) and unit spray axes (K, 3)."""

    positions_m: np.ndarray
    axes: np.ndarray
    kind: np.ndarray  # 0: along the cell's normal, 1: radial about the tunnel axis (past the bay's edges too), 2: a path's


@dataclass
class BandResult:
    """The least-excess dwells over the family for one band (see module doc)."""

    band_mm: float
    reached: bool                 # every cell within +-band_mm (excess below 1e-6 mm per cell)
    cells_past_band: int          # cells that optimum leaves past the band
    excess_mm: float              # its total excess past the band [mm summed over cells]
    dwell_s: float                # its total dwell (the spraying time it needs) [s]
    residual_mm: np.ndarray       # per valid cell (grid order of the valid cells), TD - layer [mm]
    solve_s: float


@dataclass
class DepositBound:
    """``band_programme`` over one family for each band asked."""

    bands: list                   # BandResult per band asked
    placements: int
    cells: int
    nonzeros: int
    matrix_s: float


def placement_family(surface, config, extend_cells: int | None = None) -> PlacementFamily:
    """Placements at ``planner.standoff_m``: from each valid cell's mean point along its mean normal
    (axis against it), and radially about the tunnel axis over the grid's lattice extended by
    ``extend_cells`` (default: the spot's radius in cells, rounded up) on every side, at the nearest
    valid cell's radius. Radial placements past the bay's edges are what passes overrunning the
    bay's ends do."""
    grid = surface.grid
    standoff = float(config.planner.standoff_m)
    valid = np.asarray(grid.valid).reshape(-1)
    mean_xyz = np.asarray(grid.mean_xyz)
    mean_n = np.asarray(grid.mean_normal)
    if extend_cells is None:
        extend_cells = int(np.ceil(config.deposition.spot_radius_m / grid.cell_size_m))
    pos = [mean_xyz[valid] + standoff * mean_n[valid]]
    ax = [-mean_n[valid]]
    kind = [np.zeros(int(valid.sum()), dtype=int)]

    n_t, n_d = grid.n_theta, grid.n_d
    axis = grid.axis
    radius = np.full(n_t * n_d, np.nan)
    for c in np.flatnonzero(valid):
        radius[c] = axis.to_cylindrical(mean_xyz[c])[0]
    rows, cols = np.divmod(np.flatnonzero(valid), n_d)
    rp, ap = [], []
    for r in range(-extend_cells, n_t + extend_cells):
        for c in range(-extend_cells, n_d + extend_cells):
            # the radius of the nearest valid cell (lattice distance)
            k = np.argmin((rows - r) ** 2 + (cols - c) ** 2)
            r_wall = radius[rows[k] * n_d + cols[k]]
            theta = grid.theta0_rad + (r + 0.5) * grid.dtheta_rad
            d = grid.d0_m + (c + 0.5) * grid.cell_size_m
            on_wall = np.asarray(axis.to_cartesian(r_wall, theta, d))
            inward = np.asarray(axis.to_cartesian(r_wall - standoff, theta, d))
            a = on_wall - inward
            rp.append(inward)
            ap.append(a / np.linalg.norm(a))
    pos.append(np.asarray(rp))
    ax.append(np.asarray(ap))
    kind.append(np.ones(len(rp), dtype=int))
    return PlacementFamily(np.vstack(pos), np.vstack(ax), np.concatenate(kind))


def path_family(trajectory, step_m: float = 0.02) -> tuple[PlacementFamily, np.ndarray]:
    """The placements of a timed trajectory's spraying samples, thinned to one per ``step_m`` of
    nozzle travel, and the path length [m] each stands for (the distance to the next one kept, the
    last one's to the end of its spraying stretch). Restricted to these, the programme asks what a
    plan along this plan's own paths could reach with any speeds and any pump."""
    pos = np.asarray(trajectory.positions)
    axes = np.asarray(trajectory.axes)
    spraying = np.asarray(trajectory.spraying, dtype=bool)
    if not spraying.any():
        raise ValueError("deposit bound: the trajectory never sprays")
    keep, length = [], []
    run_start = None
    for i in range(len(pos)):
        if not spraying[i]:
            run_start = None
            continue
        if run_start is None or np.linalg.norm(pos[i] - pos[keep[-1]]) >= step_m:
            keep.append(i)
            length.append(0.0)
            run_start = i
        if i > 0 and spraying[i - 1]:
            length[-1] += float(np.linalg.norm(pos[i] - pos[i - 1]))
    keep = np.asarray(keep)
    family = PlacementFamily(pos[keep], axes[keep], np.full(len(keep), 2))
    return family, np.asarray(length)


def placement_matrix(surface, config, family: PlacementFamily):
    """Sparse (valid cells x placements) matrix: layer [m] per second of dwell, the cell's mean over
    its points of the core's deposit (``accumulate_dwells``, rebound included)."""
    from scipy import sparse

    grid = surface.grid
    model = _core.spot_model_from_config(config.deposition)
    rebound = float(config.deposition.rebound_fraction)
    index = surface.index if hasattr(surface, "index") else _core.SurfaceIndex(surface.cloud)
    cloud = index.cloud
    xyz = np.asarray(cloud.xyz)
    axis = grid.axis
    valid = np.asarray(grid.valid).reshape(-1)
    cell_of_point = np.full(len(xyz), -1)
    for i, p in enumerate(xyz):
        r, theta, d = axis.to_cylindrical(p)
        cell_of_point[i] = grid.cell_at(theta, d)
    keep = (cell_of_point >= 0)
    keep[keep] = valid[cell_of_point[keep]]
    col_of_cell = np.full(len(valid), -1)
    col_of_cell[valid] = np.arange(int(valid.sum()))
    row_idx = np.where(keep, col_of_cell[np.maximum(cell_of_point, 0)], -1)
    counts = np.bincount(row_idx[keep], minlength=int(valid.sum())).astype(float)
    poses = _core.nozzle_poses(family.positions_m, family.axes)
    rows, cols, vals = [], [], []
    for j, pose in enumerate(poses):
        t = _core.accumulate_dwells(model, index, [pose], [1.0], rebound)
        hit = np.flatnonzero((t > 0) & keep)
        if not len(hit):
            continue
        per_cell = np.bincount(row_idx[hit], weights=t[hit], minlength=len(counts))
        nz = np.flatnonzero(per_cell)
        rows.append(nz)
        cols.append(np.full(len(nz), j))
        vals.append(per_cell[nz] / counts[nz])
    rows = np.concatenate(rows) if rows else np.zeros(0, int)
    cols = np.concatenate(cols) if cols else np.zeros(0, int)
    vals = np.concatenate(vals) if vals else np.zeros(0)
    return sparse.csr_matrix((vals, (rows, cols)), shape=(len(counts), len(poses)))


def band_programme(a_mm, td_mm: np.ndarray, band_mm: float, time_weight_mm_per_s: float = 1e-3,
                   min_dwell_s: np.ndarray | None = None, max_dwell_s: np.ndarray | None = None) -> BandResult:
    """Least excess past +-band_mm, then least dwell: variables (w, u, o) >= 0 with u, o the excess
    above +band / below -band per cell; TD - A w <= band + u, TD - A w >= -band - o; minimise
    sum(u + o) + time_weight * sum(w). The time weight is small enough that excess wins (a second
    of dwell lays at most a few mm on a cell) and picks the shortest dwells among the patterns
    with the least excess. ``min_dwell_s`` (per placement) floors the dwells: a nozzle that sprays
    all along a path no faster than v dwells at least step / v at each of its placements.
    ValueError if HiGHS does not solve it."""
    import time

    from scipy import sparse
    from scipy.optimize import linprog

    n_c, n_p = a_mm.shape
    eye = sparse.identity(n_c, format="csr")
    zero = sparse.csr_matrix((n_c, n_c))
    a_ub = sparse.vstack([sparse.hstack([-a_mm, -eye, zero]), sparse.hstack([a_mm, zero, -eye])]).tocsc()
    b_ub = np.concatenate([band_mm - td_mm, band_mm + td_mm])
    c = np.concatenate([np.full(n_p, time_weight_mm_per_s), np.ones(2 * n_c)])
    t0 = time.perf_counter()
    # Interior point: the dual simplex took more than 5 min on the default bay; IPM 35-85 s.
    lower = np.zeros(n_p + 2 * n_c)
    if min_dwell_s is not None:
        min_dwell_s = np.asarray(min_dwell_s, dtype=float)
        if min_dwell_s.shape != (n_p,) or not np.all(np.isfinite(min_dwell_s)) or (min_dwell_s < 0).any():
            raise ValueError(f"deposit bound: min_dwell_s needs {n_p} finite values >= 0")
        lower[:n_p] = min_dwell_s
    upper = np.full(n_p + 2 * n_c, np.inf)
    if max_dwell_s is not None:
        max_dwell_s = np.asarray(max_dwell_s, dtype=float)
        if max_dwell_s.shape != (n_p,) or np.isnan(max_dwell_s).any() or (max_dwell_s < lower[:n_p]).any():
            raise ValueError(f"deposit bound: max_dwell_s needs {n_p} values, none below min_dwell_s")
        upper[:n_p] = max_dwell_s
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=np.column_stack([lower, upper]),
                  method="highs-ipm")
    if res.status != 0 or res.x is None:
        raise ValueError(f"deposit bound: the programme for +-{band_mm:g} mm did not solve ({res.message})")
    w = res.x[:n_p]
    excess = res.x[n_p:]
    residual = td_mm - a_mm @ w
    past = np.abs(residual) > band_mm + 1e-6
    return BandResult(band_mm=band_mm, reached=bool(excess.sum() < 1e-6 * n_c), cells_past_band=int(past.sum()),
                      excess_mm=float(excess.sum()), dwell_s=float(w.sum()), residual_mm=residual,
                      solve_s=time.perf_counter() - t0)


def deposit_bound(surface, config, bands_mm=(25.0,), family: PlacementFamily | None = None) -> DepositBound:
    """``band_programme`` for each band over ``family`` (default ``placement_family``) on the
    surface's valid cells. ValueError if the grid has no valid cell or a programme does not solve."""
    import time

    grid = surface.grid
    valid = np.asarray(grid.valid).reshape(-1)
    if not valid.any():
        raise ValueError("deposit bound: the grid has no valid cell")
    td_mm = np.asarray(grid.td_m).reshape(-1)[valid] * 1000.0
    family = family or placement_family(surface, config)
    t0 = time.perf_counter()
    a_mm = (placement_matrix(surface, config, family) * 1000.0).tocsc()  # mm per second of dwell
    matrix_s = time.perf_counter() - t0
    bands = [band_programme(a_mm, td_mm, float(b)) for b in bands_mm]
    return DepositBound(bands=bands, placements=a_mm.shape[1], cells=a_mm.shape[0], nonzeros=int(a_mm.nnz),
                        matrix_s=matrix_s)
