"""Flight over one slot, batch-first: controls from waypoints, and the path flown, for poses of any leading shape.

The engine (one scene) and the vector env (B scenes) fly their UAVs with these functions, so both fly the same
arithmetic. :func:`fly_arc` (a control held for the slot) flies eq. 1 through
:func:`~covert_env.geometry.dynamics.unicycle_arc`; :func:`fly_turn_straight` (the manoeuvre) and
:func:`closest_constant_control` (the fallback's grid search) are compiled loops with unicycle_arc's arithmetic
(the turn's samples by :func:`~covert_env.geometry.dynamics.arc_point`). Each computes a sine and cosine once per
distinct value (tests/test_batch_flight.py checks them against the plain per-sample integration, bit for bit).
A UAV's move over a slot is either a unicycle control (v, omega) held for the whole slot (eq. 1, integrated
exactly) or the turn-then-straight manoeuvre to a waypoint (eqs. 22-29); a waypoint the manoeuvre cannot reach is
flown as the closest admissible constant control and flagged (see :mod:`covert_env.world.engine`).
"""

from __future__ import annotations

import warnings

import numba
import numpy as np

from covert_env.geometry.angles import TWO_PI, wrap_heading
from covert_env.geometry.dynamics import arc_point, manoeuvre_controls, unicycle_arc, unicycle_heading

__all__ = ["HEADING_GRID", "POSITION_GRID", "check_unicycle", "closest_constant_control", "fly_arc",
           "fly_turn_straight", "fly_waypoints", "settle_pose", "waypoint_controls"]

if numba.config.USING_SVML:                     # numba was imported before covert_env, with SVML installed
    warnings.warn("numba uses Intel's SVML here (NUMBA_DISABLE_INTEL_SVML unset when numba was first imported): the "
                  "compiled flights' sines may differ from numpy's in the last bit; import covert_env first or set "
                  "NUMBA_DISABLE_INTEL_SVML=1", RuntimeWarning, stacklevel=2)

#: The grids a UAV's pose is settled on at every slot end (docs/decisions/flight.md#settled-slot-end-poses): positions
#: (m) and headings (rad). Powers of two, so that settling is exact arithmetic.
POSITION_GRID = 2.0 ** -20
HEADING_GRID = 2.0 ** -24


def check_unicycle(ctl: np.ndarray, c) -> None:
    v, w = ctl[..., 0], ctl[..., 1]
    # One combined test on the hot path (NaN fails every comparison); the messages below find the culprit.
    if (np.all(v > 0) and np.all(v <= c.v_max * (1 + 1e-9)) and np.all(np.abs(w) <= c.w_max * (1 + 1e-9))):
        return
    if not np.all(np.isfinite(ctl)):
        raise ValueError("Engine.step: unicycle controls must be finite (got NaN or inf)")
    if np.any(v <= 0) or np.any(v > c.v_max * (1 + 1e-9)):
        raise ValueError(f"Engine.step: speed v must be in (0, V_max={c.v_max:g}], got {v.tolist()}")
    if np.any(np.abs(w) > c.w_max * (1 + 1e-9)):
        raise ValueError(f"Engine.step: turn rate omega must be in [-W_max, W_max] = "
                         f"[{-c.w_max:g}, {c.w_max:g}], got {w.tolist()}")


def fly_arc(xy, theta, v, w, times):
    """Path samples (B, U, P, 2) at ``times`` (P,) and end headings (B, U) in [0, 2 pi) for controls held for the
    slot: :func:`~covert_env.geometry.dynamics.unicycle_arc` per sample, written into the path in place (the arrays are
    B U P: at B = 1024 every temporary spills the cache), with the exact start as sample 0."""
    path = np.empty(theta.shape + (len(times), 2))
    path[..., 0, :] = xy
    unicycle_arc(xy[..., 0, None], xy[..., 1, None], theta[..., None], v[..., None], w[..., None], times[1:],
                 out=(path[..., 1:, 0], path[..., 1:, 1]), heading=False)
    return settle_pose(path, unicycle_heading(theta, w, times[-1]))


def settle_pose(path, end_theta):
    """The slot's end pose settled on :data:`POSITION_GRID` and :data:`HEADING_GRID`: rounds ``path[..., -1, :]``
    in place and returns ``(path, end headings)``, each a multiple of the grid in [0, 2 pi).

    A waypoint flight maps a start heading to an end heading with a gain of a few per slot, so a last-bit
    difference in a sine or an arctangent (numpy's float64 ``arctan2``, ``exp`` and ``arccos`` differ by an ulp
    between CPUs with and without AVX-512) would grow to centimetres within about thirty slots and change
    decisions. Rounding the carried pose to about a micrometre and 6e-8 rad removes that difference at every slot
    end unless it straddles a grid boundary (none of 200,000 manoeuvres whose start heading was one ulp off)."""
    end = path[..., -1, :]
    np.multiply(np.rint(end * (1.0 / POSITION_GRID)), POSITION_GRID, out=end)
    heading = np.rint(wrap_heading(end_theta) * (1.0 / HEADING_GRID)) * HEADING_GRID
    return path, np.where(heading >= TWO_PI, 0.0, heading)          # 2 pi rounds up onto the grid: that is 0


