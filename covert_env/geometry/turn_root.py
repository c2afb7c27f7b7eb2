"""Eq. 29's root: the turn radius r (speed ``v = W_max r``) of the turn-then-straight manoeuvre.

``F(r) = r tau(r) + L(r) - delta W_max r`` (arc plus straight minus the distance flown in the slot) is solved for
its smallest root in the bracket :func:`root_bracket` finds (its existence decides feasibility), by a safeguarded
Newton iteration: Newton steps kept inside the shrinking sign-change bracket, bisection otherwise
(:mod:`covert_env.geometry.dynamics` derives F, its derivative and the root structure).

The iteration runs on every still-unconverged pair at once. Its arithmetic per pair is compiled (numba: the
heading vector, F, F' and the step, one pass per iteration), but the arctangent is numpy's ``arctan2``, called
once per iteration on the whole batch: numpy's float64 ``arctan2`` rounds differently from the C library's on CPUs
with AVX-512, and the env's numbers (fingerprints, the shipped cards' replays) are numpy's, bit for bit
(tests/test_dynamics.py holds the iteration written with numpy array operations, which the compiled one matches
to the last bit).
"""

from __future__ import annotations

import numba
import numpy as np

from covert_env.geometry.angles import TWO_PI

__all__ = ["root_bracket", "solve_turn", "straight_leg", "turn_angle"]

# Relative step size at which the Newton iteration stops; ~50 ulp, well below 1e-9 m on any real slot.
_NEWTON_RTOL = 1e-14
_NEWTON_MAX_ITER = 100
_PHI_BISECT_ITER = 60


def straight_leg(d2, b, r):
    """L = |z - g|, the straight leg; clamped at 0 so that rounding at r = R_c never gives NaN."""
    return np.sqrt(np.maximum(d2 - 2.0 * b * r, 0.0))


def turn_angle(a, b, r, d2):
    """Turn angle tau in [0, 2 pi) of left-frame goals (b >= 0) at radius r (1-D arrays): the arctangent of the
    cancellation-free heading vector (:func:`_heading_vectors`), folded as :func:`_residual_and_slope` folds it."""
    n = len(a)
    leg, ex, ey = np.empty(n), np.empty(n), np.empty(n)
    _heading_vectors(a, b, r, d2, leg, ex, ey)
    t = np.arctan2(ey, ex)
    # A left turn's angle, not a heading: just below a full circle it may round to 2 pi, which must not fold to 0.
    return np.where(t < 0, t + TWO_PI, t)


def _phi(a, b, d2, r):
    """phi(r) = L (L^2 + r b) / r^2 + a; h'(r) = -phi / D^2, and phi is strictly decreasing in r."""
    L = straight_leg(d2, b, r)
    return L * (L * L + r * b) / (r * r) + a


