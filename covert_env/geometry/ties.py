"""Choices that do not hinge on the last bit: argmin and argmax with an explicit tie rule.

Two values that are equal on paper (two symmetric lattice nodes, two manoeuvres of the same length) are often
computed along different paths and differ in their last bits, and by different last bits on different CPUs (numpy's
float64 ``arctan2``, ``exp`` and ``arccos`` differ by an ulp between CPUs with and without AVX-512). A plain
``np.argmin`` then picks whichever rounded lower, so a planner or a policy takes another decision on another
machine. Here every value within :func:`tie_tolerance` of the best counts as tied, and a tie goes to the lowest
index (docs/decisions/flight.md#settled-slot-end-poses).
"""

from __future__ import annotations

import numpy as np

__all__ = ["TIE_RTOL_FLOAT32", "TIE_RTOL_FLOAT64", "first_argmax", "first_argmin", "tie_tolerance"]

#: Relative tie tolerance for float64 values: about 4 million ulp, far above the rounding of any sum the planners
#: form and far below any difference that matters (1e-9 m of path in a stage cost of metres).
TIE_RTOL_FLOAT64 = 1e-9
#: Relative tie tolerance for float32 values (the learned policies' logits): about 84 ulp.
TIE_RTOL_FLOAT32 = 1e-5


def tie_tolerance(best, dtype) -> np.ndarray:
    """How far from ``best`` a value of ``dtype`` may be and still tie with it: the relative tolerance of the dtype
    times ``max(1, |best|)`` (an absolute tolerance near 0); 0 where ``best`` is not finite, so that an all-masked
    (infinite) row ties everywhere and picks index 0, as ``np.argmin`` does."""
    rtol = TIE_RTOL_FLOAT32 if np.dtype(dtype).itemsize <= 4 else TIE_RTOL_FLOAT64
    best = np.asarray(best, dtype=float)
    finite = np.isfinite(best)
    return np.where(finite, rtol * np.maximum(1.0, np.abs(np.where(finite, best, 0.0))), 0.0)


def first_argmin(values, axis: int | None = None):
    """The lowest index whose value is within :func:`tie_tolerance` of the minimum along ``axis`` (None: the
    flattened array, returning an int like ``np.argmin``). NaN never wins unless every value is NaN (then 0)."""
    v = np.asarray(values)
    if axis is None:
        v, axis = v.reshape(-1), 0
        return int(_first_min(v, axis))
    return _first_min(v, axis)


def first_argmax(values, axis: int | None = None):
    """The lowest index whose value is within :func:`tie_tolerance` of the maximum along ``axis`` (as
    :func:`first_argmin`)."""
    v = np.asarray(values)
    if axis is None:
        return int(_first_min(-v.reshape(-1), 0))
    return _first_min(-v, axis)


def _first_min(v: np.ndarray, axis: int):
    best = np.fmin.reduce(v, axis=axis, keepdims=True)            # NaN-ignoring unless all are NaN
    return np.argmax(v <= best + tie_tolerance(best, v.dtype), axis=axis)
