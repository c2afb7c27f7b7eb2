"""A TorchRL-native env on the vector env: B copies in one process, one TensorDict per step.

Imported on demand (``import covert_env`` never imports torch): ``from covert_env.integrations.torchrl import
make_torchrl_env`` (``pip install -e ".[torchrl]"``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase

from covert_env.envs.vector import INFO_DTYPES, CovertSensingVectorEnv

__all__ = ["CovertSensingTorchRLEnv", "make_torchrl_env", "GROUP"]

#: The agents' group: the name ``PettingZooWrapper`` gives them (README "Use it with your framework").
GROUP = "uav"


class CovertSensingTorchRLEnv(EnvBase):
    """B copies of the covert-sensing task as one TorchRL ``EnvBase`` of batch size ``[B]``, agents grouped.

    ## Description

    A view of :class:`~covert_env.envs.vector.CovertSensingVectorEnv` (whose docstring, and the parallel env's,
    describe the task, rewards, costs and observations) in TorchRL's multi-agent layout, the layout of
    TorchRL's VMAS wrapper: the U UAVs form the group ``"uav"``, every per-agent entry has shape ``[B, U, ...]``.
    The engine stays in numpy; its arrays become tensors through ``torch.from_numpy`` (no copy) where their
    dtype is already the spec's.

    ## TensorDict layout

    | key | shape | dtype | |
    |---|---|---|---|
    | ``("uav", "observation")`` | ``[B, U, D]`` | float32 | Bounded by the parallel env's observation Box |
    | ``("uav", "action_mask")`` | ``[B, U, L]`` | bool | waypoint mode only; also the action spec's mask |
    | ``"state"`` | ``[B, S]`` | float32 | the vector env's ``state()`` |
    | ``("uav", "info", key)`` | ``[B, U]`` | int64/bool/float64 | the vector env's infos |
    | ``("uav", "action")`` | ``[B, U, 2]`` / ``[B, U]`` / ``[B, U, L]`` | float32 / int64 / bool | see below |
    | ``("uav", "reward")`` | ``[B, U, 1]`` | float32 | |
    | ``"done"``, ``"terminated"``, ``"truncated"`` | ``[B, 1]`` | bool | also under ``"uav"`` as ``[B, U, 1]`` |

    ## Action Space

    Unicycle mode: ``Bounded`` floats in [-1, 1], ``[B, U, 2]`` (speed, turn rate). Waypoint mode: lattice node
    indices, ``Categorical(L)`` of shape ``[B, U]`` (``categorical_actions=False``: ``OneHot(L)``, ``[B, U, L]``),
    masked with the current masks, so ``rand_action`` and ``MaskedCategorical`` policies pick allowed nodes.

    ## Episode ends and resets

    The vector env resets an ended copy within ``step()`` (Gymnasium's same-step mode). TorchRL wants the last
    observation under ``"next"`` and the first one of the next episode from ``reset()`` with a ``"_reset"``
    mask, so this env does what TorchRL's ``GymWrapper`` does with such vectors: ``"next"`` holds the copy's
    final observation, state and infos, and the next episode's, already drawn, are returned when TorchRL resets
    that copy. Copies reset although they did not end are reset in the vector env (``reset_mask``), from their
    own generators. Hence the TorchRL env steps through exactly the vector env's episodes (tested).

    ## Seeding

    ``set_seed(s)`` (or ``reset(seed=s)``) seeds the next full reset as ``vector_env.reset(seed=s)`` does: copy
    ``i`` from ``np.random.SeedSequence(s)``'s ``i``-th seed.

    ## Arguments

    ``num_envs`` (B), ``device`` (tensors are made on the CPU and moved), ``categorical_actions`` (waypoint
    mode), and the parallel env's keyword arguments except ``dict_obs`` (the mask has its own entry).
    """

    batch_locked = True

    def __init__(self, num_envs: int = 1, device: Any = "cpu", categorical_actions: bool = True, **kwargs: Any):
        if kwargs.pop("dict_obs", False):
            raise ValueError("dict_obs: the TorchRL env puts the mask at ('uav', 'action_mask') itself")
        self._venv = CovertSensingVectorEnv(num_envs, **kwargs)
        super().__init__(device=device, batch_size=torch.Size([self._venv.num_envs]))
        self.categorical_actions = categorical_actions
        self.waypoint = self._venv.action_mode == "waypoint"
        self.agent_names = list(self._venv.possible_agents)
        self.group_map = {GROUP: self.agent_names}
        self._seed: int | None = None
        # Copies that ended in the last step: the vector env already holds their next episode (class docstring).
        self._pending = np.zeros(self._venv.num_envs, bool)
        self._next: tuple[np.ndarray, dict[str, np.ndarray]] | None = None
        self._make_specs()

    @property
    def vector_env(self) -> CovertSensingVectorEnv:
        """The vector env underneath (numpy arrays, Gymnasium's conventions)."""
        return self._venv

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        venv, dev = self._venv, self.device
        b, u = venv.num_envs, len(self.agent_names)
        obs_box, state_box = venv.single_observation_space, venv.single_state_space
        group = {"observation": Bounded(torch.from_numpy(np.broadcast_to(obs_box.low, (b, u) + obs_box.shape).copy()),
                                        torch.from_numpy(np.broadcast_to(obs_box.high, (b, u) + obs_box.shape).copy()),
                                        shape=(b, u) + obs_box.shape, dtype=torch.float32, device=dev)}
        if self.waypoint:
            group["action_mask"] = Categorical(2, shape=(b, u, len(venv.lattice)), dtype=torch.bool, device=dev)
        group["info"] = Composite({key: _info_spec(dtype, (b, u), dev) for key, dtype in INFO_DTYPES.items()},
                                  shape=(b, u), device=dev)
        self.observation_spec = Composite(
            {GROUP: Composite(group, shape=(b, u), device=dev),
             "state": Bounded(torch.from_numpy(np.broadcast_to(state_box.low, (b,) + state_box.shape).copy()),
                              torch.from_numpy(np.broadcast_to(state_box.high, (b,) + state_box.shape).copy()),
                              shape=(b,) + state_box.shape, dtype=torch.float32, device=dev)},
            shape=(b,), device=dev)
        if not self.waypoint:
            action = Bounded(-1.0, 1.0, shape=(b, u, 2), dtype=torch.float32, device=dev)
        elif self.categorical_actions:
            action = Categorical(len(venv.lattice), shape=(b, u), dtype=torch.int64, device=dev)
        else:
            action = OneHot(len(venv.lattice), shape=(b, u, len(venv.lattice)), dtype=torch.bool, device=dev)
        self.action_spec = Composite({GROUP: Composite({"action": action}, shape=(b, u), device=dev)},
                                     shape=(b,), device=dev)
        self.reward_spec = Composite(
            {GROUP: Composite({"reward": Unbounded(shape=(b, u, 1), dtype=torch.float32, device=dev)},
                              shape=(b, u), device=dev)}, shape=(b,), device=dev)
        flags = ("done", "terminated", "truncated")
        self.done_spec = Composite(
            {**{k: Categorical(2, shape=(b, 1), dtype=torch.bool, device=dev) for k in flags},
             GROUP: Composite({k: Categorical(2, shape=(b, u, 1), dtype=torch.bool, device=dev) for k in flags},
                              shape=(b, u), device=dev)},
            shape=(b,), device=dev)

    # ------------------------------------------------------------------ EnvBase
    def _set_seed(self, seed: int | None) -> None:
        # Kept for the next full reset: a partial reset must not reseed the copies that keep running.
        self._seed = seed

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        seed = kwargs.pop("seed", None)
        if seed is not None:
            self._seed = seed
        mask = None if tensordict is None else self._reset_mask(tensordict)
        # A pending seed waits for a reset of every copy: TorchRL keeps the rows outside a partial mask as they were.
        if mask is None or self._next is None or (mask.all() and self._seed is not None):
            obs, infos = self._venv.reset(seed=self._seed, options=kwargs.pop("options", None))
            self._seed, self._pending[:] = None, False
        else:
            fresh = mask & ~self._pending
            # Ended copies already hold their next episode: taking it keeps their generators in step with the
            # vector env's automatic resets.
            obs, infos = (self._venv.reset(options={"reset_mask": fresh}) if fresh.any() else self._next)
            self._pending &= ~mask
        self._next = (obs, infos)
        return self._tensordict(obs, infos, self._venv.state())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get((GROUP, "action"))
        if self.waypoint and not self.categorical_actions:
            action = action.long().argmax(-1)
        obs, rewards, term, trunc, infos = self._venv.step(action.detach().cpu().numpy())
        state = self._venv.state()
        self._next = (obs, infos)
        ended = term[:, 0] | trunc[:, 0]              # all agents of a copy end together
        self._pending = ended
        if ended.any():
            # "next" is the last slot of an ended copy; its next episode waits for TorchRL's reset (docstring).
            obs = _where(ended, infos["final_obs"], obs)
            state = _where(ended, infos["final_state"], state)
            infos = {key: _where(ended, infos["final_info"][key], infos[key]) for key in infos["final_info"]}
        out = self._tensordict(obs, infos, state)
        group = out.get(GROUP)
        group.set("reward", self._tensor(rewards.astype(np.float32)[..., None]))
        term_t, trunc_t = self._tensor(term[..., None]), self._tensor(trunc[..., None])
        done_t = term_t | trunc_t
        group.update({"terminated": term_t, "truncated": trunc_t, "done": done_t})
        out.update({"terminated": term_t[:, 0], "truncated": trunc_t[:, 0], "done": done_t[:, 0]})
        return out

    # ------------------------------------------------------------------ helpers
    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        t = torch.from_numpy(np.ascontiguousarray(array))
        return t if self.device is None or self.device == t.device else t.to(self.device)

    def _tensordict(self, obs: np.ndarray, infos: dict[str, np.ndarray], state: np.ndarray) -> TensorDictBase:
        b, u = self.batch_size[0], len(self.agent_names)
        group = {"observation": self._tensor(obs),
                 "info": TensorDict({key: self._tensor(infos[key]) for key in INFO_DTYPES}, batch_size=(b, u),
                                    device=self.device)}
        if self.waypoint:
            mask = self._tensor(self._venv.action_masks().astype(bool))
            group["action_mask"] = mask
            # rand_action and the checkers read the mask from the spec, as PettingZooWrapper sets it.
            self.action_spec[GROUP, "action"].update_mask(mask)
        return TensorDict({GROUP: TensorDict(group, batch_size=(b, u), device=self.device),
                           "state": self._tensor(state)}, batch_size=self.batch_size, device=self.device)

    def _reset_mask(self, tensordict: TensorDictBase) -> np.ndarray | None:
        """(B,) bools from the root and group ``"_reset"`` entries; None when neither is there."""
        masks = [tensordict.get(key).reshape(self.batch_size[0], -1).any(-1)
                 for key in ("_reset", (GROUP, "_reset")) if tensordict.get(key, None) is not None]
        if not masks:
            return None
        return torch.stack(masks).any(0).cpu().numpy()


def _where(rows: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.where(rows.reshape(rows.shape + (1,) * (a.ndim - 1)), a, b)


def _info_spec(dtype: np.dtype, shape: tuple[int, int], device):
    if dtype == np.bool_:
        return Categorical(2, shape=shape, dtype=torch.bool, device=device)
    return Unbounded(shape=shape, dtype=torch.from_numpy(np.zeros(0, dtype)).dtype, device=device)


def make_torchrl_env(num_envs: int = 1, device: Any = "cpu", **kwargs: Any) -> CovertSensingTorchRLEnv:
    """``num_envs`` copies as a :class:`CovertSensingTorchRLEnv` (the parallel env's keyword arguments)."""
    return CovertSensingTorchRLEnv(num_envs, device=device, **kwargs)