def root_bracket(a, b, d, d2, wd, r_max):
    """The left-frame goals (b >= 0, not dead ahead; 1-D arrays) for which eq. 29 has a root: their indices and a
    sign-change bracket [lo, hi] of the smallest root. It decides feasibility alone: the safeguarded Newton
    iteration of :func:`solve_turn` converges on every bracket (each step halves the one before, or bisects)."""
    if a.shape[0] == 0:
        return np.zeros(0, np.intp), a, a
    # Bracket [lo, hi]: lo from "path >= |g - p|" (so F(lo) >= 0), hi from the turning circle and V_max.
    lo = d / wd
    r_c = np.where(b > 0, d2 / (2.0 * np.where(b > 0, b, 1.0)), np.inf)
    hi = np.minimum(r_c, r_max)
    alive = lo < hi

    if wd <= np.pi:
        # Unreachable by any control: |theta(t)| <= W t <= pi gives x(T) >= (v / W) sin(W T) >= 0 > a.
        alive &= a >= 0
    # Behind the UAV, eq. 29 may have two roots; cap hi at the minimiser r* of h so that the bracket holds
    # only the smaller one. phi is monotone, so plain bisection finds r*.
    behind = np.flatnonzero(alive & (a < 0))
    if behind.size:
        ab, bb, d2b = a[behind], b[behind], d2[behind]
        blo, bhi = lo[behind], hi[behind]
        phi_hi = _phi(ab, bb, d2b, bhi)
        phi_lo = _phi(ab, bb, d2b, blo)
        # phi(lo) <= 0: h increases on the whole bracket from h(lo) >= delta W_max, so there is no root.
        alive[behind[phi_lo <= 0]] = False
        need = (phi_hi < 0) & (phi_lo > 0)
        if need.any():
            sub = np.flatnonzero(need)
            s_a, s_b, s_d2 = ab[sub], bb[sub], d2b[sub]
            s_lo, s_hi = blo[sub].copy(), bhi[sub].copy()
            for _ in range(_PHI_BISECT_ITER):
                mid = 0.5 * (s_lo + s_hi)
                pos = _phi(s_a, s_b, s_d2, mid) > 0
                s_lo = np.where(pos, mid, s_lo)
                s_hi = np.where(pos, s_hi, mid)
            # s_hi has phi <= 0, i.e. lies just past r*, where h is within rounding of its minimum.
            hi[behind[sub]] = s_hi

    idx = np.flatnonzero(alive)
    if idx.size == 0:
        return idx, lo[idx], hi[idx]
    f_hi = _eq29_at(a[idx], b[idx], hi[idx], d2[idx], wd, np.empty((5, idx.size)))[0]
    # F(hi) > 0: even the largest admissible radius cannot cover the path in one slot -> infeasible.
    idx = idx[f_hi <= 0]
    return idx, lo[idx], hi[idx]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _heading_vectors(a, b, r, d2, leg, ex, ey):  # pragma: no cover
    """The straight leg L (:func:`straight_leg`) and the heading vector (ex, ey) whose arctangent is the turn angle
    tau, pair by pair, into ``leg``, ``ex``, ``ey``."""
    for i in range(len(a)):
        ai, bi, ri = a[i], b[i], r[i]
        s = d2[i] - 2.0 * bi * ri
        if s < 0.0:                                    # np.maximum(s, 0.0): NaN stays NaN
            s = 0.0
        li = np.sqrt(s)
        # a - L loses all its digits when the goal is nearly dead ahead (L ~ a); a^2 - L^2 = b (2r - b) is exact.
        # The quotient is itself rounding noise over a tiny divisor when a + L ~ 0 (goal abeam, on the turning
        # circle: a = 0+, L = 0), where a - L is exact enough; a > 0 with a + L below 1e-6 (b + r) uses a - L.
        if ai > 0 and ai + li > 1e-6 * (bi + ri):
            a_minus_l = bi * (2.0 * ri - bi) / (ai + li)
        else:
            a_minus_l = ai - li
        leg[i] = li
        ex[i] = li * ai - ri * (bi - ri)
        ey[i] = ri * a_minus_l + li * bi


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _residual_slope(a, b, r, leg, t, wd):  # pragma: no cover
    """Eq. 29's residual F(r) = r tau + L - delta W_max r and its slope
    F'(r) = tau + (L (r - b) - a r) / D^2 - delta W_max (the r tau' and L' singularities cancel) of one pair, from
    the arctangent ``t`` of its heading vector."""
    tau = t + TWO_PI if t < 0 else t
    return r * tau + leg - wd * r, tau + (leg * (r - b) - a * r) / (leg * leg + r * r) - wd


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _residual_and_slope(a, b, r, leg, t, wd, f, fp):  # pragma: no cover
    """:func:`_residual_slope` of every pair, into ``f`` and ``fp``."""
    for i in range(len(a)):
        f[i], fp[i] = _residual_slope(a[i], b[i], r[i], leg[i], t[i], wd)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _newton_pass(t, m, x, lo, hi, dx, dx_old, act, a, b, d2, r_res, leg, ex, ey, wd, rtol):  # pragma: no cover
    """One safeguarded Newton step of the first ``m`` pairs, from the arctangents ``t`` of their heading vectors
    (``leg``, ``ex``, ``ey`` at ``x``): eq. 29's residual and slope (:func:`_residual_slope`), the
    step (the numpy form's), then the heading vectors at the new ``x`` (:func:`_heading_vectors`). A converged
    pair's root goes to ``r_res[act[i]]``; the others move to the front of every array, in order. Returns how many
    are left."""
    k = 0
    for i in range(m):
        xi = x[i]
        fi, fpi = _residual_slope(a[i], b[i], xi, leg[i], t[i], wd)
        lo_i, hi_i = lo[i], hi[i]
        if fi > 0:
            lo_i = xi
        else:
            hi_i = xi
        newton = xi - fi / fpi        # fp may be 0: inf/NaN fails the bracket test and bisects instead
        bis = not (newton > lo_i and newton < hi_i) or abs(2.0 * fi) > abs(dx_old[i] * fpi)
        x_new = 0.5 * (lo_i + hi_i) if bis else newton
        dx_i = x_new - xi
        if abs(dx_i) <= rtol * x_new or fi == 0 or hi_i - lo_i <= rtol * hi_i:
            r_res[act[i]] = x_new - dx_i if fi == 0 else x_new
            continue
        x[k], lo[k], hi[k], dx_old[k], dx[k] = x_new, lo_i, hi_i, dx[i], dx_i
        act[k], a[k], b[k], d2[k] = act[i], a[i], b[i], d2[i]
        k += 1
    _heading_vectors(a[:k], b[:k], x[:k], d2[:k], leg, ex, ey)
    return k


