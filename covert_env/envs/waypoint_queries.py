"""Read-only queries of where waypoint actions would take the UAVs, for policies that plan with the model.

The safety filter, the separation shield and the viability rule of ``training.shield`` ask these of the vector env
before they act: the paths a set of candidate nodes would fly this slot (tested against eq. 2), their end points,
how many nodes a UAV could still reach from each end next slot, and the state the filter plans from. None of them
changes the env's state.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from covert_env.envs import batch
from covert_env.envs.arguments import int_arg
from covert_env.geometry.zone import to_world

__all__ = ["SafetyState", "WaypointQueries"]


class SafetyState(NamedTuple):
    """What the safety filter (:mod:`covert_env.envs.safety_filter`) reads of a waypoint env at the start of a slot k,
    for B copies of U UAVs (copies, not views: the filter may keep it)."""

    xy: np.ndarray            # (B, U, 2) the UAVs' positions (world frame, m)
    theta: np.ndarray         # (B, U) their headings (rad)
    q_next: np.ndarray        # (B, 2) where this slot's lattice is placed: the target at k+1 as predicted at k
    phi_next: np.ndarray      # (B,) its heading
    q_ahead: np.ndarray       # (B, D, 2) where the lattices of slots k+1 .. k+D will be placed (the env's predictions)
    phi_ahead: np.ndarray     # (B, D) their headings
    slots_left: np.ndarray    # (B,) int64, slots of the episode after this one (0: this slot ends it)
    tops: np.ndarray          # (B, T, 3) each copy's polytope tops (eq. 3), padded with inf
    masks: np.ndarray         # (B, U, L) bool, the env's action masks
    slot: np.ndarray          # (B,) int64, the slot k of each copy


class WaypointQueries:
    """Where waypoint actions would take the UAVs of a vector env, read off its explicit state: the batch state
    ``copies`` (:class:`~covert_env.envs.copies.Copies`: poses, slots, scene rows, masks), the scene pool ``pool``
    (the target's predicted poses and the polytope tops), the lattice, the reach table and the sample times of a
    slot. The vector env holds one (waypoint mode) and answers ``waypoint_paths``, ``waypoint_goals``,
    ``onward_reach`` and ``safety_state`` with it, after checking its mode and that it is running (the env's
    checks: this object is not the env's API); the arguments are checked here, against the batch's shape.
    """

    def __init__(self, config, lattice: np.ndarray, copies, pool, reach, times: np.ndarray, available=None):
        self.config, self.lattice, self.copies, self.pool = config, lattice, copies, pool
        self.reach, self.times = reach, times
        self.available = available            # (B, L) the nodes each copy's task has (None: all)

    def paths(self, nodes) -> np.ndarray:
        """Where the UAVs would fly in this slot to lattice ``nodes``: path samples ``(B, U, M, path_samples, 2)``
        (world frame, m) for node indices ``(B, U, M)``, at the sample times of ``step`` and flown as ``step``
        flies them (the manoeuvre of eqs. 22-29, or its best effort where a node is out of reach). An index of -1
        stands for no node (ragged candidate lists): its samples are NaN and cost nothing. The env's
        ``waypoint_paths``: the separation shield of ``training.shield`` tests these paths against eq. 2."""
        nodes = self._checked_nodes("waypoint_paths()", nodes)
        if nodes.shape[2] > len(self.lattice):
            raise ValueError(f"waypoint_paths(): at most {len(self.lattice)} nodes per UAV (the lattice's), got "
                             f"M = {nodes.shape[2]}")
        return batch.fly_to_goals(self.copies.xy, self.copies.theta, self._goals(nodes), self.config, self.times)

    def goals(self, nodes) -> np.ndarray:
        """Where lattice ``nodes`` ``(B, U, M)`` lie at slot k+1: ``(B, U, M, 2)`` (world frame, m), the waypoints
        those actions fly to; NaN where the index is -1 (no node). The env's ``waypoint_goals``."""
        return self._goals(self._checked_nodes("waypoint_goals()", nodes))

    def onward_reach(self, xy, theta) -> np.ndarray:
        """How many lattice nodes UAVs ending this slot at poses ``xy`` ``(B, U, M, 2)`` (world frame, m), heading
        ``theta`` ``(B, U, M)``, may reach in the next slot: ``(B, U, M)`` int64, -1 where the pose holds a NaN.

        The next slot's nodes are placed at the target two slots ahead: its pose predicted for slot k+1, driven on
        for one more slot with the same displacement and turn (a constant-speed, constant-curvature guess; the env
        keeps one slot of prediction). Reachability is :class:`~covert_env.geometry.reach.ReachTable`'s lookup without
        the manoeuvre solver: the nodes in its boundary cells count as unreachable, so the count is a lower bound
        (within a cell of the reach boundary); a copy counts only the nodes its task has. A UAV with a count of 0
        reaches no node next slot, or only nodes
        at the edge of its reach: it is about to leave the zone. The env's ``onward_reach``: the viability rule of
        ``training.shield`` tests the ends of its candidate paths with it."""
        xy, theta = np.asarray(xy), np.asarray(theta)
        b, u = self.copies.theta.shape
        if xy.ndim != 4 or xy.shape[:2] != (b, u) or xy.shape[3] != 2 or theta.shape != xy.shape[:3]:
            raise ValueError(f"onward_reach(): xy must have shape ({b}, {u}, M, 2) and theta ({b}, {u}, M), got "
                             f"{xy.shape} and {theta.shape}")
        if xy.dtype.kind not in "fiu" or theta.dtype.kind not in "fiu":
            raise ValueError(f"onward_reach(): xy and theta must be real numbers, got dtypes {xy.dtype} and "
                             f"{theta.dtype}")
        xy, theta = xy.astype(np.float64), theta.astype(np.float64)
        if np.isinf(xy).any() or np.isinf(theta).any():
            raise ValueError("onward_reach(): xy and theta must be finite (NaN marks no pose), got inf")
        out = np.full(theta.shape, -1, np.int64)
        ci, ui, mi = np.nonzero(~(np.isnan(xy).any(axis=-1) | np.isnan(theta)))
        if len(ci) == 0:
            return out
        pool, rows, k = self.pool, self.copies.rows, self.copies.k
        q0, q1 = pool.q[rows, k, :2], pool.q_next[rows, k, :2]
        turn = pool.phi_next[rows, k] - pool.phi[rows, k]
        q2 = to_world((q1 - q0)[:, None], q1, turn)[:, 0]          # the displacement, turned, again
        phi2 = pool.phi_next[rows, k] + turn
        reach = self.reach.reachable(xy[ci, ui, mi][:, None], theta[ci, ui, mi][:, None], q2[ci], phi2[ci],
                                     self.lattice, exact=False)                                   # (N, 1, L)
        if self.available is not None:
            reach[:, 0] &= self.available[ci]
        out[ci, ui, mi] = reach[:, 0].sum(axis=-1)
        return out

    def safety_state(self, depth, episode_length: int) -> SafetyState:
        """What the safety filter reads of this slot (:class:`SafetyState`) in an episode of ``episode_length``
        slots: the poses, where this slot's lattice and the next ``depth`` slots' lattices lie, the polytope tops and
        the masks. The later lattices are the env's own predictions at those slots (what the observation will show
        then), so moves the filter plans for them are flown exactly as checked. The env's ``safety_state(depth)``."""
        depth = int_arg("depth", depth, 1, 1000)
        pool, rows, k = self.pool, self.copies.rows, self.copies.k
        ahead = np.minimum(k[:, None] + np.arange(1, depth + 1), pool.q_next.shape[1] - 1)        # (B, D)
        return SafetyState(self.copies.xy.copy(), self.copies.theta.copy(), pool.q_next[rows, k, :2].copy(),
                           pool.phi_next[rows, k].copy(), pool.q_next[rows[:, None], ahead, :2],
                           pool.phi_next[rows[:, None], ahead], episode_length - k - 1,
                           pool.top[rows].copy(), self.copies.masks.astype(bool), k.copy())

    def _checked_nodes(self, what: str, nodes) -> np.ndarray:
        """Node indices ``(B, U, M)`` (-1: none) checked for ``what``: shape, type, range."""
        nodes = np.asarray(nodes)
        b, u = self.copies.theta.shape
        if nodes.ndim != 3 or nodes.shape[:2] != (b, u) or not np.issubdtype(nodes.dtype, np.integer):
            raise ValueError(f"{what}: nodes must be integer indices of shape ({b}, {u}, M), got "
                             f"{nodes.dtype} {nodes.shape}")
        if nodes.size and (nodes.min() < -1 or nodes.max() >= len(self.lattice)):
            raise ValueError(f"{what}: node indices must be in [0, {len(self.lattice) - 1}] (or -1 for "
                             f"none), got [{nodes.min()}, {nodes.max()}]")
        return nodes

    def _goals(self, nodes: np.ndarray) -> np.ndarray:
        pool, rows, k = self.pool, self.copies.rows, self.copies.k
        ci, ui, mi = np.nonzero(nodes >= 0)                       # only the real (copy, UAV, node) triples
        out = np.full((*nodes.shape, 2), np.nan)
        out[ci, ui, mi] = to_world(self.lattice[nodes[ci, ui, mi]][:, None], pool.q_next[rows[ci], k[ci], :2],
                                   pool.phi_next[rows[ci], k[ci]])[:, 0]
        return out
