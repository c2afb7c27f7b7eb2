"""Which transitions to solve exactly: best-first by the manoeuvre table's lower bounds, until proven.

Every transition into a stage has a cheap lower bound ``LB = J(a) + disguise(a, b) + table bound on the path
length + penalty(b)`` (:mod:`baselines.dp.recursion` builds them). A state's winner is proven once its best
exact cost is no more than every unsolved bound into it: the rest provably cannot win, so the result equals
the dense recursion that solves every transition. Each round is one vectorised exact solve for all UAVs.
"""

from __future__ import annotations

import numpy as np

from baselines.dp.states import Layer
from baselines.dp.table import TWO_PI, ManoeuvreTable
from baselines.dp.transitions import SolvedTransitions

__all__ = ["BOUND_TOL", "select_per_bin", "select_per_node"]

#: Absolute slack when comparing float32 bounds with float64 exact costs (a few float32 ulps at ~1e4).
BOUND_TOL = 1e-2
#: First-round band (cost units = metres of path): the table's bound is within ~0.9 m of the exact path
#: length for 99% of transitions, so solving every transition this close to its column's smallest bound
#: usually settles the column in one batch.
FIRST_BAND = 0.5


def select_per_node(lb, rowmap, solved: SolvedTransitions, max_open_rounds) -> None:
    """One state per node (B = 1): best-first by bound until every node's winner is proven.

    ``lb`` is (blocks, L, L): per UAV, bound of every (node a -> node b). Round 0 solves, per column b,
    every transition within ``FIRST_BAND`` of the column's smallest bound: the table's bounds are
    that tight, so this usually contains the winner and proves it (no unsolved bound is below it). A
    column whose value is above the band then solves every transition still bounded below its value
    (and is final); a column with no feasible transition yet ("open") solves the next 1, 2, 4, ...
    smallest bounds per round. Every round is one exact solve for all UAVs. With ``max_open_rounds``
    (used under negotiation constraints, where many transitions are removed) open columns are given
    up after that many rounds: the plan stays valid, the node is just not offered.
    """
    nb, _, L = lb.shape
    best = np.full((nb, L), np.inf)
    colmin = lb.min(axis=1)
    reach = np.isfinite(colmin)
    thr = np.where(reach, colmin + FIRST_BAND, -np.inf)
    bb, r, c = np.nonzero(lb <= thr[:, None, :])

    def run(bb, r, c):
        cost = solved.solve(rowmap[bb, r], c)
        lb[bb, r, c] = np.inf
        np.minimum.at(best, (bb, c), cost)

    run(bb, r, c)
    has_exact = np.isfinite(best)
    band = has_exact & (best > thr + BOUND_TOL)
    open_ = reach & ~has_exact
    k, rounds = 1, 0
    while True:
        parts = []
        for b in range(nb):
            cols = np.flatnonzero(band[b])
            if cols.size:
                lim = best[b, cols] + BOUND_TOL + 1e-6 * np.abs(best[b, cols])
                rr, cc = np.nonzero(lb[b][:, cols] < lim[None, :])
                parts.append((np.full(rr.size, b), rr, cols[cc]))
            cols = np.flatnonzero(open_[b])
            if cols.size and (max_open_rounds is None or rounds < max_open_rounds):
                sub = lb[b][:, cols]
                if k == 1:
                    rr = np.argmin(sub, axis=0)[None]
                elif sub.shape[0] <= k:
                    rr = np.broadcast_to(np.arange(sub.shape[0])[:, None], sub.shape)
                else:
                    rr = np.argpartition(sub, k - 1, axis=0)[:k]
                cc = np.broadcast_to(np.arange(cols.size), rr.shape)
                fin = np.isfinite(sub[rr, cc])
                parts.append((np.full(int(fin.sum()), b), rr[fin], cols[cc[fin]]))
        if not parts or sum(p[1].size for p in parts) == 0:
            return
        bb, r, c = (np.concatenate(x) for x in zip(*parts, strict=True))
        run(bb, r, c)
        now = np.isfinite(best)
        band = open_ & now                     # newly solved: one band pass, then final
        open_ = open_ & ~now
        for b in range(nb):                    # columns with no finite bound left are unreachable
            cols = np.flatnonzero(open_[b])
            if cols.size:
                open_[b, cols] = np.isfinite(lb[b][:, cols].min(axis=0))
        k, rounds = min(2 * k, 64), rounds + 1


def select_per_bin(table: ManoeuvreTable, n_nodes: int, rows, nodes, bounds, cells, layer: Layer, bins: int,
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
