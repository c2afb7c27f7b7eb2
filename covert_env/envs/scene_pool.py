"""Scenes shared by the copies of a vector env, as padded arrays with one row per scene.

Everything that depends only on the scene and the slot (the target's track, the observation's shared block with
its visibility maps, which lattice nodes are visible, the start candidates) is computed when scenes enter the
pool, for all the scenes a reset needs at once (:class:`~covert_env.envs.scene_cache.SceneBatch`, one batched
line-of-sight call per quantity, :func:`~covert_env.world.visibility.visible_nodes_rows`), and stored in arrays
``(R, ...)``: every copy and reset sees the same numbers. A copy of the vector env only holds its row index: every
per-step quantity is a gather ``array[rows, slots]``, one array operation for the whole batch.

The terrains are rows of a :class:`~covert_env.world.visibility.TerrainRows` (padded half-spaces, footprint circles and
tops per row), whose batched line of sight clips with the same routine as every other LoS path. Scene objects
(terrain, track) are built only when asked for (:meth:`ScenePool.cache`).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from covert_env.envs.observation import shared_block_size
from covert_env.envs.scene_cache import SceneBatch, SceneCache, shared_blocks, start_nodes
from covert_env.geometry.zone import zone_lattice
from covert_env.world.metrics import terrain_clearance
from covert_env.world.road import points_along_rows, segments_at
from covert_env.world.scenario import Scenario, pick_starts_many
from covert_env.world.visibility import LOS_TOLERANCE, TerrainRows, grown, visible_nodes_rows

__all__ = ["ScenePool"]


class ScenePool:
    """Scenes by key (a scene seed, ``"paper"`` or a fixed :class:`Scenario`), each in one row of the arrays.

    Args:
        spec: the env's ``scenario`` argument (``"random"``, ``"paper"`` or a Scenario).
        config, lattice, map_offsets, map_in_zone: the env's (see the parallel env).
        waypoint: whether to tabulate the lattice's visibility per slot (the waypoint masks need it).
        path_slots: predicted slots of the target's path in the shared blocks (the env's ``target_path``).
        capacity: rows kept; the least recently used scene no copy flies is replaced beyond it.
        mix: the copies' tasks (:class:`~covert_env.envs.task_mix.TaskMix`) for an env of several tasks, else
            None. A scene's key is then ``(task, seed)``: each is drawn with its task's config, its maps mark its
            task's zone, and its start candidates are its task's zone lattice (padded with unusable nodes).

    Attributes (rows R, slots T = track slots + 1, polytopes M, faces F, lattice nodes L):
        q (R, T, 3), phi (R, T): the target's track, clamped at its end like ``TargetTrack.position``.
        q_next (R, T, 3), phi_next (R, T): row k, the target's pose at slot k + 1 as predicted at slot k
            (``TargetTrack.next_predicted``; ``q[:, k + 1]`` when the prediction is the truth): the waypoint
            actions' and masks' frame.
        blocks (R, T, D) float32: the observation's shared block per slot
            (:func:`~covert_env.envs.scene_cache.shared_blocks`).
        lattice_ok (R, T, L) bool: row k, the lattice nodes visible at slot k as predicted at slot k - 1 (eq. 10,
            :func:`~covert_env.world.visibility.visible_nodes`; the action mask of slot k - 1's move; waypoint mode
        only). start_xy (R, L0, 2), start_visible (R, L0), start_clear (R, L0): the zone lattice at slot 0, its nodes'
            visibility and clearance of the tops (eq. 3): what the starts are drawn from.
        roads (R, K, 2), road_lengths (R, K), road_last (R,): each scene's road (padded; its last vertex
            ``road_last``) and the arc length at each vertex; arc (R, T), arc_segment (R, T): the target's arc
            length at each slot and the road segment it lies on; target_z (R,): the filmed point's height. What
            :meth:`target_between` reads.
        terrains: the scenes' terrains, row r the scene's (:class:`~covert_env.world.visibility.TerrainRows`).
        top (R, M, 3): polytope top points (eq. 3), padded with inf; centre (R, M, 2), radius (R, M): footprint
        circles (views of ``terrains``).
    """

    def __init__(self, spec, config, lattice, map_offsets, map_in_zone, *, waypoint: bool, capacity: int,
                 path_slots: int = 0, mix=None):
        self.spec, self.config, self.lattice = spec, config, lattice
        self._map_cells, self._map_in_zone = map_offsets[map_in_zone], map_in_zone
        self.waypoint, self.capacity, self.path_slots = waypoint, capacity, path_slots
        self.mix = mix
        # Per task (one for an env of one task): its config, map cells in its zone and start lattice.
        if mix is None:
            self._configs, self._in_zone, self._starts = (config,), map_in_zone[None], (zone_lattice(config),)
        else:
            self._configs, self._in_zone, self._starts = mix.configs, mix.map_in_zone, mix.start_lattices
        self._rows: OrderedDict = OrderedDict()          # key -> row, least recently used first
        self._caches: list[SceneCache | None] = []
        self._names: list[str] = []                      # per row, for error messages
        d = shared_block_size(len(map_offsets), path_slots)
        self.q, self.phi = np.zeros((0, 1, 3)), np.zeros((0, 1))
        self.q_next, self.phi_next = np.zeros((0, 1, 3)), np.zeros((0, 1))
        self.blocks = np.zeros((0, 1, d), np.float32)
        self.lattice_ok = np.zeros((0, 1, len(lattice)), bool)
        n0 = max(len(a) for a in self._starts)
        self.start_xy, self.start_visible = np.zeros((0, n0, 2)), np.zeros((0, n0), bool)
        self.start_clear = np.zeros((0, n0), bool)
        self.roads, self.road_lengths = np.zeros((0, 2, 2)), np.zeros((0, 2))
        self.road_last, self.target_z = np.zeros(0, np.intp), np.zeros(0)
        self.arc, self.arc_segment = np.zeros((0, 1)), np.zeros((0, 1), np.intp)
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
    def key(self, scene_seed, task: int = 0) -> object:
        if isinstance(self.spec, Scenario):
            return ("scenario", id(self.spec))
        if self.spec == "paper":
            return "paper"
        return int(scene_seed) if self.mix is None else (int(task), int(scene_seed))

    def rows_of(self, keys: list, in_use: np.ndarray) -> np.ndarray:
        """The rows of the scenes ``keys``, the missing ones built as one batch; ``in_use``: rows copies fly now
        (never replaced, nor are the rows of ``keys``)."""
        out = np.empty(len(keys), dtype=np.intp)
        missing: dict = {}
        for n, key in enumerate(keys):
            if key in self._rows:
                self._rows.move_to_end(key)
                out[n] = self._rows[key]
            else:
                missing.setdefault(key, []).append(n)
        if not missing:
            return out
        # Rows first: unused ones in order, then those of the least recently used scenes no copy flies (nor a copy of
        # this call). Nothing leaves the pool before the new scenes are built: a scene that fails to build leaves
        # the pool as it was.
        hits = [n for n, key in enumerate(keys) if key not in missing]
        busy = set(np.asarray(in_use).tolist()) | set(out[hits].tolist())
        taken = np.fromiter(self._rows.values(), dtype=np.intp, count=len(self._rows))
        free = np.setdiff1d(np.arange(self.capacity), taken)[:len(missing)].tolist()
        stale = [k for k, r in self._rows.items() if r not in busy][:len(missing) - len(free)]
        if len(free) + len(stale) < len(missing):
            raise RuntimeError("ScenePool: every row is in use; raise the capacity")
        # One batch per task (one for an env of one task), all built before any is written.
        keys = list(missing)
        task = np.array([k[0] for k in keys] if self.mix is not None else [0] * len(keys))
        batches = [(t, np.flatnonzero(task == t)) for t in np.unique(task).tolist()]
        batches = [(t, sel, self._batch([keys[i] for i in sel], t)) for t, sel in batches]
        rows = free + [self._rows.pop(k) for k in stale]
        for t, sel, batch in batches:
            self._fill(np.array(rows, dtype=np.intp)[sel], batch, t)
        for (key, ns), r in zip(missing.items(), rows, strict=True):
            self._rows[key] = r
            out[ns] = r
        return out

    def row(self, key, in_use: np.ndarray) -> int:
        """The row of the scene ``key``, built if needed (:meth:`rows_of` of one key)."""
        return int(self.rows_of([key], in_use)[0])

    def cache(self, row: int) -> SceneCache:
        """The scene objects of ``row`` (built on first use)."""
        return self._caches[row]

    def draw_episodes(self, rows: np.ndarray, idx: np.ndarray, rngs, scene_seeds, scene_pool: int, draw_starts: bool,
                      n_uavs: int, tasks=None) -> tuple[np.ndarray, np.ndarray]:
        """Scenes and starts of new episodes for the copies ``idx``, each from its own generator in ``rngs``.

        ``rows`` (B,): every copy's scene row, updated in place for ``idx`` (their old scenes may leave the pool
        first, so a pool of B scenes works). A copy's scene is ``scene_seeds[n]`` or, for ``scenario="random"``,
        a seed drawn from its generator in ``range(scene_pool)``; its starts are drawn from the generator
        (``draw_starts``) or the scene's own seeded ones (a new generator of its seed, as ``Scenario.random``),
        both by :func:`~covert_env.world.scenario.pick_starts_many` on the pool's start candidates. Returns the starts
        ``(len(idx), U, 2)`` and headings ``(len(idx), U)``. The missing scenes are built as one batch;
        drawing is the one per-copy step of a reset (a few µs per copy, once per episode): every copy has its own
        generator. ``tasks``: the copies' tasks (an env of several tasks).
        """
        if len(idx) == 0:
            return np.zeros((0, n_uavs, 2)), np.zeros((0, n_uavs))
        rows[idx] = -1
        seeds = [None if scene_seeds is None else int(scene_seeds[n]) for n in range(len(idx))]
        if self.spec == "random":
            seeds = [int(rng.integers(scene_pool)) if s is None else s for s, rng in zip(seeds, rngs, strict=True)]
        tasks = np.zeros(len(idx), np.intp) if tasks is None else tasks
        rows[idx] = got = self.rows_of([self.key(s, t) for s, t in zip(seeds, tasks.tolist(), strict=True)], rows)
        if not draw_starts and self.spec == "random":
            # Each scene's own starts (Scenario.random(seed)): the start rule with a new generator of its seed.
            rngs = [np.random.default_rng(s) for s in seeds]
        elif not draw_starts:
            sc = self.cache(int(got[0])).seeded_scenario()            # a fixed scenario: its starts
            return np.broadcast_to(sc.uav_xy, (len(idx), n_uavs, 2)).copy(), \
                np.broadcast_to(sc.uav_theta, (len(idx), n_uavs)).copy()
        usable = self.start_clear[got]
        vis = self.start_visible[got] & usable
        return pick_starts_many(self.config, self.start_xy[got], [np.flatnonzero(v) for v in vis],
                                [np.flatnonzero(v) for v in usable & ~vis], rngs, n_uavs,
                                [self._names[r] for r in got.tolist()])

    def _batch(self, keys: list, task: int) -> SceneBatch:
        c = self._configs[task]
        if isinstance(self.spec, Scenario):
            return SceneBatch.of(keys[0], self.spec)
        if self.spec == "paper":
            return SceneBatch.of(keys[0], Scenario.paper(c))
        return SceneBatch.random(keys if self.mix is None else [k[1] for k in keys], c)

    def _fill(self, rows: np.ndarray, batch: SceneBatch, task: int) -> None:
        """Write the scenes of ``batch`` (of task ``task``) into ``rows``, with their per-slot quantities (one batched
        call each)."""
        c = self._configs[task]
        n_t = batch.q.shape[1]
        n = max(int(rows.max()) + 1, len(self.q))
        t = max(n_t, self.q.shape[1])
        if n > len(self.q):                                 # grow geometrically: amortised O(1) per scene
            n = max(n, min(2 * len(self.q), self.capacity))
        self.q = grown(self.q, (n, t, 3), 0.0)
        self.phi = grown(self.phi, (n, t), 0.0)
        self.q_next = grown(self.q_next, (n, t, 3), 0.0)
        self.phi_next = grown(self.phi_next, (n, t), 0.0)
        self.blocks = grown(self.blocks, (n, t, self.blocks.shape[2]), 0.0)
        if self.waypoint:
            self.lattice_ok = grown(self.lattice_ok, (n, t, len(self.lattice)), False)
        self.start_xy = grown(self.start_xy, (n,) + self.start_xy.shape[1:], 0.0)
        self.start_visible = grown(self.start_visible, (n,) + self.start_visible.shape[1:], False)
        self.start_clear = grown(self.start_clear, (n,) + self.start_clear.shape[1:], False)
        k_road = max(batch.roads.shape[1], self.roads.shape[1])
        self.roads = grown(self.roads, (n, k_road, 2), 0.0)
        self.road_lengths = grown(self.road_lengths, (n, k_road), 0.0)
        self.road_last, self.target_z = grown(self.road_last, (n,), 0), grown(self.target_z, (n,), 0.0)
        self.arc, self.arc_segment = grown(self.arc, (n, t), 0.0), grown(self.arc_segment, (n, t), 0)
        while len(self._caches) < n:
            self._caches.append(None)
            self._names.append("")

        self.terrains.set_rows(rows, batch.hs, batch.centre, batch.radius, batch.z_max, batch.top, batch.growth)
        ks = np.minimum(np.arange(t), n_t - 1)             # clamped at the track's end
        self.q[rows], self.phi[rows] = batch.q[:, ks], batch.phi[:, ks]
        self.q_next[rows], self.phi_next[rows] = batch.q_next[:, ks], batch.phi_next[:, ks]
        k_road = batch.roads.shape[1]
        self.roads[rows, :k_road], self.road_lengths[rows, :k_road] = batch.roads, batch.road_lengths
        self.road_last[rows], self.target_z[rows] = k_road - 1, batch.z
        self.arc[rows] = batch.arc[:, ks]
        self.arc_segment[rows] = segments_at(batch.road_lengths, batch.arc)[:, ks]
        self.blocks[rows] = self._blocks(rows, batch, task)[:, ks]
        if self.waypoint:
            self.lattice_ok[rows] = self._lattice_visible(rows, batch)[:, ks]
        self._write_starts(rows, batch, task)
        prefix = "" if self.mix is None else f"{self.mix.names[task]}/"
        for key, r in zip(batch.keys, rows.tolist(), strict=True):
            sc = batch.scenario
            self._caches[r] = SceneCache(c, seed=None if sc is not None else key, scenario=sc)
            self._names[r] = sc.name if sc is not None else f"{prefix}random-{key}"

    def _blocks(self, rows: np.ndarray, batch: SceneBatch, task: int) -> np.ndarray:
        """(N, T, D) the shared blocks of the scenes just written into ``rows``: their maps at every slot and at
        the predicted next one (the next slot's maps when the prediction is the truth). The maps are 1 only in the
        task's zone: each cell's line of sight is its own, so the cells of the env's zone are tested and those
        outside the task's (eroded) zone set to 0."""
        c, in_zone = self._configs[task], self._map_in_zone
        outside = ~self._in_zone[task][in_zone]
        maps = np.zeros(batch.q.shape[:2] + (len(in_zone),), np.float32)
        seen = visible_nodes_rows(self.terrains, rows, self._map_cells, batch.q, batch.phi, c.altitude)
        seen[..., outside] = False
        maps[..., in_zone] = seen
        if batch.exact:
            maps_next = maps[:, np.minimum(np.arange(maps.shape[1]) + 1, maps.shape[1] - 1)]
        else:
            maps_next = np.zeros_like(maps)
            seen = visible_nodes_rows(self.terrains, rows, self._map_cells, batch.q_next, batch.phi_next, c.altitude)
            seen[..., outside] = False
            maps_next[..., in_zone] = seen
        return shared_blocks(c, batch, maps, maps_next, self.path_slots)

    def _lattice_visible(self, rows: np.ndarray, batch: SceneBatch) -> np.ndarray:
        """(N, T, L) row k: the lattice nodes visible at slot k as predicted at k - 1 (row 0: slot 0; no mask reads
        it)."""
        q = np.concatenate([batch.q[:, :1], batch.q_next[:, :-1]], axis=1)
        phi = np.concatenate([batch.phi[:, :1], batch.phi_next[:, :-1]], axis=1)
        return visible_nodes_rows(self.terrains, rows, self.lattice, q, phi, self.config.altitude)

    def _write_starts(self, rows: np.ndarray, batch: SceneBatch, task: int) -> None:
        """The start candidates of the scenes just written into ``rows`` (:func:`start_nodes` and their LoS): the
        task's start lattice, padded with unusable nodes to the longest task's."""
        c, nodes = self._configs[task], self._starts[task]
        n = len(nodes)
        self.start_xy[rows, n:], self.start_clear[rows, n:], self.start_visible[rows, n:] = 0.0, False, False
        self.start_xy[rows, :n], self.start_clear[rows, :n] = start_nodes(c, nodes, batch.q[:, 0], batch.phi[:, 0],
                                                                          batch.top)
        if self.waypoint and batch.exact and np.array_equal(self.lattice, nodes):
            # The same nodes and targets: the same decisions.
            self.start_visible[rows, :n] = self.lattice_ok[rows, 0]
        else:
            self.start_visible[rows, :n] = visible_nodes_rows(self.terrains, rows, nodes, batch.q[:, :1],
                                                              batch.phi[:, :1], c.altitude)[:, 0]

    # ------------------------------------------------------------------ geometry
    def line_of_sight(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                      *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) from UAVs ``uav_xy`` (B, U, 2) at ``altitude`` to targets ``target_xyz`` (B, 3), copy
        b against the terrain of scene row ``rows[b]``; (B, U) bool (:meth:`TerrainRows.line_of_sight
        <covert_env.world.visibility.TerrainRows.line_of_sight>`)."""
        return self.terrains.line_of_sight(rows, uav_xy, altitude, target_xyz, tol=tol)

    def target_between(self, rows: np.ndarray, k: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        """(B, F, 3) the target of copy b (scene row ``rows[b]``) at times (k[b] + f) delta within slot k[b], for the
        ``fractions`` f (F,) in [0, 1]: ``TargetTrack.position_between`` of the scene's track, bit for bit."""
        a0, a1 = self.arc[rows, k], self.arc[rows, k + 1]
        s = a0[:, None] + fractions * (a1 - a0)[:, None]
        xy = points_along_rows(self.roads, self.road_lengths, self.road_last, rows, s, self.arc_segment[rows, k, None])
        return np.concatenate([xy, np.broadcast_to(self.target_z[rows, None, None], s.shape + (1,))], axis=-1)

    def path_line_of_sight(self, rows: np.ndarray, k: np.ndarray, path_xy: np.ndarray, altitude: float,
                           fractions: np.ndarray) -> np.ndarray:
        """(B, U, F) clear LoS (eq. 6) from the path samples ``path_xy`` (B, U, F, 2) of slot k[b] to the target at
        the same instants (``fractions`` (F,) of the slot), copy b against its own scene: one batched call
        (:meth:`TerrainRows.line_of_sight_paths <covert_env.world.visibility.TerrainRows.line_of_sight_paths>`)."""
        target = self.target_between(rows, k, fractions)
        return self.terrains.line_of_sight_paths(rows, path_xy, altitude, target)

    def terrain_clearance(self, rows: np.ndarray, xy: np.ndarray, altitude: float) -> np.ndarray:
        """(B, U) distance from (x, y, h) to the nearest polytope top of each copy's scene (eq. 3; inf if none)."""
        return terrain_clearance(xy, altitude, self.copy_terrains(rows))

    def copy_terrains(self, rows: np.ndarray) -> _CopyTerrains:
        """The terrain of each copy, copy b flying scene row ``rows[b]``: what
        :func:`~covert_env.world.metrics.moves_quantities` and :func:`~covert_env.world.metrics.terrain_clearance`
        read."""
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
