"""PettingZoo ParallelEnv: a team of UAVs covertly filming a target on uneven terrain.

A thin adapter over :class:`covert_env.engine.Engine`: the engine flies the UAVs and records the
episode; this module turns agent actions into engine controls, engine state into observations, and
the paper's stage cost into rewards. No geometry or physics is written here.
"""

from __future__ import annotations

import copy
import math
import operator
from collections import OrderedDict
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from covert_env.config import Config
from covert_env.dynamics import solve_manoeuvre
from covert_env.engine import Engine, step_engines
from covert_env.envs.batch import COSTS as _COSTS
from covert_env.envs.batch import (
    OFFSET_CLIP,
    constraint_costs,
    own_features,
    reward_terms,
    unicycle_controls,
)
from covert_env.envs.batch import REWARD_TERMS as _REWARD_TERMS
from covert_env.metrics import nearest_teammate, terrain_clearance
from covert_env.scenario import PAPER_UAV_STARTS, Scenario, _sample_starts
from covert_env.visibility import line_of_sight, line_of_sight_rows
from covert_env.zone import in_feasible_zone, lattice_offsets, to_world, zone_distance, zone_lattice

__all__ = ["CovertSensingParallelEnv", "env", "parallel_env", "raw_env", "step_copies", "ACTION_MODES"]

ACTION_MODES = ("unicycle", "waypoint")
#: Largest ``scene_pool``: training scene seeds 0 .. scene_pool-1 stay below the held-out seeds 1_000_000 + i.
MAX_SCENE_POOL = 1_000_000
#: Largest ``path_samples`` accepted: memory per step grows with it, and 1000 samples per 1 s slot is far past useful.
MAX_PATH_SAMPLES = 1000


class _SceneCache:
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
            terrain, track, self._rng = Scenario._random_world(seed, config)
            self.parts = _World(config, terrain, track, f"random-{seed}")
        else:
            self.parts = _World(scenario.config, scenario.terrain, scenario.track, scenario.name)
        self._seeded = scenario
        self._map_offsets = map_offsets[map_in_zone]
        self._map_in_zone = map_in_zone
        self._lattice = lattice
        # One row per slot 0..n of the track (positions are clamped at its end, like TargetTrack.position).
        self._maps = np.zeros((self.parts.track.n_slots + 1, len(map_offsets)), np.float32)
        self._chunks: set[int] = set()
        self._lattice_ok: dict[int, np.ndarray] = {}
        # The observation's shared block per slot (see CovertSensingParallelEnv._shared_features).
        self._blocks = np.zeros((len(self._maps), 3 + 2 * len(map_offsets)), np.float32)
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
            xy, th = _sample_starts(w.config, w.terrain, w.track, copy.deepcopy(self._rng), w.config.n_uavs, w.name)
            self._seeded = Scenario(w.config, w.terrain, w.track, xy, th, name=w.name)
        return self._seeded

    def with_starts(self, rng: np.random.Generator, n_uavs: int) -> Scenario:
        """The scene with ``n_uavs`` starts drawn from ``rng`` (see :meth:`Scenario.sample_starts`)."""
        w = self.parts
        xy, th = _sample_starts(w.config, w.terrain, w.track, rng, n_uavs, w.name)
        return Scenario(w.config, w.terrain, w.track, xy, th, name=w.name)


class _World:
    """The scene without starts (what the scene cache's slot computations need)."""

    __slots__ = ("config", "terrain", "track", "name")

    def __init__(self, config: Config, terrain, track, name: str):
        self.config, self.terrain, self.track, self.name = config, terrain, track, name


