"""UAV-UAV separation (eq. 2 of the paper): every two UAVs keep a horizontal distance of at least d_safe1.

The UAVs fly in one plane (z = h), so eq. 2 is a distance in that plane, measured between two UAVs at the same
instant. :func:`separation` computes it for paths sampled at common instants; everything that measures or
enforces eq. 2 calls it with its own batch axes: the metrics and rewards (:func:`team_separation`,
:func:`nearest_teammate`), the start placement (:func:`covert_env.zone.spread_nodes`), the DP team's conflicts,
negotiation records and safety layer (``baselines.dp``), and the learned teams' shield (``training.shield``).
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["nearest_teammate", "separation", "team_separation"]


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
