"""PettingZoo ParallelEnv: a team of UAVs covertly filming a target on uneven terrain.

The B = 1 view of :class:`~covert_env.envs.vector.CovertSensingVectorEnv`: this module turns agent dicts into the
vector env's arrays and back, and adds what PettingZoo asks of a single env (agents that leave at the end, AEC
conversion, rendering). The task, the model and every number come from the vector env (and through it from the
model's modules); no geometry, physics or reward is written here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from covert_env.envs.arguments import ConstructionSettings, Forwarded, int_arg, reset_options
from covert_env.envs.observation import observation_table
from covert_env.envs.recorder import CopyView
from covert_env.envs.settings import ACTION_MODES, MAX_PATH_SAMPLES, MAX_SCENE_POOL, RENDER_MODES, EnvSettings
from covert_env.envs.vector import INFO_KEYS, MAX_SCENE_SEED, CovertSensingVectorEnv
from covert_env.render import EpisodeRenderer
from covert_env.world.config import Config
from covert_env.world.scenario import Scenario

__all__ = ["CovertSensingParallelEnv", "env", "parallel_env", "raw_env", "ACTION_MODES", "MAX_PATH_SAMPLES",
           "MAX_SCENE_POOL"]


class CovertSensingParallelEnv(ConstructionSettings, ParallelEnv):
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
    the visible zone (eq. 10) at k+1 (``mask_mode="visible"``, the default), or, with ``mask_mode="kinematic"``,
    every node reachable in one slot: shadowed nodes are then the policy's to avoid, from the observation's maps
    and the LoS costs (docs/decisions/environments.md#action-mask-modes). It lives in one place per setting:
    ``infos[agent]["action_mask"]`` by default, or, with ``dict_obs=True``, the observation
    ``{"observation": ..., "action_mask": ...}`` (and then not in the infos); ``env.action_mask(agent)`` returns it
    in both. If no node qualifies, reachable nodes are unmasked, and if none is reachable every node is, so a
    masked sampler always has a choice. A masked-out but reachable node is flown exactly and flagged
    ``infos[agent]["infeasible"]``; an unreachable one is flown as a best effort (the admissible constant
    (v, omega) ending closest to it, see :mod:`covert_env.world.engine`) and flagged too.

    ## Observation Space

    ``Box(float32)`` in the target's frame at the current slot (x forward along the target's heading,
    y to its left), roughly unit scale. For agent i:

    {OBSERVATION_TABLE}

    S = ``map_size``. The maps cover the zone's bounding box in the target's frame, row-major,
    computed with the exact vectorised line of sight.

    ``target_path=P`` (0 by default, at most ``config.horizon``) appends the target's poses at slots k+1..k+P as
    the tracker predicts them at slot k (what the DP planner plans on, ``TargetTrack.predict``): the planner reads
    ``config.horizon`` slots ahead, the default observation one (``target_displacement``, ``map_next``).

    ``state()`` (for centralised critics) concatenates, for every UAV, indices 0-7 above, then the
    target displacement, the time remaining, both maps and the target's path.

    ## Rewards

    Per agent and slot, from the paper's stage cost g = v delta - lambda (eta |d alpha| + |d d|)
    (eq. 18), divided by ``reward_scale``, plus penalties (each term is ``infos[agent]["reward_<term>"]``):

    * ``path``: ``-v delta / reward_scale`` (energy, eq. 15);
    * ``disguise``: ``+lambda kappa / reward_scale`` (eq. 11);
    * ``los``: ``-los_penalty`` if LoS to the target is blocked at the end of the slot;
    * ``los_path``: ``-los_path_penalty`` times the share of the slot's flown path with LoS to the target blocked
      (``cost_los_path``: the video lost between slot times);
    * ``zone``: ``-zone_penalty * (1 + min(outside distance / (R2 - R1), 2))`` if outside the zone;
    * ``separation``: ``-separation_penalty`` if closer than d_safe1 to a teammate at any sample of the slot;
    * ``terrain``: ``-terrain_penalty`` if closer than d_safe2 to a polytope's highest point.

    ## Constraint Costs

    For constrained (safe) RL, e.g. Lagrangian methods, ``infos[agent]`` carries the violations of the
    paper's constraints (§2.4) in the slot just flown, each 0.0 or 1.0, the share of the flown path with LoS
    blocked, in [0, 1], and their sum ``cost``; they do not depend on the penalty weights (set the penalties to 0 to
    train on the stage cost alone):

    | key | constraint violated |
    |---|---|
    | ``cost_los`` | LoS to the (true) target blocked at the end of the slot (eq. 6; outside eq. 10's zone) |
    | ``cost_los_path`` | the share of the slot's ``path_samples`` after its start (its end included) whose LoS to |
    | | the target at the same instant is blocked (eq. 6 between slot times; the metric ``blocked_path_share``) |
    | ``cost_zone`` | outside the feasible flight zone of the true target at the end of the slot (eq. 4, not eroded: |
    | | eq. 5's erosion by r_u is the planner's margin that guarantees eq. 4) |
    | ``cost_separation`` | closer than d_safe1 to a teammate at any of the ``path_samples`` of the slot (eq. 2) |
    | ``cost_terrain`` | closer than d_safe2 to a polytope's highest point at the end of the slot (eq. 3) |

    LoS, zone and terrain are checked at slot times, as the paper's constraints are stated on the slot
    positions; separation and ``cost_los_path`` along the path: the paper films the target continuously, and a
    team that keeps LoS at slot times can lose it in between
    (docs/decisions/environments.md#line-of-sight-along-the-path).
    (Terrain generated with the default ``max_height`` keeps every top at least d_safe2 below the UAVs, so there
    ``cost_terrain`` fires only on terrain given by the user, e.g. a tall pole; the ``towers`` family's masts reach
    within d_safe2 of the UAVs, so there it binds.)

    ## Infos

    Flat and scalar, with the same keys and types at ``reset()`` and every ``step()`` (as TorchRL and
    BenchMARL need). At reset no slot has been flown: rewards, costs, ``kappa``, ``g`` and ``v`` are 0.

    | key | type | meaning |
    |---|---|---|
    | ``slot`` | int | slot k reached |
    | ``los``, ``in_zone`` | bool | LoS clear / inside the zone at slot k |
    | ``los_path`` | bool | LoS clear at every path sample of the slot (at reset: ``los``) |
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
    A :class:`~covert_env.world.scenario.Scenario` instance may also be passed.
    ``random_starts=True`` samples the starts from the env's RNG for every scenario.
    After a reset, ``env.scenario`` is the scene with the starts actually flown in this episode.

    ## Episode End

    Truncation after ``min(max_cycles, config.n_slots)`` slots (``env.episode_length``; default 70, the
    end of the target's route: a larger ``max_cycles`` cannot extend the route). Termination only if
    ``terminate_on_collision=True`` and two UAVs come closer than d_safe1.

    ## Calls Out of Order

    ``step()``, ``render()``, ``state()`` and ``action_mask()`` before the first ``reset()``, and every call but
    ``close()`` after ``close()``, raise a RuntimeError that names the call (the vector env, the AEC env and the
    Gymnasium envs alike; their order-enforcing wrappers may answer first). ``reset(options=...)`` warns about
    keys other than ``scene_seed`` and ignores them. ``penalties`` is validated on item assignment too. The AEC
    env checks each agent's action at that agent's own ``step()``.

    ## Arguments

    * ``config``: a :class:`~covert_env.world.config.Config` or dict (paper defaults).
    * ``n_uavs``: team size U (default ``config.n_uavs``).
    * ``scenario``: ``"random"``, ``"paper"`` or a ``Scenario``.
    * ``action_mode``: ``"unicycle"`` or ``"waypoint"``.
    * ``max_cycles``: bound on the episode length in slots (an integer >= 1; validated also when set as an
      attribute); episodes end at ``config.n_slots`` in any case.
    * ``render_mode``: ``None``, ``"human"`` or ``"rgb_array"``.
    * ``map_size``: side S of the observation maps (default 8).
    * ``dict_obs``: Dict observations carrying the action mask (waypoint mode only; Tianshou needs it).
    * ``mask_mode``: ``"visible"`` (default: reachable nodes of the visible zone) or ``"kinematic"`` (reachable
      nodes only); waypoint mode only.
    * ``target_path``: P, the target's predicted slots in the observation (default 0: none; in
      [0, ``config.horizon``]).
    * ``reward_scale``: the stage cost's divisor (default 100, in [1e-6, 1e12]).
    * ``los_penalty``, ``los_path_penalty``, ``zone_penalty``, ``separation_penalty``, ``terrain_penalty``: the
      penalty weights (each in [0, 1e6]; default 1.0).
    * ``terminate_on_collision``: end the episode when separation < d_safe1.
    * ``scene_pool``: number of training scene seeds for ``scenario="random"`` (default 10000, at most
      1_000_000 so that training scenes never include the held-out seeds 1_000_000 + i).
    * ``path_samples``: samples per slot for LoS/separation checks along the path (default 11, in [2, 1000]; each
      sample is a line-of-sight test per UAV and step).
    * ``random_starts``: sample start poses from the env's RNG even for a fixed scenario.
    * ``family``: a scene family's name (:mod:`covert_env.world.families`: ``"sparse"``, ``"paper"``, ``"winding"``,
      ``"dense"``, ``"downtown"``, ``"towers"``), whose generator fields are set on ``config``; with
      ``scenario="random"`` only. None (default): the config as given (at its defaults, the ``paper`` family).
    * ``task``: a task of the suite (:mod:`covert_env.world.tasks`, e.g. ``"downtown-3uav"``,
      ``"paper-3uav-deviating"``): its family, team size and target behaviour set on ``config``;
      ``family`` and ``n_uavs``, if given too, must agree with it.

    ## Version History

    * v4 (covert_env 0.10.0): every UAV's pose is settled at each slot end on a fine grid
      (docs/decisions/flight.md#settled-slot-end-poses), so that seeded rollouts give the same numbers on every CPU.
    * v3 (covert_env 0.7.0): LoS lost along the flown path counts (``reward_los_path``, ``cost_los_path``,
      ``los_path``); ``mask_mode="kinematic"``. 0.8.0 added ``onward_reach``, 0.9.0 ``target_path``; no number changed.
    * v2 (covert_env 0.6.0): random scenes from the batched generator; the waypoint mask, maps and starts read eq. 10's
      one rule; under a prediction error a waypoint is placed about the target's predicted pose.
    * v1 (covert_env 0.2.0): flat infos with the same keys at reset and every step, constraint costs. 0.3.0 made the
      env the B = 1 view of the vector env, 0.4.0 added ``waypoint_paths``, 0.5.0 the checks of calls out of order;
      no number changed.
    * v0 (covert_env 0.1.0): initial release.

    What each version changed, and by how much: ``CHANGELOG.md``. The retired ids raise an error that says it
    (:data:`covert_env.retired.RETIRED`).
    """

    metadata = {"name": "covert_sensing_v4", "render_modes": list(RENDER_MODES), "render_fps": 4,
                "is_parallelizable": True}

    def __init__(self, config: Config | dict | None = None, *, n_uavs: int | None = None,
                 scenario: str | Scenario = "random", action_mode: str = "unicycle",
                 max_cycles: int | None = None, render_mode: str | None = None, map_size: int = 8,
                 dict_obs: bool = False, reward_scale: float = 100.0, los_penalty: float = 1.0,
                 los_path_penalty: float = 1.0, zone_penalty: float = 1.0, separation_penalty: float = 1.0,
                 terrain_penalty: float = 1.0,
                 terminate_on_collision: bool = False, scene_pool: int = 10_000, path_samples: int = 11,
                 random_starts: bool = False, family: str | None = None, task: str | None = None,
                 mask_mode: str = "visible", target_path: int = 0):
        super().__init__()
        s = EnvSettings(config, n_uavs=n_uavs, scenario=scenario, action_mode=action_mode, max_cycles=max_cycles,
                        render_mode=render_mode, map_size=map_size, dict_obs=dict_obs, reward_scale=reward_scale,
                        los_penalty=los_penalty, los_path_penalty=los_path_penalty, zone_penalty=zone_penalty,
                        separation_penalty=separation_penalty, terrain_penalty=terrain_penalty,
                        terminate_on_collision=terminate_on_collision,
                        scene_pool=scene_pool, path_samples=path_samples, random_starts=random_starts,
                        family=family, task=task, mask_mode=mask_mode, target_path=target_path)
        # One copy, no automatic reset (PettingZoo's agents leave at the end and reset() starts the next
        # episode), episodes recorded for the metrics.
        self._vec = CovertSensingVectorEnv.from_settings(1, s, autoreset_mode=AutoresetMode.DISABLED, record=True)
        self.config, self.scenario_spec, self.action_mode = s.config, s.scenario, s.action_mode
        self.render_mode, self.map_size, self.dict_obs = s.render_mode, s.map_size, s.dict_obs
        self.scene_pool, self.path_samples, self.random_starts = s.scene_pool, s.path_samples, s.random_starts
        #: The scene family's name (:mod:`covert_env.world.families`), or None for the config as given.
        self.family = s.family
        #: The suite task's name (:mod:`covert_env.world.tasks`), or None.
        self.task = s.task
        #: What the waypoint action mask allows: ``"visible"`` or ``"kinematic"`` (see Action Space).
        self.mask_mode = s.mask_mode
        #: Predicted slots of the target's path in the observation (0: none; see Observation Space).
        self.target_path = s.target_path
        self.lattice, self.map_offsets, self.layout = s.lattice, s.map_offsets, s.layout
        self.possible_agents = list(s.possible_agents)
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.state_space = s.state_space
        self.observation_spaces = {a: s.observation_space for a in self.possible_agents}
        self.action_spaces = {a: s.action_space for a in self.possible_agents}
        self._view = CopyView(self._vec, 0)
        self._renderer = None

    # ------------------------------------------------------------------ spaces
    # Plain lookups, not functools.cache: a cache on a method is a module-level dict that would keep every env
    # ever built alive. The dicts return the same object every call, as PettingZoo's API test requires.
    def observation_space(self, agent: str) -> gymnasium.Space:
        return self.observation_spaces[self._known(agent)]

    def action_space(self, agent: str) -> gymnasium.Space:
        return self.action_spaces[self._known(agent)]

    def _known(self, agent) -> str:
        if agent not in self._index:
            raise KeyError(f"unknown agent {agent!r}; the agents are {self.possible_agents}")
        return agent

    # ------------------------------------------------------------------ settings read live by the vector env
    # Validated on every assignment (by the vector env): PettingZoo's test battery and users set them as attributes.
    max_cycles: int = Forwarded("_vec")
    """Episode length bound in slots; the episode also ends at the end of the route (``config.n_slots``)."""
    episode_length: int = Forwarded("_vec", writable=False)
    """Slots in an episode: ``min(max_cycles, config.n_slots)`` (the target's route has n_slots slots)."""
    reward_scale: float = Forwarded("_vec")
    """The stage cost's divisor (eq. 18 / reward_scale), in [1e-6, 1e12]."""
    penalties: dict = Forwarded("_vec")
    """The penalty weights by term (``los``, ``los_path``, ``zone``, ``separation``, ``terrain``), read at every step;
    assigning a dict or an item (``penalties["los"] = 2.0``, live) validates it."""
    terminate_on_collision: bool = Forwarded("_vec")
    """Whether the episode ends when two UAVs come closer than d_safe1."""

    # ------------------------------------------------------------------ the episode, read as an engine
    @property
    def engine(self) -> CopyView | None:
        """The UAVs and the target in the engine's terms (``k``, ``uav_xy``, ``uav_theta``, ``predict``,
        ``trajectory()``, ...), or None before the first reset. A live, read-only view of the env's one copy: it
        follows later steps and episodes (copy what you need to keep)."""
        return self._view if self._vec.started else None

    @property
    def scenario(self) -> Scenario:
        """The scene of this episode with the starts actually flown (after a reset; before, an AttributeError as
        for an attribute not yet set)."""
        if not self._vec.started:
            raise _NotReset("env.scenario is known after reset()")
        return self._vec.scenario(0)

    # ------------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None):
        scene_seed = self._scene_seed_option(options)
        obs, infos = self._vec.reset(seed=None if seed is None else [seed],
                                     options=None if scene_seed is None else {"scene_seed": [scene_seed]})
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        return self._obs_dict(obs), self._agent_infos(infos)

    def _scene_seed_option(self, options) -> int | None:
        """``options["scene_seed"]`` checked: an integer >= 0, and only for ``scenario="random"``. Other keys are
        warned about and ignored (:func:`~covert_env.envs.arguments.reset_options`)."""
        options = reset_options(options, ("scene_seed",))
        if options.get("scene_seed") is None:
            return None
        if self.scenario_spec != "random":
            flown = "the paper scenario" if self.scenario_spec == "paper" else "a given Scenario"
            raise ValueError("reset(options={'scene_seed': ...}) picks a random scene: it needs scenario='random', "
                             f"but this env flies {flown}")
        return int_arg("options['scene_seed']", options["scene_seed"], 0, MAX_SCENE_SEED)

    def step(self, actions: dict[str, Any]):
        self._vec.require_running("step()")
        if not self.agents:
            raise RuntimeError("step() called after the episode ended; call reset()")
        if not isinstance(actions, Mapping):
            raise TypeError(f"step() expects a dict {{agent: action}} for the agents {self.agents}, "
                            f"got {type(actions).__name__}")
        unknown = [a for a in actions if a not in self._index]
        if unknown:
            raise ValueError(f"step(): unknown agent(s) {unknown}; the agents are {self.agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"step(): missing actions for {missing}")
        act = self._unicycle_actions(actions) if self.action_mode == "unicycle" else self._waypoint_indices(actions)
        obs, rew, term, trunc, infos = self._vec.step(act[None])
        agents = self.possible_agents
        terminated, truncated = bool(term[0, 0]), bool(trunc[0, 0])
        if terminated or truncated:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return (self._obs_dict(obs), dict(zip(agents, rew[0].tolist(), strict=True)),
                dict.fromkeys(agents, terminated), dict.fromkeys(agents, truncated), self._agent_infos(infos))

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
        return np.array([_one_waypoint_index(a, actions[a], len(self.lattice)) for a in self.agents], dtype=int)

    def check_action(self, agent: str, action) -> None:
        """Raise the error ``step()`` would raise for ``agent``'s ``action`` (the AEC env checks each agent's action
        as it is given, not when the last agent's completes the slot)."""
        self._vec.require_running("step()")
        if self.action_mode == "unicycle":
            _one_unicycle_action(agent, action)
        else:
            _one_waypoint_index(agent, action, len(self.lattice))

    def _obs_dict(self, obs) -> dict[str, Any]:
        """Per-agent observations from the vector env's batch of one."""
        if self.dict_obs:
            rows, masks = obs["observation"][0], obs["action_mask"][0]
            return {a: {"observation": rows[i], "action_mask": masks[i]} for i, a in enumerate(self.possible_agents)}
        return dict(zip(self.possible_agents, obs[0], strict=True))

    def _agent_infos(self, infos: dict) -> dict[str, dict]:
        """Flat per-agent info dicts (python scalars, keys in ``INFO_KEYS`` order) from the (1, U) info arrays; the
        action mask last where it lives in the infos (waypoint mode without ``dict_obs``). One ``tolist`` per key."""
        cols = [infos[key][0].tolist() for key in INFO_KEYS]
        out = {a: dict(zip(INFO_KEYS, vals, strict=True))
               for a, vals in zip(self.possible_agents, zip(*cols, strict=True), strict=True)}
        if self.action_mode == "waypoint" and not self.dict_obs:
            masks = self._vec.action_masks()[0]
            for i, a in enumerate(self.possible_agents):
                out[a]["action_mask"] = masks[i]
        return out

    def action_mask(self, agent: str) -> np.ndarray:
        """The waypoint action mask of ``agent`` (int8, 1 = allowed); all ones in unicycle mode."""
        self._vec.require_running("action_mask()")
        if agent not in self._index:
            raise ValueError(f"action_mask(): unknown agent {agent!r}; the agents are {self.possible_agents}")
        return self._vec.action_masks()[0, self._index[agent]]

    def waypoint_paths(self, nodes) -> np.ndarray:
        """Where the UAVs would fly in this slot to lattice ``nodes`` ``(U, M)`` (agents in ``possible_agents``
        order): path samples ``(U, M, path_samples, 2)`` in the world frame (m), flown as ``step`` flies them.
        Read-only; waypoint mode, after ``reset()`` (:meth:`CovertSensingVectorEnv.waypoint_paths`)."""
        return self._vec.waypoint_paths(np.asarray(nodes)[None])[0]

    def onward_reach(self, xy, theta) -> np.ndarray:
        """How many lattice nodes UAVs ending this slot at poses ``xy`` ``(U, M, 2)``, ``theta`` ``(U, M)`` may reach
        in the next slot: ``(U, M)`` int64, -1 where ``xy`` is NaN. Read-only; waypoint mode, after ``reset()``
        (:meth:`CovertSensingVectorEnv.onward_reach`)."""
        return self._vec.onward_reach(np.asarray(xy)[None], np.asarray(theta)[None])[0]

    def safety_state(self, depth: int = 1):
        """What the safety filter reads of this slot and the next ``depth``, as a batch of one copy
        (:meth:`CovertSensingVectorEnv.safety_state`). Read-only; waypoint mode, after ``reset()``."""
        return self._vec.safety_state(depth)

    def state(self) -> np.ndarray:
        """Global state for centralised critics (see the class docstring)."""
        return self._vec.state()[0]

    def render(self):
        """The current slot drawn (``rgb_array``: an (H, W, 3) uint8 frame; ``human``: a window, None). Before
        ``reset()`` and after ``close()`` a RuntimeError, as Gymnasium's order enforcing does; without a render_mode
        a warning and None."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        self._vec.require_running("render()")
        if self._renderer is None:
            self._renderer = EpisodeRenderer(human=self.render_mode == "human")
        frame = self._renderer.draw(self.scenario, self._view)
        return frame if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        """Close the render window and release the scene; later calls but ``close()`` raise a RuntimeError."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._vec.close()
        self.agents = []


class _NotReset(RuntimeError, AttributeError):
    """Asked before ``reset()``: a RuntimeError that ``hasattr``/``getattr(..., default)`` treat as absent."""


CovertSensingParallelEnv.__doc__ = CovertSensingParallelEnv.__doc__.replace(
    "{OBSERVATION_TABLE}", observation_table().replace("\n", "\n    "))


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


def _one_waypoint_index(agent: str, value, n: int) -> int:
    """One agent's Discrete(n) action as an int (integers; floats only with an integral value), or a clear error."""
    act = np.asarray(value)
    val = float(act.reshape(-1)[0]) if act.size == 1 and act.ndim <= 1 and act.dtype.kind in "iuf" else math.nan
    if not (math.isfinite(val) and val == int(val) and 0 <= val < n):
        raise ValueError(f"action for {agent} must be an integer in [0, {n - 1}], got {value!r}")
    return int(val)


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

    def step(self, action) -> None:
        # parallel_to_aec stores the action until the last agent acts: check it now, so the error names the
        # agent that gave it and comes from its own step() call. A finished agent's action is None.
        agent = self.agent_selection
        if self._has_reset and not (self.terminations.get(agent) or self.truncations.get(agent)):
            self.unwrapped.check_action(agent, action)
        super().step(action)


def env(**kwargs):
    """The AEC version, through ``parallel_to_aec`` with PettingZoo's order-enforcing wrappers."""
    return _AECEnv(parallel_to_aec(parallel_env(**kwargs)))

