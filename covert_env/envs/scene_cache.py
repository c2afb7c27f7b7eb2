"""What a scene gives every agent, reset and copy: per-slot maps, shared observation blocks and lattice visibility.

A :class:`SceneCache` holds one scene (terrain and target track; the starts only when asked) and computes, lazily
and vectorised over slots, everything of an observation that does not depend on the UAVs. The vector env's
:class:`~covert_env.envs.scene_pool.ScenePool` stacks them into arrays.
"""

from __future__ import annotations

import copy

import numpy as np

from covert_env.config import Config
from covert_env.envs.observation import FIELDS, shared_block_slices
from covert_env.scenario import Scenario, sample_starts_on
from covert_env.visibility import visible_nodes

__all__ = ["SceneCache", "World"]

#: The target-displacement field of the observation layout (its bounds clip the shared block).
DISPLACEMENT = next(f for f in FIELDS if f.name == "target_displacement")


class SceneCache:
    """Per-scene, per-slot results that do not depend on the UAVs (shared by all copies and resets).

    The observation maps' cells are fixed in the target's frame, so which cells lie in the eroded zone is one mask
    for every slot; only their line of sight changes. Everything is computed for all slots of the track at once,
    one vectorised line-of-sight call with a target per slot (a new scene costs a few ms, a few tens of ms with
    the waypoint lattice).
    """

    def __init__(self, scenario: Scenario | None, map_offsets: np.ndarray, map_in_zone: np.ndarray,
                 lattice: np.ndarray, *, seed: int | None = None, config: Config | None = None, world=None):
        if scenario is None:
            # A random scene (``world``: its terrain, track and starts generator, if drawn with others in a batch):
            # its seeded starts only if a reset asks for them (training resets draw their own starts).
            terrain, track, self._rng = Scenario.random_world(seed, config) if world is None else world
            self.parts = World(config, terrain, track, f"random-{seed}")
        else:
            self.parts = World(scenario.config, scenario.terrain, scenario.track, scenario.name)
        self._seeded = scenario
        self._map_offsets = map_offsets[map_in_zone]
        self._map_in_zone = map_in_zone
        self._n_cells = len(map_offsets)
        self._lattice = lattice

    def _maps(self, q: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """(K, S*S) float32 maps around target poses q (K, 3), phi (K,): 1 where a cell is in the visible zone
        (eq. 10: in the eroded zone, decided in the target frame, with clear LoS as the action mask sees it)."""
        rows = np.zeros((len(q), self._n_cells), np.float32)
        if len(self._map_offsets):
            rows[:, self._map_in_zone] = visible_nodes(self.parts.terrain, self._map_offsets, q, phi,
                                                       self.parts.config.altitude)
        return rows

    def shared_blocks(self) -> np.ndarray:
        """(n + 1, D) float32, row k the observation's shared block at slot k of the track (n = its last slot): the
        target's displacement to k + 1 as predicted at k, in the target's frame at k; 0 for the time remaining
        (the env writes it); the maps at k and at the predicted k + 1 (:mod:`covert_env.envs.observation`)."""
        track, c = self.parts.track, self.parts.config
        n = track.n_slots
        q, phi = track.positions[:n + 1], track.headings[:n + 1]
        maps = self._maps(q, phi)
        # Slot k+1 as predicted at slot k (the truth when the config has no prediction error; slot n: n itself).
        q_next, phi_next = track.next_predicted
        dx, dy = q_next[:, 0] - q[:, 0], q_next[:, 1] - q[:, 1]
        cs, sn = np.cos(phi), np.sin(phi)
        scale = c.v_max * c.delta
        at = shared_block_slices(self._n_cells)
        blocks = np.zeros((n + 1, at["map_next"].stop), np.float32)
        lo, hi = DISPLACEMENT.low, DISPLACEMENT.high
        disp = blocks[:, at["target_displacement"]]
        disp[:, 0] = np.clip((cs * dx + sn * dy) / scale, lo, hi)
        disp[:, 1] = np.clip((cs * dy - sn * dx) / scale, lo, hi)
        blocks[:, at["map_now"]] = maps
        blocks[:, at["map_next"]] = (maps[np.minimum(np.arange(n + 1) + 1, n)] if track.exact
                                     else self._maps(q_next, phi_next))
        return blocks

    def lattice_visible(self) -> np.ndarray:
        """(n + 1, L) bool, row k: the waypoint lattice nodes (all in the eroded zone) visible (eq. 10,
        :func:`~covert_env.visibility.visible_nodes`) at slot k as predicted at slot k - 1 (the action mask of slot
        k - 1's move; row 0 at slot 0)."""
        c, track = self.parts.config, self.parts.track
        q_next, phi_next = track.next_predicted
        q0, phi0 = track.predict(-1, 1)
        q = np.vstack([q0, q_next[:-1]])
        phi = np.concatenate([phi0, phi_next[:-1]])
        return visible_nodes(self.parts.terrain, self._lattice, q, phi, c.altitude)

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
