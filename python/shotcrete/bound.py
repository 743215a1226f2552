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
    reached: bool                 # every cell of the solution within +-band_mm (tol_mm, 1 micron)
    cells_past_band: int          # cells the solution leaves past the band (one solution's, not the fewest possible)
    excess_mm: float              # its total excess past the band [mm summed over cells]
    least_excess_mm: float        # programme 1's optimum: no dwell pattern in the bounds has less (if exact)
    least_excess_exact: bool      # False: HiGHS failed the unweighted check, least_excess_mm is an upper estimate
    dwell_s: float                # its total dwell (the spraying time it needs) [s]
    dwell: np.ndarray             # per placement [s]
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
    nozzle travel, and the path length [m] each stands for (along the path from it to the next one
    kept, the last one's to the end of its spraying stretch). Restricted to these, the programme asks what a
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
        # The segment (i-1, i) belongs to the placement that covers i-1; then i may start the next.
        if run_start is not None:
            length[-1] += float(np.linalg.norm(pos[i] - pos[i - 1]))
        if run_start is None or np.linalg.norm(pos[i] - pos[keep[-1]]) >= step_m:
            keep.append(i)
            length.append(0.0)
            run_start = i
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
    # The grid's own points only (surface.in_grid): its TD and the sprayed wall leave out points
    # that are not wall (face, floor, a duct) and those facing away.
    keep = (cell_of_point >= 0) & np.asarray(surface.in_grid, dtype=bool)
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


def band_programme(a_mm, td_mm: np.ndarray, band_mm: float, min_dwell_s: np.ndarray | None = None,
                   max_dwell_s: np.ndarray | None = None, nearest_flush: bool = True,
                   time_weight_mm_per_s: float = 1e-3, tol_mm: float = 1e-3) -> BandResult:
    """Two linear programmes over the dwells w (one per placement, [s]):

    1. least excess past +-band_mm: variables (w, u, o) >= 0 with u, o each cell's excess short of
       / past the band, TD - A w <= band + u, TD - A w >= -band - o; minimise sum(u + o);
    2. among the patterns with that excess (plus tol_mm per cell), the one nearest flush:
       minimise sum |TD - A w| (variables p, m >= 0 with p >= r, m >= -r), so that its dwell and
       RMS compare with a plan that fills to flush rather than to the band's short edge.

    ``min_dwell_s`` / ``max_dwell_s`` (per placement) bound the dwells: a nozzle that sprays all
    along a path at speeds within [v_lo, v_hi] dwells step / v_hi .. step / v_lo at each placement.
    ``nearest_flush=False`` skips programme 2 (several times slower on a whole bay): the result is
    then programme 1's solution, with its least excess exact but its dwell and residual one of many.
    ValueError if HiGHS does not solve either programme or a bound is malformed."""
    import time

    from scipy import sparse
    from scipy.optimize import linprog

    n_c, n_p = a_mm.shape
    lower = np.zeros(n_p)
    if min_dwell_s is not None:
        min_dwell_s = np.asarray(min_dwell_s, dtype=float)
        if min_dwell_s.shape != (n_p,) or not np.all(np.isfinite(min_dwell_s)) or (min_dwell_s < 0).any():
            raise ValueError(f"deposit bound: min_dwell_s needs {n_p} finite values >= 0")
        lower = min_dwell_s
    upper = np.full(n_p, np.inf)
    if max_dwell_s is not None:
        max_dwell_s = np.asarray(max_dwell_s, dtype=float)
        if max_dwell_s.shape != (n_p,) or np.isnan(max_dwell_s).any() or (max_dwell_s < lower).any():
            raise ValueError(f"deposit bound: max_dwell_s needs {n_p} values, none below min_dwell_s")
        upper = max_dwell_s
    eye = sparse.identity(n_c, format="csr")
    zero = sparse.csr_matrix((n_c, n_c))
    t0 = time.perf_counter()
    # Interior point: the dual simplex took more than 5 min on the default bay; IPM 13-85 s.
    a_ub = sparse.vstack([sparse.hstack([-a_mm, -eye, zero]), sparse.hstack([a_mm, zero, -eye])]).tocsc()
    b_ub = np.concatenate([band_mm - td_mm, band_mm + td_mm])
    # A small weight on the dwells regularises the interior point (without it HiGHS failed on a
    # +-10 mm bay); the excess of its solution is then an upper estimate of the least excess,
    # checked below by the unweighted programme when it is not zero.
    c = np.concatenate([np.full(n_p, time_weight_mm_per_s), np.ones(2 * n_c)])
    bounds = np.column_stack([np.concatenate([lower, np.zeros(2 * n_c)]), np.concatenate([upper, np.full(2 * n_c, np.inf)])])
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs-ipm")
    if res.status != 0 or res.x is None:
        raise ValueError(f"deposit bound: the programme for +-{band_mm:g} mm did not solve ({res.message})")
    least_excess = float(res.x[n_p:].sum())
    exact = least_excess <= tol_mm * n_c  # a pattern within the band: nothing to certify
    if not exact:
        res0 = linprog(np.concatenate([np.zeros(n_p), np.ones(2 * n_c)]), A_ub=a_ub, b_ub=b_ub, bounds=bounds,
                       method="highs-ipm")
        if res0.status == 0 and res0.x is not None:
            least_excess, exact = min(least_excess, float(res0.x[n_p:].sum())), True

    def result(w: np.ndarray) -> BandResult:
        residual = td_mm - a_mm @ w
        over = np.maximum(np.abs(residual) - band_mm, 0.0)
        past = over > tol_mm
        return BandResult(least_excess_exact=exact, band_mm=band_mm, reached=bool(not past.any()),
                          cells_past_band=int(past.sum()), excess_mm=float(over.sum()), least_excess_mm=least_excess,
                          dwell_s=float(w.sum()), dwell=w, residual_mm=residual, solve_s=time.perf_counter() - t0)

    if not nearest_flush:
        return result(res.x[:n_p])
    # 2: variables (w, u, o, p, m); rows: the band with its excess, the excess held, p >= r, m >= -r.
    ones = sparse.csr_matrix(np.concatenate([np.zeros(n_p), np.ones(2 * n_c), np.zeros(2 * n_c)])[None, :])
    a2 = sparse.vstack([
        sparse.hstack([-a_mm, -eye, zero, zero, zero]),
        sparse.hstack([a_mm, zero, -eye, zero, zero]),
        ones,
        sparse.hstack([-a_mm, zero, zero, -eye, zero]),
        sparse.hstack([a_mm, zero, zero, zero, -eye]),
    ]).tocsc()
    b2 = np.concatenate([band_mm - td_mm, band_mm + td_mm, [least_excess + tol_mm * n_c], -td_mm, td_mm])
    c2 = np.concatenate([np.zeros(n_p + 2 * n_c), np.ones(2 * n_c)])
    bounds2 = np.vstack([bounds, np.column_stack([np.zeros(2 * n_c), np.full(2 * n_c, np.inf)])])
    res2 = linprog(c2, A_ub=a2, b_ub=b2, bounds=bounds2, method="highs-ipm")
    if res2.status != 0 or res2.x is None:
        raise ValueError(f"deposit bound: the flush programme for +-{band_mm:g} mm did not solve ({res2.message})")
    return result(res2.x[:n_p])


def deposit_bound(surface, config, bands_mm=(25.0,), family: PlacementFamily | None = None,
                  nearest_flush: bool = True) -> DepositBound:
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
    bands = [band_programme(a_mm, td_mm, float(b), nearest_flush=nearest_flush) for b in bands_mm]
    return DepositBound(bands=bands, placements=a_mm.shape[1], cells=a_mm.shape[0], nonzeros=int(a_mm.nnz),
                        matrix_s=matrix_s)