class CovertSensingParallelEnv(ParallelEnv):
    """Covert video sensing of a ground target by a team of UAVs on uneven terrain.

    ## Description

    A target drives along a road through buildings and hills (convex polytopes). U UAVs at a fixed
    altitude h must film it covertly, as in Almuzaini & Savkin (2024): stay inside the feasible flight
    zone behind the target (an annular sector between radii R1 and R2 and within mu/2 of straight
    behind, eq. 4), keep a clear line of sight (outside the terrain's "shadows", eqs. 6-10), change
    bearing and range every slot (the disguise kappa, eq. 11), fly short paths (energy, eq. 15), keep
    d_safe1 from each other (eq. 2) and d_safe2 from the terrain (eq. 3). One step is one slot of
    ``delta`` seconds. Agents are ``uav_0 .. uav_{U-1}``; all act at once.

    ## Action Space

    ``action_mode="unicycle"`` (default): ``Box(-1, 1, (2,), float32)``, held for the whole slot and
    integrated exactly (a circular arc):

    | index | meaning | scaling |
    |---|---|---|
    | 0 | speed v | ``v = V_max * (0.01 + 0.99 * (a0 + 1) / 2)``, so 0 < v <= V_max |
    | 1 | turn rate omega | ``omega = W_max * a1`` |

    Out-of-range values are clipped to [-1, 1] (documented, as SB3 expects); NaN or inf raise ``ValueError``.

    ``action_mode="waypoint"``: ``Discrete(L)``: the index of a node of a fixed lattice in the target's
    frame (spacing ``grid_step``, the nodes of the eroded zone), placed at the target's next pose
    q[k+1], phi[k+1]. The env flies the turn-then-straight manoeuvre (eqs. 22-29) to it. The planner
    of ``baselines.dp`` uses the same lattice, so it acts exactly through this env.
    The action mask (int8, length L, 1 = allowed) marks nodes that are reachable in one slot and in
    the visible zone (eq. 10) at k+1. It lives in one place per setting: ``infos[agent]["action_mask"]``
    by default, or, with ``dict_obs=True``, the observation ``{"observation": ..., "action_mask": ...}``
    (and then not in the infos); ``env.action_mask(agent)`` returns it in both. If no node qualifies,
    reachable nodes are unmasked, and if none is reachable every node is, so a masked sampler always has a
    choice. A masked-out but reachable node is flown exactly and flagged ``infos[agent]["infeasible"]``;
    an unreachable one is flown as a best effort (the admissible constant (v, omega) ending closest to it,
    see :mod:`covert_env.engine`) and flagged too.

    ## Observation Space

    ``Box(float32)`` in the target's frame at the current slot (x forward along the target's heading,
    y to its left), roughly unit scale. For agent i:

    | index | observation | scale |
    |---|---|---|
    | 0-1 | own offset from the target | / R2, clipped to +-5 |
    | 2-3 | cos, sin of own heading minus target heading | |
    | 4 | own speed in the last slot | / V_max |
    | 5 | LoS to the target is clear (eq. 6) | 0 or 1 |
    | 6 | inside the feasible zone (eq. 4) | 0 or 1 |
    | 7 | signed distance to the zone boundary (negative inside) | / (R2 - R1), clipped to +-5 |
    | 8-9 | target's displacement to its next slot, in the current target frame | / (V_max delta) |
    | 10 | fraction of the episode remaining | 0..1 |
    | 11 .. 11+2(U-1) | teammates' offsets from the target, by agent index | / R2, clipped to +-5 |
    | then S*S | map of cells around the zone: 1 if in the eroded zone with clear LoS, now | 0 or 1 |
    | then S*S | the same map at the next predicted slot k+1 | 0 or 1 |

    S = ``map_size``. The maps cover the zone's bounding box in the target's frame, row-major,
    computed with the exact vectorised line of sight.

    ``state()`` (for centralised critics) concatenates, for every UAV, indices 0-7 above, then the
    target displacement, the time remaining and both maps.

    ## Rewards

    Per agent and slot, from the paper's stage cost g = v delta - lambda (eta |d alpha| + |d d|)
    (eq. 18), divided by ``reward_scale``, plus penalties (each term is ``infos[agent]["reward_<term>"]``):

    * ``path``: ``-v delta / reward_scale`` (energy, eq. 15);
    * ``disguise``: ``+lambda kappa / reward_scale`` (eq. 11);
    * ``los``: ``-los_penalty`` if LoS to the target is blocked at the end of the slot;
    * ``zone``: ``-zone_penalty * (1 + min(outside distance / (R2 - R1), 2))`` if outside the zone;
    * ``separation``: ``-separation_penalty`` if closer than d_safe1 to a teammate at any sample of the slot;
    * ``terrain``: ``-terrain_penalty`` if closer than d_safe2 to a polytope's highest point.

    ## Constraint Costs

    For constrained (safe) RL, e.g. Lagrangian methods, ``infos[agent]`` carries the violations of the
    paper's constraints (§2.4) in the slot just flown, each 0.0 or 1.0, and their sum ``cost``; they do not
    depend on the penalty weights (set the penalties to 0 to train on the stage cost alone):

    | key | constraint violated |
    |---|---|
    | ``cost_los`` | LoS to the (true) target blocked at the end of the slot (eq. 6; outside eq. 10's zone) |
    | ``cost_zone`` | outside the feasible flight zone of the true target at the end of the slot (eq. 4, not eroded: |
    | | eq. 5's erosion by r_u is the planner's margin that guarantees eq. 4) |
    | ``cost_separation`` | closer than d_safe1 to a teammate at any of the ``path_samples`` of the slot (eq. 2) |
    | ``cost_terrain`` | closer than d_safe2 to a polytope's highest point at the end of the slot (eq. 3) |

    LoS, zone and terrain are checked at slot times, as the paper's constraints are stated on the slot
    positions; separation, which the engine samples anyway, along the path. (Terrain generated with the
    default ``max_height`` keeps every top at least d_safe2 below the UAVs, so ``cost_terrain`` fires only on
    terrain given by the user, e.g. a tall pole.)

    ## Infos

    Flat and scalar, with the same keys and types at ``reset()`` and every ``step()`` (as TorchRL and
    BenchMARL need). At reset no slot has been flown: rewards, costs, ``kappa``, ``g`` and ``v`` are 0.

    | key | type | meaning |
    |---|---|---|
    | ``slot`` | int | slot k reached |
    | ``los``, ``in_zone`` | bool | LoS clear / inside the zone at slot k |
    | ``infeasible`` | bool | the waypoint was masked out or unreachable (see Action Space) |
    | ``kappa``, ``g``, ``v`` | float | disguise (eq. 11), stage cost (eq. 18), speed of the slot |
    | ``separation`` | float | nearest teammate along the slot (m; inf with one UAV) |
    | ``terrain_clearance`` | float | distance to the nearest polytope top (m, eq. 3) |
    | ``reward_path`` .. ``reward_terrain`` | float | the reward's terms (they sum to the reward) |
    | ``cost``, ``cost_los`` .. ``cost_terrain`` | float | the constraint costs above |
    | ``action_mask`` | int8 array | waypoint mode without ``dict_obs`` only |

    ## Starting State

    ``scenario="paper"``: the paper's map and UAV starts (40, 10), (60, 0), (50, -10) with headings
    2pi, pi, pi/2 (the first U of them). ``scenario="random"`` (default): every reset draws a scene
    seed from the env's RNG in ``range(scene_pool)`` (a random road and terrain) and UAV starts from
    the same RNG: distinct visible-zone nodes, ``2 d_safe1`` apart, with uniform headings.
    ``options={"scene_seed": s}`` picks the scene and then uses ``Scenario.random(s)``'s own starts,
    exactly what the evaluation harness and ``reproduce`` fly (evaluate on seeds outside the pool).
    A :class:`~covert_env.scenario.Scenario` instance may also be passed.
    ``random_starts=True`` samples the starts from the env's RNG for every scenario.
    After a reset, ``env.scenario`` is the scene with the starts actually flown in this episode.

    ## Episode End

    Truncation after ``min(max_cycles, config.n_slots)`` slots (``env.episode_length``; default 70, the
    end of the target's route: a larger ``max_cycles`` cannot extend the route). Termination only if
    ``terminate_on_collision=True`` and two UAVs come closer than d_safe1.

    ## Arguments

    * ``config``: a :class:`~covert_env.config.Config` or dict (paper defaults).
    * ``n_uavs``: team size U (default ``config.n_uavs``).
    * ``scenario``: ``"random"``, ``"paper"`` or a ``Scenario``.
    * ``action_mode``: ``"unicycle"`` or ``"waypoint"``.
    * ``max_cycles``: bound on the episode length in slots (an integer >= 1; validated also when set as an
      attribute); episodes end at ``config.n_slots`` in any case.
    * ``render_mode``: ``None``, ``"human"`` or ``"rgb_array"``.
    * ``map_size``: side S of the observation maps (default 8).
    * ``dict_obs``: Dict observations carrying the action mask (waypoint mode only; Tianshou needs it).
    * ``reward_scale``, ``los_penalty``, ``zone_penalty``, ``separation_penalty``, ``terrain_penalty``.
    * ``terminate_on_collision``: end the episode when separation < d_safe1.
    * ``scene_pool``: number of training scene seeds for ``scenario="random"`` (default 10000, at most
      1_000_000 so that training scenes never include the held-out seeds 1_000_000 + i).
    * ``path_samples``: samples per slot for LoS/separation checks along the path (default 11, in [2, 1000]).
    * ``random_starts``: sample start poses from the env's RNG even for a fixed scenario.

    ## Version History

    * v1 (covert_env 0.2.0): infos are flat scalars with the same keys and types at reset and every step
      (``reward_terms[t]`` became ``reward_<t>``); constraint costs ``cost``, ``cost_los``, ``cost_zone``,
      ``cost_separation``, ``cost_terrain``; with ``dict_obs=True`` the action mask is only in the
      observation; ``max_cycles`` above ``config.n_slots`` is accepted (the episode ends with the route) and is
      validated on assignment; ``dict_obs=True`` in unicycle mode is an error; starts on scenes whose visible
      zone cannot hold the team use a documented fallback (:meth:`Scenario.sample_starts`; other scenes' starts
      are unchanged); a waypoint dead behind the UAV turns right, as eq. 22 states (v0 turned left; reachable
      only when W_max delta > pi, so no seeded result of the defaults changed). Observations and rewards
      are otherwise unchanged.
    * v0: initial release.
    """

    metadata = {"name": "covert_sensing_v1", "render_modes": ["human", "rgb_array"], "render_fps": 4,
                "is_parallelizable": True}

    def __init__(self, config: Config | dict | None = None, *, n_uavs: int | None = None,
                 scenario: str | Scenario = "random", action_mode: str = "unicycle",
                 max_cycles: int | None = None, render_mode: str | None = None, map_size: int = 8,
                 dict_obs: bool = False, reward_scale: float = 100.0, los_penalty: float = 1.0,
                 zone_penalty: float = 1.0, separation_penalty: float = 1.0, terrain_penalty: float = 1.0,
                 terminate_on_collision: bool = False, scene_pool: int = 10_000, path_samples: int = 11,
                 random_starts: bool = False):
        super().__init__()
        if isinstance(config, Mapping):
            cfg = Config.from_dict(dict(config))
        elif config is None or isinstance(config, Config):
            cfg = config or Config()
        else:
            raise TypeError(f"config must be a covert_env.Config, a dict of its fields or None, "
                            f"got {type(config).__name__} {config!r}")
        if n_uavs is not None:
            cfg = cfg.replace(n_uavs=_int_arg("n_uavs", n_uavs, 1))
        if isinstance(scenario, Scenario):
            # A scenario's terrain and track were built and checked under its own config: flying them under
            # another one (altitude, speeds, zone) would mix two worlds, so the two must agree.
            if config is not None:
                differ = [f for f in cfg.to_dict() if f != "n_uavs" and getattr(cfg, f) != getattr(scenario.config, f)]
                if differ:
                    raise ValueError(f"config differs from scenario.config in {differ}; build the Scenario with this "
                                     "config, or pass only the scenario")
            cfg = scenario.config if n_uavs is None else scenario.config.replace(n_uavs=cfg.n_uavs)
            if scenario.n_uavs != cfg.n_uavs:
                raise ValueError(f"n_uavs={cfg.n_uavs} but the scenario has {scenario.n_uavs} UAVs")
        elif not isinstance(scenario, str) or scenario not in ("random", "paper"):
            raise ValueError(f"scenario must be 'random', 'paper' or a Scenario, got {scenario!r}")
        elif scenario == "paper" and cfg.n_uavs > len(PAPER_UAV_STARTS):
            raise ValueError(f"scenario='paper' has starts for {len(PAPER_UAV_STARTS)} UAVs, got n_uavs={cfg.n_uavs}; "
                             "use scenario='random' or a Scenario with your own starts")
        if not isinstance(action_mode, str) or action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, "
                             f"got {render_mode!r}")
        if _bool_arg("dict_obs", dict_obs) and action_mode != "waypoint":
            raise ValueError("dict_obs=True needs action_mode='waypoint': the unicycle mode has no action mask")
        map_size = _int_arg("map_size", map_size, 2, 64)
        # Training scene seeds stay below the held-out ones (1_000_000 + i) that evaluations fly.
        scene_pool = _int_arg("scene_pool", scene_pool, 1, MAX_SCENE_POOL)
        path_samples = _int_arg("path_samples", path_samples, 2, MAX_PATH_SAMPLES)
        reward_scale = _number_arg("reward_scale", reward_scale)
        if not 1e-6 <= reward_scale <= 1e12:     # outside, rewards over- or underflow (eq. 18 / reward_scale)
            raise ValueError(f"reward_scale must be a finite number in [1e-06, 1e+12], got {reward_scale!r}")
        penalties = {"los": los_penalty, "zone": zone_penalty, "separation": separation_penalty,
                     "terrain": terrain_penalty}
        for key, val in penalties.items():
            penalties[key] = _number_arg(f"{key}_penalty", val)
            if penalties[key] < 0:
                raise ValueError(f"{key}_penalty must be a finite number >= 0, got {val!r}")

        self.config = cfg
        self.scenario_spec = scenario
        self.action_mode = action_mode
        self.max_cycles = cfg.n_slots if max_cycles is None else max_cycles     # validated by the setter
        self.render_mode = render_mode
        self.map_size = map_size
        self.dict_obs = bool(dict_obs)
        self.reward_scale = reward_scale
        self.penalties = penalties
        self.terminate_on_collision = _bool_arg("terminate_on_collision", terminate_on_collision)
        self.scene_pool = scene_pool
        self.path_samples = path_samples
        self.random_starts = _bool_arg("random_starts", random_starts)

        self.possible_agents = [f"uav_{i}" for i in range(cfg.n_uavs)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        u = cfg.n_uavs
        # Teammates of agent i, by index, skipping i: the observation's fixed-size teammate block.
        self._mates = np.array([[j for j in range(u) if j != i] for i in range(u)], dtype=int).reshape(u, u - 1)

        c = cfg
        self.lattice = zone_lattice(c)                        # the DP planner's nodes, target frame
        box = lattice_offsets(c.r1, c.r2, c.mu, c.grid_step)
        lo, hi = box.min(0), box.max(0)
        s = self.map_size
        gx = lo[0] + (np.arange(s) + 0.5) * (hi[0] - lo[0]) / s
        gy = lo[1] + (np.arange(s) + 0.5) * (hi[1] - lo[1]) / s
        self.map_offsets = np.array([(x, y) for y in gy[::-1] for x in gx])   # row-major, +y on top
        self._map_in_zone = in_feasible_zone(self.map_offsets, np.zeros(2), 0.0, c.r1, c.r2, c.mu, c.r_u)

        n_mate = 2 * (c.n_uavs - 1)
        low = np.concatenate([[-OFFSET_CLIP] * 2, [-1, -1, 0, 0, 0, -OFFSET_CLIP], [-2, -2, 0],
                              [-OFFSET_CLIP] * n_mate, np.zeros(2 * s * s)]).astype(np.float32)
        high = np.concatenate([[OFFSET_CLIP] * 2, [1, 1, 1, 1, 1, OFFSET_CLIP], [2, 2, 1],
                               [OFFSET_CLIP] * n_mate, np.ones(2 * s * s)]).astype(np.float32)
        self._obs_box = spaces.Box(low, high, dtype=np.float32)
        n_own = 8
        st_low = np.concatenate([np.tile(low[:n_own], c.n_uavs), low[8:11], np.zeros(2 * s * s)])
        st_high = np.concatenate([np.tile(high[:n_own], c.n_uavs), high[8:11], np.ones(2 * s * s)])
        self.state_space = spaces.Box(st_low.astype(np.float32), st_high.astype(np.float32), dtype=np.float32)
        if action_mode == "unicycle":
            self._act_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        else:
            self._act_space = spaces.Discrete(len(self.lattice))
        if self.dict_obs:
            self._obs_space = spaces.Dict({"observation": self._obs_box,
                                           "action_mask": spaces.Box(0, 1, (len(self.lattice),), dtype=np.int8)})
        else:
            self._obs_space = self._obs_box
        self.observation_spaces = {a: self._obs_space for a in self.possible_agents}
        self.action_spaces = {a: self._act_space for a in self.possible_agents}

        self._scenes: OrderedDict[Any, _SceneCache] = OrderedDict()
        self._np_random, _ = gymnasium.utils.seeding.np_random(None)
        self.engine: Engine | None = None
        self._masks: np.ndarray | None = None
        self._last_speed = np.zeros(c.n_uavs)
        self._renderer = None

    # ------------------------------------------------------------------ spaces
    # Plain lookups, not functools.cache: a cache on a method is a module-level dict that would keep every env
    # ever built alive. The dicts return the same object every call, as PettingZoo's API test requires.
    def observation_space(self, agent: str) -> gymnasium.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.Space:
        return self.action_spaces[agent]

    @property
    def max_cycles(self) -> int:
        """Episode length bound in slots; the episode also ends at the end of the route (``config.n_slots``)."""
        return self._max_cycles

    @max_cycles.setter
    def max_cycles(self, value) -> None:
        # Validated on every assignment: PettingZoo's test battery and users set it as an attribute.
        self._max_cycles = _int_arg("max_cycles", value, 1)

    @property
    def episode_length(self) -> int:
        """Slots in an episode: ``min(max_cycles, config.n_slots)`` (the target's route has n_slots slots)."""
        return min(self._max_cycles, self.config.n_slots)

    # ------------------------------------------------------------------ scenes
    def _scene(self, scene_seed: int | None) -> _SceneCache:
        spec = self.scenario_spec
        key = id(spec) if isinstance(spec, Scenario) else ("paper" if spec == "paper" else scene_seed)
        if key not in self._scenes:
            if isinstance(spec, Scenario):
                sc = spec
            elif spec == "paper":
                sc = Scenario.paper(self.config)
            else:
                sc = None                                     # built by the cache, starts on demand
            self._scenes[key] = _SceneCache(sc, self.map_offsets, self._map_in_zone, self.lattice,
                                            seed=None if sc is not None else int(scene_seed), config=self.config)
            while len(self._scenes) > 32:                     # bounded memory over long training runs
                self._scenes.popitem(last=False)
        self._scenes.move_to_end(key)
        return self._scenes[key]

    # ------------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._np_random, _ = gymnasium.utils.seeding.np_random(seed)
        scene_seed = self._scene_seed_option(options)
        if scene_seed is None and self.scenario_spec == "random":
            scene_seed = int(self._np_random.integers(self.scene_pool))
        self._cache = self._scene(scene_seed)
        if self.random_starts or (self.scenario_spec == "random" and (options or {}).get("scene_seed") is None):
            self.scenario = self._cache.with_starts(self._np_random, self.config.n_uavs)
        else:
            self.scenario = self._cache.seeded_scenario()
        self.engine = Engine(self.scenario, path_samples=self.path_samples, path_los=False)
        self.agents = list(self.possible_agents)
        self._last_speed = np.zeros(len(self.agents))
        c = self.config
        self._los = line_of_sight(self.scenario.terrain, self.engine.uav_xy, c.altitude, self.engine.target_xyz)
        self._zone_dist = zone_distance(self.engine.uav_xy, self.engine.target_xyz[:2], self.engine.target_phi,
                                        c.r1, c.r2, c.mu)
        self._update_masks()
        obs = self._obs_dict(_observations([self])[0])
        infos = dict(zip(self.agents, self._reset_infos(), strict=True))
        if self.render_mode == "human":
            self.render()
        return obs, infos

    def _scene_seed_option(self, options) -> int | None:
        """``options["scene_seed"]`` checked: an integer >= 0, and only for ``scenario="random"``. Other keys are
        warned about, not rejected: PettingZoo's API test passes ``options={"options": 1}`` to every env."""
        if options is None:
            return None
        if not isinstance(options, Mapping):
            raise TypeError(f"reset(options=...) must be a dict or None, got {type(options).__name__}")
        unknown = sorted(set(options) - {"scene_seed"}, key=str)
        if unknown:
            gymnasium.logger.warn(f"reset(options=...): ignoring unknown option(s) {unknown}; known: ['scene_seed']")
        if options.get("scene_seed") is None:
            return None
        if self.scenario_spec != "random":
            flown = "the paper scenario" if self.scenario_spec == "paper" else "a given Scenario"
            raise ValueError("reset(options={'scene_seed': ...}) picks a random scene: it needs scenario='random', "
                             f"but this env flies {flown}")
        return _int_arg("options['scene_seed']", options["scene_seed"], 0)

    def step(self, actions: dict[str, Any]):
        if self.engine is None or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        if not isinstance(actions, Mapping):
            raise TypeError(f"step() expects a dict {{agent: action}} for the agents {self.agents}, "
                            f"got {type(actions).__name__}")
        unknown = [a for a in actions if a not in self._index]
        if unknown:
            raise ValueError(f"step(): unknown agent(s) {unknown}; the agents are {self.agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"step(): missing actions for {missing}")
        if self.action_mode == "unicycle":
            act = self._unicycle_actions(actions)
        else:
            act = self._waypoint_indices(actions)
        obs, rew, term, trunc, infos = step_copies([self], act[None])
        agents = self.possible_agents
        terminations = dict.fromkeys(agents, bool(term[0]))
        truncations = dict.fromkeys(agents, bool(trunc[0]))
        return (self._obs_dict(obs[0]), dict(zip(agents, rew[0].tolist(), strict=True)), terminations, truncations,
                dict(zip(agents, infos[0], strict=True)))

    # ------------------------------------------------------------------ internals
    def _unicycle_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """(U, 2) raw Box actions in agent order, checked for type, shape and finiteness."""
        # Each agent's own dtype: stacked together, a bool action beside float ones would be upcast to 0.0/1.0.
        # Arrays (what samplers and frameworks pass) are checked by attribute; anything else by the loop below.
        vals = [actions[a] for a in self.agents]
        act = None
        if all(type(v) is np.ndarray and v.dtype.kind in "iuf" for v in vals):
            try:
                act = np.asarray(vals)
            except ValueError:               # ragged: the loop below names the culprit
                pass
        if act is None or act.shape != (len(self.agents), 2) or not np.isfinite(act).all():
            act = np.array([_one_unicycle_action(a, actions[a]) for a in self.agents])
        return act.astype(float, copy=False)

    def _waypoint_indices(self, actions: dict[str, Any]) -> np.ndarray:
        """(U,) lattice indices from Discrete(L) actions, validated (integers; floats only with an integral value)."""
        n = len(self.lattice)
        idx = np.empty(len(self.agents), dtype=int)
        for i, a in enumerate(self.agents):
            act = np.asarray(actions[a])
            val = float(act.reshape(-1)[0]) if act.size == 1 and act.ndim <= 1 and act.dtype.kind in "iuf" \
                else math.nan
            if not (math.isfinite(val) and val == int(val) and 0 <= val < n):
                raise ValueError(f"action for {a} must be an integer in [0, {n - 1}], got {actions[a]!r}")
            idx[i] = int(val)
        return idx

    def _update_masks(self) -> None:
        if self.action_mode != "waypoint":
            return
        eng, c = self.engine, self.config
        if eng.k >= c.n_slots + c.horizon:
            return
        q1, phi1 = eng.predict(1)
        goals = to_world(self.lattice, q1[0, :2], float(phi1[0]))
        visible = self._cache.lattice_visible(eng.k + 1)
        u, n = len(eng.uav_xy), len(goals)
        m = solve_manoeuvre(np.repeat(eng.uav_xy, n, axis=0), np.repeat(eng.uav_theta, n),
                            np.tile(goals, (u, 1)), v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        reach = np.asarray(m.feasible, bool).reshape(u, n)
        mask = reach & visible
        for i in range(u):
            if not mask[i].any():
                mask[i] = reach[i] if reach[i].any() else True
        self._masks = mask.astype(np.int8)

    def action_mask(self, agent: str) -> np.ndarray:
        """The waypoint action mask of ``agent`` (int8, 1 = allowed); all ones in unicycle mode."""
        if self.action_mode != "waypoint":
            return np.ones(2, np.int8)
        if self._masks is None:
            raise RuntimeError("action_mask() called before reset(): the mask depends on the UAVs' poses")
        if agent not in self._index:
            raise ValueError(f"action_mask(): unknown agent {agent!r}; the agents are {self.possible_agents}")
        return self._masks[self._index[agent]].copy()

    def _lockstep_key(self) -> tuple:
        """What copies stepped together by :func:`step_copies` must share (read live: attributes may be set after
        construction). Rewards, penalties, ``max_cycles`` and ``terminate_on_collision`` may differ per copy."""
        return self.config, self.action_mode, self.map_size, self.dict_obs, self.path_samples, len(self.possible_agents)

    def _reset_infos(self) -> list[dict]:
        """Infos at reset: the keys and types of every step's (:func:`_agent_infos`). No slot has been flown,
        so rewards, costs and the slot's motion are 0; LoS, zone, separation and clearance are the starts'."""
        eng, c = self.engine, self.config
        flags = np.stack([self._los, self._zone_dist <= 0, np.zeros(len(self._los), bool)])[:, None]
        floats = np.zeros((len(_STEP_INFO_FLOATS), 1, len(self._los)))
        floats[3, 0] = nearest_teammate(eng.uav_xy)
        floats[4, 0] = terrain_clearance(eng.uav_xy, c.altitude, eng.terrain)
        return _agent_infos([self], [int(eng.k)], flags, floats)[0]

    def _own_features(self) -> np.ndarray:
        """(U, 8) per-UAV features 0-7 of the observation table."""
        return _own_features([self])[0]

    def _shared_features(self) -> np.ndarray:
        """Target displacement, time remaining and both maps (shared by all agents; a new float32 array)."""
        out = self._shared_block().copy()
        out[2] = self._remaining()
        return out

    def _remaining(self) -> float:
        length = self.episode_length
        return max(length - self.engine.k, 0) / length

    def _shared_block(self) -> np.ndarray:
        """:meth:`_shared_features` with 0 for the time remaining (read-only): it depends only on the scene
        and the slot, and a scene is flown many times (every agent, every reset on it)."""
        return self._cache.shared_block(self.engine.k)

    def _obs_dict(self, rows: np.ndarray) -> dict[str, Any]:
        """Per-agent observations from the (U, D) rows of :func:`_observations`."""
        if self.dict_obs:
            return {a: {"observation": rows[i], "action_mask": self._masks[i].copy()}
                    for i, a in enumerate(self.possible_agents)}
        return dict(zip(self.possible_agents, rows, strict=True))

    def state(self) -> np.ndarray:
        """Global state for centralised critics (see the class docstring)."""
        if self.engine is None:
            raise RuntimeError("state() called before reset()")
        own = self._own_features()
        return np.concatenate([own.reshape(-1).astype(np.float32), self._shared_features()])

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if self.engine is None:
            return None
        from covert_env.render import EpisodeRenderer

        if self._renderer is None:
            self._renderer = EpisodeRenderer(human=self.render_mode == "human")
        frame = self._renderer.draw(self.scenario, self.engine)
        return frame if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


# ----------------------------------------------------------------------------- lock-step copies
# Everything below works on N env copies at once: arrays (N, U, ...) with one vectorised numpy call per
# quantity, because on the few-element arrays of one step numpy's per-call overhead, not the maths, is
# the cost. ``env.step`` is the case N = 1; the SB3 adapter (training.vec_env) steps all its copies
# through :func:`step_copies`, so both paths run the same code.

#: Float infos of a step (the class docstring's Infos table), besides the bools los, in_zone, infeasible.
_STEP_INFO_FLOATS = (("kappa", "g", "v", "separation", "terrain_clearance")
                     + tuple(f"reward_{t}" for t in _REWARD_TERMS) + ("cost",) + tuple(f"cost_{n}" for n in _COSTS))


def step_copies(envs, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[list[dict]]]:
    """Step N copies of :class:`CovertSensingParallelEnv` in lock-step: one slot each, the same results
    as calling ``env.step`` on every copy, with the numpy work done once for all copies.

    Args:
        envs: N envs built with the same arguments (scenes and slots may differ), all mid-episode.
        actions: (N, U, 2) Box actions (unicycle mode) or (N, U) lattice indices (waypoint mode), agents
            in ``possible_agents`` order.

    Returns:
        ``(observations, rewards, terminated, truncated, infos)``: a new (N, U, D) float32 array of the
        observation rows (the array form, also with ``dict_obs=True``), (N, U) rewards, (N,) bools (every
        agent of a copy ends together) and N lists of U info dicts. A copy that ended has no agents left
        and must be reset before its next step.
    """
    e0 = envs[0]
    c = e0.config
    n, u = len(envs), len(e0.possible_agents)
    for env in envs:
        if env.engine is None or not env.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
    key = e0._lockstep_key()
    for env in envs[1:]:
        if env._lockstep_key() != key:
            raise ValueError("step_copies: every env must have the same config, action_mode, map_size, dict_obs, "
                             "path_samples and team size")
    engines = [env.engine for env in envs]
    if e0.action_mode == "unicycle":
        act = np.asarray(actions, dtype=float)
        if act.shape != (n, u, 2):
            raise ValueError(f"step_copies: unicycle actions must have shape ({n}, {u}, 2), got {act.shape}")
        quant = step_engines(engines, unicycle=_unicycle_controls(act, c, e0.possible_agents))
    else:
        idx = _lattice_indices(actions, n, u, len(e0.lattice), e0.possible_agents)
        rows = np.arange(u)
        decision = np.stack([env._masks[rows, idx[j]] == 0 for j, env in enumerate(envs)])
        goals = np.empty((n, u, 2))
        for j, env in enumerate(envs):
            q1, phi1 = env.engine.predict(1)
            goals[j] = to_world(env.lattice[idx[j]], q1[0, :2], float(phi1[0]))
        quant = step_engines(engines, waypoints=goals, infeasible=decision)
    speed = quant.path_length / c.delta
    costs = constraint_costs(quant, c)
    terms = _reward_terms(envs, quant, costs)
    rewards = terms.sum(axis=0)
    ks = [eng.k for eng in engines]
    if n == 1:
        stop_on_collision, max_cycles = e0.terminate_on_collision, e0.episode_length
    else:
        stop_on_collision = np.array([env.terminate_on_collision for env in envs])
        max_cycles = np.array([env.episode_length for env in envs])
    terminate = (quant.separation_path < c.d_safe1).any(axis=1) & stop_on_collision
    truncate = (np.array(ks) >= max_cycles) & ~terminate
    for j, env in enumerate(envs):
        env._last_speed, env._los, env._zone_dist = speed[j], quant.los[j], quant.zone_distance[j]
        env._update_masks()
    obs = _observations(envs)

    flags = np.stack([quant.los, quant.in_zone, np.stack([eng._infeasible[-1] for eng in engines])])
    floats = np.empty((len(_STEP_INFO_FLOATS), n, u))
    floats[:5] = quant.kappa, quant.g, speed, quant.separation_path, quant.terrain_clearance
    floats[5:5 + len(_REWARD_TERMS)] = terms
    floats[5 + len(_REWARD_TERMS)] = costs.sum(axis=0)
    floats[6 + len(_REWARD_TERMS):] = costs
    infos = _agent_infos(envs, ks, flags, floats)
    for j, env in enumerate(envs):
        if terminate[j] or truncate[j]:
            env.agents = []
        if env.render_mode == "human":
            env.render()
    return obs, rewards, terminate, truncate, infos


def _unicycle_controls(act: np.ndarray, c: Config, agents) -> np.ndarray:
    """(..., U, 2) controls (v, omega) from Box(-1, 1) actions: clipped, then scaled (class docstring)."""
    if not np.isfinite(act).all():
        bad = tuple(np.argwhere(~np.isfinite(act).all(axis=-1))[0])
        where = f" (copy {bad[0]})" if len(act) > 1 else ""
        raise ValueError(f"action for {agents[bad[-1]]}{where} must be finite, got {act[bad].tolist()}")
    ctl = np.empty_like(act)
    ctl[..., 0], ctl[..., 1] = unicycle_controls(act, c)
    return ctl


def _lattice_indices(actions, n: int, u: int, n_nodes: int, agents) -> np.ndarray:
    """(N, U) validated lattice indices from Discrete(L) actions."""
    a = np.asarray(actions)
    if a.shape != (n, u):
        raise ValueError(f"step_copies: waypoint actions must have shape ({n}, {u}), got {a.shape}")
    ok = np.zeros(a.shape, bool)
    if a.dtype.kind in "iuf":
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(a) & (a == np.round(a)) & (a >= 0) & (a < n_nodes)
    if not ok.all():
        bad = tuple(np.argwhere(~ok)[0])
        where = f" (copy {bad[0]})" if n > 1 else ""
        raise ValueError(f"action for {agents[bad[-1]]}{where} must be an integer in [0, {n_nodes - 1}], "
                         f"got {a[bad].item()!r}")
    return a.astype(int)


def _agent_infos(envs, slots, flags: np.ndarray, floats: np.ndarray) -> list[list[dict]]:
    """N lists of U flat info dicts from (3, N, U) ``flags`` (los, in_zone, infeasible) and (F, N, U) ``floats``
    (``_STEP_INFO_FLOATS``): every key in a fixed order, the action mask last where it lives in the infos (waypoint
    mode without ``dict_obs``). Reset and step both build them here, so their keys and types agree (TorchRL builds
    its info spec from reset's). One ``tolist`` per array: per-key conversions dominated the step's dict work."""
    keys = ("slot", "los", "in_zone", "infeasible") + _STEP_INFO_FLOATS
    flag_rows, float_rows = flags.transpose(1, 2, 0).tolist(), floats.transpose(1, 2, 0).tolist()
    mask_in_info = envs[0].action_mode == "waypoint" and not envs[0].dict_obs
    out = []
    for j, env in enumerate(envs):
        infos = [dict(zip(keys, [slots[j], *f, *x], strict=True))
                 for f, x in zip(flag_rows[j], float_rows[j], strict=True)]
        if mask_in_info:
            for i, info in enumerate(infos):
                info["action_mask"] = env._masks[i].copy()
        out.append(infos)
    return out


def _reward_terms(envs, quant, costs: np.ndarray) -> np.ndarray:
    """(6, N, U) reward terms (:func:`covert_env.envs.batch.reward_terms`) with each copy's own reward scale and
    penalties (read live: ``set_attr`` may change them per copy)."""
    e0 = envs[0]
    if len(envs) == 1:
        return reward_terms(quant, costs, e0.config, e0.reward_scale, e0.penalties)
    scale = np.array([env.reward_scale for env in envs])[:, None]
    p = {key: np.array([env.penalties[key] for env in envs])[:, None] for key in e0.penalties}
    return reward_terms(quant, costs, e0.config, scale, p)


def _own_features(envs) -> np.ndarray:
    """(N, U, 8) per-UAV features 0-7 of the observation table."""
    e0 = envs[0]
    c = e0.config
    if len(envs) == 1:
        eng, tr = e0.engine, e0.scenario.track
        k = min(eng.k, tr.n_slots)
        q, phi = tr.positions[k:k + 1], tr.headings[k:k + 1]
        xy, th = eng.uav_xy[None], eng.uav_theta[None]
        speed, los, zd = e0._last_speed[None], e0._los[None], e0._zone_dist[None]
    else:
        ks = [min(env.engine.k, env.scenario.track.n_slots) for env in envs]
        q = np.array([env.scenario.track.positions[k] for env, k in zip(envs, ks, strict=True)])
        phi = np.array([env.scenario.track.headings[k] for env, k in zip(envs, ks, strict=True)])
        xy, th = np.stack([env.engine.uav_xy for env in envs]), np.stack([env.engine.uav_theta for env in envs])
        speed, los = np.stack([env._last_speed for env in envs]), np.stack([env._los for env in envs])
        zd = np.stack([env._zone_dist for env in envs])
    return own_features(xy, th, q, phi, speed, los, zd, c)


def _observations(envs) -> np.ndarray:
    """(N, U, D) float32 observation rows (the class docstring's table), a new array."""
    e0 = envs[0]
    own = _own_features(envs)
    n, u = own.shape[:2]
    n_own, n_mate = 8, 2 * (u - 1)
    if n == 1:
        shared, remaining = e0._shared_block()[None], np.array([e0._remaining()])
    else:
        shared = np.stack([env._cache.shared_block(env.engine.k) for env in envs])
        remaining = np.array([env._remaining() for env in envs])
    rows = np.empty((n, u, e0._obs_box.shape[0]), np.float32)
    rows[..., :n_own] = own
    rows[..., n_own:n_own + 3] = shared[:, None, :3]
    rows[..., n_own + 2] = remaining[:, None]
    rows[..., n_own + 3:n_own + 3 + n_mate] = own[:, e0._mates, :2].reshape(n, u, -1)
    rows[..., n_own + 3 + n_mate:] = shared[:, None, 3:]
    return rows


# ----------------------------------------------------------------------------- argument checks
def _one_unicycle_action(agent: str, value) -> np.ndarray:
    """One agent's Box action as a (2,) array, or a clear error naming the agent (the slow path of
    :meth:`CovertSensingParallelEnv._unicycle_actions`: anything that is not already a numeric array)."""
    try:
        one = np.asarray(value)
    except ValueError:                       # ragged nesting such as [0.1, [0.2]]
        raise ValueError(f"action for {agent} must have shape (2,), got {value!r}") from None
    if one.dtype.kind not in "iuf":
        raise TypeError(f"action for {agent} must be 2 numbers (speed, turn rate) in [-1, 1], got {value!r}")
    if one.shape != (2,):
        raise ValueError(f"action for {agent} must have shape (2,), got {one.shape}")
    if not np.all(np.isfinite(one)):
        raise ValueError(f"action for {agent} must be finite, got {one.tolist()}")
    return one


def _int_arg(name: str, value, low: int, high: int | None = None) -> int:
    """``value`` as an int in [low, high]: ints and numpy integers pass; bools, floats and strings are rejected
    (a fractional team size or map side has no meaning, and silent truncation hides the mistake)."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    try:
        v = operator.index(value)
    except TypeError:
        raise TypeError(f"{name} must be an integer, got {type(value).__name__} {value!r}") from None
    if v < low or (high is not None and v > high):
        allowed = f"in [{low}, {high}]" if high is not None else f">= {low}"
        raise ValueError(f"{name} must be an integer {allowed}, got {v!r}")
    return v


def _number_arg(name: str, value) -> float:
    """``value`` as a finite float; bools and strings are rejected."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return float(value)


def _bool_arg(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def raw_env(**kwargs) -> CovertSensingParallelEnv:
    """The bare parallel environment (no wrappers)."""
    return CovertSensingParallelEnv(**kwargs)


def parallel_env(**kwargs) -> CovertSensingParallelEnv:
    """The PettingZoo ParallelEnv (see :class:`CovertSensingParallelEnv` for the arguments)."""
    return CovertSensingParallelEnv(**kwargs)


class _AECEnv(wrappers.OrderEnforcingWrapper):
    """PettingZoo's order-enforcing AEC wrapper, with ``max_cycles`` forwarded to the parallel env (set on a plain
    wrapper, the attribute would land on the wrapper and silently change nothing)."""

    @property
    def max_cycles(self) -> int:
        return self.unwrapped.max_cycles

    @max_cycles.setter
    def max_cycles(self, value) -> None:
        self.unwrapped.max_cycles = value


def env(**kwargs):
    """The AEC version, through ``parallel_to_aec`` with PettingZoo's order-enforcing wrappers."""
    return _AECEnv(parallel_to_aec(parallel_env(**kwargs)))

