"""What a scene gives every agent, reset and copy: per-slot maps, shared observation blocks and lattice visibility.

A :class:`SceneCache` holds one scene (terrain and target track; the starts only when asked) and computes, lazily
and vectorised over slots, everything of an observation that does not depend on the UAVs. The vector env's
:class:`~covert_env.envs.scene_pool.ScenePool` stacks them into arrays.
"""

from __future__ import annotations

import copy

import numpy as np

from covert_env.config import Config
from covert_env.envs.observation import shared_block_size
from covert_env.scenario import Scenario, sample_starts_on
from covert_env.visibility import line_of_sight, line_of_sight_rows
from covert_env.zone import in_feasible_zone, to_world

__all__ = ["SceneCache", "World"]


class SceneCache:
    """Per-scene, per-slot results that do not depend on the UAVs (shared by all agents and resets).

    The observation maps' cells are fixed in the target's frame, so which cells lie in the eroded zone
    is one mask for every slot; only their line of sight changes. It is computed for ``_MAP_CHUNK``
    slots at once (one vectorised call with a target per slot): a new scene costs a few ms for the
    whole episode instead of a broad phase per slot.
    """

    _MAP_CHUNK = 32

    def __init__(self, scenario: Scenario | None, map_offsets: np.ndarray, map_in_zone: np.ndarray,
                 lattice: np.ndarray, *, seed: int | None = None, config: Config | None = None):
        if scenario is None:
            # A random scene: build the world now, its seeded starts only if a reset asks for them
            # (training resets draw their own starts).
            terrain, track, self._rng = Scenario.random_world(seed, config)
            self.parts = World(config, terrain, track, f"random-{seed}")
        else:
            self.parts = World(scenario.config, scenario.terrain, scenario.track, scenario.name)
        self._seeded = scenario
        self._map_offsets = map_offsets[map_in_zone]
        self._map_in_zone = map_in_zone
        self._lattice = lattice
        # One row per slot 0..n of the track (positions are clamped at its end, like TargetTrack.position).
        self._maps = np.zeros((self.parts.track.n_slots + 1, len(map_offsets)), np.float32)
        self._chunks: set[int] = set()
        self._lattice_ok: dict[int, np.ndarray] = {}
        # The observation's shared block per slot (ObservationLayout.shared_size: the target's displacement, the
        # time remaining, both maps).
        self._blocks = np.zeros((len(self._maps), shared_block_size(len(map_offsets))), np.float32)
        self._blocks.setflags(write=False)

    def _visible(self, offsets: np.ndarray, k: int) -> np.ndarray:
        """Which offsets are in the eroded zone with clear LoS at slot k >= 1, as predicted at slot k - 1."""
        c = self.parts.config
        q, phi = self.parts.track.predict(k - 1, 1)
        q, phi = q[0], float(phi[0])
        xy = to_world(offsets, q[:2], phi)
        ok = in_feasible_zone(xy, q[:2], phi, c.r1, c.r2, c.mu, c.r_u)
        if ok.any():
            ok[ok] = line_of_sight(self.parts.terrain, xy[ok], c.altitude, q)
        return ok

    def shared_block(self, k: int) -> np.ndarray:
        """The observation's shared block at slot k, read-only: the target's displacement to k+1 in its
        frame, 0 for the time remaining (per env), and the maps at k and k+1."""
        k = min(k, len(self._maps) - 1)
        self._chunk(k // self._MAP_CHUNK)
        return self._blocks[k]

    def _chunk(self, chunk: int) -> None:
        """Maps of slots lo..hi and shared blocks of slots lo..hi-1 (hi = lo + _MAP_CHUNK), each in one
        vectorised call; the last chunk stops at the track's last slot n, blocks included."""
        if chunk in self._chunks:
            return
        self._chunks.add(chunk)
        track, c = self.parts.track, self.parts.config
        n = len(self._maps) - 1
        lo, hi = chunk * self._MAP_CHUNK, min((chunk + 1) * self._MAP_CHUNK, n)
        ks = np.arange(lo, hi + 1)
        q, phi = track.positions[ks], track.headings[ks]
        cs, sn = np.cos(phi), np.sin(phi)
        if len(self._map_offsets):
            ox, oy = self._map_offsets[:, 0], self._map_offsets[:, 1]
            xy = np.stack([q[:, :1] + cs[:, None] * ox - sn[:, None] * oy,
                           q[:, 1:2] + sn[:, None] * ox + cs[:, None] * oy], axis=-1)
            clear = line_of_sight_rows(self.parts.terrain, xy, c.altitude, q)
            rows = self._maps[ks]
            rows[:, self._map_in_zone] = clear
            self._maps[ks] = rows
        # Blocks of slots lo..hi-1 (slot hi's belongs to the next chunk); the last chunk also writes slot n's,
        # whose next slot is n itself (the track's end: no displacement).
        own = ks if (chunk + 1) * self._MAP_CHUNK > n else ks[:-1]
        nxt = np.minimum(own + 1, n)
        # Slot k+1 as predicted at slot k (the truth when the config has no prediction error).
        q_next, phi_next = track.next_predicted[0][own], track.next_predicted[1][own]
        dx, dy = q_next[:, 0] - q[:len(own), 0], q_next[:, 1] - q[:len(own), 1]
        scale = c.v_max * c.delta
        cs, sn = cs[:len(own)], sn[:len(own)]
        blocks = self._blocks
        blocks.setflags(write=True)
        blocks[own, 0] = np.clip((cs * dx + sn * dy) / scale, -2.0, 2.0)
        blocks[own, 1] = np.clip((cs * dy - sn * dx) / scale, -2.0, 2.0)
        blocks[own, 2] = 0.0
        s2 = self._maps.shape[1]
        blocks[own, 3:3 + s2] = self._maps[own]
        blocks[own, 3 + s2:] = self._maps[nxt] if track.exact else self._predicted_maps(q_next, phi_next)
        blocks.setflags(write=False)

    def _predicted_maps(self, q: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Map rows (like ``_maps``) around predicted target poses q (K, 3), phi (K,)."""
        rows = np.zeros((len(q), self._maps.shape[1]), np.float32)
        if len(self._map_offsets):
            cs, sn = np.cos(phi)[:, None], np.sin(phi)[:, None]
            ox, oy = self._map_offsets[:, 0], self._map_offsets[:, 1]
            xy = np.stack([q[:, :1] + cs * ox - sn * oy, q[:, 1:2] + sn * ox + cs * oy], axis=-1)
            rows[:, self._map_in_zone] = line_of_sight_rows(self.parts.terrain, xy, self.parts.config.altitude, q)
        return rows

    def lattice_visible(self, k: int) -> np.ndarray:
        """Waypoint lattice nodes in the eroded zone with clear LoS at slot k >= 1 as predicted at slot
        k - 1 (the action mask of slot k - 1's move; bool)."""
        if k not in self._lattice_ok:
            self._lattice_ok[k] = self._visible(self._lattice, k)
        return self._lattice_ok[k]

    def seeded_scenario(self) -> Scenario:
        """The scene with its own starts: ``Scenario.random(seed)`` exactly (or the given scenario)."""
        if self._seeded is None:
            w = self.parts
            # A copy of the generator: a failed attempt must not shift the starts of the next one.
            xy, th = sample_starts_on(w.config, w.terrain, w.track, copy.deepcopy(self._rng), w.config.n_uavs, w.name)
            self._seeded = Scenario(w.config, w.terrain, w.track, xy, th, name=w.name)
        return self._seeded

    def with_starts(self, rng: np.random.Generator, n_uavs: int) -> Scenario:
        """The scene with ``n_uavs`` starts drawn from ``rng`` (see :meth:`Scenario.sample_starts`)."""
        w = self.parts
        xy, th = sample_starts_on(w.config, w.terrain, w.track, rng, n_uavs, w.name)
        return Scenario(w.config, w.terrain, w.track, xy, th, name=w.name)


class World:
    """The scene without starts (what the scene cache's slot computations need)."""

    __slots__ = ("config", "terrain", "track", "name")

    def __init__(self, config: Config, terrain, track, name: str):
        self.config, self.terrain, self.track, self.name = config, terrain, track, name
