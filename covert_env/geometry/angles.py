"""Angle wrapping, the one home of the model's two conventions.

* Differences of angles (bearing changes, eq. 11; offsets from an axis) live in ``(-pi, pi]``:
  :func:`wrap_angle`, and :func:`abs_wrapped` for the size of a difference of two wrapped angles.
* Headings of UAVs (the unicycle's theta, eq. 1) live in ``[0, 2 pi)``: :func:`wrap_heading`.

All three work on scalars and arrays of any shape and keep a float array's dtype (float32 stays float32).
"""

from __future__ import annotations

import numpy as np

__all__ = ["TWO_PI", "abs_wrapped", "wrap_angle", "wrap_heading"]

TWO_PI = 2.0 * np.pi


def _floats(a) -> np.ndarray:
    a = np.asarray(a)
    return a if a.dtype.kind == "f" else a.astype(float)


def wrap_angle(a):
    """Wrap angles into (-pi, pi].

    Differences of bearings must always be wrapped: straight behind the target the UAV-target angle
    alpha is near +-pi, and an unwrapped difference would jump by 2 pi there. The interval is closed at
    +pi so that ``atan2``'s own range (-pi, pi] is left unchanged.
    Returns a float for scalar input.
    """
    w = np.pi - np.mod(np.pi - _floats(a), TWO_PI)
    return float(w) if np.ndim(w) == 0 else w


def abs_wrapped(a, out=None):
    """``|wrap_angle(a)|`` for differences ``a`` of two wrapped angles (so ``|a| < 2 pi``): ``min(|a|, 2 pi - |a|)``.

    Exact where ``|a| <= pi`` (it is ``|a|`` there, while ``wrap_angle`` rounds through ``pi - a``), and one pass
    over the array with ``out`` (e.g. the input itself): the planner's float32 (L, L) bearing-change bounds.
    """
    a = _floats(a)
    mag = np.abs(a, out=out)
    return np.minimum(mag, mag.dtype.type(TWO_PI) - mag, out=mag if out is not None else None)


def wrap_heading(a):
    """Wrap headings into [0, 2 pi).

    ``np.mod`` alone returns exactly 2 pi for tiny negative input (-1e-17 rounds to 2 pi - 1e-17 = 2 pi); that
    is folded to 0, so the interval is half-open as stated. Returns a float for scalar input.
    """
    w = np.mod(_floats(a), TWO_PI)
    w = np.where(w >= TWO_PI, 0.0, w)
    return float(w) if np.ndim(w) == 0 else w
