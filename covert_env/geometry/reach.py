"""Which waypoints the turn-then-straight manoeuvre reaches in one slot, from a table in the UAV's frame.

Whether :func:`~covert_env.geometry.dynamics.solve_manoeuvre` finds a manoeuvre depends only on the waypoint's position
in the UAV's frame: ``a`` ahead and ``b = |lateral|`` to the side (the manoeuvre is mirror-symmetric). So the
feasible set is one region of the (a, b) half-plane per (V_max, W_max, delta), tabulated here once on a grid of
cells labelled *feasible*, *infeasible* or *near the boundary*. A query looks its cell up; only points in
boundary cells are solved exactly (by :func:`~covert_env.geometry.dynamics.manoeuvre_feasible`, ``solve_manoeuvre``'s
own test on the same inputs, without the speed), so the answer is exactly ``solve_manoeuvre(...).feasible``, at a
fraction of the root finding.

A cell is labelled feasible or infeasible only when every grid node of the 3 x 3 cells around it agrees (and, on
the coarse level, a finer check of the cell's centre and edge midpoints agrees too): the region's boundary is a few
smooth curves (the largest admissible radius, the turning circle, the slot length), so no feature of it fits
between the nodes of three cells. The table has two levels: coarse cells of V_max delta / 128 (0.39 m at the
paper's 50 m) everywhere, then cells 8 times finer whose nodes are solved only near the coarse boundary cells, so
about 1 % of the cells are boundary cells. Cells near the origin (where every boundary ray meets) and near the
circle ``|g - p| = V_max delta`` (where ``solve_manoeuvre`` cuts exactly) are always boundary cells; points
beyond the table are infeasible (farther than V_max delta). Tested against ``solve_manoeuvre`` on many random
poses; building a table takes about a second, once per process and set of limits.

It holds labels only, no cost: a planner that needs bounds on the manoeuvre's length or heading change tabulates
those itself (the DP planner's ``baselines.dp.table.ManoeuvreBoundsTable``).
"""

from __future__ import annotations

import functools

import numba
import numpy as np

from covert_env.geometry.dynamics import manoeuvre_feasible
from covert_env.geometry.zone import to_world

__all__ = ["ReachTable", "reach_table"]

INFEASIBLE, FEASIBLE, BOUNDARY = 0, 1, 2
_MIXED = 3               # a coarse cell whose fine cells' labels differ (ReachTable.coarse_labels)
_CELLS = 128            # coarse cells per V_max delta: 0.39 m at the paper's 50 m
_REFINE = 8             # fine cells per coarse cell, solved only in the coarse boundary band: 0.05 m


