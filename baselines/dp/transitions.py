"""Exact transition costs c_ab (eq. 18) and the per-state winners among the transitions solved into a stage.

A transition a -> b is flown by the turn-then-straight manoeuvre (eqs. 22-29); its cost is the stage
cost of eq. 18, ``g = v delta - lambda kappa`` with ``kappa = eta |wrap(alpha_b - alpha_a)| + |d_b - d_a|``
(eq. 11), computed by :func:`covert_env.geometry.cost.stage_cost` (the model's one definition), or inf when no
manoeuvre exists or a check along it fails (:mod:`baselines.dp.path_checks`, eq. 3 by
:mod:`baselines.dp.clearance`).
"""

from __future__ import annotations

import numpy as np

from baselines.dp.path_checks import PathChecker, record_circles, separated
from baselines.dp.states import Layer, Problem, SolveCounts
from covert_env.geometry.angles import TWO_PI, wrap_heading
from covert_env.geometry.cost import stage_cost
from covert_env.geometry.dynamics import Manoeuvre, solve_manoeuvre
from covert_env.geometry.ties import tie_tolerance
from covert_env.world.config import Config

__all__ = ["SolvedTransitions", "solve_transitions", "transition_costs"]


def transition_costs(config: Config, m: Manoeuvre, ok, alpha_from, d_from, alpha_to, d_to) -> np.ndarray:
    """Stage costs g (eq. 18, :func:`covert_env.geometry.cost.stage_cost`) of the manoeuvres ``m``; inf where not
    ``ok``.

    alpha and d (eqs. 12-13) at both ends of every transition broadcast against the manoeuvres.
    """
    c = config
    g = stage_cost(np.nan_to_num(m.length), alpha_from, alpha_to, d_from, d_to, c.eta, c.lam)
    return np.where(ok, g, np.inf)


def solve_transitions(config: Config, paths: PathChecker, prob: Problem, j: int, *, start_xy, theta, uav, alpha_from,
                      d_from, nodes, counts: SolveCounts):
    """Exact manoeuvres from poses (``start_xy``, ``theta``) of batch UAVs ``uav`` to ``nodes`` of stage j.

    Returns ``(m, g, extra)``: the manoeuvres, their stage costs g (eq. 18; inf where infeasible or where a
    check along the path fails) and the soft path penalties of fallback level 2 (0 otherwise).
    """
    c = config
    st = prob.stages[j]
    m = solve_manoeuvre(start_xy, theta, st.xy[nodes], v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    counts.exact += nodes.size
    ok = np.asarray(m.feasible, bool).reshape(-1).copy()
    if paths.clearance.active and ok.any():
        ok[ok] = paths.clearance.manoeuvres_clear(m, ok)           # eq. 3 along the path
    extra = paths.penalties(m, ok, prob.path, j, len(prob.stages), prob.path_soft, prob.path_cost)
    if prob.avoid is not None and ok.any():
        if j not in prob.avoid_circles:
            prob.avoid_circles[j] = record_circles(prob.avoid, prob.avoid_dist, j)
        ok[ok] = separated(m, ok, prob.avoid, prob.avoid_dist, uav, j, prob.avoid_circles[j])
    g = transition_costs(c, m, ok, alpha_from, d_from, st.alpha[nodes], st.d[nodes])
    return m, g, extra


class SolvedTransitions:
    """Exactly solved transitions from a layer into stage j, and the per-state winners among them."""

    def __init__(self, config: Config, paths: PathChecker, n_nodes: int, prob: Problem, layer: Layer, j: int,
                 counts: SolveCounts):
        self.config, self.paths, self.n_nodes = config, paths, n_nodes
        self.prob, self.layer, self.j, self.counts = prob, layer, j, counts
        self.parts: list[tuple] = []

    def solve(self, rows, nodes) -> np.ndarray:
        """Solve transitions (row of the layer -> node) exactly, record them, return J + c + penalty."""
        lay, sa = self.layer, self.prob.stages[self.j - 1]
        a = lay.node[rows]
        m, g, extra = solve_transitions(self.config, self.paths, self.prob, self.j, start_xy=sa.xy[a],
                                        theta=lay.theta[rows], uav=lay.uav[rows], alpha_from=sa.alpha[a],
                                        d_from=sa.d[a], nodes=nodes, counts=self.counts)
        pen = self.prob.penalties[self.j]
        cost = lay.J[rows] + g + pen[lay.uav[rows] if len(pen) > 1 else 0, nodes] + extra
        self.parts.append((rows, nodes, cost, np.asarray(m.heading_after).reshape(-1), np.asarray(m.v).reshape(-1),
                           g))
        return cost

    def _all(self):
        return [np.concatenate(x) for x in zip(*self.parts, strict=True)]

    def _key(self, rows, nodes, head, bins):
        node_key = self.layer.uav[rows] * self.n_nodes + nodes
        if bins == 1:
            return node_key
        return node_key * bins + (np.floor(wrap_heading(head) * (bins / TWO_PI)).astype(np.int64) % bins)

    def best(self, n_keys: int, bins: int) -> np.ndarray:
        """(n_keys,) best exact cost per (uav, node, bin) key so far."""
        best = np.full(n_keys, np.inf)
        if self.parts:
            rows, nodes, cost, head, _, _ = self._all()
            ok = np.isfinite(cost)
            np.minimum.at(best, self._key(rows[ok], nodes[ok], head[ok], bins), cost[ok])
        return best

    def winners(self, bins: int) -> Layer:
        """The next layer (eq. 20): per (uav, node, bin) state, the cheapest solved arrival."""
        if not self.parts:
            return Layer.empty()
        rows, nodes, cost, head, v, g = self._all()
        ok = np.isfinite(cost)
        if not ok.any():
            return Layer.empty()
        rows, nodes, cost, head, v, g = rows[ok], nodes[ok], cost[ok], head[ok], v[ok], g[ok]
        key = self._key(rows, nodes, head, bins)
        # Sort by (key, cost): every key's cheapest row comes first, and layers come out sorted by uav. Rows within
        # the tie tolerance of that cost tie (covert_env.geometry.ties), and a tie goes to the row solved first.
        order = np.lexsort((cost, key))
        ks, cs = key[order], cost[order]
        starts = np.flatnonzero(np.concatenate([[True], ks[1:] != ks[:-1]]))
        best = np.repeat(cs[starts], np.diff(np.append(starts, len(cs))))
        tied = cs <= best + tie_tolerance(best, cs.dtype)
        w = np.minimum.reduceat(np.where(tied, order, len(order)), starts)
        return Layer(uav=self.layer.uav[rows[w]], node=nodes[w], theta=wrap_heading(head[w]), J=cost[w],
                     parent=rows[w], v=v[w], g=g[w])
