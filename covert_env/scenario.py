"""Scenarios: a config, a terrain, a road with the target's track, and the UAVs' start poses.

:meth:`Scenario.paper` is the paper's setting (§3): the target starts at (120, 0) heading +x, so the
paper's UAV starts (40, 10), (60, 0), (50, -10) with headings 2 pi, pi, pi/2 lie inside its feasible
zone; 16 polytopes line a 70-slot road. :meth:`Scenario.random` draws a held-out scene (terrain and
road seeds) with starts sampled in the visible zone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from covert_env.config import Config
from covert_env.road import Road, TargetTrack
from covert_env.terrain import Terrain

__all__ = ["Scenario", "PAPER_UAV_STARTS", "PAPER_SEED"]

#: The paper's UAV starts (x, y, heading), §3.1-3.2.
PAPER_UAV_STARTS = np.array([[40.0, 10.0, 2 * math.pi], [60.0, 0.0, math.pi], [50.0, -10.0, math.pi / 2]])
#: Seed of the paper scenario's road and terrain (the paper's own map is not published).
PAPER_SEED = 2024
#: Where the target is at slot 0 in the paper scenario.
PAPER_TARGET_START = (120.0, 0.0)
#: Road driven before the target's start (m): buildings there cast shadows on the first zones.
_ROAD_LEAD_IN = 140.0


@dataclass(frozen=True, eq=False)
class Scenario:
    """Everything that defines an episode apart from the policy.

    Attributes:
        config: model parameters.
        terrain: the polytopes.
        track: the target's motion (road + speed profile), at least ``n_slots + horizon`` slots long.
        uav_xy: (U, 2) start positions; uav_theta: (U,) start headings (rad).
        name: a label for logs and figures.
    """

    config: Config
    terrain: Terrain
    track: TargetTrack
    uav_xy: np.ndarray
    uav_theta: np.ndarray
    name: str = "scenario"

    def __post_init__(self) -> None:
        xy = np.asarray(self.uav_xy, dtype=float).reshape(-1, 2)
        th = np.asarray(self.uav_theta, dtype=float).reshape(-1)
        if len(xy) != len(th):
            raise ValueError(f"Scenario: {len(xy)} start positions but {len(th)} start headings")
        if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(th))):
            raise ValueError("Scenario: start poses must be finite")
        need = self.config.n_slots + self.config.horizon
        if self.track.n_slots < need:
            raise ValueError(f"Scenario.track must cover n_slots + horizon = {need} slots, has {self.track.n_slots}")
        object.__setattr__(self, "uav_xy", xy)
        object.__setattr__(self, "uav_theta", th)

    @property
    def n_uavs(self) -> int:
        return len(self.uav_xy)

    @property
    def road(self) -> Road:
        return self.track.road

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def _road_and_track(config: Config, seed, start=PAPER_TARGET_START, heading: float = 0.0):
        c = config
        travel = c.target_speed * c.delta * (c.n_slots + c.horizon + 1)
        road_start = np.asarray(start, float) - _ROAD_LEAD_IN * np.array([math.cos(heading), math.sin(heading)])
        road = Road.random(seed, length=_ROAD_LEAD_IN + travel + 60.0, start=road_start, heading=heading,
                           straight_start=_ROAD_LEAD_IN + 30.0)
        track = TargetTrack.constant(road, c.target_speed, c.n_slots + c.horizon + 1, delta=c.delta,
                                     z=c.target_height, s0=_ROAD_LEAD_IN)
        return road, track

    @classmethod
    def paper(cls, config: Config | None = None, n_uavs: int | None = None) -> Scenario:
        """The paper's scenario (§3) with the first ``n_uavs`` (default ``config.n_uavs``) paper starts.

        The paper's map is not published; ours is the seeded random generator's output with the
        paper's M = 16, along a road whose first 170 m are straight so the paper's starts are in the zone.
        """
        c = config or Config()
        u = c.n_uavs if n_uavs is None else n_uavs
        if not 1 <= u <= len(PAPER_UAV_STARTS):
            raise ValueError(f"Scenario.paper: n_uavs must be in [1, {len(PAPER_UAV_STARTS)}], got {u}")
        road, track = cls._road_and_track(c, PAPER_SEED)
        terrain = Terrain.random(seed=PAPER_SEED, road=road, config=c)
        starts = PAPER_UAV_STARTS[:u]
        return cls(c, terrain, track, starts[:, :2], starts[:, 2], name=f"paper-{u}uav")

    @classmethod
    def random(cls, seed: int, config: Config | None = None, n_uavs: int | None = None) -> Scenario:
        """A random scene: road, terrain and UAV starts drawn from ``seed``.

        Starts are distinct grid nodes of the eroded zone at slot 0 with clear LoS, at least
        ``2 d_safe1`` apart, with headings drawn uniformly.
        """
        c = config or Config()
        u = c.n_uavs if n_uavs is None else n_uavs
        _check_team(u, "Scenario.random")
        terrain, track, rng = cls._random_world(seed, c)
        xy, th = _sample_starts(c, terrain, track, rng, u, f"random-{seed}")
        return cls(c, terrain, track, xy, th, name=f"random-{seed}")

    @classmethod
    def _random_world(cls, seed: int, config: Config) -> tuple[Terrain, TargetTrack, np.random.Generator]:
        """The terrain and track of :meth:`random` (seed), and the generator positioned to draw its starts.

        Environments that draw their own starts use this and skip the seeded ones."""
        rng = np.random.default_rng(seed)
        road, track = cls._road_and_track(config, rng)
        terrain = Terrain.random(seed=rng, road=road, config=config)
        return terrain, track, rng

    def sample_starts(self, rng: np.random.Generator, n_uavs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Random start poses: distinct lattice nodes of the eroded zone at slot 0 with clear LoS, at
        least ``2 d_safe1`` apart, headings uniform in [0, 2 pi). Returns (xy (U, 2), theta (U,)).
        """
        u = self.n_uavs if n_uavs is None else n_uavs
        _check_team(u, "Scenario.sample_starts")
        return _sample_starts(self.config, self.terrain, self.track, rng, u, self.name)


def _sample_starts(c: Config, terrain: Terrain, track: TargetTrack, rng: np.random.Generator, u: int,
                   name: str) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Scenario.sample_starts` on the parts of a scenario."""
    from covert_env.visibility import line_of_sight
    from covert_env.zone import grid_nodes

    q0, phi0 = track.position(0), float(track.heading(0))
    nodes = grid_nodes(q0[:2], phi0, c.grid_step, c.r1, c.r2, c.mu, c.r_u)
    nodes = nodes[line_of_sight(terrain, nodes, c.altitude, q0)]
    picked: list[np.ndarray] = []
    for idx in rng.permutation(len(nodes)):
        p = nodes[idx]
        if all(np.hypot(*(p - o)) >= 2 * c.d_safe1 for o in picked):
            picked.append(p)
            if len(picked) == u:
                break
    if len(picked) < u:
        raise ValueError(f"Scenario {name}: could not place {u} UAVs in the visible zone")
    return np.array(picked), rng.uniform(0, 2 * math.pi, u)


def _check_team(u, where: str) -> None:
    if isinstance(u, bool) or not isinstance(u, (int, np.integer)) or u < 1:
        raise ValueError(f"{where}: n_uavs must be an integer >= 1, got {u!r}")
