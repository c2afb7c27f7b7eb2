"""One slot of B env copies x U UAVs as array operations: controls, flight, rewards, costs, observations, masks.

Pure functions on batch-first arrays ``(B, U, ...)``, no Python loop over copies, UAVs or lattice nodes: the
vector env (:mod:`covert_env.envs.vector`) is a thin state holder around them. They use the model's own
functions (:func:`~covert_env.metrics.moves_quantities`, the manoeuvre solver, the reachability table) with the
batch as their leading axes, and fly with the engine's arithmetic (:func:`fly_unicycle`, :func:`fly_turn_straight`,
:func:`closest_constant_control`: the operations of ``dynamics.unicycle_step`` in the same order, each sine and
cosine computed once per distinct value; tests/test_batch_flight.py checks them against the engine bit for bit),
so a copy computes exactly what the parallel env computes for the same scene, starts and actions. Written with
numpy calls that have direct torch counterparts, so a torch backend is a port.
"""

from __future__ import annotations

import math

import numpy as np

from covert_env.dynamics import solve_manoeuvre

_TWO_PI = 2.0 * math.pi
#: Smallest commanded speed as a fraction of V_max: the unicycle needs v > 0 (eq. 1).
MIN_SPEED_FRACTION = 0.01
#: Offsets in observations are divided by R2 and clipped to this magnitude (500 m at R2 = 100 m).
OFFSET_CLIP = 5.0
#: The reward's terms; ``infos[agent]["reward_<term>"]`` holds each (the parallel env's Rewards section).
REWARD_TERMS = ("path", "disguise", "los", "zone", "separation", "terrain")
#: The constraints of the paper's problem (§2.4); ``infos[agent]["cost_<name>"]`` is 1.0 where the slot violated one.
COSTS = ("los", "zone", "separation", "terrain")

__all__ = ["COSTS", "MIN_SPEED_FRACTION", "OFFSET_CLIP", "REWARD_TERMS", "action_masks", "closest_constant_control",
           "constraint_costs", "fly_turn_straight", "fly_unicycle", "fly_waypoints", "observations", "own_features",
           "reward_terms", "to_world_batch", "unicycle_actions", "unicycle_controls", "waypoint_actions",
           "waypoint_controls"]


def unicycle_actions(actions, shape: tuple[int, int], agents) -> np.ndarray:
    """Box actions (B, U, 2) as floats, checked: numbers, the shape, finite (errors name the copy and agent)."""
    a = np.asarray(actions)
    shape = shape + (2,)
    if a.dtype.kind not in "iuf":
        raise TypeError(f"unicycle actions must be numbers (speed, turn rate) in [-1, 1], got dtype {a.dtype}")
    if a.shape != shape:
        raise ValueError(f"unicycle actions must have shape {shape} (copies, agents, 2), got {a.shape}")
    a = a.astype(float, copy=False)
    bad = ~np.isfinite(a).all(axis=-1)
    if bad.any():
        j, i = np.argwhere(bad)[0]
        raise ValueError(f"action of copy {j}, agent {agents[i]} must be finite, got {a[j, i].tolist()}")
    return a


def waypoint_actions(actions, shape: tuple[int, int], n: int, agents) -> np.ndarray:
    """Lattice indices (B, U) as int64, checked: numbers, the shape, integers in [0, n) (errors name copy, agent)."""
    a = np.asarray(actions)
    if a.dtype.kind not in "iuf":
        raise TypeError(f"waypoint actions must be integers (lattice node indices), got dtype {a.dtype}")
    if a.shape != shape:
        raise ValueError(f"waypoint actions must have shape {shape} (copies, agents), got {a.shape}")
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(a) & (a == np.round(a)) & (a >= 0) & (a < n)
    if not ok.all():
        j, i = np.argwhere(~ok)[0]
        raise ValueError(f"action of copy {j}, agent {agents[i]} must be an integer in "
                         f"[0, {n - 1}], got {a[j, i].item()!r}")
    return a.astype(np.int64)


def unicycle_controls(act: np.ndarray, c) -> tuple[np.ndarray, np.ndarray]:
    """(v, omega) (B, U) from Box(-1, 1) actions (B, U, 2): clipped, then scaled (the parallel env's docstring)."""
    act = np.minimum(np.maximum(act, -1.0), 1.0)
    v = c.v_max * (MIN_SPEED_FRACTION + (1 - MIN_SPEED_FRACTION) * (act[..., 0] + 1) / 2)
    return v, c.w_max * act[..., 1]


