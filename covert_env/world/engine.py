"""The world: terrain, the target on its road, and the UAV team, advanced one slot at a time.

One scene's world at B = 1 of the vector env's kernel: flown with :mod:`covert_env.geometry.flight`, scored with
:func:`~covert_env.world.metrics.moves_quantities` and recorded by
:class:`~covert_env.world.trajectory.EpisodeRecorder`, the functions the vector env (and so every env) flies, scores
and records its B copies with. So a DP rollout on an engine and an env rollout are the same arithmetic (tested), and
every episode ends as a :class:`~covert_env.world.trajectory.Trajectory` that :mod:`covert_env.world.metrics` scores.
The engine takes what the envs' action spaces do not: unicycle controls in m/s and rad/s, and any waypoint.

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

from covert_env.geometry.angles import wrap_heading
from covert_env.geometry.flight import check_unicycle, fly_arc, fly_waypoints
from covert_env.world.config import MAX_N_UAVS, check_coordinates, short_repr
from covert_env.world.metrics import SlotQuantities, moves_quantities
from covert_env.world.roles import TargetReads
from covert_env.world.scenario import Scenario, valid_start_shapes
from covert_env.world.trajectory import EpisodeRecorder, Trajectory

__all__ = ["Engine", "MAX_PATH_SAMPLES"]


class Engine(TargetReads):
    """Advance a :class:`Scenario` slot by slot and record the episode.

    What the planner, the renderer and the policies read of it (``k``, ``uav_xy``, ``predict``, ``trajectory``,
    ...) is :class:`~covert_env.world.roles.EngineView`, which a vector env's copy plays too.

    Args:
        scenario: the world and the start poses (a :class:`Scenario`; TypeError otherwise).
        path_samples: samples per slot along each path (endpoints included), used for LoS and
            separation checks between slot times: an integer in [2, 1000] (``MAX_PATH_SAMPLES``).
        path_los: a bool, whether :meth:`step`'s quantities include LoS along the path (off saves time; the
            episode metrics compute it from the trajectory in any case).
    """

    def __init__(self, scenario: Scenario, path_samples: int = 11, path_los: bool = True):
        if not isinstance(scenario, Scenario):
            raise TypeError(f"Engine: scenario must be a Scenario (e.g. Scenario.paper() or Scenario.random(seed)), "
                            f"got {short_repr(scenario)} ({type(scenario).__name__})")
        if (isinstance(path_samples, bool) or not isinstance(path_samples, (int, np.integer))
                or not 2 <= path_samples <= MAX_PATH_SAMPLES):
            raise ValueError(f"Engine.path_samples must be an integer in [2, {MAX_PATH_SAMPLES}], got "
                             f"{short_repr(path_samples)} ({type(path_samples).__name__})")
        if not isinstance(path_los, (bool, np.bool_)):
            raise TypeError(f"Engine.path_los must be a bool, got {short_repr(path_los)} ({type(path_los).__name__})")
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
                             f"got {short_repr(uav_xy)} and {short_repr(uav_theta)}") from None
        if not valid_start_shapes(xy if uav_xy is None else uav_xy, th if uav_theta is None else uav_theta):
            raise ValueError(f"Engine.reset: uav_xy must be a (U, 2) array and uav_theta a (U,) array, got shapes "
                             f"{np.shape(uav_xy)} and {np.shape(uav_theta)}")
        if len(xy) != len(th):
            raise ValueError(f"Engine.reset: {len(xy)} positions (uav_xy) but {len(th)} headings (uav_theta)")
        if not (np.isfinite(xy).all() and np.isfinite(th).all()):
            raise ValueError(f"Engine.reset: uav_xy positions and uav_theta headings must be finite (no NaN or inf), "
                             f"got {short_repr(xy.tolist())} and {short_repr(th.tolist())}")
        if not 1 <= len(xy) <= MAX_N_UAVS:
            raise ValueError(f"Engine.reset: the team must have 1 to {MAX_N_UAVS} UAVs, got {len(xy)}")
        check_coordinates(xy, "Engine.reset: uav_xy")
        self.k = 0
        self.uav_xy = xy.copy()
        self.uav_theta = wrap_heading(th)
        self.n_uavs = len(xy)
        # The episode as the vector env records its copies', with B = 1 (its pages are written as slots are flown).
        self._episode = EpisodeRecorder(1, self.n_uavs, self.config.n_slots, self.path_samples)
        self._episode.start(0, self.uav_xy, self.uav_theta)

    @property
    def done(self) -> bool:
        """True once the episode's ``config.n_slots`` slots have been flown."""
        return self.k >= self.config.n_slots

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
                                f"got {short_repr(a)} ({type(a).__name__})")
            # The size and the last axis must match: a (3, 2) array reshaped from (2, 3) would scramble UAVs.
            if arr.size != math.prod(shape) or (len(shape) == 2 and arr.shape[-1:] != (2,)):
                raise ValueError(f"Engine.step: {name} must have shape {_shape_text(shape)} (U = {u} UAVs), "
                                 f"got shape {arr.shape}")
            return arr.astype(dtype, copy=False).reshape((1,) + shape)

        unicycle, waypoints = one(unicycle, (u, 2), "unicycle"), one(waypoints, (u, 2), "waypoints")
        decision_time, infeasible = one(decision_time, (u,), "decision_time"), one(infeasible, (u,), "infeasible", bool)
        if self.done:
            raise RuntimeError("Engine.step called after the episode ended; call reset()")
        if (unicycle is None) == (waypoints is None):
            raise ValueError("Engine.step: pass exactly one of unicycle= or waypoints=")
        c = self.config
        xy, theta = self.uav_xy[None], self.uav_theta[None]
        flagged = np.zeros((1, u), bool) if infeasible is None else infeasible.copy()
        times = self._fractions * c.delta
        # The vector env's flight at B = 1: the same functions, so an engine and an env fly the same arithmetic.
        if unicycle is not None:
            ctl = unicycle.copy()                                        # the engine keeps v and omega
            check_unicycle(ctl, c)
            v, w = ctl[..., 0], ctl[..., 1]                              # held for the whole slot
            path, end_theta = fly_arc(xy, theta, v, w, times)
        else:
            path, end_theta, v, fallback, w = fly_waypoints(xy, theta, waypoints, c, times)
            flagged |= fallback
        end_theta = wrap_heading(end_theta)
        self._episode.record(np.array([self.k]), path, end_theta=end_theta, v=v, w=w, flagged=flagged, delta=c.delta,
                             decision_time=decision_time)
        self.uav_xy, self.uav_theta = path[0, :, -1].copy(), end_theta[0]
        self.k += 1
        return self.last_quantities()

    # ------------------------------------------------------------------ records
    def trajectory(self, last: int | None = None) -> Trajectory:
        """The episode so far as a :class:`Trajectory` (only the last ``last`` slots if given: an integer >= 0)."""
        if last is not None and (isinstance(last, bool) or not isinstance(last, (int, np.integer)) or last < 0):
            raise ValueError(f"Engine.trajectory: last must be None or an integer >= 0 (slots), got {short_repr(last)}")
        k0 = 0 if last is None else max(self.k - last, 0)
        return self._episode.trajectory(0, self.k, self.track, first=k0)

    def last_quantities(self) -> SlotQuantities:
        """Quantities of the slot just flown (arrays of shape (1, U))."""
        if self.k == 0:
            raise RuntimeError("Engine.last_quantities: no slot flown yet")
        k, tr, e = self.k, self.track, self._episode
        q, phi = tr.positions[k - 1:k + 1], tr.headings[k - 1:k + 1]
        target_path = tr.position_between(k - 1, self._fractions)[None] if self.path_los else None
        return moves_quantities(e.xy[:, k - 1], e.xy[:, k], target_start=q[0], phi_start=phi[0],
                                target_end=q[1], phi_end=phi[1], path_xy=e.path[:, k - 1],
                                path_length=e.length[:, k - 1], target_path_xyz=target_path,
                                terrain=self.terrain, config=self.config)

    @property
    def positions(self) -> np.ndarray:
        """(k + 1, U, 2) the UAVs' positions at slot times 0..k (the trails the renderer draws)."""
        return self._episode.xy[0, :self.k + 1].copy()


#: Most samples per slot along a path (Engine's path_samples): every slot stores (U, path_samples, 2) points.
MAX_PATH_SAMPLES = 1000



def _shape_text(shape) -> str:
    return "(U, 2)" if len(shape) == 2 else "(U,)"
