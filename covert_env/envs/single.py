"""Gymnasium single-UAV environments, thin wrappers over the PettingZoo env with one agent.

Registered at ``import covert_env`` as ``covert_env/CovertSensing-v4`` (continuous unicycle actions)
and ``covert_env/CovertSensingWaypoint-v4`` (discrete waypoint actions with ``action_masks()`` for
sb3-contrib's MaskablePPO).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from covert_env.envs.arguments import Forwarded
from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from covert_env.envs.observation import observation_table
from covert_env.world.config import Config

__all__ = ["CovertSensingEnv", "CovertSensingWaypointEnv"]


class CovertSensingEnv(gym.Env):
    """One UAV covertly filming a target on uneven terrain (Almuzaini & Savkin 2024).

    ## Description

    The single-UAV case of :class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv`: keep
    the target in view from inside the feasible flight zone behind it (eq. 4), out of the terrain's
    shadows (eqs. 8-10), changing bearing and range every slot (disguise, eq. 11) on a short path
    (eq. 15). One step is one slot of ``delta`` = 1 s.

    ## Action Space

    ``Box(-1, 1, (2,), float32)``: (speed, turn rate) scaled to 0 < v <= V_max = 50 m/s and
    |omega| <= W_max = 3 rad/s, integrated exactly over the slot. Out-of-range values are clipped;
    NaN/inf raise ``ValueError``. (``CovertSensingWaypoint-v4``: ``Discrete(L)`` lattice waypoints.)

    ## Observation Space

    ``Box(float32)`` in the target's frame, the single-agent version of the parallel env's table:

    {OBSERVATION_TABLE}

    S = ``map_size`` (default 8).

    ## Rewards

    ``-g / reward_scale`` (eq. 18: path length minus lambda times disguise) minus penalties for lost LoS (at the
    slot's end, and the share of its flown path with LoS blocked), leaving the zone and terrain clearance;
    ``info["reward_path"]`` .. ``info["reward_terrain"]`` itemise them.
    ``info["cost"]`` and ``info["cost_los"]`` .. ``info["cost_terrain"]`` are the constraint violations of the
    slot, for constrained RL. The infos are flat, with the same keys at reset and every step (the parallel
    env's Infos and Constraint Costs tables).

    ## Starting State

    ``scenario="random"`` (default): a random road, terrain and visible start per reset (pass
    ``options={"scene_seed": s}`` to choose); ``scenario="paper"``: the paper's map and start
    (40, 10) heading 2 pi.

    ## Episode End

    Truncated after ``min(max_cycles, config.n_slots)`` slots (default 70, the end of the route); never
    terminated.

    ## Vectorized Environment

    ``gym.make_vec("covert_env/CovertSensing-v4", num_envs=N)`` gives Gymnasium's ``SyncVectorEnv`` (or, with
    ``vectorization_mode="async"``, ``AsyncVectorEnv``) of N of these envs; it resets an ended env in
    Gymnasium's next-step mode (``AutoresetMode.NEXT_STEP``: the ``step()`` after the end resets it and ignores
    its action). ``covert_env.vector_env(num_envs=N, n_uavs=1)`` is the batched alternative (one process, array
    operations over all copies, observations ``(N, 1, D)``), and it resets in the same step
    (``AutoresetMode.SAME_STEP``, the last observation in ``infos["final_obs"]``; see
    :class:`~covert_env.envs.vector.CovertSensingVectorEnv`).

    ## Arguments

    Every keyword of the parallel env: ``config``, ``scenario``, ``max_cycles``, ``render_mode``,
    ``map_size``, ``target_path``, reward weights, ``scene_pool``, ``path_samples``; ``n_uavs`` may only be 1
    (``config.n_uavs`` is not read: a Config's default team of 3 would otherwise forbid every Config here) and
    ``action_mode`` only this env's (an error otherwise); ``dict_obs=True`` (waypoint env only) puts the
    action mask in the observation.

    ## Version History

    The PettingZoo env's it wraps (:class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv`): each version
    of ``covert_env/CovertSensing-vN`` and ``covert_env/CovertSensingWaypoint-vN`` has the task and numbers of
    ``covert_sensing_vN``. What each version changed: ``CHANGELOG.md``.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}
    _action_mode = "unicycle"

    def __init__(self, render_mode: str | None = None, **kwargs: Any):
        # Arguments that contradict this env are errors, not silently dropped: a user passing n_uavs=3 wants a team.
        if "n_uavs" in kwargs and (isinstance(kwargs["n_uavs"], (bool, np.bool_)) or kwargs["n_uavs"] != 1
                                   or not isinstance(kwargs["n_uavs"], (int, np.integer))):
            raise ValueError(f"{type(self).__name__} flies one UAV, got n_uavs={kwargs['n_uavs']!r}; for a team "
                             "use covert_env.parallel_env(n_uavs=U) (PettingZoo)")
        if kwargs.get("action_mode", self._action_mode) != self._action_mode:
            other = "CovertSensingWaypoint" if self._action_mode == "unicycle" else "CovertSensing"
            raise ValueError(f"{type(self).__name__} has action_mode={self._action_mode!r}, got "
                             f"action_mode={kwargs['action_mode']!r}; use the id covert_env/{other}-v4")
        kwargs.update(n_uavs=1, action_mode=self._action_mode)
        self.par = CovertSensingParallelEnv(render_mode=render_mode, **kwargs)
        self.render_mode = render_mode
        self._agent = self.par.possible_agents[0]
        self.observation_space = self.par.observation_space(self._agent)
        self.action_space = self.par.action_space(self._agent)

    config: Config = Forwarded("par", writable=False)
    """The env's :class:`~covert_env.world.config.Config`."""
    max_cycles: int = Forwarded("par")
    """Episode length bound in slots (validated on assignment; the route ends at ``config.n_slots``)."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, infos = self.par.reset(seed=seed, options=options)
        return obs[self._agent], infos[self._agent]

    def step(self, action):
        obs, rew, term, trunc, infos = self.par.step({self._agent: action})
        a = self._agent
        return obs[a], float(rew[a]), bool(term[a]), bool(trunc[a]), infos[a]

    def render(self):
        return self.par.render()

    def close(self):
        self.par.close()


CovertSensingEnv.__doc__ = CovertSensingEnv.__doc__.replace(
    "{OBSERVATION_TABLE}", observation_table(single_agent=True).replace("\n", "\n    "))


class CovertSensingWaypointEnv(CovertSensingEnv):
    """The single-UAV env with discrete waypoint actions (``Discrete(L)``) and ``action_masks()``.

    Each action is a node of the fixed lattice in the target's frame (the DP planner's node set),
    placed at the target's next pose; the env flies the turn-then-straight manoeuvre (eqs. 22-29)
    to it. ``action_masks()`` (and ``info["action_mask"]``, or ``obs["action_mask"]`` with ``dict_obs=True``)
    mark nodes reachable in one slot and in the visible zone (eq. 10). If no node is both, the reachable nodes
    are allowed; if the UAV can reach no node at all (how often: docs/environments.md), every
    node is, so a masked sampler always has a choice. A node the UAV cannot reach is flown as a best effort (the
    admissible constant (v, omega) ending closest to it) and flagged ``info["infeasible"]``, as is a masked-out
    node. See :class:`CovertSensingEnv` for everything else.
    """

    _action_mode = "waypoint"

    def action_masks(self) -> np.ndarray:
        """Boolean mask of valid actions, the interface of sb3-contrib's MaskablePPO."""
        return self.par.action_mask(self._agent).astype(bool)