def fly_unicycle(xy, theta, v, w, times):
    """Path samples (B, U, P, 2) at ``times`` (P,) and end headings (B, U) for controls held for the slot.

    The arithmetic of :func:`~covert_env.dynamics.unicycle_step` (so the samples are the engine's, bit for bit),
    with the heading wrapped only at the slot's end and the exact start as sample 0."""
    dt = times[1:]
    # In place where possible (the arrays are B U P: at B = 1024 every temporary spills the cache); each value is
    # computed with the operations, operands and order of unicycle_step, so the results are the same bits.
    half = (0.5 * w)[..., None] * dt                                   # (B, U, P-1)
    straight = half == 0.0
    safe = np.where(straight, 1.0, half)
    ratio = np.sin(safe)
    ratio /= safe
    ratio[straight] = 1.0
    chord = v[..., None] * dt
    chord *= ratio
    mid = np.add(theta[..., None], half, out=half)
    path = np.empty(theta.shape + (len(times), 2))
    path[..., 0, :] = xy
    out_x, out_y = path[..., 1:, 0], path[..., 1:, 1]
    np.cos(mid, out=out_x)
    out_x *= chord
    out_x += xy[..., 0, None]
    np.sin(mid, out=out_y)
    out_y *= chord
    out_y += xy[..., 1, None]
    end = np.mod(theta + w * times[-1], _TWO_PI)
    return path, np.where(end >= _TWO_PI, 0.0, end)


def fly_waypoints(xy, theta, goals, c, times):
    """The turn-then-straight manoeuvre to ``goals`` (B, U, 2) (best effort where unreachable, see
    :func:`waypoint_controls`), flown by :func:`fly_turn_straight`.

    Returns path samples (B, U, P, 2), end headings (B, U), speeds v (B, U) and the fallback flags (B, U)."""
    shape = theta.shape
    v, w, t_turn, fallback = waypoint_controls(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), c)
    v, w, t_turn = v.reshape(shape), w.reshape(shape), t_turn.reshape(shape)
    path, end_theta = fly_turn_straight(xy, theta, v, w, t_turn, times)
    return path, end_theta, v, fallback.reshape(shape)


