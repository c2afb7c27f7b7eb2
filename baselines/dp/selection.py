"""Which transitions to solve exactly: best-first by the manoeuvre table's lower bounds, until proven.

Every transition into a stage has a cheap lower bound ``LB = J(a) + disguise(a, b) + table bound on the path
length + penalty(b)`` (:mod:`baselines.dp.recursion` builds them). A state's winner is proven once its best
exact cost is no more than every unsolved bound into it: the rest provably cannot win, so the result equals
the dense recursion that solves every transition. Each round is one vectorised exact solve for all UAVs.
"""

from __future__ import annotations

import numpy as np

from baselines.dp.states import Layer
from baselines.dp.table import ManoeuvreBoundsTable
from baselines.dp.transitions import SolvedTransitions
from covert_env.geometry.angles import TWO_PI

__all__ = ["BOUND_TOL", "first_round", "nonzero_indices", "select_per_bin", "select_per_node"]

#: Absolute slack when comparing float32 bounds with float64 exact costs (a few float32 ulps at ~1e4).
BOUND_TOL = 1e-2
#: First-round band (cost units = metres of path): the table's bound is usually within a metre of the exact
#: path length (docs/decisions/planner.md), so solving every transition this close to its column's smallest
#: bound usually settles the column in one batch.
FIRST_BAND = 0.5


def nonzero_indices(mask: np.ndarray) -> tuple:
    """``np.nonzero(mask)`` (same indices, same C order), several times faster on large N-d masks: numpy's
    N-d nonzero unravels every index as it scans, the flat scan is a tight loop over the few hits."""
    return np.unravel_index(np.flatnonzero(mask), mask.shape)


def first_round(lb, colmin) -> tuple[np.ndarray, np.ndarray]:
    """Round 0 of :func:`select_per_node` for some targets: ``lb`` (targets, L) their bounds [target, source].

    Writes each target's smallest bound into ``colmin`` and returns ``(target, source)`` (C order) of the
    transitions within ``FIRST_BAND`` of it (none for a target without a finite bound).
    """
    lb.min(axis=1, out=colmin)
    thr = np.where(np.isfinite(colmin), colmin + FIRST_BAND, -np.inf)
    return nonzero_indices(lb <= thr[:, None])


