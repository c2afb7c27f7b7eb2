"""An SB3 ``VecEnv`` on :class:`~covert_env.envs.vector.CovertSensingVectorEnv`: B copies x U agents, one process.

The same contract as :class:`training.sb3.vec_env.ParallelEnvVecAdapter` (row ``j * U + i`` is agent ``i`` of copy
``j``, parameter sharing, ``terminal_observation`` and ``TimeLimit.truncated`` at episode ends, the next episode's
first observation returned at once, ``reward_fn`` shaping, ``env_method("action_masks")`` for MaskablePPO), with
the same results for the same seed (tested): ``VecEnv.seed(s)`` gives copy ``j`` the seed ``s + j * U``, exactly
the seed that adapter gives its copy ``j``. The vector env steps every copy in one batch of array operations and
resets finished copies itself (same-step autoreset), so stepping costs no Python loop over copies; only SB3's list
of per-row info dicts is built row by row (SB3 needs one dict per row).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from covert_env.envs.vector import INFO_KEYS, CovertSensingVectorEnv

__all__ = ["VectorEnvVecAdapter", "make_vector_vec_env"]


class VectorEnvVecAdapter(VecEnv):
    """SB3 VecEnv over a :class:`CovertSensingVectorEnv` of B copies with U agents (``num_envs = B * U``).

    Args:
        venv: the vector env (``dict_obs=False``: SB3 takes the masks from ``env_method("action_masks")``).
        reward_fn: optional ``(reward, info) -> float`` applied per agent and step (training-time shaping).
    """

    def __init__(self, venv: CovertSensingVectorEnv, reward_fn: Callable[[float, dict], float] | None = None):
        if venv.dict_obs:
            raise ValueError("Dict observations are not supported; use dict_obs=False and env_method('action_masks')")
        self.venv, self.reward_fn = venv, reward_fn
        self.n_copies, self.n_agents = venv.num_envs, len(venv.possible_agents)
        super().__init__(self.n_copies * self.n_agents, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> VecEnvObs:
        first = self._seeds[::self.n_agents]                 # a copy takes the seed of its first row
        seed = None if first[0] is None else [int(s) for s in first]
        options = [o or {} for o in self._options[::self.n_agents]]
        scene = [o.get("scene_seed") for o in options]
        if any(set(o) - {"scene_seed"} for o in options) or (any(s is None for s in scene)
                                                               and any(s is not None for s in scene)):
            raise ValueError("VectorEnvVecAdapter: options must give every copy a 'scene_seed' (or none)")
        obs, infos = self.venv.reset(seed=seed, options=None if scene[0] is None else {"scene_seed": scene})
        self.reset_infos = _rows(infos, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs.reshape(self.num_envs, -1)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        shape = (self.n_copies, self.n_agents) + self.action_space.shape
        if self._actions.size != np.prod(shape):
            raise ValueError(f"actions must have shape {(self.num_envs,) + self.action_space.shape} (one row per "
                             f"copy and agent), got {self._actions.shape}")
        obs, rew, term, trunc, infos = self.venv.step(self._actions.reshape(shape))
        dones = (term | trunc).reshape(-1)
        if dones.any():
            # SB3 wants the last slot's infos for a finished row (the vector env's are the next episode's first).
            ended = np.repeat(infos["_final_info"], self.n_agents)
            infos = {key: np.where(ended.reshape(term.shape), infos["final_info"][key], infos[key])
                     for key in INFO_KEYS} | {"final_obs": infos["final_obs"]}
        rows = _rows(infos, self.num_envs)
        rewards = rew.reshape(-1)
        if self.reward_fn is not None:
            for info, r in zip(rows, rewards.tolist(), strict=True):
                info["env_reward"] = r
            rewards = np.array([self.reward_fn(r, info) for r, info in zip(rewards.tolist(), rows, strict=True)])
        if dones.any():
            final = infos["final_obs"].reshape(self.num_envs, -1)
            late = (trunc & ~term).reshape(-1)
            for r in np.flatnonzero(dones).tolist():
                rows[r]["terminal_observation"] = final[r].copy()
                rows[r]["TimeLimit.truncated"] = bool(late[r])
        return obs.reshape(self.num_envs, -1), rewards.astype(np.float32), dones, rows

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        seeds = super().seed(seed)
        self.action_space.seed(seeds[0])
        return seeds

    def close(self) -> None:
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.n_copies

    def _indices(self, indices: VecEnvIndices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        # One env holds every copy: an attribute is the same for all rows, so setting it for some only is refused.
        if sorted(set(self._indices(indices))) != list(range(self.num_envs)):
            raise ValueError(f"set_attr({attr_name!r}): the vector env holds every copy, so an attribute is set for "
                             f"all rows at once (indices=None), got indices={indices!r}")
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        rows = self._indices(indices)
        if method_name == "action_masks":
            masks = self.venv.action_masks().reshape(self.num_envs, -1).astype(bool)
            return [masks[r] for r in rows]
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result] * len(rows)

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._indices(indices))


def _rows(infos: dict, n: int) -> list[dict]:
    """SB3's list of per-row info dicts from the vector env's (B, U) arrays (the parallel env's keys and types)."""
    cols = [infos[key].reshape(-1).tolist() for key in INFO_KEYS]
    return [dict(zip(INFO_KEYS, row, strict=True)) for row in zip(*cols, strict=True)] if n else []


def make_vector_vec_env(n_copies: int, env_kwargs: dict | None = None,
                        reward_fn: Callable[[float, dict], float] | None = None) -> VectorEnvVecAdapter:
    """``n_copies`` copies of the covert_env env built with ``env_kwargs`` as one vector env, flattened for a shared
    SB3 policy (the drop-in for :func:`training.sb3.vec_env.make_vec_env`)."""
    return VectorEnvVecAdapter(CovertSensingVectorEnv(num_envs=n_copies, **dict(env_kwargs or {})), reward_fn=reward_fn)

