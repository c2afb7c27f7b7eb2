"""What scenes give every agent, reset and copy, for many scenes at once: the target's track per slot, the
observation's shared blocks with their visibility maps, the lattice's visibility and the start candidates.

A :class:`SceneBatch` holds N scenes as arrays (terrain arrays and tracks: the batched generator's random scenes,
or one given scenario); the vector env's :class:`~covert_env.envs.scene_pool.ScenePool` writes them into its rows
and computes their per-slot quantities with one batched line-of-sight call each
(:func:`~covert_env.world.visibility.visible_nodes_rows`). A :class:`SceneCache` builds one scene's objects (terrain,
track, seeded starts) only when asked for them (``VectorEnv.scene``, ``scenario``).
"""

from __future__ import annotations

import copy
from functools import cached_property

import numpy as np

from covert_env.envs.observation import FIELDS, SHARED, shared_block_slices
from covert_env.geometry.zone import to_target_frame, to_world
from covert_env.world.config import Config
from covert_env.world.metrics import top_clearance
from covert_env.world.road import cumulative_lengths
from covert_env.world.scenario import Scenario, random_scene_arrays, sample_starts_on
from covert_env.world.visibility import terrain_arrays

__all__ = ["SceneBatch", "SceneCache", "World", "shared_blocks", "start_nodes"]

#: The target-displacement and target-path fields of the observation layout (their bounds clip the shared block).
DISPLACEMENT = next(f for f in FIELDS if f.name == "target_displacement")
PATH = next(f for f in FIELDS if f.name == "target_path")


class SceneBatch:
    """N scenes of M polytopes each, as arrays (slots T = the track's n + 1).

    Attributes:
        keys: the scenes' pool keys; config.
        hs (N, M, F, 4), centre (N, M, 2), radius (N, M), z_max (N, M), top (N, M, 3), growth (N, M): the terrains
            (:meth:`TerrainRows.set_rows <covert_env.world.visibility.TerrainRows.set_rows>`).
        q (N, T, 3), phi (N, T): the target's true track; q_next (N, T, 3), phi_next (N, T): slot k + 1 as predicted
            at slot k (row n: the track's end), as ``TargetTrack.next_predicted``; exact: the prediction is the truth.
            q_ahead (N, T, H, 3), phi_ahead (N, T, H): slots k + 1..k + H as predicted at slot k (H =
            ``config.horizon``), as ``TargetTrack.predicted_ahead``: what the observation's path fields read.
        roads (N, K, 2), road_lengths (N, K): the roads' vertices and their arc lengths (``Road.cumulative_length``),
            every road K vertices here; arc (N, T): the target's arc length at each slot (``TargetTrack.arc``);
            z (N,): the filmed point's height. The target between slot times, as ``TargetTrack.position_between``.
        scenario: the given scenario (N = 1), or None for random scenes.
    """

    def __init__(self, keys, config: Config, terrain: tuple, track: tuple, route: tuple, exact: bool,
                 scenario=None):
        self.keys, self.config, self.exact, self.scenario = list(keys), config, exact, scenario
        self.hs, self.centre, self.radius, self.z_max, self.top, self.growth = terrain
        self.q, self.phi, self.q_next, self.phi_next, self.q_ahead, self.phi_ahead = track
        self.roads, self.road_lengths, self.arc, self.z = route

    def __len__(self) -> int:
        return len(self.keys)

    @classmethod
    def random(cls, seeds, config: Config) -> SceneBatch:
        """The random scenes ``seeds`` (:func:`~covert_env.world.scenario.random_scene_arrays`, one batch). Without
        prediction error the tracks are computed for all scenes at once; with it, each track draws its own speed
        noise from its scene's seed (a generator per scene, so a loop over the scenes)."""
        a = random_scene_arrays(seeds, config)
        terrain = (a.hs, a.centre, a.radius, a.z_max, a.highest, a.growth)
        n, z = len(a), np.full(len(a), float(config.target_height))
        if config.prediction_error == 0:
            q, phi = a.tracks()
            slots = np.arange(q.shape[1])
            nxt = np.minimum(slots + 1, q.shape[1] - 1)
            ahead = np.minimum(slots[:, None] + np.arange(1, config.horizon + 1), q.shape[1] - 1)
            arc = np.broadcast_to(a.nominal_arc(), (n, q.shape[1]))
            route = (a.roads, cumulative_lengths(a.roads), arc, z)
            track = (q, phi, q[:, nxt], phi[:, nxt], q[:, ahead], phi[:, ahead])
            return cls(a.seeds, config, terrain, track, route, exact=True)
        tracks = [a.track(i) for i in range(n)]
        parts = [np.stack(x) for x in zip(*((t.positions, t.headings) + t.next_predicted
                                            + t.predicted_ahead(config.horizon) for t in tracks), strict=True)]
        route = (a.roads, np.stack([t.road.cumulative_length for t in tracks]), np.stack([t.arc for t in tracks]), z)
        return cls(a.seeds, config, terrain, tuple(parts), route, exact=False)

    @classmethod
    def of(cls, key, scenario: Scenario) -> SceneBatch:
        """One given scenario (its terrain's arrays and its track)."""
        arr, track = terrain_arrays(scenario.terrain), scenario.track
        tops = np.asarray(scenario.terrain.highest_points, float).reshape(-1, 3)
        terrain = tuple(x[None] for x in (arr.hs, arr.centre, arr.radius, arr.z_max, tops, arr.growth_factor))
        parts = tuple(np.asarray(x)[None] for x in (track.positions, track.headings) + track.next_predicted
                      + track.predicted_ahead(scenario.config.horizon))
        route = (track.road.points[None], track.road.cumulative_length[None], track.arc[None], np.array([track.z]))
        return cls([key], scenario.config, terrain, parts, route, exact=track.exact, scenario=scenario)


