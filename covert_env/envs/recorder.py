"""One copy of a vector env seen as an engine.

The vector env records its copies' episodes (``record=True``) with the engine's recorder,
:class:`~covert_env.world.trajectory.EpisodeRecorder` (importable from here too), so the metrics of
:mod:`covert_env.world.metrics` score the envs' episodes and the engine's alike. :class:`CopyView` reads copy i of a
vector env in the engine's terms (``k``, ``uav_xy``, ``predict``, ``trajectory``, ...), so the DP planner, the
renderer and the evaluation harness drive an env exactly as they drive an engine.
"""

from __future__ import annotations

import numpy as np

from covert_env.envs.arguments import Forwarded
from covert_env.world.config import Config
from covert_env.world.roles import TargetReads
from covert_env.world.trajectory import EpisodeRecorder, Trajectory

__all__ = ["CopyView", "EpisodeRecorder"]


class CopyView(TargetReads):
    """Copy ``i`` of a :class:`~covert_env.envs.vector.CovertSensingVectorEnv`, read as an engine (read-only).

    An :class:`~covert_env.world.roles.EngineView`, as :class:`~covert_env.world.engine.Engine` is: ``k``, ``uav_xy``,
    ``uav_theta``, ``positions`` (every slot so far), ``target_xyz``, ``target_phi``, ``predict``, ``track``,
    ``terrain``, ``config``, ``path_samples``, ``done`` and ``trajectory()`` (``positions`` and ``trajectory()``
    need ``record=True``).
    """

    def __init__(self, venv, i: int):
        self._venv, self._i = venv, int(i)

    @property
    def config(self) -> Config:
        """The copy's :class:`~covert_env.world.config.Config`: the env's, or in an env of several tasks its own
        task's (a deviating task's ``r_u`` and ``prediction_error``; :mod:`covert_env.envs.task_mix`)."""
        mix = self._venv.task_mix
        return self._venv.config if mix is None else mix.configs[int(mix.copy_task[self._i])]

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