def select_per_node(lb, rowmap, colmin, first, solved: SolvedTransitions, max_open_rounds) -> None:
    """One state per node (B = 1): best-first by bound until every node's winner is proven.

    ``lb`` is (blocks, L, L): per UAV, bound of every transition, indexed [block, target b, source a]; ``colmin``
    (blocks, L) and ``first`` = (block, target, source) are round 0's candidates (:func:`first_round`, computed with
    the bounds, while they are in cache). Round 0 solves, per target b, every transition within ``FIRST_BAND`` of
    b's smallest bound: the table's bounds are that tight, so this usually contains the winner and proves it (no
    unsolved bound is below it). A target whose value is above the band then solves every transition still bounded
    below its value (and is final); a target with no feasible transition yet ("open") solves the next 1, 2, 4, ...
    smallest bounds per round. Every round is one exact solve for all UAVs. With ``max_open_rounds`` (used under
    negotiation constraints, where many transitions are removed) open targets are given up after that many rounds:
    the plan stays valid, the node is just not offered.

    Transitions are solved in (block, source, target) order within a round, then band before open per
    block: ties between equal exact costs are broken by that order (:meth:`SolvedTransitions.winners`).
    """
    nb, L, _ = lb.shape
    best = np.full((nb, L), np.inf)
    reach = np.isfinite(colmin)
    thr = np.where(reach, colmin + FIRST_BAND, -np.inf)
    bb, c, r = first

    def run(bb, r, c):
        cost = solved.solve(rowmap[bb, r], c)
        lb[bb, c, r] = np.inf
        np.minimum.at(best, (bb, c), cost)

    o = np.lexsort((c, r, bb))
    run(bb[o], r[o], c[o])
    has_exact = np.isfinite(best)
    band = has_exact & (best > thr + BOUND_TOL)
    open_ = reach & ~has_exact
    k, rounds = 1, 0
    while True:
        keys = []                               # (block, kind: 0 band / 1 open, source or rank, target)
        bb_, cc_ = np.nonzero(band)
        if bb_.size:
            lim = best[bb_, cc_] + BOUND_TOL + 1e-6 * np.abs(best[bb_, cc_])
            q, rr = nonzero_indices(lb[bb_, cc_] < lim[:, None])
            keys.append((bb_[q], np.zeros(q.size, np.int64), rr, cc_[q], rr))
        bo, co = np.nonzero(open_) if (max_open_rounds is None or rounds < max_open_rounds) else ((), ())
        if len(bo):
            sub = lb[bo, co]                    # (open targets, L)
            if k == 1:
                rr = np.argmin(sub, axis=1)[:, None]
            elif L <= k:
                rr = np.broadcast_to(np.arange(L)[None, :], sub.shape)
            else:
                rr = np.argpartition(sub, k - 1, axis=1)[:, :k]
            qq = np.broadcast_to(np.arange(len(bo))[:, None], rr.shape)
            rank = np.broadcast_to(np.arange(rr.shape[1])[None, :], rr.shape)
            fin = np.isfinite(sub[qq, rr])
            keys.append((bo[qq[fin]], np.ones(int(fin.sum()), np.int64), rank[fin], co[qq[fin]], rr[fin]))
        if not keys or sum(x[0].size for x in keys) == 0:
            return
        b_, kind, first, c_, r_ = (np.concatenate(x) for x in zip(*keys, strict=True))
        o = np.lexsort((c_, first, kind, b_))
        run(b_[o], r_[o], c_[o])
        now = np.isfinite(best)
        band = open_ & now                     # newly solved: one band pass, then final
        open_ = open_ & ~now
        bo, co = np.nonzero(open_)             # targets with no finite bound left are unreachable
        if bo.size:
            open_[bo, co] = np.isfinite(lb[bo, co].min(axis=1))
        k, rounds = min(2 * k, 64), rounds + 1


def select_per_bin(table: ManoeuvreBoundsTable, n_nodes: int, rows, nodes, bounds, cells, layer: Layer, bins: int,
                   solved: SolvedTransitions, constrained: bool) -> None:
    """(node, bin) states: the table's heading-change interval names the bins a transition can land in.

    ``rows, nodes, bounds, cells``: the candidate transitions (layer row -> node), their bounds and table cells.
    """
    tab, r, cc, lbv, cl = table, rows, nodes, bounds, cells
    if r.size == 0:
        return
    scale = bins / TWO_PI
    th = layer.theta[r]
    blo = np.floor((th + tab.dlo[cl]) * scale).astype(np.int64)
    span = np.minimum(np.floor((th + tab.dhi[cl]) * scale).astype(np.int64) - blo, bins - 1)
    blo %= bins
    node_key = (layer.uav[r] * n_nodes + cc) * bins
    key0 = node_key + blo
    K = (int(layer.uav.max()) + 1) * n_nodes * bins
    # Round 1: per estimated key, the transition with the smallest bound.
    first = np.full(K, np.inf, np.float32)
    np.minimum.at(first, key0, lbv)
    cand = np.flatnonzero(lbv == first[key0])
    _, u = np.unique(key0[cand], return_index=True)
    pick = cand[u]
    done = np.zeros(r.size, bool)
    done[pick] = True
    solved.solve(r[pick], cc[pick])
    best = solved.best(K, bins)
    # Round 2: a transition is needed unless its bound exceeds the best of every bin it can land in.
    bound = best[key0]
    for o in range(1, int(span.max(initial=0)) + 1):
        other = best[node_key + (blo + o) % bins]
        bound = np.where(span >= o, np.maximum(bound, other), bound)
    if constrained:
        # Under negotiation constraints a bin whose first pick was removed is given up (bounded search).
        bound = np.where(np.isfinite(bound), bound, -np.inf)
    rem = np.flatnonzero(~done & (lbv < bound + BOUND_TOL + 1e-6 * np.abs(np.nan_to_num(bound, posinf=0.0,
                                                                                        neginf=0.0))))
    if rem.size:
        solved.solve(r[rem], cc[rem])