def waypoint_controls(xy, theta, goals, c):
    """Manoeuvre controls (v, omega, turn time) from (K, 2) poses to (K, 2) goals, and the fallback flags (K,).

    ``solve_manoeuvre`` (eqs. 22-29) where the goal is reachable in one slot; elsewhere the best effort of
    :func:`closest_constant_control`, held for the whole slot. The engine's rule, value for value."""
    if not np.all(np.isfinite(goals)):
        raise ValueError("Engine.step: waypoints must be finite (got NaN or inf)")
    m = solve_manoeuvre(xy, theta, goals, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    feasible = np.asarray(m.feasible, bool).reshape(-1)
    # The engine's np.where(feasible, np.nan_to_num(.), 0.0): a feasible manoeuvre's numbers are finite.
    v = np.where(feasible, m.v, 0.0)
    w = np.where(feasible, m.omega, 0.0)
    t_turn = np.where(feasible, m.turn_time, 0.0)
    bad = ~feasible
    if bad.any():
        v[bad], w[bad] = closest_constant_control(xy[bad], theta[bad], goals[bad], c)
        t_turn[bad] = c.delta
    return v, w, t_turn, bad


def closest_constant_control(xy, theta, goals, c):
    """Best effort for unreachable waypoints: the admissible constant (v, omega) whose exact end point
    (:func:`~covert_env.dynamics.unicycle_step` over the slot) lies closest to the waypoint, on a 17 x 17 grid
    refined twice around the best; (K,) each for (K, 2) poses and goals.

    The arc's turn-dependent factors (sin(omega delta / 2) / (omega delta / 2) and the chord's direction) are
    computed once per grid omega, not once per (v, omega) pair: the same operations on the same operands as
    ``unicycle_step``, so the same end points, 17 times fewer sines and cosines."""
    n = len(goals)
    x0, y0, th0 = xy[:, 0, None, None], xy[:, 1, None, None], theta[:, None, None]
    gx, gy = goals[:, 0, None, None], goals[:, 1, None, None]
    lo_v, hi_v = np.full(n, 0.01 * c.v_max), np.full(n, c.v_max)
    lo_w, hi_w = np.full(n, -c.w_max), np.full(n, c.w_max)
    f = np.linspace(0.0, 1.0, 17)
    rows = np.arange(n)
    for _ in range(3):
        gv = lo_v[:, None] + (hi_v - lo_v)[:, None] * f                   # (K, 17): grid speeds
        gw = lo_w[:, None] + (hi_w - lo_w)[:, None] * f                   # (K, 17): grid turn rates
        half = 0.5 * gw[:, None, :] * c.delta                              # (K, 1, 17)
        straight = half == 0.0
        safe = np.where(straight, 1.0, half)
        chord = gv[:, :, None] * c.delta * np.where(straight, 1.0, np.sin(safe) / safe)    # (K, 17, 17)
        mid = th0 + half
        dx = x0 + chord * np.cos(mid) - gx
        dy = y0 + chord * np.sin(mid) - gy
        best = np.argmin((dx ** 2 + dy ** 2).reshape(n, -1), axis=1)      # v major, omega minor
        bv, bw = gv[rows, best // 17], gw[rows, best % 17]
        dv, dw = (hi_v - lo_v) / 16, (hi_w - lo_w) / 16
        lo_v, hi_v = np.maximum(bv - dv, 0.01 * c.v_max), np.minimum(bv + dv, c.v_max)
        lo_w, hi_w = np.maximum(bw - dw, -c.w_max), np.minimum(bw + dw, c.w_max)
    return bv, bw


def fly_turn_straight(xy, theta, v, w, t_turn, times):
    """Turn at (v, w) for ``t_turn``, then straight at v: path samples (B, U, P, 2) at ``times`` (P,) from poses
    (B, U), and the end headings (B, U) in [0, 2 pi).

    Two :func:`~covert_env.dynamics.unicycle_step` arcs per sample, as the engine flies them, with the same
    operations on the same operands (the same bits), but each sine and cosine computed once per distinct
    value: after the turn every sample shares the turn's end pose and the straight leg's heading, and before it
    the straight leg has length 0. Sample 0 is the exact start."""
    p = len(times)
    t = times[1:]                                                          # (P-1,)
    tt = t_turn[..., None]
    path = np.empty(theta.shape + (p, 2))
    path[..., 0, :] = xy
    # The turn's end (t >= t_turn): one pose per UAV, shared by the later samples.
    t1_end = np.minimum(times[-1], t_turn)
    x1e, y1e = _arc(xy[..., 0], xy[..., 1], theta, v, w, t1_end)
    th1e = _wrap(theta + w * t1_end)
    # The straight leg from there: heading th1e (+ 0.5 * 0.0 * t2 = 0), length v * t2 (* 1.0).
    mid2 = th1e + 0.0
    c2, s2 = np.cos(mid2), np.sin(mid2)
    t2 = np.maximum(t - tt, 0.0)                                           # (B, U, P-1)
    chord2 = v[..., None] * t2
    # During the turn (t < t_turn): each sample its own point of the arc; the straight leg adds 0.
    x1 = np.broadcast_to(x1e[..., None], t2.shape).copy()
    y1 = np.broadcast_to(y1e[..., None], t2.shape).copy()
    turning = t < tt
    if turning.any():
        bu, j = np.nonzero(turning.reshape(-1, p - 1))
        x1.reshape(-1, p - 1)[bu, j], y1.reshape(-1, p - 1)[bu, j] = _arc(
            xy[..., 0].reshape(-1)[bu], xy[..., 1].reshape(-1)[bu], theta.reshape(-1)[bu], v.reshape(-1)[bu],
            w.reshape(-1)[bu], t[j])
    np.multiply(chord2, c2[..., None], out=path[..., 1:, 0])
    path[..., 1:, 0] += x1
    np.multiply(chord2, s2[..., None], out=path[..., 1:, 1])
    path[..., 1:, 1] += y1
    return path, _wrap(th1e + 0.0 * t2[..., -1])


def _arc(x, y, theta, v, w, dt):
    """End point of :func:`~covert_env.dynamics.unicycle_step` (the same operations in the same order)."""
    half = 0.5 * w * dt
    straight = half == 0.0
    safe = np.where(straight, 1.0, half)
    chord = v * dt * np.where(straight, 1.0, np.sin(safe) / safe)
    mid = theta + half
    return x + chord * np.cos(mid), y + chord * np.sin(mid)


def _wrap(a):
    """Into [0, 2 pi), as ``dynamics._wrap_2pi``: ``np.mod`` can return exactly 2 pi for tiny negative input."""
    w = np.mod(a, _TWO_PI)
    return np.where(w >= _TWO_PI, 0.0, w)


def to_world_batch(offsets, q_xy, phi) -> np.ndarray:
    """World positions of target-frame ``offsets`` (B, ..., 2) for targets q_xy (B, 2), phi (B,): q + R(phi) o
    (the same arithmetic as :func:`covert_env.zone.to_world`, one target per copy)."""
    extra = (None,) * (offsets.ndim - 2)
    c, s = np.cos(phi)[(slice(None),) + extra], np.sin(phi)[(slice(None),) + extra]
    x = q_xy[(slice(None),) + extra + (0,)] + c * offsets[..., 0] - s * offsets[..., 1]
    y = q_xy[(slice(None),) + extra + (1,)] + s * offsets[..., 0] + c * offsets[..., 1]
    return np.stack([x, y], axis=-1)


def action_masks(xy, theta, q_xy, phi, lattice, visible, table) -> np.ndarray:
    """Waypoint masks (B, U, L) int8: the ``lattice`` nodes (L, 2) placed at the targets q_xy (B, 2), phi (B,) of
    slot k+1, reachable in one slot from the poses (B, U) (``table``: the config's
    :class:`~covert_env.reach.ReachTable`, exactly ``solve_manoeuvre``'s answer) and ``visible`` (B, L) there;
    where no node qualifies the reachable ones, and where none is reachable all."""
    reach = table.reachable(xy, theta, q_xy, phi, lattice)
    mask = reach & visible[:, None, :]
    empty = ~mask.any(axis=-1)
    if empty.any():                                   # rare: fix those rows only
        rows = reach[empty]
        mask[empty] = np.where(rows.any(axis=-1, keepdims=True), rows, True)
    return mask.view(np.int8)


def constraint_costs(quant, c) -> np.ndarray:
    """(4, B, U) float 0/1 violations in the order of ``COSTS``: LoS, zone, separation,
    terrain (its Constraint Costs table)."""
    costs = np.empty((len(COSTS),) + quant.los.shape)
    np.logical_not(quant.los, out=costs[0])
    np.logical_not(quant.in_zone, out=costs[1])
    np.less(quant.separation_path, c.d_safe1, out=costs[2])
    np.less(quant.terrain_clearance, c.d_safe2, out=costs[3])
    return costs


def reward_terms(quant, costs, c, scale, p: dict) -> np.ndarray:
    """(6, B, U) reward terms in the order of ``REWARD_TERMS`` (the parallel env's Rewards section); ``scale`` and
    the penalties ``p`` are numbers, or (B, 1) arrays when copies have their own."""
    outside = np.maximum(quant.zone_distance, 0.0) / (c.r2 - c.r1)
    cols = np.empty((len(REWARD_TERMS),) + outside.shape)
    np.divide(quant.path_length, -scale, out=cols[0])
    np.multiply(quant.kappa, c.lam, out=cols[1])
    cols[1] /= scale
    np.multiply(costs[0], -p["los"], out=cols[2])
    cols[3] = np.minimum(outside, 2.0) + 1.0
    cols[3] *= costs[1]
    cols[3] *= -p["zone"]
    np.multiply(costs[2], -p["separation"], out=cols[4])
    np.multiply(costs[3], -p["terrain"], out=cols[5])
    return cols


def own_features(xy, theta, q, phi, speed, los, zone_dist, c) -> np.ndarray:
    """(B, U, 8) per-UAV features 0-7 of the observation table, targets q (B, 3), phi (B,)."""
    cs, sn = np.cos(phi)[:, None], np.sin(phi)[:, None]
    dx, dy = xy[..., 0] - q[:, 0, None], xy[..., 1] - q[:, 1, None]
    f = np.empty(theta.shape + (8,))
    f[..., 0] = (cs * dx + sn * dy) / c.r2
    f[..., 1] = (cs * dy - sn * dx) / c.r2
    np.minimum(np.maximum(f[..., :2], -OFFSET_CLIP), OFFSET_CLIP, out=f[..., :2])
    dth = theta - phi[:, None]
    f[..., 2] = np.cos(dth)
    f[..., 3] = np.sin(dth)
    f[..., 4] = np.minimum(speed / c.v_max, 1.0)
    f[..., 5] = los
    f[..., 6] = zone_dist <= 0
    f[..., 7] = np.minimum(np.maximum(zone_dist / (c.r2 - c.r1), -OFFSET_CLIP), OFFSET_CLIP)
    return f


def observations(own, shared, remaining, mates) -> np.ndarray:
    """(B, U, D) float32 rows: own features (B, U, 8), shared blocks (B, 3 + 2 S^2), time remaining (B,) and
    ``mates`` (U, U-1), the teammates of each agent by index."""
    n, u = own.shape[:2]
    n_own, n_mate = 8, 2 * (u - 1)
    rows = np.empty((n, u, n_own + shared.shape[1] + n_mate), np.float32)
    rows[..., :n_own] = own
    rows[..., n_own:n_own + 3] = shared[:, None, :3]
    rows[..., n_own + 2] = remaining[:, None]
    rows[..., n_own + 3:n_own + 3 + n_mate] = own[:, mates, :2].reshape(n, u, -1)
    rows[..., n_own + 3 + n_mate:] = shared[:, None, 3:]
    return rows
