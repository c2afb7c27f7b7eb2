"""Disguise measure and stage cost (paper §2.3, eqs. 11-18).

A UAV disguises its intent by changing its angle and distance to the target every slot. With
alpha the UAV-target angle relative to the target's heading (eq. 12) and d the horizontal distance
(eq. 13), the discrete disguise of a slot is ``kappa = eta |d alpha| + |d d|`` (eq. 11) and the
stage cost the planner minimises is path length minus lambda times disguise (eq. 18).

Angle differences are always wrapped into (-pi, pi]: the feasible zone lies straight behind the
target, where alpha is near +-pi, and an unwrapped difference would read a tiny move as a 2 pi jump.
"""

from __future__ import annotations

import numpy as np

from covert_env.geometry.angles import wrap_angle

__all__ = ["uav_target_angle", "uav_target_distance", "disguise", "stage_cost"]


def uav_target_angle(uav_xy, target_xy, target_heading):
    """alpha_i = wrap(atan2(y_i - y_q, x_i - x_q) - phi), eq. 12. Broadcasts; result in (-pi, pi].

    The paper writes arctan of the ratio; the two-argument form is the one that is defined on the
    whole plane, which eq. 12 intends.
    """
    rel = np.asarray(uav_xy, dtype=float)[..., :2] - np.asarray(target_xy, dtype=float)[..., :2]
    return wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - np.asarray(target_heading, dtype=float))


def uav_target_distance(uav_xy, target_xy):
    """d_i, the horizontal UAV-target distance, eq. 13. Broadcasts."""
    rel = np.asarray(uav_xy, dtype=float)[..., :2] - np.asarray(target_xy, dtype=float)[..., :2]
    return np.hypot(rel[..., 0], rel[..., 1])


def disguise(alpha_prev, alpha_next, d_prev, d_next, eta: float):
    """kappa = eta |wrap(alpha[k+1] - alpha[k])| + |d[k+1] - d[k]|, eq. 11 discretised over one slot.

    Larger is better disguised: the target sees the UAV at a changing bearing and range.
    """
    return eta * np.abs(wrap_angle(np.asarray(alpha_next) - np.asarray(alpha_prev))) + np.abs(
        np.asarray(d_next, dtype=float) - np.asarray(d_prev, dtype=float))


def stage_cost(path_length, alpha_prev, alpha_next, d_prev, d_next, eta: float, lam: float, *, kappa=None):
    """g = v delta - lambda eta |d alpha| - lambda |d d|, eq. 18 (the summand of eq. 17).

    ``path_length`` is v[k] delta, the distance flown in the slot (the paper's energy proxy, eq. 15).
    Equivalent to ``path_length - lam * disguise(...)``. Broadcasts over any shapes. ``kappa``: the slot's
    disguise if the caller already has it (eq. 11), so it is not computed twice.
    """
    if kappa is None:
        kappa = disguise(alpha_prev, alpha_next, d_prev, d_next, eta)
    return np.asarray(path_length, dtype=float) - lam * kappa
