"""Scenes shared by the copies of a vector env, as padded arrays with one row per scene.

Everything that depends only on the scene and the slot (the target's track, the observation's shared block with
its visibility maps, which lattice nodes are visible, the start nodes) is computed once when a scene enters the
pool, by :class:`~covert_env.envs.scene_cache.SceneCache` (so every copy and reset sees
the same numbers), and stacked into arrays ``(R, ...)``. A copy of the vector env only holds its row index: every
per-step quantity is a gather ``array[rows, slots]``, one array operation for the whole batch.

The terrains are padded to ``(R, M_max, F_max, 4)`` half-spaces as in :class:`~covert_env.visibility.TerrainStack`:
extra faces are the always-true row ``0.x - 1 <= 0`` and extra polytopes are marked invalid, so padding never
blocks a line of sight.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from covert_env.envs.observation import shared_block_size
from covert_env.envs.scene_cache import SceneCache
from covert_env.metrics import terrain_clearance
from covert_env.scenario import Scenario, pick_starts, start_candidates
from covert_env.visibility import LOS_TOLERANCE, _arrays, _clip, _passes_near

__all__ = ["ScenePool"]


def _grown(arr: np.ndarray, shape: tuple, fill) -> np.ndarray:
    """``arr`` copied into a larger array of ``shape`` (each axis at least as long), the rest ``fill``."""
    if arr.shape == shape:
        return arr
    out = np.full(shape, fill, dtype=arr.dtype)
    out[tuple(slice(0, n) for n in arr.shape)] = arr
    return out


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
        lattice_ok (R, T, L) bool: lattice nodes in the eroded zone with clear LoS (waypoint mode only).
        hs (R, M, F, 4), centre (R, M, 2), radius (R, M), z_max (R, M), valid (R, M): padded terrain.
        top (R, M, 3): polytope top points (eq. 3), padded with inf.
    """

    def __init__(self, spec, config, lattice, map_offsets, map_in_zone, *, waypoint: bool, capacity: int):
        self.spec, self.config, self.lattice = spec, config, lattice
        self._map_offsets, self._map_in_zone = map_offsets, map_in_zone
        self.waypoint, self.capacity = waypoint, capacity
        self._rows: OrderedDict = OrderedDict()          # key -> row, least recently used first
        self._caches: list[SceneCache | None] = []
        self._start_nodes: list[tuple | None] = []
        d = shared_block_size(len(map_offsets))
        self.q, self.phi = np.zeros((0, 1, 3)), np.zeros((0, 1))
        self.blocks = np.zeros((0, 1, d), np.float32)
        self.lattice_ok = np.zeros((0, 1, len(lattice)), bool)
        self.hs, self.centre = np.zeros((0, 0, 1, 4)), np.zeros((0, 0, 2))
        self.radius, self.z_max, self.valid = np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((0, 0), bool)
        self.top = np.zeros((0, 0, 3))

    def __len__(self) -> int:
        return len(self._rows)

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
        for n, (j, rng) in enumerate(zip(idx, rngs, strict=True)):
            s = None if scene_seeds is None else int(scene_seeds[n])
            if s is None and self.spec == "random":
                s = int(rng.integers(scene_pool))
            rows[j] = row = self.row(self.key(s), rows)
            if draw_starts:
                xy[n], theta[n] = pick_starts(c, *self.start_candidates(row), rng, n_uavs, self.cache(row).parts.name)
            else:
                sc = self.cache(row).seeded_scenario()
                xy[n], theta[n] = sc.uav_xy, sc.uav_theta
        return xy, theta

    def start_candidates(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """What ``Scenario.sample_starts`` draws the scene's starts from (``scenario.start_candidates``): the
        zone lattice at slot 0 and its nodes with clear LoS, computed once per scene."""
        return self._start_nodes[row]

    def _build(self, key) -> SceneCache:
        c = self.config
        if isinstance(self.spec, Scenario):
            sc, seed = self.spec, None
        elif self.spec == "paper":
            sc, seed = Scenario.paper(c), None
        else:
            sc, seed = None, key
        return SceneCache(sc, self._map_offsets, self._map_in_zone, self.lattice, seed=seed, config=c)

    def _fill(self, r: int, cache: SceneCache) -> None:
        w, c = cache.parts, self.config
        n_t = w.track.n_slots + 1
        arr = _arrays(w.terrain)
        m, f = arr.hs.shape[:2]
        rows = max(r + 1, len(self.q))
        t = max(n_t, self.q.shape[1])
        if rows > len(self.q):                              # grow geometrically: amortised O(1) per scene
            rows = max(rows, min(2 * len(self.q), self.capacity))
        self.q = _grown(self.q, (rows, t, 3), 0.0)
        self.phi = _grown(self.phi, (rows, t), 0.0)
        self.blocks = _grown(self.blocks, (rows, t, self.blocks.shape[2]), 0.0)
        if self.waypoint:
            self.lattice_ok = _grown(self.lattice_ok, (rows, t, len(self.lattice)), False)
        mm, ff = max(m, self.hs.shape[1]), max(f, self.hs.shape[2])
        pad_face = np.array([0.0, 0.0, 0.0, -1.0])
        hs = _grown(self.hs, (rows, mm, ff, 4), 0.0)
        hs[len(self.hs):] = pad_face
        hs[:len(self.hs), :, self.hs.shape[2]:] = pad_face
        hs[:len(self.hs), self.hs.shape[1]:] = pad_face
        self.hs = hs
        self.centre = _grown(self.centre, (rows, mm, 2), 0.0)
        self.radius = _grown(self.radius, (rows, mm), 0.0)
        self.z_max = _grown(self.z_max, (rows, mm), 0.0)
        self.valid = _grown(self.valid, (rows, mm), False)
        self.top = _grown(self.top, (rows, mm, 3), np.inf)
        while len(self._caches) < rows:
            self._caches.append(None)
            self._start_nodes.append(None)

        ks = np.minimum(np.arange(t), n_t - 1)             # clamped at the track's end
        self.q[r] = w.track.positions[ks]
        self.phi[r] = w.track.headings[ks]
        self.blocks[r] = cache.shared_blocks()[ks]
        if self.waypoint:
            self.lattice_ok[r] = cache.lattice_visible()[ks]
        self.hs[r] = pad_face
        self.hs[r, :m, :f] = arr.hs
        self.centre[r] = 0.0
        self.centre[r, :m] = arr.centre
        self.radius[r], self.z_max[r], self.valid[r], self.top[r] = 0.0, 0.0, False, np.inf
        self.radius[r, :m], self.z_max[r, :m], self.valid[r, :m] = arr.radius, arr.z_max, True
        self.top[r, :m] = w.terrain.highest_points
        self._start_nodes[r] = start_candidates(c, w.terrain, w.track)
        self._caches[r] = cache

    # ------------------------------------------------------------------ geometry
    def line_of_sight(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                      *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) from UAVs ``uav_xy`` (B, U, 2) at ``altitude`` to targets ``target_xyz`` (B, 3), copy
        b against the terrain of scene row ``rows[b]``; (B, U) bool.

        Two broad phases, then the exact clip (``visibility``'s Cyrus-Beck routine), each one array operation over
        the batch: (copy, UAV, polytope) triples whose footprint circle lies in the UAV's direction from the target
        and within reach of the part of the segment lower than the polytope's top (that part lies within
        ``|p - q| (z_max - z_q) / (h - z_q)`` of the target); then that part must pass within the circle
        (``line_of_sight``'s test); the triples left are clipped exactly."""
        q = target_xyz
        rel_x, rel_y = uav_xy[..., 0] - q[:, 0, None], uav_xy[..., 1] - q[:, 1, None]
        dist = np.sqrt(rel_x * rel_x + rel_y * rel_y)                                  # (B, U)
        z_max, centre, radius = self.z_max[rows], self.centre[rows], self.radius[rows]   # (B, M, ...)
        if altitude > q[:, 2].max():
            low = np.clip((z_max - q[:, 2, None]) / (altitude - q[:, 2, None]), 0.0, 1.0)
        else:
            low = np.ones(z_max.shape)
        cx, cy = centre[..., 0] - q[:, 0, None], centre[..., 1] - q[:, 1, None]          # (B, M)
        gap = np.hypot(cx, cy)
        r = radius + 1e-9
        reach = gap - r
        reach[~self.valid[rows]] = np.inf
        # The UAV's bearing from the target must lie in the cone the footprint circle subtends there:
        # rel . c >= |rel| sqrt(gap^2 - r^2) (every direction when the target is inside the circle). 1e-9 slack.
        cone = np.where(gap > r, np.sqrt(np.maximum(gap * gap - r * r, 0.0)) - 1e-9 * gap, -1e300)
        cand = reach[:, None, :] <= dist[..., None] * low[:, None, :]
        dot = rel_x[..., None] * cx[:, None, :] + rel_y[..., None] * cy[:, None, :]
        cand &= dot >= dist[..., None] * cone[:, None, :]
        b, u, m = np.nonzero(cand)
        out = np.ones(uav_xy.shape[:2], dtype=bool)
        if len(b) == 0:
            return out
        # The part of the segment UAV -> target lower than the top, s in [s0, s1], must pass within the circle.
        ux, uy, qb = uav_xy[b, u, 0], uav_xy[b, u, 1], q[b]
        dz = qb[:, 2] - altitude
        with np.errstate(over="ignore", divide="ignore"):
            sc = (z_max[b, m] - altitude) / np.where(dz == 0, -1e-300, dz)
        down = dz <= 0
        s0 = np.clip(np.where(down, sc, 0.0), 0.0, 1.0)
        s1 = np.clip(np.where(down, 1.0, sc), 0.0, 1.0)
        near = (s1 > s0 - 1e-12) & _passes_near(ux, uy, qb[:, 0] - ux, qb[:, 1] - uy, s0, s1,
                                                centre[b, m, 0], centre[b, m, 1], radius[b, m])
        b, u, m = b[near], u[near], m[near]
        if len(b) == 0:
            return out
        hm = self.hs[rows[b], m]                                                 # (K, F, 4)
        p = np.empty((len(b), 3))
        p[:, :2] = uav_xy[b, u]
        p[:, 2] = altitude
        num = np.einsum("pfi,pi->pf", hm[..., :3], p) + hm[..., 3] + tol
        vq = np.einsum("pfi,pi->pf", hm[..., :3], q[b]) + hm[..., 3] + tol
        blocked = _clip(num, vq - num)
        out[b[blocked], u[blocked]] = False
        return out

    def terrain_clearance(self, rows: np.ndarray, xy: np.ndarray, altitude: float) -> np.ndarray:
        """(B, U) distance from (x, y, h) to the nearest polytope top of each copy's scene (eq. 3; inf if none)."""
        return terrain_clearance(xy, altitude, _Tops(self.top[rows]))


class _Tops:
    """Polytope tops of a batch of copies, as :func:`~covert_env.metrics.terrain_clearance` reads a terrain stack."""

    __slots__ = ("highest_points",)

    def __init__(self, top: np.ndarray):
        self.highest_points = top
