"""UAV-UAV separation (eq. 2 of the paper): every two UAVs keep a horizontal distance of at least d_safe1.

The UAVs fly in one plane (z = h), so eq. 2 is a distance in that plane, measured between two UAVs at the same
instant. :func:`separation` computes it for paths sampled at common instants; everything that measures or
enforces eq. 2 calls it with its own batch axes: the metrics and rewards (:func:`team_separation`,
:func:`nearest_teammate`), the start placement (:func:`covert_env.geometry.zone.spread_nodes`), the DP team's conflicts,
negotiation records and safety layer (``baselines.dp``), and the learned teams' shield (``training.shield``).

:func:`priority_negotiation` is the one order rule of a team that settles its UAVs' moves one after another
(paper §2.5, "the UAVs negotiate"): the DP team's safety layer and the shield both use it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

__all__ = ["nearest_teammate", "priority_negotiation", "separation", "team_separation"]


def separation(paths: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Eq. 2's distance: the closest horizontal approach (m) of two UAVs flying ``paths`` and ``others``.

    Args:
        paths, others: ``(..., P, 2)`` positions (x, y) at P common instants (P = 1: two positions), broadcast
            against each other, so one call compares every candidate path with every teammate's.

    Returns:
        ``(...)`` the smallest distance over the P instants; eq. 2 holds where it is >= d_safe1. NaN where a
        sample is NaN (no path), which every comparison treats as False.
    """
    d = np.hypot(paths[..., 0] - others[..., 0], paths[..., 1] - others[..., 1])
    return d.min(axis=-1)


def team_separation(paths: np.ndarray) -> np.ndarray:
    """``(..., U, P, 2)`` the paths of a team at common instants -> ``(..., U)`` each UAV's :func:`separation` from
    its nearest teammate (inf with one UAV)."""
    u = paths.shape[-3]
    if u == 1:
        return np.full(paths.shape[:-3] + (1,), np.inf)
    # Each unordered pair once: |p_i - p_j| = |p_j - p_i| exactly in floating point.
    i, j, of = _pairs(u)
    d = separation(paths[..., i, :, :], paths[..., j, :, :])                   # (..., pairs)
    return d[..., of].min(axis=-1)


def nearest_teammate(xy: np.ndarray) -> np.ndarray:
    """``(..., U, 2)`` positions -> ``(..., U)`` distance to the nearest other UAV (inf with one UAV)."""
    return team_separation(np.asarray(xy)[..., None, :])


@functools.cache
def _pairs(u: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs i < j of U UAVs, and for each UAV the indices of its U - 1 pairs."""
    i, j = np.triu_indices(u, 1)
    of = np.array([[k for k in range(len(i)) if a in (i[k], j[k])] for a in range(u)])
    return i, j, of


def priority_negotiation(settle: Callable[[np.ndarray, np.ndarray], np.ndarray], n_copies: int,
                         n_uavs: int) -> np.ndarray:
    """The order in which a team settles its moves for one slot, each UAV keeping eq. 2 from those settled before.

    The UAVs settle in priority order (the agent index, docs/decisions/planner.md#team-priority-rule). Where a UAV is
    left without a separated move, it is promoted to the front (the others keep their order) and the team
    settles again: the UAV that lacked room gets the first choice. A UAV is promoted at most once and at most U
    orders are tried, so the work is polynomial in U (trying all U! orders is not, and did no better). Where
    no order settles every UAV, the last order tried stands.

    Args:
        settle: ``settle(order, rows) -> stuck_at``. ``order`` ``(B, U)``: each copy's priority order;
            ``rows`` ``(B,)`` bool: the copies to settle in it (their results replace the earlier ones, the other
            copies' are kept). ``stuck_at`` ``(B,)`` int: per copy the position in ``order`` of the first UAV
            left without a separated move, U if none (read only at ``rows``).
        n_copies, n_uavs: B and U.

    Returns:
        ``(B,)`` bool: the copies where the order that stands left some UAV without a separated move.
    """
    b, u = int(n_copies), int(n_uavs)
    copies = np.arange(b)
    order = np.tile(np.arange(u), (b, 1))
    promoted = np.zeros((b, u), bool)
    stuck_at = np.array(settle(order, np.ones(b, bool)), dtype=np.int64)
    for _ in range(u - 1):
        stuck = order[copies, np.minimum(stuck_at, u - 1)]
        again = (stuck_at < u) & ~promoted[copies, stuck]
        if not again.any():
            break
        promoted[copies[again], stuck[again]] = True
        rest = order[order != stuck[:, None]].reshape(b, u - 1)
        order = np.where(again[:, None], np.concatenate([stuck[:, None], rest], axis=1), order)
        stuck_at[again] = np.asarray(settle(order, again))[again]
    return stuck_at < u
