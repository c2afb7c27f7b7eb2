"""The forward recursion (eqs. 19-21) over the stages, for a batch of UAVs at once.

``J_0(b) = c_sb`` from each UAV's start s (eq. 19), ``J_j(b) = min_a (c_ab + J_{j-1}(a))`` (eq. 20), and a
virtual final state f with ``c_af = 0`` (eq. 21), so the optimum is ``min_a J_{N-1}(a)`` and
:func:`backtrack` follows the parents from there. A state is a node (``bins = 1``, the paper's
position-only states with the heading inherited from the best arrival) or a (node, heading bin) pair.
Transitions are bounded through the manoeuvre table and solved exactly only where they can matter
(:mod:`baselines.dp.selection`).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from baselines.dp.lattice import StageCache
from baselines.dp.path_checks import PathChecker
from baselines.dp.selection import BOUND_TOL, FIRST_BAND, nonzero_indices, select_per_bin, select_per_node
from baselines.dp.states import Layer, Problem, SolveCounts
from baselines.dp.table import ManoeuvreBoundsTable
from baselines.dp.transitions import SolvedTransitions, solve_transitions
from covert_env.geometry.ties import first_argmin
from covert_env.world.config import Config

__all__ = ["ForwardRecursion", "backtrack"]

#: Under negotiation constraints, best-first rounds (1 + 2 transitions) before an unsolved node is given up.
OPEN_ROUNDS_CONSTRAINED = 2
#: Entries per chunk of the binned variant's dense bound (~16 MB of float32).
CHUNK = 1 << 22


def _bound_threads() -> int:
    """Threads for the dense bound: ``COVERT_DP_THREADS`` (default 1: the caller's thread only)."""
    raw = os.environ.get("COVERT_DP_THREADS", "1")
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if not 1 <= n <= 64:
        raise ValueError(f"COVERT_DP_THREADS must be an integer in [1, 64], got {raw!r}")
    return n


#: Threads that compute the inherited variant's dense bound (read once, from ``COVERT_DP_THREADS``). A
#: team replan spends much of its time there, in compiled passes that release the GIL, so
#: 2 threads can use both cores of an idle 2-core machine for it; on a busy machine they only add switching
#: (docs/model.md), hence the default of 1.
BOUND_THREADS = _bound_threads()
_POOL: list = []


def _map(f, tasks) -> list:
    """``[f(t) for t in tasks]``, on ``BOUND_THREADS`` threads (one pool per process, made on first use)."""
    if BOUND_THREADS == 1 or len(tasks) == 1:
        return [f(t) for t in tasks]
    if not _POOL:
        _POOL.append(ThreadPoolExecutor(BOUND_THREADS, thread_name_prefix="dp-bounds"))
    return list(_POOL[0].map(f, tasks))


# A forked child has the pool object but not its threads: it makes its own on first use.
if hasattr(os, "register_at_fork"):                 # POSIX only; elsewhere processes are spawned
    os.register_at_fork(after_in_child=_POOL.clear)


class ForwardRecursion:
    """Eqs. 19-20 over a :class:`Problem`; bounds from the manoeuvre table, exact costs where they matter."""

    def __init__(self, config: Config, lattice: np.ndarray, table: ManoeuvreBoundsTable, cache: StageCache,
                 paths: PathChecker):
        self.config, self.lattice, self.table, self.cache, self.paths = config, lattice, table, cache, paths

    def run(self, prob: Problem, counts: SolveCounts, *, bins: int = 1, upper_bound=None, cost_to_go=None,
            prefix=None) -> list[Layer]:
        """The non-empty layers of the whole batch.

        ``bins``: heading bins per node (1: the paper's inherited heading). ``upper_bound`` (U,) and
        ``cost_to_go`` (per stage, from :meth:`cost_to_go_bounds`), given together: prune states and transitions
        that cannot complete into anything cheaper (None: no pruning). ``prefix``: already computed first layers
        (incremental replanning); the recursion continues after them.
        """
        n = len(prob.stages)
        if prefix:
            layers, j0 = list(prefix[:-1]), len(prefix) - 1
            layer = prefix[-1]
        else:
            layers, j0 = [], 0
            layer = self.first_layer(prob, counts)
            if cost_to_go is not None and layer.n:
                layer = layer.take(layer.J + cost_to_go[0][layer.node] <= upper_bound[layer.uav] + BOUND_TOL)
        for j in range(j0, n):
            if layer.n == 0:
                break
            layers.append(layer)
            if j + 1 < n:
                layer = self.advance(prob, layer, j + 1, counts, bins=bins, upper_bound=upper_bound,
                                     cost_to_go_j=None if cost_to_go is None else cost_to_go[j + 1])
        return layers

    def cost_to_go_bounds(self, stages, penalties) -> list[np.ndarray]:
        """H[j](a) <= cost of any completion from node a at stage j (heading-free: c >= chord + disguise)."""
        n = len(stages)
        H = [np.zeros(len(self.lattice), np.float32)]
        for j in range(n - 2, -1, -1):
            pair = self.cache.pair(stages[j], stages[j + 1])
            nxt = (penalties[j + 1].min(axis=0) + H[0]).astype(np.float32)
            H.insert(0, (pair.heading_free_bound + nxt[None, :]).min(axis=1))
        return H

    def first_layer(self, prob: Problem, counts: SolveCounts) -> Layer:
        """Eq. 19: each UAV's single start state s to every allowed node of stage 1, all solved exactly."""
        pen = np.broadcast_to(prob.penalties[0], (len(prob.start), len(self.lattice)))
        uu, cols = np.nonzero(np.isfinite(pen))
        if cols.size == 0:
            return Layer.empty()
        m, g, extra = solve_transitions(self.config, self.paths, prob, 0, start_xy=prob.start[uu],
                                        theta=prob.theta[uu], uav=uu, alpha_from=prob.alpha0[uu],
                                        d_from=prob.d0[uu], nodes=cols, counts=counts)
        J = g + pen[uu, cols] + extra
        k = np.isfinite(J)
        return Layer(uav=uu[k], node=cols[k], theta=np.asarray(m.heading_after)[k], J=J[k],
                     parent=np.full(int(k.sum()), -1), v=np.asarray(m.v)[k], g=g[k])

    def advance(self, prob: Problem, layer: Layer, j: int, counts: SolveCounts, *, bins: int, upper_bound,
                cost_to_go_j) -> Layer:
        """Eq. 20 from ``layer`` (stage j-1, 0-based) to stage j, exact on the transitions that matter."""
        pair = self.cache.pair(prob.stages[j - 1], prob.stages[j])
        solved = SolvedTransitions(self.config, self.paths, len(self.lattice), prob, layer, j, counts)
        pen = prob.penalties[j].astype(np.float32)
        if bins == 1:
            lb, rowmap, colmin, first = self._node_bounds(pair, pen, layer, upper_bound, cost_to_go_j, counts)
            select_per_node(lb, rowmap, colmin, first, solved,
                            OPEN_ROUNDS_CONSTRAINED if prob.avoid is not None else None)
        else:
            rows, nodes, bounds, cells = self._state_bounds(pair, pen, layer, upper_bound, cost_to_go_j, counts)
            select_per_bin(self.table, len(self.lattice), rows, nodes, bounds, cells, layer, bins, solved,
                           prob.avoid is not None)
        return solved.winners(bins)

    def _node_bounds(self, pair, pen, layer: Layer, upper_bound, cost_to_go_j, counts: SolveCounts):
        """One state per node: the dense bound LB(a, b) = J(a) + disguise(a, b) + table bound + pen(b), float32.

        Returns ``(lb, rowmap, colmin, first)``: (blocks, L, L) bounds per UAV present, indexed [block, target
        b, source a] (selection scans per target node, so a target's bounds are one contiguous row); the layer
        row of each (block, a); and round 0 of :func:`select_per_node` (:func:`first_round`), found while the
        bounds are in cache: one compiled pass per target (:func:`_bound_rows`). With ``BOUND_THREADS`` > 1 the
        targets are split between threads (the pass releases the GIL); the result does not depend on the split.
        """
        tab = self.table
        # Lay every UAV's states out on the full node grid (absent rows have J = inf), so the cached (L, L)
        # pair arrays broadcast instead of being gathered row by row.
        blocks = layer.blocks()
        L = len(self.lattice)
        nb = len(blocks)
        cost_grid = np.full((nb, L), np.inf, np.float32)
        heading_cells = np.zeros((nb, L), np.float32)
        rowmap = np.full((nb, L), -1, np.int64)
        for b, (_, s, e) in enumerate(blocks):
            nd = layer.node[s:e]
            cost_grid[b, nd] = layer.J[s:e]
            heading_cells[b, nd] = layer.theta[s:e] * tab.psi_scale
            rowmap[b, nd] = np.arange(s, e)
        base, disguise = pair.by_target()
        uav = np.array([u for u, _, _ in blocks])
        shared = pair.disguise_plus(pen[0], by_target=True) if len(pen) == 1 else None
        lb = np.empty((nb, L, L), np.float32)
        colmin = np.empty((nb, L), np.float32)
        thr = None if cost_to_go_j is None else (upper_bound[uav] + BOUND_TOL).astype(np.float32)
        no_shared = np.zeros((0, 0), np.float32)
        ctg = np.zeros(0) if cost_to_go_j is None else np.ascontiguousarray(cost_to_go_j)

        def rows(b, t0, t1):
            """Bounds into targets t0..t1 of block b, with their round-0 candidates (selection.first_round), in one
            compiled pass per target (the gather from the 3 MB table is the costly part)."""
            n = (t1 - t0) * L
            cand_t, cand_s = np.empty(n, np.int64), np.empty(n, np.int64)
            k = _bound_rows(base, heading_cells[b], tab.lb, disguise, pen[uav[b] if shared is None else 0],
                            no_shared if shared is None else shared, shared is not None, cost_grid[b], ctg,
                            thr is not None, np.float32(0.0 if thr is None else thr[b]), t0, t1, lb[b], colmin[b],
                            cand_t, cand_s)
            if k < 0:
                raise IndexError(f"the manoeuvre table's bound: a cell index outside the table ({len(tab.lb)} cells)")
            return [(np.full(k, b), cand_t[:k], cand_s[:k])]

        # Every block's targets in BOUND_THREADS contiguous ranges; the results are joined in (block, target)
        # order whatever thread computed them, so they are those of the serial loop.
        parts = [(b, t0, min(t0 + -(-L // BOUND_THREADS), L)) for b in range(nb)
                 for t0 in range(0, L, -(-L // BOUND_THREADS))]
        found = _map(lambda task: rows(*task), parts)
        counts.bounded += int(np.isfinite(cost_grid).sum()) * L
        first = [x for part in found for x in part]
        return lb, rowmap, colmin, tuple(np.concatenate(x) for x in zip(*first, strict=True))

    def _state_bounds(self, pair, pen, layer: Layer, upper_bound, cost_to_go_j, counts: SolveCounts):
        """(node, bin) states: many rows, so the dense bound is built in row chunks and kept sparse.

        Returns ``(rows, nodes, bounds, cells)`` of the finite bounds: layer row, target node, bound, table cell.
        """
        tab = self.table
        L = len(self.lattice)
        th = (layer.theta * tab.psi_scale).astype(np.float32)
        J32 = layer.J.astype(np.float32)
        disguise_pen = None if len(pen) > 1 else pair.disguise_plus(pen[0])
        thr = None if cost_to_go_j is None else (upper_bound[layer.uav] + BOUND_TOL).astype(np.float32)
        step = max(1, CHUNK // L)
        parts = []
        for s0 in range(0, layer.n, step):
            sl = slice(s0, s0 + step)
            rows = layer.node[sl]
            cell = pair.table_base[rows]
            cell -= th[sl, None]
            cell = cell.astype(np.int32)
            lb = tab.lb[cell]
            if disguise_pen is None:
                lb += pair.disguise[rows]
                lb += pen[layer.uav[sl]]
            else:
                lb += disguise_pen[rows]
            lb += J32[sl, None]
            if thr is not None:
                # Transitions whose every completion costs more than the known plan cannot matter.
                lb[lb + cost_to_go_j[None, :] > thr[sl, None]] = np.inf
            r, c = nonzero_indices(np.isfinite(lb))
            parts.append((r + s0, c, lb[r, c], cell[r, c]))
        counts.bounded += layer.n * L
        return tuple(np.concatenate(x) for x in zip(*parts, strict=True))


def backtrack(layers: list[Layer], i: int, depth: int, stages) -> dict:
    """Follow the parents from UAV i's best state at stage ``depth`` (eq. 21's virtual final state).

    Returns the :class:`~baselines.dp.plan.DPPlan` fields ``nodes``, ``waypoints``, ``headings``, ``speeds``,
    ``stage_costs``, ``cost`` and ``depth``.
    """
    n = len(stages)
    nodes = np.full(n, -1, np.int64)
    head = np.full(n, np.nan)
    v = np.full(n, np.nan)
    g = np.full(n, np.nan)
    last = layers[depth - 1]
    mine = np.flatnonzero(last.uav == i)
    s = int(mine[first_argmin(last.J[mine])])
    for j in range(depth - 1, -1, -1):
        lay = layers[j]
        nodes[j], head[j], v[j], g[j] = lay.node[s], lay.theta[s], lay.v[s], lay.g[s]
        s = int(lay.parent[s])
    wp = np.full((n, 2), np.nan)
    for j in range(depth):
        wp[j] = stages[j].xy[nodes[j]]
    return dict(nodes=nodes, waypoints=wp, headings=head, speeds=v, stage_costs=g, cost=float(np.sum(g[:depth])),
                depth=int(depth))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _bound_rows(base, heading, table_lb, disguise, pen, shared, use_shared, cost_grid, ctg, use_ctg, thr, t0, t1,
                out, colmin, cand_t, cand_s):  # pragma: no cover
    """The dense bound into targets ``t0..t1`` of one block and round 0 of the selection, as
    ``ForwardRecursion._node_bounds`` defines them, term by term in its order and dtypes (float32 sums; the cut by
    ``thr`` in the cost-to-go's dtype): ``out[t, s]`` = table bound of cell ``int32(base[t, s] - heading[s])`` +
    disguise (+ penalty) + ``cost_grid[s]``; ``colmin[t]`` its smallest; the (target, source) pairs within
    ``FIRST_BAND`` of it, in C order, into ``cand_t``, ``cand_s``. Returns how many, or -1 for a cell outside the
    table (``np.take`` raises there). A source without a state (``cost_grid`` inf) is inf without its gather (its
    heading cell is 0, so its cell lies in the table)."""
    n_cells = table_lb.shape[0]
    band = np.float32(FIRST_BAND)
    k = 0
    for t in range(t0, t1):
        row = out[t]
        best = np.float32(np.inf)
        nan = False
        for s in range(row.shape[0]):
            if cost_grid[s] == np.inf:                  # no state at this source: the sum is inf whatever the rest
                row[s] = np.inf
                continue
            cell = np.int32(base[t, s] - heading[s])
            if cell < 0 or cell >= n_cells:
                return -1
            v = table_lb[cell]
            if use_shared:
                v = v + shared[t, s]
            else:
                v = v + disguise[t, s]
                v = v + pen[t]
            v = v + cost_grid[s]
            if use_ctg and v + ctg[t] > thr:
                v = np.float32(np.inf)
            row[s] = v
            if v != v:
                nan = True
            elif v < best:
                best = v
        best = np.float32(np.nan) if nan else best          # np.min propagates NaN
        colmin[t] = best
        if np.isfinite(best):
            cut = best + band
            for s in range(row.shape[0]):
                if row[s] <= cut:
                    cand_t[k] = t
                    cand_s[k] = s
                    k += 1
    return k