def waypoint_controls(xy, theta, goals, c):
    """Manoeuvre controls (v, omega, turn time) from (K, 2) poses to (K, 2) goals, and the fallback flags (K,).

    ``solve_manoeuvre``'s controls (eqs. 22-29, :func:`~covert_env.geometry.dynamics.manoeuvre_controls`) where the
    goal is reachable in one slot; elsewhere the best effort of
    :func:`closest_constant_control`, held for the whole slot. The engine's rule, value for value."""
    if not np.all(np.isfinite(goals)):
        raise ValueError("Engine.step: waypoints must be finite (got NaN or inf)")
    feasible, v, w, t_turn = manoeuvre_controls(np.asarray(xy, float), np.asarray(theta, float),
                                                np.asarray(goals, float), v_max=c.v_max, w_max=c.w_max,
                                                delta=c.delta)
    # The engine's np.where(feasible, np.nan_to_num(.), 0.0): a feasible manoeuvre's numbers are finite.
    v = np.where(feasible, v, 0.0)
    w = np.where(feasible, w, 0.0)
    t_turn = np.where(feasible, t_turn, 0.0)
    bad = ~feasible
    if bad.any():
        v[bad], w[bad] = closest_constant_control(xy[bad], theta[bad], goals[bad], c)
        t_turn[bad] = c.delta
    return v, w, t_turn, bad


def closest_constant_control(xy, theta, goals, c):
    """Best effort for unreachable waypoints: the admissible constant (v, omega) whose exact end point
    (:func:`~covert_env.geometry.dynamics.unicycle_arc` over the slot) lies closest to the waypoint, on a 17 x 17 grid
    refined twice around the best (the first of equals, speed major); (K,) each for (K, 2) poses and goals.

    One compiled pass per pose (:func:`_grid_search`): the arc's turn-dependent factors once per grid omega, then
    unicycle_arc's arithmetic per (v, omega) pair, the C library's sines as numpy's float64 ones are
    (tests/test_batch_flight.py checks it against the plain grid search, bit for bit)."""
    xy, goals = np.asarray(xy, float).reshape(-1, 2), np.asarray(goals, float).reshape(-1, 2)
    theta = np.asarray(theta, float).reshape(-1)
    v, w = np.empty(len(theta)), np.empty(len(theta))
    _grid_search(np.ascontiguousarray(xy), np.ascontiguousarray(theta), np.ascontiguousarray(goals),
                 float(c.v_max), float(c.w_max), float(c.delta), np.linspace(0.0, 1.0, 17), v, w)
    return v, w


