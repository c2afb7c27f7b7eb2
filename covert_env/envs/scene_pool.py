"""Scenes shared by the copies of a vector env, as padded arrays with one row per scene.

Everything that depends only on the scene and the slot (the target's track, the observation's shared block with
its visibility maps, which lattice nodes are visible, the start nodes) is computed once when a scene enters the
pool, by :class:`~covert_env.envs.scene_cache.SceneCache` (so every copy and reset sees
the same numbers), and stacked into arrays ``(R, ...)``. A copy of the vector env only holds its row index: every
per-step quantity is a gather ``array[rows, slots]``, one array operation for the whole batch.

The terrains are rows of a :class:`~covert_env.visibility.TerrainRows` (padded half-spaces, footprint circles and
tops per row), whose batched line of sight clips with the same routine as every other LoS path.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from covert_env.envs.observation import shared_block_size
from covert_env.envs.scene_cache import SceneCache
from covert_env.metrics import terrain_clearance
from covert_env.scenario import Scenario, pick_starts, random_worlds, start_candidates
from covert_env.visibility import LOS_TOLERANCE, TerrainRows, grown

__all__ = ["ScenePool"]


class ScenePool:
    """Scenes by key (a scene seed, ``"paper"`` or a fixed :class:`Scenario`), each in one row of the arrays.

    Args:
        spec: the env's ``scenario`` argument (``"random"``, ``"paper"`` or a Scenario).
        config, lattice, map_offsets, map_in_zone: the env's (see the parallel env).
        waypoint: whether to tabulate the lattice's visibility per slot (the waypoint masks need it).
        capacity: rows kept; the least recently used scene no copy flies is replaced beyond it.

    Attributes (rows R, slots T = track slots + 1, polytopes M, faces F, lattice nodes L):
        q (R, T, 3), phi (R, T): the target's track, clamped at its end like ``TargetTrack.position``.
        blocks (R, T, D) float32: the observation's shared block per slot (``SceneCache.shared_blocks``).
        lattice_ok (R, T, L) bool: the visible lattice nodes (eq. 10, :func:`~covert_env.visibility.visible_nodes`;
            waypoint mode only).
        terrains: the scenes' terrains, row r the scene's (:class:`~covert_env.visibility.TerrainRows`).
        top (R, M, 3): polytope top points (eq. 3), padded with inf; centre (R, M, 2), radius (R, M): footprint
        circles (views of ``terrains``).
    """

    def __init__(self, spec, config, lattice, map_offsets, map_in_zone, *, waypoint: bool, capacity: int):
        self.spec, self.config, self.lattice = spec, config, lattice
        self._map_offsets, self._map_in_zone = map_offsets, map_in_zone
        self.waypoint, self.capacity = waypoint, capacity
        self._rows: OrderedDict = OrderedDict()          # key -> row, least recently used first
        self._caches: list[SceneCache | None] = []
        self._start_nodes: list[tuple | None] = []
        self._worlds: dict = {}                          # seed -> a random scene drawn in a batch, not yet built
        d = shared_block_size(len(map_offsets))
        self.q, self.phi = np.zeros((0, 1, 3)), np.zeros((0, 1))
        self.blocks = np.zeros((0, 1, d), np.float32)
        self.lattice_ok = np.zeros((0, 1, len(lattice)), bool)
        self.terrains = TerrainRows(capacity)

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def top(self) -> np.ndarray:
        return self.terrains.top

    @property
    def centre(self) -> np.ndarray:
        return np.stack([self.terrains.cx, self.terrains.cy], axis=-1)

    @property
    def radius(self) -> np.ndarray:
        return self.terrains.radius

    # ------------------------------------------------------------------ scenes
    def key(self, scene_seed) -> object:
        if isinstance(self.spec, Scenario):
            return ("scenario", id(self.spec))
        return "paper" if self.spec == "paper" else int(scene_seed)

    def row(self, key, in_use: np.ndarray) -> int:
        """The row of the scene ``key``, built if needed; ``in_use``: rows copies fly now (never replaced)."""
        if key in self._rows:
            self._rows.move_to_end(key)
            return self._rows[key]
        if len(self._rows) < self.capacity:
            r = len(self._rows)
        else:
            busy = set(np.asarray(in_use).tolist())
            old = next((k for k, r in self._rows.items() if r not in busy), None)
            if old is None:
                raise RuntimeError("ScenePool: every row is in use; raise the capacity")
            r = self._rows.pop(old)
        self._fill(r, self._build(key))
        self._rows[key] = r
        return r

    def cache(self, row: int) -> SceneCache:
        return self._caches[row]

    def draw_episodes(self, rows: np.ndarray, idx: np.ndarray, rngs, scene_seeds, scene_pool: int, draw_starts: bool,
                      n_uavs: int) -> tuple[np.ndarray, np.ndarray]:
        """Scenes and starts of new episodes for the copies ``idx``, each from its own generator in ``rngs``.

        ``rows`` (B,): every copy's scene row, updated in place for ``idx`` (their old scenes may leave the pool
        first, so a pool of B scenes works). A copy's scene is ``scene_seeds[n]`` or, for ``scenario="random"``,
        a seed drawn from its generator in ``range(scene_pool)``; its starts are drawn from the generator
        (``draw_starts``, :func:`~covert_env.scenario.pick_starts`) or the scene's own seeded ones. Returns the
        starts ``(len(idx), U, 2)`` and headings ``(len(idx), U)``. Drawing is the one per-copy step of a reset
        (a few µs per copy, once per episode): every copy has its own generator.
        """
        c = self.config
        xy, theta = np.empty((len(idx), n_uavs, 2)), np.empty((len(idx), n_uavs))
        rows[idx] = -1
        seeds = [None if scene_seeds is None else int(scene_seeds[n]) for n in range(len(idx))]
        if self.spec == "random":
            # Every copy's seed first (from its own generator), then the missing scenes as one batch.
            seeds = [int(rng.integers(scene_pool)) if s is None else s for s, rng in zip(seeds, rngs, strict=True)]
            new = list(dict.fromkeys(s for s in seeds if self.key(s) not in self._rows))
            self._worlds = dict(zip(new, random_worlds(new, c), strict=True)) if new else {}
        for n, (j, rng) in enumerate(zip(idx, rngs, strict=True)):
            s = seeds[n]
            rows[j] = row = self.row(self.key(s), rows)
            if draw_starts:
                xy[n], theta[n] = pick_starts(c, *self.start_candidates(row), rng, n_uavs, self.cache(row).parts.name)
            else:
                sc = self.cache(row).seeded_scenario()
                xy[n], theta[n] = sc.uav_xy, sc.uav_theta
        return xy, theta

    def start_candidates(self, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What ``Scenario.sample_starts`` draws the scene's starts from (``scenario.start_candidates``): the
        zone lattice at slot 0 and its nodes clear of the tops (eq. 3) with and without LoS, computed once per
        scene."""
        return self._start_nodes[row]

    def _build(self, key) -> SceneCache:
        c = self.config
        if isinstance(self.spec, Scenario):
            sc, seed = self.spec, None
        elif self.spec == "paper":
            sc, seed = Scenario.paper(c), None
        else:
            sc, seed = None, key
        world = self._worlds.pop(seed, None) if seed is not None else None
        return SceneCache(sc, self._map_offsets, self._map_in_zone, self.lattice, seed=seed, config=c, world=world)

    def _fill(self, r: int, cache: SceneCache) -> None:
        w, c = cache.parts, self.config
        n_t = w.track.n_slots + 1
        rows = max(r + 1, len(self.q))
        t = max(n_t, self.q.shape[1])
        if rows > len(self.q):                              # grow geometrically: amortised O(1) per scene
            rows = max(rows, min(2 * len(self.q), self.capacity))
        self.q = grown(self.q, (rows, t, 3), 0.0)
        self.phi = grown(self.phi, (rows, t), 0.0)
        self.blocks = grown(self.blocks, (rows, t, self.blocks.shape[2]), 0.0)
        if self.waypoint:
            self.lattice_ok = grown(self.lattice_ok, (rows, t, len(self.lattice)), False)
        while len(self._caches) < rows:
            self._caches.append(None)
            self._start_nodes.append(None)

        ks = np.minimum(np.arange(t), n_t - 1)             # clamped at the track's end
        self.q[r] = w.track.positions[ks]
        self.phi[r] = w.track.headings[ks]
        self.blocks[r] = cache.shared_blocks()[ks]
        if self.waypoint:
            self.lattice_ok[r] = cache.lattice_visible()[ks]
        self.terrains.set_row(r, w.terrain)
        self._start_nodes[r] = start_candidates(c, w.terrain, w.track)
        self._caches[r] = cache

    # ------------------------------------------------------------------ geometry
    def line_of_sight(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                      *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) from UAVs ``uav_xy`` (B, U, 2) at ``altitude`` to targets ``target_xyz`` (B, 3), copy
        b against the terrain of scene row ``rows[b]``; (B, U) bool (:meth:`TerrainRows.line_of_sight
        <covert_env.visibility.TerrainRows.line_of_sight>`)."""
        return self.terrains.line_of_sight(rows, uav_xy, altitude, target_xyz, tol=tol)

    def terrain_clearance(self, rows: np.ndarray, xy: np.ndarray, altitude: float) -> np.ndarray:
        """(B, U) distance from (x, y, h) to the nearest polytope top of each copy's scene (eq. 3; inf if none)."""
        return terrain_clearance(xy, altitude, self.copy_terrains(rows))

    def copy_terrains(self, rows: np.ndarray) -> _CopyTerrains:
        """The terrain of each copy, copy b flying scene row ``rows[b]``: what
        :func:`~covert_env.metrics.moves_quantities` and :func:`~covert_env.metrics.terrain_clearance` read."""
        return _CopyTerrains(self, rows)


class _CopyTerrains:
    """Each copy's terrain (copy b on scene row ``rows[b]``): its polytope tops (B, M, 3) and its line of sight."""

    def __init__(self, pool: ScenePool, rows: np.ndarray):
        self._pool, self._rows = pool, rows
        self.highest_points = pool.top[rows]

    def line_of_sight(self, uav_xy, altitude, target_xyz) -> np.ndarray:
        """(B, U) clear LoS (eq. 6) from ``uav_xy`` (B, U, 2) to one target per copy, ``target_xyz`` (B, 1, 3) or
        (B, 3)."""
        return self._pool.line_of_sight(self._rows, uav_xy, altitude, target_xyz.reshape(len(self._rows), 3))
