"""Flight over one slot, batch-first: controls from waypoints, and the path flown, for poses of any leading shape.

The engine (one scene) and the vector env (B scenes) fly their UAVs with these functions, so both fly the same
arithmetic. A UAV's move over a slot is either a unicycle control (v, omega) held for the whole slot (eq. 1,
integrated exactly) or the turn-then-straight manoeuvre to a waypoint (eqs. 22-29); a waypoint the manoeuvre cannot
reach is flown as the closest admissible constant control and flagged (see :mod:`covert_env.engine`).
"""

from __future__ import annotations

import numpy as np

from covert_env.dynamics import solve_manoeuvre, unicycle_step

__all__ = ["check_unicycle", "closest_constant_control", "fly", "waypoint_controls"]


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


def waypoint_controls(xy, theta, goals, c):
    """Manoeuvre controls (v, omega, turn time) per UAV from (K, 2) poses to (K, 2) goals, with the
    best-effort fallback; returns them and the fallback flags, each (K,)."""
    if not np.all(np.isfinite(goals)):
        raise ValueError("Engine.step: waypoints must be finite (got NaN or inf)")
    m = solve_manoeuvre(xy, theta, goals, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    feasible = np.asarray(m.feasible, bool).reshape(-1)
    v = np.where(feasible, np.nan_to_num(m.v), 0.0)
    w = np.where(feasible, np.nan_to_num(m.omega), 0.0)
    t_turn = np.where(feasible, np.nan_to_num(m.turn_time), 0.0)
    bad = ~feasible
    if bad.any():
        v[bad], w[bad] = closest_constant_control(xy[bad], theta[bad], goals[bad], c)
        t_turn[bad] = c.delta
    return v, w, t_turn, bad


def closest_constant_control(xy, theta, goals, c):
    """Best effort for unreachable waypoints: the admissible constant (v, omega) whose exact end
    point lies closest to the waypoint, found on a 17 x 17 grid refined twice around the best."""
    x0, y0, th0 = xy[:, 0, None], xy[:, 1, None], theta[:, None]
    lo_v, hi_v = np.full(len(goals), 0.01 * c.v_max), np.full(len(goals), c.v_max)
    lo_w, hi_w = np.full(len(goals), -c.w_max), np.full(len(goals), c.w_max)
    f = np.linspace(0.0, 1.0, 17)
    for _ in range(3):
        gv = (lo_v[:, None] + (hi_v - lo_v)[:, None] * f)[:, :, None] * np.ones(17)       # (B, 17, 17)
        gw = (lo_w[:, None] + (hi_w - lo_w)[:, None] * f)[:, None, :] * np.ones((17, 1))
        gv, gw = gv.reshape(len(goals), -1), gw.reshape(len(goals), -1)
        x, y, _ = unicycle_step(x0, y0, th0, gv, gw, c.delta)
        best = np.argmin((x - goals[:, :1]) ** 2 + (y - goals[:, 1:]) ** 2, axis=1)
        bv, bw = gv[np.arange(len(goals)), best], gw[np.arange(len(goals)), best]
        dv, dw = (hi_v - lo_v) / 16, (hi_w - lo_w) / 16
        lo_v, hi_v = np.maximum(bv - dv, 0.01 * c.v_max), np.minimum(bv + dv, c.v_max)
        lo_w, hi_w = np.maximum(bw - dw, -c.w_max), np.minimum(bw + dw, c.w_max)
    return bv, bw


def fly(xy, theta, v, w, t_turn, t):
    """Integrate turn (v, w) for t_turn then straight (v, 0) from poses (..., U): path samples at the
    times ``t`` (P,) as (..., U, P, 2), and the end heading (..., U)."""
    t = t.reshape((-1,) + (1,) * theta.ndim)                          # (P, 1, ...)
    if t_turn is None or (t_turn >= t[-1]).all():                     # one constant control: one arc
        x2, y2, th2 = unicycle_step(xy[..., 0], xy[..., 1], theta, v, w, t)
    else:
        t1 = np.minimum(t, t_turn)
        t2 = np.maximum(t - t_turn, 0.0)
        x1, y1, th1 = unicycle_step(xy[..., 0], xy[..., 1], theta, v, w, t1)
        x2, y2, th2 = unicycle_step(x1, y1, th1, v, 0.0, t2)
    path = np.empty(x2.shape[1:] + x2.shape[:1] + (2,))               # (..., U, P, 2)
    path[..., 0] = np.moveaxis(x2, 0, -1)
    path[..., 1] = np.moveaxis(y2, 0, -1)
    path[..., 0, :] = xy                                              # exact start, no round-off
    return path, th2[-1]