def _eq29_at(a, b, x, d2, wd, work):
    """F and F' at ``x`` for every pair (views of ``work`` (5, >= n)): the compiled heading vectors, numpy's
    arctangent, the compiled rest."""
    leg, ex, ey, f, fp = work[:, :len(a)]
    _heading_vectors(a, b, x, d2, leg, ex, ey)
    _residual_and_slope(a, b, x, leg, np.arctan2(ey, ex), wd, f, fp)
    return f, fp


def solve_turn(a, b, d, d2, wd, r_max):
    """Smallest root r of eq. 29 for left-frame goals (b >= 0, not dead ahead). Returns (ok, r).

    All arrays are 1-D of equal length; each iteration works on the still-unconverged entries only.
    """
    n = a.shape[0]
    ok = np.zeros(n, dtype=bool)
    r_out = np.full(n, np.nan)
    idx, lo, hi = root_bracket(a, b, d, d2, wd, r_max)
    if idx.size == 0:
        return ok, r_out
    a, b, d2 = a[idx], b[idx], d2[idx]            # new arrays: _newton_pass compacts them (and lo, hi) in place
    # Safeguarded Newton ("rtsafe"): start at lo, the straight-line estimate, exact for small turns.
    m = idx.size
    x = lo.copy()
    leg, ex, ey, t = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    _heading_vectors(a, b, x, d2, leg, ex, ey)
    dx_old = hi - lo
    dx = dx_old.copy()
    act = np.arange(m)
    r_res = np.full(m, np.nan)
    # Per iteration: numpy's arctangent of the pairs left, then one compiled pass (step, compaction, the next
    # heading vectors).
    for _ in range(_NEWTON_MAX_ITER):
        np.arctan2(ey[:m], ex[:m], out=t[:m])
        m = _newton_pass(t, m, x, lo, hi, dx, dx_old, act, a, b, d2, r_res, leg, ex, ey, wd, _NEWTON_RTOL)
        if m == 0:
            break
    # Anything still unconverged (never seen in practice) stays NaN and is reported infeasible.
    good = np.isfinite(r_res)
    ok[idx[good]] = True
    r_out[idx[good]] = r_res[good]
    return ok, r_out
