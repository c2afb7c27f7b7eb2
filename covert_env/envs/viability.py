"""The viability rule of the safety filter: a UAV should not end a slot where it can reach too few of the next
slot's lattice nodes, for from there it leaves the zone (docs/decisions/learning.md#safety-filter).

A move's **onward reach** is how many of the next slot's nodes (a copy's available nodes) are reachable from the
pose where the move ends: the reach table's count without the exact solver (a subset of the reachable nodes, within
a cell). A proposal whose onward reach is below the bar ``min_reach`` is a **dead end**. Then every allowed node
of that UAV is tested, the bar becomes what its best node (or its proposal) reaches where no node reaches
``min_reach``, and the UAV proposes its most preferred node at the bar instead. The nodes below the bar are
returned too, so that the filter's search ranks them last: otherwise a replacement whose certificate fails gives
way to the policy's next favourites, which lie around the dead end
(docs/decisions/learning.md#alternatives-in-the-policys-order). The search's stages of a bounded number of
candidates (8 or 48 per UAV) test their candidates as well and rank those below the bar last
(:meth:`ViabilityRule.dead_ends_last`).

Testing every allowed node (a few hundred with the kinematic mask) is paid only by a UAV whose proposal is a dead
end; the candidates are tested only in copies whose proposals the filter could not keep.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from covert_env.geometry.angles import wrap_heading
from covert_env.geometry.flight import fly_waypoints
from covert_env.geometry.zone import to_world

__all__ = ["DEAD_END_PREF", "ViabilityRule", "dead_ends_after"]

#: The filter's preference (lower first) for a node the rule found a dead end: from this to twice this, in the
#: order of the UAV's preferences, after every other node (the policy's -inf scores are at 1e300, the kept
#: proposal at -1e300), so that in the pair repair, which adds two UAVs' ranks, one dead end outweighs keeping a
#: proposal.
DEAD_END_PREF = 1e302

#: Moves whose onward reach is counted at once (bounds the (chunk, L) tables to a few MB).
_CHUNK = 4096


def dead_ends_after(pref: np.ndarray, dead: np.ndarray) -> np.ndarray:
    """The preferences ``pref`` (..., L) (lower first) with the nodes ``dead`` (..., L) bool moved after all the
    others, in their order among themselves (:data:`DEAD_END_PREF` to twice it)."""
    if not dead.any():
        return pref
    order = np.argsort(np.argsort(pref, axis=-1, kind="stable"), axis=-1)
    return np.where(dead, DEAD_END_PREF * (1.0 + order / pref.shape[-1]), pref)


class ViabilityRule:
    """The viability rule with bar ``min_reach`` (>= 1) for the filter of a waypoint env with ``config`` and
    ``lattice`` (L, 2); ``times``: the instants its moves are flown at (their ends are what count); ``reach``: the
    env's :func:`~covert_env.geometry.reach.reach_table`."""

    def __init__(self, config, lattice: np.ndarray, min_reach: int, times: np.ndarray, reach):
        self.config, self.lattice, self.min_reach, self.times, self.reach = config, lattice, min_reach, times, reach

    def onward(self, state, nodes: np.ndarray, available: np.ndarray) -> np.ndarray:
        """(B, U, M) the onward reach of the moves to ``nodes`` (B, U, M) under ``state`` (a
        :class:`~covert_env.envs.waypoint_queries.SafetyState`) with ``available`` (B, L) nodes per copy; -1 where
        a node is -1 and where the episode ends with this slot."""
        out = np.full(nodes.shape, -1, np.int64)
        ci, ui, mi = np.nonzero((nodes >= 0) & (state.slots_left > 0)[:, None, None])
        out[ci, ui, mi] = self._onward_at(state, ci, ui, nodes[ci, ui, mi], available)
        return out

    def _onward_at(self, state, c, i, nodes, available) -> np.ndarray:
        """(K,) the onward reach of copy ``c``'s UAV ``i`` moving to ``nodes`` (all (K,))."""
        out = np.empty(len(c), np.int64)
        for s in range(0, len(c), _CHUNK):
            cs, us, ns = c[s:s + _CHUNK], i[s:s + _CHUNK], nodes[s:s + _CHUNK]
            goals = to_world(self.lattice[ns][:, None], state.q_next[cs], state.phi_next[cs])         # (k, 1, 2)
            path, end_theta, *_ = fly_waypoints(state.xy[cs, us][:, None], state.theta[cs, us][:, None], goals,
                                                self.config, self.times)
            reach = self.reach.reachable(path[:, :, -1], wrap_heading(end_theta), state.q_ahead[cs, 0],
                                         state.phi_ahead[cs, 0], self.lattice, exact=False)          # (k, 1, L)
            out[s:s + _CHUNK] = (reach[:, 0] & available[cs]).sum(axis=-1)
        return out

    def apply(self, state, proposed: np.ndarray, preferences: Callable, available: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray | None]:
        """The proposals (B, U) with the rule applied, and (B, U, L) bool: the nodes found below the bar that the
        UAV no longer proposes (None if no proposal of the batch was a dead end). ``preferences(c, i)`` gives copy
        ``c``'s UAV ``i``'s preferences over the lattice (N, L), finite, lower first, for index arrays ``c``, ``i``
        (N,). A UAV's candidates are its allowed nodes (its mask, within its copy's ``available``)."""
        now = self.onward(state, proposed[..., None], available)[..., 0]
        dead = (now >= 0) & (now < self.min_reach)
        if not dead.any():
            return proposed, None
        c, i = np.nonzero(dead)
        allowed = state.masks[c, i] & available[c]                                                # (N, L)
        r, node = np.nonzero(allowed)
        count = np.full(allowed.shape, -1, np.int64)
        count[r, node] = self._onward_at(state, c[r], i[r], node, available)
        bar = np.clip(np.maximum(count.max(axis=1), now[c, i]), 1, self.min_reach)                # (N,)
        good = count >= bar[:, None]
        pick = np.argmin(np.where(good, preferences(c, i), np.inf), axis=1)
        better = good.any(axis=1) & (bar > now[c, i])
        out = proposed.copy()
        out[c[better], i[better]] = pick[better]
        demoted = np.zeros(state.masks.shape, bool)
        demoted[c, i] = allowed & (count < bar[:, None])
        demoted[c[better], i[better], proposed[c[better], i[better]]] = True                    # the replaced proposal
        demoted[np.arange(len(out))[:, None], np.arange(out.shape[1])[None], out] = False
        return out, demoted

    def dead_ends_last(self, state, nodes: np.ndarray, rank: np.ndarray, available: np.ndarray) -> np.ndarray:
        """``rank`` (B, U, M) of the candidates ``nodes`` (B, U, M), sorted by rank per UAV, with the candidates
        below the bar (``min_reach``, or what the UAV's best candidate reaches where none reaches that many) after
        the others, in the same order among themselves."""
        onward = self.onward(state, nodes, available)
        bar = np.clip(onward.max(axis=2, keepdims=True), 1, self.min_reach)
        m = nodes.shape[2]
        last = DEAD_END_PREF * (1.0 + np.arange(m) / m)
        return np.where((onward >= 0) & (onward < bar) & np.isfinite(rank), last, rank)
