"""An SB3 ``VecEnv`` over PettingZoo ParallelEnvs: copies x agents flattened, for parameter sharing.

Why not SuperSuit: it is unmaintained, its ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1`` break seeded
SB3 runs (``PPO(..., seed=0)`` is not reproducible through them) and drop ``TimeLimit.truncated``, so SB3
bootstraps nothing at the end of our 70-slot route. This adapter is ~150 lines and does exactly what SB3 needs:

* ``num_envs = n_copies * n_agents``: row ``j * U + i`` is agent ``i`` of copy ``j``; one policy acts for all rows
  (parameter sharing). Every agent of a copy must share one observation and one action space.
* Seeding: ``VecEnv.seed(s)`` (called by ``PPO(..., seed=s)``) stores per-row seeds; at the next ``reset()`` copy
  ``j`` is reset with the seed of its first row (``s + j * U``), then runs on the env's own RNG. Two runs with the
  same seed therefore see the same scenes and starts, and train to identical parameters.
* Episode ends: a copy ends when all its agents are done (our env ends every agent at once; a copy where only some
  agents finish raises, since padding dead agents is not supported). Every row of the copy then gets
  ``done=True``, ``infos[row]["terminal_observation"]`` (the agent's last observation) and
  ``infos[row]["TimeLimit.truncated"] = truncated and not terminated``; the copy is reset at once and the returned
  observation is the first one of the next episode (SB3's auto-reset convention).
* ``reward_fn(reward, info) -> float`` (optional) reshapes the per-agent reward for training only.
* ``env_method("action_masks")`` returns each row's waypoint action mask (for MaskablePPO).
* Lock-step: copies of our own env are stepped together through
  :func:`covert_env.envs.covert_sensing.step_copies` (one set of vectorised numpy calls per vector step instead
  of one per copy; the results are exactly those of ``env.step`` on each copy, tested). Any other ParallelEnv is
  stepped copy by copy.

Works under ``VecMonitor`` (episode statistics per agent row) and ``VecNormalize``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from covert_env.envs.covert_sensing import CovertSensingParallelEnv, step_copies

__all__ = ["ParallelEnvVecAdapter", "make_vec_env"]


class ParallelEnvVecAdapter(VecEnv):
    """SB3 VecEnv over ``n_copies`` PettingZoo ParallelEnvs with U agents each (``num_envs = n_copies * U``).

    Args:
        env_fns: one zero-argument constructor per copy (each returns a ParallelEnv).
        reward_fn: optional ``(reward, info) -> float`` applied per agent and step (training-time shaping).
    """

    def __init__(self, env_fns: Sequence[Callable[[], Any]], reward_fn: Callable[[float, dict], float] | None = None):
        if not env_fns:
            raise ValueError("ParallelEnvVecAdapter needs at least one env constructor")
        self.envs = [fn() for fn in env_fns]
        first = self.envs[0]
        self.agents = list(first.possible_agents)
        self.n_agents = len(self.agents)
        self.n_copies = len(self.envs)
        obs_space = first.observation_space(self.agents[0])
        act_space = first.action_space(self.agents[0])
        for env in self.envs:
            if list(env.possible_agents) != self.agents:
                raise ValueError("every copy must have the same possible_agents")
            for a in self.agents:
                if env.observation_space(a) != obs_space or env.action_space(a) != act_space:
                    raise ValueError(f"agent {a} has another observation/action space than {self.agents[0]}: "
                                     "parameter sharing needs identical spaces")
        if isinstance(obs_space, spaces.Dict):
            raise ValueError("Dict observations are not supported; use dict_obs=False and env_method('action_masks')")
        self.reward_fn = reward_fn
        super().__init__(self.n_copies * self.n_agents, obs_space, act_space)
        self._obs = np.zeros((self.num_envs, *obs_space.shape), dtype=obs_space.dtype)
        self._rews = np.zeros(self.num_envs, dtype=np.float32)
        self._dones = np.zeros(self.num_envs, dtype=bool)
        self._infos: list[dict] = [{} for _ in range(self.num_envs)]
        self._actions: np.ndarray | None = None
        # Our own env steps all copies at once (step_copies); any other ParallelEnv is stepped copy by copy.
        self._lockstep = (all(type(e).step is CovertSensingParallelEnv.step and not e.dict_obs for e in self.envs)
                          and all(e._lockstep_key() == first._lockstep_key() for e in self.envs))

    # ------------------------------------------------------------------ helpers
    def _rows(self, j: int) -> range:
        return range(j * self.n_agents, (j + 1) * self.n_agents)

    def _reset_copy(self, j: int) -> dict:
        row0 = j * self.n_agents
        seed, options = self._seeds[row0], self._options[row0] or None
        obs, infos = self.envs[j].reset(seed=seed, options=options)
        for i, a in enumerate(self.agents):
            self._obs[row0 + i] = obs[a]
            self.reset_infos[row0 + i] = infos.get(a, {})
        return obs

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> VecEnvObs:
        for j in range(self.n_copies):
            self._reset_copy(j)
        # Seeds and options are used once, at this reset (SB3 semantics).
        self._reset_seeds()
        self._reset_options()
        return self._obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._lockstep:
            return self._step_lockstep()
        discrete = isinstance(self.action_space, spaces.Discrete)
        for j, env in enumerate(self.envs):
            rows = self._rows(j)
            acts = {a: (int(self._actions[r]) if discrete else self._actions[r])
                    for a, r in zip(self.agents, rows, strict=True)}
            obs, rew, term, trunc, infos = env.step(acts)
            ended = not env.agents
            for a, r in zip(self.agents, rows, strict=True):
                done_a = bool(term[a] or trunc[a])
                if done_a != ended:
                    raise NotImplementedError(f"agent {a} ended alone: agents that finish at different times "
                                              "are not supported by ParallelEnvVecAdapter")
                self._obs[r] = obs[a]
                self._infos[r] = dict(infos.get(a, {}))
            self._end_copy(j, ended, [bool(term[a]) for a in self.agents], [bool(trunc[a]) for a in self.agents],
                           [float(rew[a]) for a in self.agents])
        return self._obs.copy(), self._rews.copy(), self._dones.copy(), list(self._infos)

    def _step_lockstep(self) -> VecEnvStepReturn:
        """All copies in one :func:`~covert_env.envs.covert_sensing.step_copies` call (same results)."""
        expected = (self.num_envs,) + self.action_space.shape
        if self._actions.shape != expected:
            raise ValueError(f"actions must have shape {expected} (one row per copy and agent), "
                             f"got {self._actions.shape}")
        acts = self._actions.reshape((self.n_copies, self.n_agents) + self.action_space.shape)
        obs, rew, term, trunc, infos = step_copies(self.envs, acts)
        self._obs[:] = obs.reshape(self._obs.shape)
        # Fresh dicts from the env: no copy needed.
        self._infos[:] = [info for copy_infos in infos for info in copy_infos]
        for j in range(self.n_copies):
            self._end_copy(j, bool(term[j] or trunc[j]), [bool(term[j])] * self.n_agents,
                           [bool(trunc[j])] * self.n_agents, rew[j])
        return self._obs.copy(), self._rews.copy(), self._dones.copy(), list(self._infos)

    def _end_copy(self, j: int, ended: bool, terminated: list[bool], truncated: list[bool], rewards) -> None:
        """Rewards (float64 from the env, shaped by ``reward_fn``), done flags and SB3's end-of-episode infos
        for copy j (per-agent flags); reset the copy if it ended."""
        for i, r in enumerate(self._rows(j)):
            info = self._infos[r]
            reward = float(rewards[i])
            if self.reward_fn is not None:
                info["env_reward"] = reward
                reward = float(self.reward_fn(reward, info))
            self._rews[r] = reward
            self._dones[r] = ended
            if ended:
                info["terminal_observation"] = self._obs[r].copy()
                info["TimeLimit.truncated"] = truncated[i] and not terminated[i]
        if ended:
            self._reset_copy(j)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        seeds = super().seed(seed)
        self.action_space.seed(seeds[0])
        return seeds

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        # One frame per copy (all agents of a copy share the scene).
        return [env.render() for env in self.envs]

    def _indices(self, indices: VecEnvIndices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.envs[r // self.n_agents], attr_name) for r in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for j in sorted({r // self.n_agents for r in self._indices(indices)}):
            setattr(self.envs[j], attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        rows = self._indices(indices)
        if method_name == "action_masks":
            return [self.envs[r // self.n_agents].action_mask(self.agents[r % self.n_agents]).astype(bool)
                    for r in rows]
        return [getattr(self.envs[r // self.n_agents], method_name)(*method_args, **method_kwargs) for r in rows]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._indices(indices)]


def make_vec_env(n_copies: int, env_kwargs: dict | None = None,
                 reward_fn: Callable[[float, dict], float] | None = None) -> ParallelEnvVecAdapter:
    """``n_copies`` covert_env ParallelEnvs built with ``env_kwargs``, flattened for a shared SB3 policy."""
    kw = dict(env_kwargs or {})
    return ParallelEnvVecAdapter([lambda: CovertSensingParallelEnv(**kw) for _ in range(n_copies)], reward_fn=reward_fn)
