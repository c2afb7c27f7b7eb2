"""Bounds on the turn-then-straight manoeuvre (eqs. 22-29), tabulated in the UAV's own frame.

The planner uses them only to bound transitions and decide which ones to solve exactly; every cost it
returns comes from the exact solver (:func:`covert_env.geometry.dynamics.solve_manoeuvre`).

Not the model's reach table (:class:`covert_env.geometry.reach.ReachTable`), although both tabulate the same solver in
the UAV's frame: that one answers *whether* a waypoint is reachable, exactly (it solves the points near the boundary
of the reachable set), for the env's action masks; this one gives, per (range, bearing) cell, a lower bound on the
path length (eq. 18's energy term) and an interval of the heading change, which the planner's selection of
transitions needs and the reach table does not hold. Its own reachability is coarser: a cell none of whose corners
is feasible gets an infinite bound and its transitions are never solved (the reachable set is taken to be no
thinner than a cell), where the reach table would solve the points near the boundary.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from covert_env.geometry.angles import TWO_PI, wrap_angle, wrap_heading
from covert_env.geometry.dynamics import solve_manoeuvre

__all__ = ["ManoeuvreBoundsTable", "manoeuvre_bounds_table"]


class ManoeuvreBoundsTable:
    """Bounds on the turn-then-straight manoeuvre (eqs. 22-29), tabulated in the UAV's own frame.

    A goal at range rho and bearing psi from the UAV (relative to its heading) needs a path of length
    ``ell(rho, psi) = v delta`` and ends with heading change ``dth(rho, psi)``; both are independent of
    where the UAV is and where it points. Vertices ``rho_i = i R / n_rho`` (R = V_max delta) and
    ``psi_j = 2 pi j / n_psi`` are solved exactly once. For the cell [rho_i, rho_i+1] x [psi_j, psi_j+1]:

    * ``lb`` = min of ell over the 4 x 4 vertices around the cell: a lower bound on ell anywhere in the
      cell (the vertex at rho = 0 counts as 0, its limit); inf if none of the cell's own 4 corners is
      feasible (the reachable set is not thinner than a cell);
    * ``dlo``, ``dhi`` = min / max of dth over the same vertices, widened by 1e-3 rad (and, next to the edge
      of the reachable set, where dth climbs steeply to the full turn W_max delta, widened to it): the
      interval the heading change lies in, which places a transition in a few heading bins before solving.

    Row ``n_rho + 1`` is a sentinel of infinite bounds for ranges beyond R. The planner uses the table only
    to decide which transitions to solve exactly; every cost it returns comes from the exact solver.
    """

    def __init__(self, v_max: float, w_max: float, delta: float, n_rho: int = 256, n_psi: int = 1024):
        if n_psi & (n_psi - 1):
            raise ValueError(f"ManoeuvreBoundsTable: n_psi must be a power of two, got {n_psi}")
        self.v_max, self.w_max, self.delta = float(v_max), float(w_max), float(delta)
        self.n_rho, self.n_psi = int(n_rho), int(n_psi)
        self.reach = self.v_max * self.delta
        self.rho_step = self.reach / self.n_rho
        self.psi_scale = self.n_psi / TWO_PI          # cells per radian
        rho = np.arange(self.n_rho + 1) * self.rho_step
        psi = np.arange(self.n_psi) / self.psi_scale
        goals = np.stack([rho[:, None] * np.cos(psi), rho[:, None] * np.sin(psi)], axis=-1)
        m = solve_manoeuvre(np.zeros(2), 0.0, goals, v_max=v_max, w_max=w_max, delta=delta)
        ok = np.asarray(m.feasible, bool)
        ell = np.where(ok, m.length, np.inf)
        ell[0] = 0.0                                    # rho -> 0: the path length tends to 0
        dth = np.where(ok, wrap_angle(np.where(ok, m.heading_after, 0.0)), np.nan)
        dth[0] = 0.0
        lb = self._block(ell, np.minimum, np.inf)
        # Reachability from the cell's own 4 corners only (the dilated block would call many unreachable
        # transitions at the edge of the reachable set possible and send them to the exact solver).
        corner = np.zeros_like(ok)
        for di in (0, 1):
            rows = np.vstack([ok, np.zeros((1, self.n_psi), bool)])[di:di + self.n_rho + 1]
            corner |= rows | np.roll(rows, -1, axis=1)
        corner[0] = True                              # rho -> 0 is reachable in the limit
        lb[~corner] = np.inf
        with np.errstate(invalid="ignore"):
            lo = self._block(np.where(np.isnan(dth), np.inf, dth), np.minimum, np.inf) - 1e-3
            hi = self._block(np.where(np.isnan(dth), -np.inf, dth), np.maximum, -np.inf) + 1e-3
        # Next to the edge of the reachable set the turn angle climbs steeply to W_max delta between a
        # feasible and an infeasible vertex, beyond the feasible vertices' range: widen those cells.
        edge = self._block(np.where(ok, 0.0, 1.0), np.maximum, 0.0) > 0
        turn = min(self.w_max * self.delta, math.pi)
        hi = np.where(edge & (hi > 0), np.maximum(hi, turn + 1e-3), hi)
        lo = np.where(edge & (lo < 0), np.minimum(lo, -turn - 1e-3), lo)
        bad = ~np.isfinite(lb)
        lo[bad], hi[bad] = 0.0, 0.0
        sentinel = np.full((1, self.n_psi), np.inf, np.float32)
        # Rows repeat psi three times: an index "range row * width + (bearing - heading) in cells, shifted
        # into [0, 3 n_psi)" then needs no modulo, only a subtraction and a truncation per transition.
        self.width = 3 * self.n_psi
        self.lb = np.tile(np.vstack([lb.astype(np.float32), sentinel]), 3).reshape(-1)
        self.dlo = np.tile(np.vstack([lo.astype(np.float32), np.zeros_like(sentinel)]), 3).reshape(-1)
        self.dhi = np.tile(np.vstack([hi.astype(np.float32), np.zeros_like(sentinel)]), 3).reshape(-1)
        for a in (self.lb, self.dlo, self.dhi):
            a.setflags(write=False)

    def _block(self, vert: np.ndarray, op, fill: float) -> np.ndarray:
        """(n_rho + 1, n_psi) cell values: ``op`` over vertices i-1..i+2, j-1..j+2 (periodic in psi)."""
        nr = self.n_rho + 1
        padded = np.full((nr + 3, self.n_psi), fill)
        padded[1:nr + 1] = vert
        out = np.full((nr, self.n_psi), fill)
        for di in range(4):
            rows = padded[di:di + nr]
            for dj in (-1, 0, 1, 2):
                out = op(out, np.roll(rows, -dj, axis=1))
        return out

    def base_index(self, rel_xy, rho=None, bearing=None) -> np.ndarray:
        """float32 ``row * width + bearing in cells + 2 n_psi`` of goals at ``rel_xy`` (goal - start).

        Subtracting a heading in cells (in [0, n_psi)) and truncating gives the cell index: the offset keeps
        the result in [n_psi, 3 n_psi) of the periodically repeated row. Ranges beyond the reach use the
        sentinel row. float32 is exact to ~0.1 cell here, inside the bounds' one-cell margin. ``rho`` and
        ``bearing`` may be passed instead of ``rel_xy`` when already known.
        """
        if rho is None:
            rel = np.asarray(rel_xy, float)
            rho, bearing = np.hypot(rel[..., 0], rel[..., 1]), np.arctan2(rel[..., 1], rel[..., 0])
        row = np.minimum(np.floor(rho / self.rho_step), self.n_rho + 1)
        cells = bearing * self.psi_scale + 2 * self.n_psi
        return (row * self.width + cells).astype(np.float32)

    def cell(self, base, theta) -> np.ndarray:
        """int32 cell indices from :meth:`base_index` values and headings (rad, any range)."""
        th = wrap_heading(np.asarray(theta, float)) * self.psi_scale
        return (np.asarray(base, np.float32) - th.astype(np.float32)).astype(np.int32)

    def lower_bound(self, rel_xy, theta) -> np.ndarray:
        """Lower bound on the manoeuvre length to goals at ``rel_xy`` (goal - start) from heading ``theta``."""
        return self.lb[self.cell(self.base_index(rel_xy), theta)]


@lru_cache(maxsize=8)
def manoeuvre_bounds_table(v_max: float, w_max: float, delta: float) -> ManoeuvreBoundsTable:
    """The :class:`ManoeuvreBoundsTable` for these limits, built once per process (~0.1 s)."""
    return ManoeuvreBoundsTable(v_max, w_max, delta)

