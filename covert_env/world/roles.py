"""The roles that several classes play, as :class:`typing.Protocol` s: what a function reads of its argument.

* :class:`PolytopeTops`: the polytopes' highest points, what terrain clearance (eq. 3) reads of a terrain.
* :class:`TerrainPerCopy`: one terrain per copy of a batch of moves, what the per-step quantities read of the vector
  env's copies (line of sight, eq. 6, and the tops, eq. 3, row b for copy b).
* :class:`EngineView`: one episode read at its current slot k, what the DP team, the renderer and the policies
  read of an :class:`~covert_env.world.engine.Engine` or of a vector env's copy
  (:class:`~covert_env.envs.recorder.CopyView`).

One scene's terrain has no protocol: everywhere it is a :class:`~covert_env.world.terrain.Terrain` (the geometry
caches its padded arrays per Terrain object, :func:`covert_env.world.visibility.terrain_arrays`).

The protocols are ``runtime_checkable``, so ``isinstance`` tells whether an object has every member (not their
signatures); tests/test_roles.py checks that the classes playing each role do.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

    from covert_env.world.config import Config
    from covert_env.world.road import TargetTrack
    from covert_env.world.terrain import Terrain
    from covert_env.world.trajectory import Trajectory

__all__ = ["EngineView", "PolytopeTops", "TargetReads", "TerrainPerCopy"]


@runtime_checkable
class PolytopeTops(Protocol):
    """The highest point of every polytope C_m (eq. 3): a :class:`~covert_env.world.terrain.Terrain` (M, 3), or one
    terrain per row of a batch (N, M, 3), padded with inf where a row has fewer polytopes."""

    highest_points: np.ndarray


@runtime_checkable
class TerrainPerCopy(Protocol):
    """One terrain per copy of a batch of N moves (the vector env's copies, each on its own scene).

    Attributes:
        highest_points: (N, M, 3) each copy's polytope tops (eq. 3), padded with inf.
    """

    highest_points: np.ndarray

    def line_of_sight(self, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray) -> np.ndarray:
        """(N, U) clear LoS (eq. 6) from UAVs ``uav_xy`` (N, U, 2) at ``altitude`` to one target per copy,
        ``target_xyz`` (N, 1, 3), copy b against its own terrain only."""
        ...


class TargetReads:
    """The target's pose and predictions, read from ``track`` at slot ``k`` (``config.horizon`` slots ahead by
    default): what :class:`~covert_env.world.engine.Engine` and :class:`~covert_env.envs.recorder.CopyView` share of
    :class:`EngineView`."""

    @property
    def target_xyz(self) -> np.ndarray:
        """(3,) q[k], the target's position."""
        return self.track.position(self.k)

    @property
    def target_phi(self) -> float:
        """phi[k], the target's heading."""
        return float(self.track.heading(self.k))

    def predict(self, horizon: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Predicted target positions (N, 3) and headings (N,) for slots k+1..k+N (N = ``config.horizon``)."""
        return self.track.predict(self.k, self.config.horizon if horizon is None else horizon)


@runtime_checkable
class EngineView(Protocol):
    """One episode of one scene, read at its current slot k (read-only).

    :class:`~covert_env.world.engine.Engine` and :class:`~covert_env.envs.recorder.CopyView` (a vector env's copy, the
    parallel env's ``env.engine``) play it; :meth:`trajectory` and :attr:`positions` of a copy need ``record=True``.
    """

    @property
    def config(self) -> Config: ...

    @property
    def terrain(self) -> Terrain: ...

    @property
    def track(self) -> TargetTrack:
        """The target's track: its true positions, and the predictions the planner sees."""
        ...

    @property
    def path_samples(self) -> int:
        """Samples per slot along each path (endpoints included)."""
        ...

    @property
    def k(self) -> int:
        """The current slot: k slots have been flown."""
        ...

    @property
    def done(self) -> bool:
        """True once the episode's last slot has been flown."""
        ...

    @property
    def uav_xy(self) -> np.ndarray:
        """(U, 2) the UAVs' positions p[k]."""
        ...

    @property
    def uav_theta(self) -> np.ndarray:
        """(U,) the UAVs' headings."""
        ...

    @property
    def target_xyz(self) -> np.ndarray:
        """(3,) q[k], the target's position."""
        ...

    @property
    def target_phi(self) -> float:
        """phi[k], the target's heading."""
        ...

    @property
    def positions(self) -> np.ndarray:
        """(k + 1, U, 2) the UAVs' positions at slot times 0..k (the trails the renderer draws)."""
        ...

    def predict(self, horizon: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Predicted target positions (N, 3) and headings (N,) for slots k+1..k+N (N = ``config.horizon``)."""
        ...

    def trajectory(self) -> Trajectory:
        """The episode so far, as the metrics score it."""
        ...
