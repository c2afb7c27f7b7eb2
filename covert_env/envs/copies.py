"""Where the copies of a vector env stand: the batch state every step reads and writes, in one place.

:class:`~covert_env.envs.vector.CovertSensingVectorEnv` holds one :class:`Copies` (``env.copies``); its step and
reset write it; its readers (``slots``, ``scene(i)``, ...) and its waypoint queries
(:class:`~covert_env.envs.waypoint_queries.WaypointQueries`, given the batch state when the env is made) read it.
Arrays are batch-first: B copies of U UAVs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Copies"]


@dataclass
class Copies:
    """The batch state of B copies of a team of U UAVs (world frame, m and rad).

    Attributes:
        rows: (B,) the scene-pool row each copy flies (-1 before its first reset).
        k: (B,) int64, the slot each copy has reached.
        xy, theta: (B, U, 2), (B, U) the UAVs' poses, headings in [0, 2 pi).
        start_xy, start_theta: the poses the episodes started from.
        drawn: (B,) whether a copy's starts were drawn (else its scene's own).
        ended: (B,) copies whose episodes ended and wait for a reset (``autoreset_mode`` DISABLED, or a scene
            that failed to build).
        speed, zone, los: (B, U) the last slot's speed (m/s), signed distance to the zone (m, <= 0 inside) and
            line of sight at its end: what the observations read besides the scene.
        masks: (B, U, L) int8 waypoint action masks (1 = allowed); (B, U, 2) ones in unicycle mode.
        started: whether ``reset()`` has been called.
    """

    rows: np.ndarray
    k: np.ndarray
    xy: np.ndarray
    theta: np.ndarray
    start_xy: np.ndarray
    start_theta: np.ndarray
    drawn: np.ndarray
    ended: np.ndarray
    speed: np.ndarray
    zone: np.ndarray
    los: np.ndarray
    masks: np.ndarray
    started: bool = False

    @classmethod
    def empty(cls, b: int, u: int, n_actions: int) -> Copies:
        """B copies of U UAVs before the first reset (zeros; ``n_actions`` mask columns)."""
        return cls(rows=np.full(b, -1), k=np.zeros(b, dtype=np.int64), xy=np.zeros((b, u, 2)), theta=np.zeros((b, u)),
                   start_xy=np.zeros((b, u, 2)), start_theta=np.zeros((b, u)), drawn=np.zeros(b, bool),
                   ended=np.zeros(b, bool), speed=np.zeros((b, u)), zone=np.zeros((b, u)), los=np.zeros((b, u), bool),
                   masks=np.ones((b, u, n_actions), np.int8))
