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
* Copies are stepped one by one: this adapter is for any ParallelEnv (e.g. mpe2's, in ``benchmarks/sb3_fps.py``).
  Our own env has a batched one: :func:`make_vec_env` returns :class:`training.sb3.vector_adapter.VectorEnvVecAdapter`
  on :class:`covert_env.envs.vector.CovertSensingVectorEnv` (every copy in one batch of array operations, the same
  results for the same seed, tested).

Works under ``VecMonitor`` (episode statistics per agent row) and ``VecNormalize``.

VecNormalize statistics are saved as JSON, not pickled (:func:`save_vecnormalize`, :func:`load_vecnormalize`,
:func:`read_vecnormalize`): a run folder holds ``vecnormalize.json`` beside ``model.zip``. Loading a file never
runs code from it; ``.pkl`` statistics of older runs are refused (convert a trusted one explicitly with
``python -m training.sb3.convert_vecnormalize --trust-checkpoint PATH``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from covert_env.world.config import read_json

__all__ = ["ParallelEnvVecAdapter", "make_vec_env", "save_vecnormalize", "load_vecnormalize", "read_vecnormalize",
           "vecnormalize_state", "NormStats", "VECNORMALIZE_FORMAT"]


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
                 reward_fn: Callable[[float, dict], float] | None = None):
    """``n_copies`` copies of the covert_env env built with ``env_kwargs``, flattened for a shared SB3 policy: the
    batched :class:`training.sb3.vector_adapter.VectorEnvVecAdapter` (one vector env of ``n_copies`` copies)."""
    from training.sb3.vector_adapter import make_vector_vec_env

    return make_vector_vec_env(n_copies, env_kwargs, reward_fn=reward_fn)


# ---------------------------------------------------------------------- VecNormalize statistics as JSON
#: The ``format`` field of a VecNormalize statistics file.
VECNORMALIZE_FORMAT = "covert_env.vecnormalize"
_VN_VERSION = 1


@dataclass(frozen=True)
class NormStats:
    """VecNormalize statistics read from JSON (what evaluation needs, and what :func:`load_vecnormalize` sets).

    ``obs_mean`` / ``obs_var`` are float64 arrays of the observation shape (``None`` if ``norm_obs`` is false);
    ``normalize_obs`` applies them exactly as ``VecNormalize.normalize_obs`` does.
    """

    norm_obs: bool
    norm_reward: bool
    clip_obs: float
    clip_reward: float
    gamma: float
    epsilon: float
    obs_mean: np.ndarray | None
    obs_var: np.ndarray | None
    obs_count: float | None
    ret_mean: float
    ret_var: float
    ret_count: float

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        if not self.norm_obs:
            return np.asarray(obs)
        return np.clip((np.asarray(obs) - self.obs_mean) / np.sqrt(self.obs_var + self.epsilon),
                       -self.clip_obs, self.clip_obs).astype(np.float32)


def vecnormalize_state(vn) -> dict:
    """The JSON-able state of a ``VecNormalize`` (Box observations; Dict observations are not supported)."""
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    obs_rms = getattr(vn, "obs_rms", None) if vn.norm_obs else None
    if obs_rms is not None and not isinstance(obs_rms, RunningMeanStd):
        raise NotImplementedError("VecNormalize statistics of Dict observations are not supported")

    def rms(r) -> dict:
        return {"mean": np.asarray(r.mean, np.float64).tolist(), "var": np.asarray(r.var, np.float64).tolist(),
                "count": float(r.count), "shape": list(np.shape(r.mean))}

    return {"format": VECNORMALIZE_FORMAT, "version": _VN_VERSION,
            "norm_obs": bool(vn.norm_obs), "norm_reward": bool(vn.norm_reward),
            "clip_obs": float(vn.clip_obs), "clip_reward": float(vn.clip_reward),
            "gamma": float(vn.gamma), "epsilon": float(vn.epsilon),
            "obs_rms": rms(obs_rms) if obs_rms is not None else None, "ret_rms": rms(vn.ret_rms)}


def save_vecnormalize(vn, path: str | Path) -> Path:
    """Write the statistics of ``vn`` (a ``VecNormalize``) to ``path`` as JSON (floats round-trip exactly)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(vecnormalize_state(vn)))
    tmp.replace(path)
    return path


def _refuse_pickle(path: Path) -> None:
    if path.suffix == ".pkl":
        raise ValueError(
            f"{path}: VecNormalize statistics pickled by an older covert_env; they are not loaded, since unpickling "
            f"a file can run any code. If you trust the file, convert it once with "
            f"`python -m training.sb3.convert_vecnormalize --trust-checkpoint {path}` (writes "
            f"{path.with_suffix('.json').name} beside it)")


def read_vecnormalize(path: str | Path) -> NormStats:
    """Read VecNormalize statistics written by :func:`save_vecnormalize` (``ValueError`` naming the file if not)."""
    path = Path(path)
    _refuse_pickle(path)
    d = read_json(path, "VecNormalize statistics")          # a ValueError naming the file, or FileNotFoundError
    if not isinstance(d, dict) or d.get("format") != VECNORMALIZE_FORMAT:
        raise ValueError(f"{path}: not a VecNormalize statistics file (no \"format\": \"{VECNORMALIZE_FORMAT}\")")
    if d.get("version") != _VN_VERSION:
        raise ValueError(f"{path}: VecNormalize statistics version {d.get('version')!r}, "
                         f"this covert_env reads version {_VN_VERSION}")

    def num(key, v, positive=False) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
            raise ValueError(f"{path}: {key} must be a finite{' positive' if positive else ''} number, got {v!r}")
        return float(v)

    def rms(key) -> tuple[np.ndarray, np.ndarray, float]:
        r = d.get(key)
        if not isinstance(r, dict):
            raise ValueError(f"{path}: {key} is missing")
        try:
            shape = tuple(int(n) for n in r["shape"])
            mean = np.asarray(r["mean"], np.float64).reshape(shape)
            var = np.asarray(r["var"], np.float64).reshape(shape)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: {key} must hold mean and var arrays of its shape ({exc})") from None
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0)):
            raise ValueError(f"{path}: {key} holds non-finite means or negative/non-finite variances")
        return mean, var, num(f"{key}.count", r.get("count"), positive=True)

    flags = {}
    for k in ("norm_obs", "norm_reward"):
        if not isinstance(d.get(k), bool):
            raise ValueError(f"{path}: {k} must be true or false, got {d.get(k)!r}")
        flags[k] = d[k]
    obs = rms("obs_rms") if flags["norm_obs"] else (None, None, None)
    ret = rms("ret_rms")
    return NormStats(norm_obs=flags["norm_obs"], norm_reward=flags["norm_reward"],
                     clip_obs=num("clip_obs", d.get("clip_obs"), True),
                     clip_reward=num("clip_reward", d.get("clip_reward"), True),
                     gamma=num("gamma", d.get("gamma")), epsilon=num("epsilon", d.get("epsilon"), True),
                     obs_mean=obs[0], obs_var=obs[1], obs_count=obs[2],
                     ret_mean=float(ret[0]), ret_var=float(ret[1]), ret_count=ret[2])


def load_vecnormalize(path: str | Path, venv: VecEnv, training: bool = True):
    """A ``VecNormalize`` around ``venv`` with the statistics of ``path`` (the JSON of :func:`save_vecnormalize`).

    Replaces SB3's pickle-based loader; the result normalises observations and rewards exactly as
    the saved wrapper did.
    """
    from stable_baselines3.common.vec_env import VecNormalize

    s = read_vecnormalize(path)
    vn = VecNormalize(venv, training=training, norm_obs=s.norm_obs, norm_reward=s.norm_reward, clip_obs=s.clip_obs,
                      clip_reward=s.clip_reward, gamma=s.gamma, epsilon=s.epsilon)
    if s.norm_obs:
        if s.obs_mean.shape != vn.obs_rms.mean.shape:
            raise ValueError(f"{path}: statistics of observations of shape {s.obs_mean.shape}, but the env's "
                             f"observations have shape {vn.obs_rms.mean.shape}")
        vn.obs_rms.mean, vn.obs_rms.var, vn.obs_rms.count = s.obs_mean.copy(), s.obs_var.copy(), s.obs_count
    vn.ret_rms.mean, vn.ret_rms.var, vn.ret_rms.count = np.array(s.ret_mean), np.array(s.ret_var), s.ret_count
    return vn