def shared_blocks(config: Config, batch: SceneBatch, maps: np.ndarray, maps_next: np.ndarray,
                  path_slots: int = 0) -> np.ndarray:
    """(N, T, D) float32, row k of scene n the observation's shared block at slot k: the target's displacement to
    k + 1 as predicted at k, in the target's frame at k; 0 for the time remaining (the env writes it); the maps
    ``maps`` at k and ``maps_next`` at the predicted k + 1, (N, T, S*S) each; and with ``path_slots`` P > 0 the
    target's poses at k + 1..k + P as predicted at k, in the target's frame at k
    (:mod:`covert_env.envs.observation`)."""
    q, phi = batch.q, batch.phi
    cs, sn = np.cos(phi), np.sin(phi)
    at = shared_block_slices(maps.shape[-1], path_slots)
    blocks = np.zeros(q.shape[:2] + (at[SHARED[-1]].stop,), np.float32)
    disp = blocks[..., at["target_displacement"]]
    disp[:] = np.clip(to_target_frame(batch.q_next[..., :2] - q[..., :2], cs, sn) / (config.v_max * config.delta),
                      DISPLACEMENT.low, DISPLACEMENT.high)
    blocks[..., at["map_now"]] = maps
    blocks[..., at["map_next"]] = maps_next
    if path_slots:
        ahead = batch.q_ahead[:, :, :path_slots, :2] - q[:, :, None, :2]                 # (N, T, P, 2)
        path = to_target_frame(ahead, cs[..., None], sn[..., None]) / config.r2
        blocks[..., at["target_path"]] = np.clip(path, PATH.low, PATH.high).reshape(*q.shape[:2], -1)
        turn = batch.phi_ahead[:, :, :path_slots] - phi[..., None]
        blocks[..., at["target_path_heading"]] = np.stack([np.cos(turn), np.sin(turn)], -1).reshape(*q.shape[:2], -1)
    return blocks



def start_nodes(config: Config, lattice: np.ndarray, q0: np.ndarray, phi0: np.ndarray,
                top: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The zone lattice at slot 0 of N scenes, (N, L, 2) world positions, and which nodes are at least d_safe2 from
    every polytope top ``top`` (N, M, 3) (eq. 3), (N, L): with the nodes' visibility, what
    :func:`~covert_env.world.scenario.start_candidates` gives per scene."""
    nodes = to_world(lattice, q0[:, :2], phi0)
    clear = np.ones(nodes.shape[:2], dtype=bool)
    # Only a top within d_safe2 (+ 1 µm, above rounding) below the flight plane can be that close; the others are
    # left out as inf, which changes no decision (both sides are >= d_safe2 then).
    low = config.altitude - top[..., 2] <= config.d_safe2 + 1e-6
    scenes = np.flatnonzero(low.any(axis=1))
    if len(scenes):
        near = np.where(low[scenes, :, None], top[scenes], np.inf)
        clear[scenes] = top_clearance(nodes[scenes], config.altitude, near) >= config.d_safe2
    return nodes, clear


class SceneCache:
    """One scene's objects, built on first use: ``parts`` (:class:`World`) and its seeded starts.

    A random scene is rebuilt from its seed (:meth:`Scenario.random_world`: the same scene as in any batch), so
    the pool keeps no scene object for the many scenes nobody asks about."""

    def __init__(self, config: Config, *, seed: int | None = None, scenario: Scenario | None = None):
        self._config, self._seed, self._seeded, self._rng = config, seed, scenario, None

    @cached_property
    def parts(self) -> World:
        if self._seeded is not None:
            sc = self._seeded
            return World(sc.config, sc.terrain, sc.track, sc.name)
        terrain, track, self._rng = Scenario.random_world(self._seed, self._config)
        return World(self._config, terrain, track, f"random-{self._seed}")

    def seeded_scenario(self) -> Scenario:
        """The scene with its own starts: ``Scenario.random(seed)`` exactly (or the given scenario)."""
        if self._seeded is None:
            w = self.parts
            # A copy of the generator: a failed attempt must not shift the starts of the next one.
            xy, th = sample_starts_on(w.config, w.terrain, w.track, copy.deepcopy(self._rng), w.config.n_uavs, w.name)
            self._seeded = Scenario(w.config, w.terrain, w.track, xy, th, name=w.name)
        return self._seeded


class World:
    """The scene without starts (what the scene cache's slot computations need)."""

    __slots__ = ("config", "terrain", "track", "name")

    def __init__(self, config: Config, terrain, track, name: str):
        self.config, self.terrain, self.track, self.name = config, terrain, track, name
