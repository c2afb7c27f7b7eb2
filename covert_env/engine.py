"""The world: terrain, the target on its road, and the UAV team, advanced one slot at a time.

The engine is the single place where physics happens. Environments, the DP planner and the
evaluation harness all drive an :class:`Engine`, so a DP rollout and an env rollout are the same
thing, and every episode ends as a :class:`~covert_env.trajectory.Trajectory` that
:mod:`covert_env.metrics` scores.

Each UAV's move over a slot is either

* a unicycle control (v, omega) held for the whole slot (eq. 1, integrated exactly), or
* a waypoint, flown by the turn-then-straight manoeuvre (eqs. 22-29): a turn at +-W_max then a
  straight leg, at one constant speed, ending on the waypoint at the end of the slot.

A waypoint the manoeuvre cannot reach in one slot (inside the turning circle, or needing v > V_max)
is flown as a documented best effort instead: the constant admissible control (v, omega) whose end
point lies closest to the waypoint (a 17 x 17 grid search, refined twice). The slot is flagged ``infeasible``.
"""

from __future__ import annotations

import math

import numpy as np

from covert_env.config import MAX_N_UAVS
from covert_env.dynamics import solve_manoeuvre, unicycle_step
from covert_env.metrics import SlotQuantities, moves_quantities
from covert_env.scenario import Scenario
from covert_env.trajectory import Trajectory
from covert_env.visibility import TerrainStack

__all__ = ["Engine", "MAX_PATH_SAMPLES", "step_engines"]


