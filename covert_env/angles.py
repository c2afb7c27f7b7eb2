"""Angle helpers shared by the model: wrapping into (-pi, pi]."""

from __future__ import annotations

import numpy as np

__all__ = ["wrap_angle"]


def wrap_angle(a):
    """Wrap angles into (-pi, pi].

    Differences of bearings must always be wrapped: straight behind the target the UAV-target angle
    alpha is near +-pi, and an unwrapped difference would jump by 2 pi there.
    Works on scalars and arrays; returns a float for scalar input.
    """
    w = np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2 * np.pi)
    return float(w) if np.ndim(w) == 0 else w