@numba.njit(cache=True, nogil=True)
def _grid_search(xy, theta, goals, v_max, w_max, delta, f, out_v, out_w):  # pragma: no cover
    """:func:`closest_constant_control`'s search: for each pose, three rounds of the 17 x 17 grid of speeds (major)
    and turn rates in the current box, the box shrunk to one grid step around the best each round."""
    n = len(f)
    ratio, mid_c, mid_s = np.empty(n), np.empty(n), np.empty(n)
    gv, gw = np.empty(n), np.empty(n)
    for k in range(len(theta)):
        x0, y0, th0, gx, gy = xy[k, 0], xy[k, 1], theta[k], goals[k, 0], goals[k, 1]
        lo_v, hi_v, lo_w, hi_w = 0.01 * v_max, v_max, -w_max, w_max
        bv, bw = 0.0, 0.0
        for _ in range(3):
            for q in range(n):
                gv[q] = lo_v + (hi_v - lo_v) * f[q]
                gw[q] = lo_w + (hi_w - lo_w) * f[q]
                half = 0.5 * gw[q] * delta
                ratio[q] = 1.0 if half == 0.0 else np.sin(half) / half
                mid = half + th0
                mid_c[q], mid_s[q] = np.cos(mid), np.sin(mid)
            best, best_d = 0, np.inf
            for a in range(n):
                vd = gv[a] * delta
                for b in range(n):
                    chord = vd * ratio[b]
                    dx = (x0 + chord * mid_c[b]) - gx
                    dy = (y0 + chord * mid_s[b]) - gy
                    d = dx * dx + dy * dy
                    if best_d == best_d and (d < best_d or d != d):     # np.argmin: the first NaN, if any
                        best, best_d = a * n + b, d
            bv, bw = gv[best // n], gw[best % n]
            dv, dw = (hi_v - lo_v) / 16, (hi_w - lo_w) / 16
            lo_v, hi_v = max(bv - dv, 0.01 * v_max), min(bv + dv, v_max)
            lo_w, hi_w = max(bw - dw, -w_max), min(bw + dw, w_max)
        out_v[k], out_w[k] = bv, bw


def fly_turn_straight(xy, theta, v, w, t_turn, times):
    """Turn at (v, w) for ``t_turn``, then straight at v: path samples (B, U, P, 2) at ``times`` (P,) from poses
    (B, U), and the end headings (B, U) in [0, 2 pi).

    Two :func:`~covert_env.geometry.dynamics.unicycle_arc` legs per sample, as the engine flies them: the turn's end
    pose once per UAV (numpy), then every sample in one compiled pass (:func:`_turn_straight_samples`, the turn's
    points by :func:`~covert_env.geometry.dynamics.arc_point`: tests/test_batch_flight.py checks the bits). After
    the turn every sample shares the turn's end pose and the straight leg's heading, and before it the straight leg
    has length 0. Sample 0 is the exact start."""
    shape = np.shape(theta)
    times = np.ascontiguousarray(times, float)
    # The turn's end (t >= t_turn): one pose per UAV, shared by the later samples.
    x1e, y1e, th1e = unicycle_arc(xy[..., 0], xy[..., 1], theta, v, w, np.minimum(times[-1], t_turn))
    th1e = wrap_heading(th1e)
    path = np.empty(shape + (len(times), 2))
    _turn_straight_samples(*(_flat(a, shape) for a in (xy, theta, v, w, t_turn, x1e, y1e, th1e)), times,
                           path.reshape(-1, len(times), 2))
    return settle_pose(path, unicycle_heading(th1e, 0.0, np.maximum(times[-1] - t_turn, 0.0)))


def _flat(a, shape) -> np.ndarray:
    """``a`` (``shape``, or ``shape`` + (2,) for positions) as a contiguous float array with one leading axis."""
    a = np.asarray(a, float)
    lead = a.shape[:len(shape)]
    if lead != shape:
        a = np.broadcast_to(a, shape + a.shape[len(shape):])
    return np.ascontiguousarray(a).reshape((-1,) + a.shape[len(shape):])


@numba.njit(cache=True, nogil=True)
def _turn_straight_samples(xy, th0, v, w, t_turn, x1e, y1e, th1e, times, path):  # pragma: no cover
    """The samples of :func:`fly_turn_straight`, flight by flight: ``unicycle_arc(*xy, th0, v, w, t)`` while
    ``t < t_turn``, the turn's end (x1e, y1e) after; then ``unicycle_arc(., ., th1e, v, 0.0, max(t - t_turn, 0))``
    from there: ``cos(th1e + 0.0) * (v t2) + x1``, the products and sums in unicycle_arc's order."""
    for i in range(len(th0)):
        xi, yi, ti, vi, wi, tt = xy[i, 0], xy[i, 1], th0[i], v[i], w[i], t_turn[i]
        mid_s = th1e[i] + 0.0
        cs, sn = np.cos(mid_s), np.sin(mid_s)
        path[i, 0, 0], path[i, 0, 1] = xi, yi
        for j in range(1, len(times)):
            t = times[j]
            if t < tt:                                   # in the turn: the arc's own point at t
                x1, y1 = arc_point(xi, yi, ti, vi, wi, t)
            else:
                x1, y1 = x1e[i], y1e[i]
            t2 = t - tt
            if t2 < 0.0:                                 # np.maximum(t - t_turn, 0.0): NaN stays NaN
                t2 = 0.0
            chord2 = vi * t2
            path[i, j, 0] = cs * chord2 + x1
            path[i, j, 1] = sn * chord2 + y1


def fly_waypoints(xy, theta, goals, c, times):
    """The turn-then-straight manoeuvre to ``goals`` (B, U, 2) (best effort where unreachable, see
    :func:`waypoint_controls`), flown by :func:`fly_turn_straight`.

    Returns path samples (B, U, P, 2), end headings (B, U), speeds v (B, U), the fallback flags (B, U) and the
    turn rates omega (B, U)."""
    shape = theta.shape
    v, w, t_turn, fallback = waypoint_controls(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), c)
    v, w, t_turn = v.reshape(shape), w.reshape(shape), t_turn.reshape(shape)
    path, end_theta = fly_turn_straight(xy, theta, v, w, t_turn, times)
    return path, end_theta, v, fallback.reshape(shape), w
