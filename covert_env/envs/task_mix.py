"""Copies of several tasks in one vector env: ``covert_env.vector_env(num_envs=B, task=[...])``.

The suite's tasks of one team size differ only in how their scenes are drawn (the scene family's fields of the
config, :data:`~covert_env.world.families.FAMILIES`) and in their target model (``prediction_error`` and the zone's
erosion ``r_u`` that comes with it, :mod:`covert_env.world.tasks`). Everything a step computes from the config (the
flight, the costs, the rewards, the observation) is the same for all of them, so one vector env steps copies of
every task in one batch: each copy draws its scenes with its own task's config into the env's one scene pool. A
deviating task's eroded zone holds fewer lattice nodes: the env acts on the largest lattice, and a copy's masks
allow only the nodes of its own task (:attr:`TaskMix.available`); its observation maps mark its own eroded zone.

Copies are assigned in blocks of ``B / T`` (B a multiple of the T tasks): copy ``i`` flies task ``i // (B / T)``.
``reset(seed=s)`` seeds task ``t``'s copies as a vector env of that task alone reset with ``seed=s + t``, so every
copy of a mix steps bit for bit as the same copy of its task's own env.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from covert_env.envs.arguments import copy_seeds
from covert_env.envs.settings import EnvSettings
from covert_env.world.config import Config
from covert_env.world.families import FAMILIES

__all__ = ["MIX_FIELDS", "TaskMix", "mix_settings"]

#: The config fields in which the tasks of one mix may differ: those a scene family sets (read only when a scene
#: is drawn) and the target model's.
MIX_FIELDS = frozenset(k for f in FAMILIES.values() for k in f.fields) | {"prediction_error", "r_u"}


@dataclass(frozen=True)
class TaskMix:
    """The tasks of a vector env's copies (module docstring).

    Attributes (T tasks, B copies, L nodes of the env's lattice, S * S map cells):
        names: the task names, in the order given.
        configs: each task's config (``Task.config`` on the env's ``config`` argument).
        copy_task: (B,) int, the task of each copy (blocks of B / T).
        available: (T, L) bool, the lattice nodes each task has (all of them for a nominal target).
        map_in_zone: (T, S * S) bool, the map cells in each task's (eroded) zone.
        start_lattices: each task's zone lattice at slot 0, the nodes its starts are drawn from.
    """

    names: tuple[str, ...]
    configs: tuple[Config, ...]
    copy_task: np.ndarray
    available: np.ndarray
    map_in_zone: np.ndarray
    start_lattices: tuple[np.ndarray, ...]

    def copy_seeds(self, seed) -> np.ndarray:
        """(B,) per-copy seeds for ``reset(seed=seed)`` with an int: task t's copies those of ``seed + t``."""
        b = len(self.copy_task)
        per = b // len(self.names)
        return np.concatenate([copy_seeds(seed + t, per) for t in range(len(self.names))])


def mix_settings(tasks, num_envs: int, kwargs: dict) -> tuple[EnvSettings, TaskMix]:
    """The settings of a vector env over ``tasks`` (the env's other keyword arguments ``kwargs``) and its
    :class:`TaskMix`. A ValueError names the first argument or task that does not fit."""
    names = [str(t) if isinstance(t, str) else t for t in tasks]          # numpy's str_ too
    if not names or not all(isinstance(t, str) for t in names) or len(set(names)) != len(names):
        raise ValueError(f"task must be a task name or a list of distinct task names, got {tasks!r}")
    if kwargs.get("dict_obs"):
        raise ValueError(f"task={names!r}: dict_obs=True is not supported with several tasks")
    if num_envs % len(names):
        raise ValueError(f"num_envs must be a multiple of the {len(names)} tasks (each gets as many copies), got "
                         f"{num_envs}")
    every = [EnvSettings(task=t, **kwargs) for t in names]         # each checks family= and n_uavs= against its task
    first = every[0].config
    for t, s in zip(names[1:], every[1:], strict=True):
        differ = {f: (getattr(first, f), v) for f, v in s.config.to_dict().items()
                  if f not in MIX_FIELDS and v != getattr(first, f)}
        if differ:
            raise ValueError(f"task {t!r} differs from {names[0]!r} in {sorted(differ)} ({differ}): the tasks of "
                             "one vector env share the team size and every config field but the scene family's, "
                             "prediction_error and r_u")
    # The largest lattice holds every other task's (an eroded zone's nodes are some of the nominal zone's).
    big = max(range(len(every)), key=lambda i: len(every[i].lattice))
    base = every[big]
    where = {tuple(p): i for i, p in enumerate(base.lattice.tolist())}
    available = np.zeros((len(names), len(base.lattice)), bool)
    for i, (t, s) in enumerate(zip(names, every, strict=True)):
        at = [where.get(tuple(p), -1) for p in s.lattice.tolist()]
        if min(at) < 0:
            raise ValueError(f"task {t!r}: its waypoint lattice is not part of {names[big]!r}'s, so the two cannot "
                             "share one action space")
        available[i, at] = True
        if (s.map_in_zone & ~base.map_in_zone).any():
            raise ValueError(f"task {t!r}: its map cells in the zone are not among {names[big]!r}'s")
    settings = copy.copy(base)
    settings.task, settings.family = tuple(names), None
    mix = TaskMix(tuple(names), tuple(s.config for s in every),
                  np.repeat(np.arange(len(names)), num_envs // len(names)), available,
                  np.stack([s.map_in_zone for s in every]), tuple(s.lattice for s in every))
    for a in (mix.copy_task, mix.available, mix.map_in_zone):
        a.setflags(write=False)
    return settings, mix
