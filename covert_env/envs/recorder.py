"""The episodes a vector env's copies are flying, recorded for the metrics, and one copy seen as an engine.

:class:`EpisodeRecorder` keeps, per copy, what :class:`~covert_env.world.engine.Engine` records (positions, headings,
path samples, speeds, turn rates, fallback flags) in preallocated arrays written by one array operation per step,
and turns a copy's episode into a :class:`~covert_env.world.trajectory.Trajectory`: the metrics of
:mod:`covert_env.world.metrics` score the envs' episodes and the engine's alike. :class:`CopyView` reads copy i of a
vector env in the engine's terms (``k``, ``uav_xy``, ``predict``, ``trajectory``, ...), so the DP planner, the
renderer and the evaluation harness drive an env exactly as they drive an engine.
"""

from __future__ import annotations

import numpy as np

from covert_env.envs.arguments import Forwarded
from covert_env.world.config import Config
from covert_env.world.roles import TargetReads
from covert_env.world.trajectory import Trajectory

__all__ = ["CopyView", "EpisodeRecorder"]


class EpisodeRecorder:
    """B copies' current episodes (at most ``n_slots`` slots of U UAVs, P path samples per slot)."""

    def __init__(self, b: int, u: int, n_slots: int, path_samples: int):
        n, p = n_slots, path_samples
        self.xy, self.theta = np.zeros((b, n + 1, u, 2)), np.zeros((b, n + 1, u))
        self.path = np.zeros((b, n, u, p, 2))
        self.length, self.max_speed, self.max_turn_rate = np.zeros((b, n, u)), np.zeros((b, n, u)), np.zeros((b, n, u))
        self.infeasible = np.zeros((b, n, u), bool)
        self.fractions = np.linspace(0.0, 1.0, p)

    def start(self, idx, xy: np.ndarray, theta: np.ndarray) -> None:
        """Copies ``idx`` begin an episode at poses ``xy`` (len(idx), U, 2), ``theta`` (len(idx), U)."""
        self.xy[idx, 0], self.theta[idx, 0] = xy, theta

    def record(self, k: np.ndarray, path, *, end_theta, v, w, flagged, delta: float) -> None:
        """Slot ``k`` (B,) -> k + 1 of every copy: path samples (B, U, P, 2), end headings (wrapped), controls v and
        w and the fallback flags (B, U)."""
        b = np.arange(len(k))
        self.path[b, k], self.length[b, k] = path, v * delta
        self.max_speed[b, k], self.max_turn_rate[b, k], self.infeasible[b, k] = v, np.abs(w), flagged
        self.xy[b, k + 1], self.theta[b, k + 1] = path[..., -1, :], end_theta

    def trajectory(self, i: int, k: int, track) -> Trajectory:
        """Copy i's episode up to slot k on the target's ``track``, as the engine records it."""
        ks = np.arange(k + 1)
        p, u = len(self.fractions), self.xy.shape[2]
        return Trajectory(
            uav_xy=self.xy[i, :k + 1].copy(), uav_theta=self.theta[i, :k + 1].copy(),
            path_xy=self.path[i, :k].copy(), path_length=self.length[i, :k].copy(),
            target_xyz=track.position(ks), target_phi=np.asarray(track.heading(ks)).reshape(-1),
            target_path_xyz=np.array(track.position_between(ks[:-1], self.fractions)).reshape(-1, p, 3),
            max_speed=self.max_speed[i, :k].copy(), max_turn_rate=self.max_turn_rate[i, :k].copy(),
            infeasible=self.infeasible[i, :k].copy(), decision_time=np.full((k, u), np.nan))


class CopyView(TargetReads):
    """Copy ``i`` of a :class:`~covert_env.envs.vector.CovertSensingVectorEnv`, read as an engine (read-only).

    An :class:`~covert_env.world.roles.EngineView`, as :class:`~covert_env.world.engine.Engine` is: ``k``, ``uav_xy``,
    ``uav_theta``, ``positions`` (every slot so far), ``target_xyz``, ``target_phi``, ``predict``, ``track``,
    ``terrain``, ``config``, ``path_samples``, ``done`` and ``trajectory()`` (``positions`` and ``trajectory()``
    need ``record=True``).
    """

    def __init__(self, venv, i: int):
        self._venv, self._i = venv, int(i)

    config: Config = Forwarded("_venv", writable=False)
    """The env's :class:`~covert_env.world.config.Config`."""
    path_samples: int = Forwarded("_venv", writable=False)
    """Samples per slot along each path (endpoints included)."""

    @property
    def k(self) -> int:
        return int(self._venv.slots[self._i])

    @property
    def uav_xy(self) -> np.ndarray:
        return self._venv.uav_xy[self._i].copy()

    @property
    def uav_theta(self) -> np.ndarray:
        return self._venv.uav_theta[self._i].copy()

    @property
    def track(self):
        return self._venv.scene(self._i).track

    @property
    def terrain(self):
        return self._venv.scene(self._i).terrain

    @property
    def done(self) -> bool:
        """True once the copy's episode has flown ``episode_length`` slots (``max_cycles`` or the route's end)."""
        return self.k >= self._venv.episode_length

    @property
    def positions(self) -> np.ndarray:
        """(k + 1, U, 2) the UAVs' positions at slot times 0..k."""
        return self.trajectory().uav_xy

    def trajectory(self) -> Trajectory:
        return self._venv.trajectory(self._i)