class ReachTable:
    """Labels of (a, b) cells in the UAV frame: ``INFEASIBLE``, ``FEASIBLE`` or ``BOUNDARY`` (solve exactly).

    Built in two levels: coarse cells over the whole table, then cells ``refine`` times finer whose nodes are
    solved only near the coarse boundary cells (elsewhere they take the coarse cell's label). Lookups use the
    fine table.

    Args:
        v_max, w_max, delta: the manoeuvre's limits (as ``solve_manoeuvre``).
        cells: coarse cells per ``v_max * delta``; refine: fine cells per coarse cell.
    """

    def __init__(self, v_max: float, w_max: float, delta: float, cells: int = _CELLS, refine: int = _REFINE):
        self.v_max, self.w_max, self.delta = float(v_max), float(w_max), float(delta)
        if not (isinstance(refine, int) and refine >= 1 and refine & (refine - 1) == 0):
            raise ValueError(f"ReachTable: refine must be a power of two (1, 2, 4, 8, ...), got {refine!r}")
        reach = self.v_max * self.delta
        pad = 2
        self.a0 = -(reach + pad * reach / cells)
        na, nb = 2 * (cells + pad), cells + pad                       # coarse cells along a and b
        h = reach / cells
        coarse = self._labels(self._feasible_nodes(h, na, nb), h, check=True)
        # Fine nodes: solved within one coarse cell of a coarse boundary cell, else the coarse label.
        hf = h / refine
        unsure = np.pad(coarse == BOUNDARY, 1)
        unsure = (unsure[:-2, 1:-1] | unsure[2:, 1:-1] | unsure[1:-1, :-2] | unsure[1:-1, 2:] | unsure[:-2, :-2]
                  | unsure[:-2, 2:] | unsure[2:, :-2] | unsure[2:, 2:] | unsure[1:-1, 1:-1])
        ci = np.minimum(np.arange(na * refine + 1) // refine, na - 1)[:, None]
        cj = np.minimum(np.arange(nb * refine + 1) // refine, nb - 1)[None, :]
        node = coarse[ci, cj] == FEASIBLE
        ii, jj = np.nonzero(unsure[ci, cj])
        node[ii, jj] = self._feasible(self.a0 + ii * hf, jj * hf)
        self.h = hf
        self.shape = (na * refine, nb * refine)
        self.labels = self._labels(node, hf, check=False)
        self._flat = self.labels.reshape(-1)
        # The lookup's first level: per coarse cell, the label all its fine cells share, else _MIXED (look the fine
        # cell up). Most lookups end in this small table, which stays in the cache; the labels are the fine table's.
        blocks = self.labels.reshape(na, refine, nb, refine)                      # self.shape = (na, nb) * refine
        same = (blocks.min(axis=(1, 3)) == blocks.max(axis=(1, 3)))
        self._shift = refine.bit_length() - 1
        self.coarse_labels = np.where(same, blocks[:, 0, :, 0], _MIXED).astype(np.int8)
        self._nodes_key: tuple | None = None
        self._nodes_arr = np.zeros((3, 0), np.float32)

    def _feasible(self, a, b) -> np.ndarray:
        goals = np.stack([a, b], axis=-1).reshape(-1, 2)
        ok = manoeuvre_feasible(np.zeros((len(goals), 2)), np.zeros(len(goals)), goals, v_max=self.v_max,
                                w_max=self.w_max, delta=self.delta)
        return ok.reshape(np.shape(a))

    def _feasible_nodes(self, h: float, na: int, nb: int) -> np.ndarray:
        return self._feasible(*np.meshgrid(self.a0 + np.arange(na + 1) * h, np.arange(nb + 1) * h, indexing="ij"))

    def _labels(self, node: np.ndarray, h: float, *, check: bool) -> np.ndarray:
        """Cell labels from the feasibility of the (na+1, nb+1) nodes at spacing h (module docstring)."""
        na, nb = node.shape[0] - 1, node.shape[1] - 1
        # A cell is certain when the 4 x 4 nodes of the 3 x 3 cells around it agree.
        lo = np.pad(node, 1, mode="edge").astype(np.int8)
        win = np.lib.stride_tricks.sliding_window_view(lo, (4, 4))                     # (na, nb, 4, 4)
        agree = (win.min(axis=(-1, -2)) == win.max(axis=(-1, -2)))[:na, :nb]
        labels = np.where(agree, node[:na, :nb].astype(np.int8), BOUNDARY)
        # The finer check: centres and edge midpoints of the certain cells.
        for da, db in ((0.5, 0.5), (0.5, 0.0), (0.0, 0.5)) if check else ():
            a, b = np.meshgrid(self.a0 + (np.arange(na) + da) * h, (np.arange(nb) + db) * h, indexing="ij")
            bad = agree & (self._feasible(a, b) != (labels == FEASIBLE))
            if bad.any():                                                              # never seen: be safe
                grow = np.pad(bad, 1)
                labels[(grow[:-2, 1:-1] | grow[2:, 1:-1] | grow[1:-1, :-2] | grow[1:-1, 2:] | bad)] = BOUNDARY
        # Exact cuts of solve_manoeuvre: |g - p| in (MIN_GOAL_DISTANCE, V_max delta].
        ca, cb = np.meshgrid(self.a0 + (np.arange(na) + 0.5) * h, (np.arange(nb) + 0.5) * h, indexing="ij")
        dist = np.hypot(ca, cb)
        reach = self.v_max * self.delta
        labels[(np.abs(dist - reach) <= 2 * h) | (dist <= 2 * h)] = BOUNDARY
        # The outer ring is infeasible (beyond V_max delta): clipped queries land there.
        labels[0], labels[-1], labels[:, -1] = INFEASIBLE, INFEASIBLE, INFEASIBLE
        return labels

    def _nodes(self, offsets: np.ndarray) -> np.ndarray:
        """(3, L) float32 ``[o_x, o_y, 1]`` of the lattice offsets, kept for the last lattice asked."""
        key = (offsets.shape, offsets.tobytes())
        if self._nodes_key != key:
            self._nodes_key = key
            self._nodes_arr = np.vstack([offsets.T, np.ones((1, len(offsets)))]).astype(np.float32)
        return self._nodes_arr

    def classify(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Labels (int8) of points ``a`` ahead, ``b >= 0`` to the side (any shape); beyond the table INFEASIBLE."""
        na, nb = self.shape
        ia = np.clip(((a - self.a0) * (1.0 / self.h)).astype(np.int64), 0, na - 1)
        ib = np.minimum((b * (1.0 / self.h)).astype(np.int64), nb - 1)
        return self._flat[ia * nb + ib]

    def reachable(self, xy: np.ndarray, theta: np.ndarray, q_xy: np.ndarray, phi: np.ndarray,
                  offsets: np.ndarray, exact: bool = True) -> np.ndarray:
        """(B, U, L) bool: ``solve_manoeuvre(xy[b, u], theta[b, u], goal[b, l], ...).feasible`` for poses ``xy``
        (B, U, 2), ``theta`` (B, U) and the goals ``to_world(offsets, q_xy[b], phi[b])`` (offsets (L, 2), targets
        q_xy (B, 2), phi (B,)): table lookups, then the exact solver on the points in boundary cells (their goals
        computed exactly as :func:`~covert_env.geometry.zone.to_world` does, the only goals ever built in float64).
        ``exact=False`` skips the solver: points in boundary cells count as unreachable (a subset, within a cell
        of the exact set).

        The lookup works in float32 table units (cells): with ``o`` a node's offset in the target frame, its
        position in the frame of a UAV at (p, theta) is ``(q - p) . e_theta + R(phi - theta) o``, one affine map of
        the offsets per UAV, so the lattice is shared by every copy and one compiled loop maps and looks up every
        (UAV, node) pair. Its rounding (well below a cell, also for a far UAV whose nodes all land beyond the
        table) is covered by the margin of a cell that certain cells keep."""
        # Per UAV: the target in the UAV's frame, in cells (a - a0) / h and lateral / h, and the rotation by
        # phi - theta scaled to cells (float64, then float32 for the product).
        dx, dy = q_xy[:, None, 0] - xy[..., 0], q_xy[:, None, 1] - xy[..., 1]
        c, s = np.cos(theta), np.sin(theta)
        rel = phi[:, None] - theta
        cr, sr = np.cos(rel) / self.h, np.sin(rel) / self.h
        coef = np.empty(theta.shape + (2, 3), np.float32)                                     # (B, U, 2, 3)
        coef[..., 0, 0], coef[..., 0, 1] = cr, -sr
        coef[..., 0, 2] = (c * dx + s * dy - self.a0) / self.h
        coef[..., 1, 0], coef[..., 1, 1] = sr, cr
        coef[..., 1, 2] = (c * dy - s * dx) / self.h
        nodes = self._nodes(offsets)                                                           # (3, L)
        lab = np.empty(theta.shape + (len(offsets),), np.int8)
        _lookup_labels(coef.reshape(-1, 2, 3), nodes, self.labels, self.coarse_labels, self._shift,
                       lab.reshape(-1, len(offsets)))
        out = lab == FEASIBLE
        if not exact:
            return out
        flat = np.flatnonzero(lab == BOUNDARY)
        if len(flat):
            bi, rest = np.divmod(flat, lab.shape[1] * lab.shape[2])
            ui, li = np.divmod(rest, lab.shape[2])
            goals = to_world(offsets[li][:, None], q_xy[bi], phi[bi])[:, 0]
            out[bi, ui, li] = manoeuvre_feasible(xy[bi, ui], theta[bi, ui], goals, v_max=self.v_max,
                                                 w_max=self.w_max, delta=self.delta, cos_sin=(c[bi, ui], s[bi, ui]))
        return out


@functools.lru_cache(maxsize=8)
def reach_table(v_max: float, w_max: float, delta: float) -> ReachTable:
    """The table for these limits, built once per process (about a second)."""
    return ReachTable(v_max, w_max, delta)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lookup_labels(coef, nodes, labels, coarse, shift, out):  # pragma: no cover
    """``out[r, l]``: the label of node l for UAV r, whose float32 map to table cells is ``coef[r]`` (2, 3) applied to
    ``nodes[:, l]`` = ``[o_x, o_y, 1]`` (:meth:`ReachTable.reachable`). Coordinates are clipped to the table (the
    lateral one taken as its absolute value first) and truncated to the cell. Float32 rounding may move a point near
    a cell's edge into the neighbouring cell: harmless, as a certain cell's 3 x 3 neighbourhood shares its label.
    The fine cell's label is read from ``coarse`` (its coarse cell's, ``2 ** shift`` fine cells a side) unless that
    is ``_MIXED``: the same label, from a table of a few tens of kB."""
    na, nb = labels.shape
    cnb = coarse.shape[1]
    flat, flat_coarse = labels.reshape(-1), coarse.reshape(-1)
    top_a, top_b = np.float32(na - 1), np.float32(nb - 1)
    zero = np.float32(0.0)
    xs, ys = nodes[0].copy(), nodes[1].copy()
    n = len(xs)
    coarse_at, fine_at = np.empty(n, np.int64), np.empty(n, np.int64)
    for r in range(coef.shape[0]):
        a0, a1, a2 = coef[r, 0, 0], coef[r, 0, 1], coef[r, 0, 2]
        b0, b1, b2 = coef[r, 1, 0], coef[r, 1, 1], coef[r, 1, 2]
        # Two passes: the cells of every node first (branch-free arithmetic the compiler vectorises), then the
        # table reads, whose branch would keep the first pass scalar.
        for j in range(n):
            x, y = xs[j], ys[j]
            ia = a0 * x + a1 * y + a2
            ib = abs(b0 * x + b1 * y + b2)
            ia = ia if ia > zero else zero                  # NaN -> 0: never an index outside the table
            ia = ia if ia < top_a else top_a
            ib = ib if ib < top_b else top_b                # NaN -> the last column
            i, k = np.int32(ia), np.int32(ib)
            coarse_at[j] = (i >> shift) * cnb + (k >> shift)
            fine_at[j] = i * nb + k
        row = out[r]
        for j in range(n):
            label = flat_coarse[coarse_at[j]]
            row[j] = label if label != _MIXED else flat[fine_at[j]]