class Engine:
    """Advance a :class:`Scenario` slot by slot and record the episode.

    Args:
        scenario: the world and the start poses (a :class:`Scenario`; TypeError otherwise).
        path_samples: samples per slot along each path (endpoints included), used for LoS and
            separation checks between slot times: an integer in [2, 1000] (``MAX_PATH_SAMPLES``).
        path_los: a bool, whether :meth:`step`'s quantities include LoS along the path (environments turn it
            off for speed; the episode metrics compute it from the trajectory in any case).
    """

    def __init__(self, scenario: Scenario, path_samples: int = 11, path_los: bool = True):
        if not isinstance(scenario, Scenario):
            raise TypeError(f"Engine: scenario must be a Scenario (e.g. Scenario.paper() or Scenario.random(seed)), "
                            f"got {_short(scenario)} ({type(scenario).__name__})")
        if (isinstance(path_samples, bool) or not isinstance(path_samples, (int, np.integer))
                or not 2 <= path_samples <= MAX_PATH_SAMPLES):
            raise ValueError(f"Engine.path_samples must be an integer in [2, {MAX_PATH_SAMPLES}], got "
                             f"{_short(path_samples)} ({type(path_samples).__name__})")
        if not isinstance(path_los, (bool, np.bool_)):
            raise TypeError(f"Engine.path_los must be a bool, got {_short(path_los)} ({type(path_los).__name__})")
        self.scenario = scenario
        self.config = scenario.config
        self.terrain = scenario.terrain
        self.track = scenario.track
        self.path_samples = int(path_samples)
        self.path_los = bool(path_los)
        self._fractions = np.linspace(0.0, 1.0, self.path_samples)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self, uav_xy=None, uav_theta=None) -> None:
        """Put the target at slot 0 and the UAVs at ``uav_xy``/``uav_theta`` (default: the scenario's).

        ``uav_xy``: (U, 2) finite positions, ``uav_theta``: (U,) finite headings (rad); ValueError otherwise."""
        try:
            xy = self.scenario.uav_xy if uav_xy is None else np.asarray(uav_xy, dtype=float).reshape(-1, 2)
            th = self.scenario.uav_theta if uav_theta is None else np.asarray(uav_theta, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"Engine.reset: uav_xy must be a (U, 2) array of numbers and uav_theta a (U,) array, "
                             f"got {_short(uav_xy)} and {_short(uav_theta)}") from None
        if len(xy) != len(th):
            raise ValueError(f"Engine.reset: {len(xy)} positions (uav_xy) but {len(th)} headings (uav_theta)")
        if not (np.isfinite(xy).all() and np.isfinite(th).all()):
            raise ValueError(f"Engine.reset: uav_xy positions and uav_theta headings must be finite (no NaN or inf), "
                             f"got {_short(xy.tolist())} and {_short(th.tolist())}")
        if not 1 <= len(xy) <= MAX_N_UAVS:
            raise ValueError(f"Engine.reset: the team must have 1 to {MAX_N_UAVS} UAVs, got {len(xy)}")
        self.k = 0
        self.uav_xy = xy.copy()
        self.uav_theta = np.mod(th, 2 * math.pi)
        u = len(xy)
        self._xy = [self.uav_xy.copy()]
        self._theta = [self.uav_theta.copy()]
        self._path: list[np.ndarray] = []
        self._length: list[np.ndarray] = []
        self._vmax: list[np.ndarray] = []
        self._wmax: list[np.ndarray] = []
        self._infeasible: list[np.ndarray] = []
        self._dtime: list[np.ndarray | None] = []
        self.n_uavs = u

    @property
    def done(self) -> bool:
        """True once the episode's ``config.n_slots`` slots have been flown."""
        return self.k >= self.config.n_slots

    @property
    def target_xyz(self) -> np.ndarray:
        """q[k], the target's current position (x, y, z)."""
        return self.track.position(self.k)

    @property
    def target_phi(self) -> float:
        """phi[k], the target's current heading."""
        return float(self.track.heading(self.k))

    def predict(self, horizon: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Predicted target (positions (N, 3), headings (N,)) for slots k+1..k+N (N = config.horizon)."""
        return self.track.predict(self.k, self.config.horizon if horizon is None else horizon)

    # ------------------------------------------------------------------ stepping
    def step(self, *, unicycle=None, waypoints=None, decision_time=None, infeasible=None) -> SlotQuantities:
        """Fly one slot and return its :class:`SlotQuantities` (arrays of shape (1, U)).

        Exactly one of:
            unicycle: (U, 2) array of (v, omega); requires 0 < v <= V_max and |omega| <= W_max.
            waypoints: (U, 2) array of next positions, flown by the manoeuvre.
        Optional:
            decision_time: (U,) seconds the policy spent deciding (recorded for the metrics).
            infeasible: (U,) bool, the policy's own flag that its move is a fallback.
        """
        u = self.n_uavs

        def one(a, shape, name, dtype=float):
            if a is None:
                return None
            try:
                arr = np.asarray(a)
                ok = arr.dtype.kind in ("biuf" if dtype is bool else "iuf")     # no strings, no bools as numbers
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise TypeError(f"Engine.step: {name} must be a {_shape_text(shape)} array of numbers (U = {u} UAVs), "
                                f"got {_short(a)} ({type(a).__name__})")
            # The size and the last axis must match: a (3, 2) array reshaped from (2, 3) would scramble UAVs.
            if arr.size != math.prod(shape) or (len(shape) == 2 and arr.shape[-1:] != (2,)):
                raise ValueError(f"Engine.step: {name} must have shape {_shape_text(shape)} (U = {u} UAVs), "
                                 f"got shape {arr.shape}")
            return arr.astype(dtype, copy=False).reshape((1,) + shape)

        return step_engines([self], unicycle=one(unicycle, (u, 2), "unicycle"),
                            waypoints=one(waypoints, (u, 2), "waypoints"),
                            decision_time=one(decision_time, (u,), "decision_time"),
                            infeasible=one(infeasible, (u,), "infeasible", bool))

    def _record(self, path, end_theta, v, w, flagged, decision_time) -> None:
        self._path.append(path)
        self._length.append(v * self.config.delta)
        self._vmax.append(v)
        self._wmax.append(np.abs(w))
        self._infeasible.append(flagged)
        self._dtime.append(decision_time)                             # None = not measured (NaN in trajectories)
        self.uav_xy = path[:, -1].copy()
        self.uav_theta = np.mod(end_theta, 2 * math.pi)
        self.k += 1
        self._xy.append(self.uav_xy.copy())
        self._theta.append(self.uav_theta.copy())

    # ------------------------------------------------------------------ records
    def trajectory(self, last: int | None = None) -> Trajectory:
        """The episode so far as a :class:`Trajectory` (only the last ``last`` slots if given)."""
        k0 = 0 if last is None else max(self.k - last, 0)
        ks = np.arange(k0, self.k + 1)
        u = self.n_uavs

        def stack(xs, shape):
            return np.array(xs[k0:]) if len(xs[k0:]) else np.zeros((0,) + shape)

        p = self.path_samples
        nan = np.full(u, np.nan)
        return Trajectory(
            uav_xy=np.array(self._xy[k0:]), uav_theta=np.array(self._theta[k0:]),
            path_xy=stack(self._path, (u, p, 2)), path_length=stack(self._length, (u,)),
            target_xyz=self.track.position(ks), target_phi=np.asarray(self.track.heading(ks)).reshape(-1),
            target_path_xyz=np.array(self.track.position_between(ks[:-1], self._fractions)).reshape(-1, p, 3),
            max_speed=stack(self._vmax, (u,)), max_turn_rate=stack(self._wmax, (u,)),
            infeasible=stack(self._infeasible, (u,)).astype(bool),
            decision_time=stack([nan if d is None else d for d in self._dtime], (u,)))

    def last_quantities(self) -> SlotQuantities:
        """Quantities of the slot just flown (arrays of shape (1, U))."""
        return _last_quantities([self])


#: Most samples per slot along a path (Engine's path_samples): every slot stores (U, path_samples, 2) points.
MAX_PATH_SAMPLES = 1000


def _short(v) -> str:
    import reprlib

    return reprlib.repr(v)


def _shape_text(shape) -> str:
    return "(U, 2)" if len(shape) == 2 else "(U,)"


def _check_unicycle(ctl: np.ndarray, c) -> None:
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


def _waypoint_controls(xy, theta, goals, c):
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
        v[bad], w[bad] = _closest_constant_control(xy[bad], theta[bad], goals[bad], c)
        t_turn[bad] = c.delta
    return v, w, t_turn, bad


def _closest_constant_control(xy, theta, goals, c):
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


def _fly(xy, theta, v, w, t_turn, t):
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


def step_engines(engines, *, unicycle=None, waypoints=None, decision_time=None, infeasible=None) -> SlotQuantities:
    """Fly one slot in each of N engines at once (lock-step), with one set of vectorised numpy calls.

    :meth:`Engine.step` is this function with N = 1; environment copies stepped together (the SB3
    adapter's fast path) call it with all their engines, so the per-call cost of numpy is paid once per
    vector step, not once per copy. The engines must share the config, the team size and the path
    sampling; each keeps its own terrain, track and slot.

    Args:
        engines: the N engines, none of them done.
        unicycle: (N, U, 2) controls (v, omega), or
        waypoints: (N, U, 2) next positions (exactly one of the two).
        decision_time: optional (N, U) seconds; infeasible: optional (N, U) bool (see :meth:`Engine.step`).

    Returns:
        :class:`SlotQuantities` with arrays of shape (N, U).
    """
    e0 = engines[0]
    c, u = e0.config, e0.n_uavs
    for e in engines:
        if e.done:
            raise RuntimeError("Engine.step called after the episode ended; call reset()")
        if e is not e0 and (e.n_uavs != u or e.path_samples != e0.path_samples or e.path_los != e0.path_los
                            or (e.config is not c and e.config != c)):
            raise ValueError("step_engines: engines must share config, team size, path_samples and path_los")
    if (unicycle is None) == (waypoints is None):
        raise ValueError("Engine.step: pass exactly one of unicycle= or waypoints=")
    n = len(engines)
    if n == 1:
        xy, theta = e0.uav_xy[None], e0.uav_theta[None]
    else:
        xy, theta = np.stack([e.uav_xy for e in engines]), np.stack([e.uav_theta for e in engines])
    flagged = np.zeros((n, u), bool) if infeasible is None else np.array(infeasible, bool).reshape(n, u)
    if unicycle is not None:
        ctl = np.array(unicycle, dtype=float).reshape(n, u, 2)          # a copy: the engine keeps v and omega
        _check_unicycle(ctl, c)
        v, w, t_turn = ctl[..., 0], ctl[..., 1], None                 # held for the whole slot
    else:
        goals = np.asarray(waypoints, dtype=float).reshape(n * u, 2)
        v, w, t_turn, fallback = _waypoint_controls(xy.reshape(-1, 2), theta.reshape(-1), goals, c)
        v, w, t_turn = v.reshape(n, u), w.reshape(n, u), t_turn.reshape(n, u)
        flagged |= fallback.reshape(n, u)
    path, end_theta = _fly(xy, theta, v, w, t_turn, e0._fractions * c.delta)
    dtime = None if decision_time is None else np.array(decision_time, float).reshape(n, u)   # a copy: kept
    for j, e in enumerate(engines):
        e._record(path[j], end_theta[j], v[j], w[j], flagged[j], None if dtime is None else dtime[j])
    return _last_quantities(engines)


_STACK: list = [None]   # the last TerrainStack built (copies keep their terrain for a whole episode)


def _terrain_stack(engines):
    st = _STACK[0]
    if st is None or len(st) != len(engines) or any(
            a is not e.terrain for a, e in zip(st.terrains, engines, strict=True)):
        st = _STACK[0] = TerrainStack([e.terrain for e in engines])
    return st


def _last_quantities(engines) -> SlotQuantities:
    """Quantities of the slot each engine just flew (arrays of shape (N, U))."""
    e0 = engines[0]
    if any(e.k == 0 for e in engines):
        raise RuntimeError("Engine.last_quantities: no slot flown yet")
    if len(engines) == 1:
        k, tr = e0.k, e0.track
        start, end = e0._xy[-2][None], e0._xy[-1][None]
        path, length = e0._path[-1][None], e0._length[-1][None]
        q, phi = tr.positions[k - 1:k + 1], tr.headings[k - 1:k + 1]
        terrain = e0.terrain
    else:
        start, end = np.stack([e._xy[-2] for e in engines]), np.stack([e._xy[-1] for e in engines])
        path, length = np.stack([e._path[-1] for e in engines]), np.stack([e._length[-1] for e in engines])
        q = np.stack([e.track.positions[e.k - 1:e.k + 1] for e in engines], axis=1)      # (2, N, 3)
        phi = np.stack([e.track.headings[e.k - 1:e.k + 1] for e in engines], axis=1)
        terrain = _terrain_stack(engines)
    target_path = None
    if e0.path_los:
        target_path = np.stack([e.track.position_between(e.k - 1, e._fractions) for e in engines])
    return moves_quantities(start, end, q[0], phi[0], q[1], phi[1], path, length, target_path, terrain, e0.config)
