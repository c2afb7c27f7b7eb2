"""Checks of the envs' arguments at the boundary: a clear error naming the argument, the value and the allowed range."""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping

import gymnasium
import numpy as np

from covert_env.world.config import Config, short_repr

__all__ = ["CONSTRUCTION_SETTINGS", "MAX_SCENE_SEED", "ConstructionSetting", "ConstructionSettings", "bool_arg",
           "copy_seeds", "int_arg", "number_arg", "reset_options", "scene_seeds", "vector_reset_options"]

#: Largest scene seed: scenes are keyed by int64 in the scene pool.
MAX_SCENE_SEED = 2**63 - 1
#: The envs' settings that shape the spaces, the scenes or the dynamics: fixed when an env is made.
CONSTRUCTION_SETTINGS = ("config", "action_mode", "mask_mode", "task", "family", "map_size", "target_path", "dict_obs",
                         "scenario_spec", "scene_pool", "path_samples", "random_starts")


class ConstructionSetting:
    """An attribute set once, while the env is made, and read-only after: assigning ``env.task = ...`` later would
    change nothing the env has built (its scenes, spaces and lattice), so it raises an ``AttributeError`` that says
    to make a new env instead. (``max_cycles``, ``reward_scale``, ``penalties`` and ``terminate_on_collision`` are
    live settings: they may be assigned.)"""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        try:
            return obj.__dict__["_construction"][self.name]
        except KeyError:
            raise AttributeError(f"{type(obj).__name__} has no {self.name} yet (it is set while the env is made)") \
                from None

    def __set__(self, obj, value) -> None:
        fixed = obj.__dict__.setdefault("_construction", {})
        if self.name in fixed:
            raise AttributeError(f"{type(obj).__name__}.{self.name} is a construction setting, fixed when the env was "
                                 f"made ({self.name}={fixed[self.name]!r}); make a new env with {self.name}={value!r}")
        fixed[self.name] = value


class Forwarded:
    """An attribute that lives on another object the env holds (``via``, e.g. ``"_vec"``): reading it reads there and
    assigning it assigns there, where it is validated. The views of the vector env (the parallel env of its one copy,
    the Gymnasium env of one UAV, a copy read as an engine) show its live settings this way. ``writable=False``
    makes it read-only (assigning raises an ``AttributeError``, as a property without a setter does). Declare it
    with its type and a docstring below it, as a dataclass field, so the API reference shows both::

        max_cycles: int = Forwarded("_vec")
        '''Episode length bound in slots.'''
    """

    def __init__(self, via: str, writable: bool = True):
        self.via, self.writable = via, writable

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return getattr(getattr(obj, self.via), self.name)

    def __set__(self, obj, value) -> None:
        if not self.writable:
            raise AttributeError(f"{type(obj).__name__}.{self.name} is read-only")
        setattr(getattr(obj, self.via), self.name, value)


class ConstructionSettings:
    """Base of the envs: :data:`CONSTRUCTION_SETTINGS` as :class:`ConstructionSetting` attributes, read-only once the
    env is made (the parallel env's Arguments describe each)."""

    config: Config = ConstructionSetting()
    """The model's parameters (:class:`~covert_env.world.config.Config`), with a task's or family's fields set on it."""
    action_mode: str = ConstructionSetting()
    """``"unicycle"`` (controls v, omega) or ``"waypoint"`` (a lattice node per UAV and slot)."""
    mask_mode: str = ConstructionSetting()
    """``"visible"`` or ``"kinematic"``: what the waypoint action mask allows."""
    task: str | None = ConstructionSetting()
    """The suite task the env was made for (``covert_env.world.tasks``), or None."""
    family: str | None = ConstructionSetting()
    """The scene family random scenes are drawn from (``covert_env.world.families``), or None (the config's)."""
    map_size: int = ConstructionSetting()
    """Side S of the observation's maps (cells)."""
    target_path: int = ConstructionSetting()
    """Predicted slots of the target's path in the observation (0: none)."""
    dict_obs: bool = ConstructionSetting()
    """Whether observations are dicts with the action mask (waypoint mode)."""
    scenario_spec: object = ConstructionSetting()
    """What the scenes are: ``"random"``, ``"paper"`` or a :class:`~covert_env.world.scenario.Scenario`."""
    scene_pool: int = ConstructionSetting()
    """Training scene seeds are drawn from ``range(scene_pool)``."""
    path_samples: int = ConstructionSetting()
    """Samples per slot along each path (endpoints included), for LoS and separation between slot times."""
    random_starts: bool = ConstructionSetting()
    """Whether starts are drawn at every reset on a fixed scenario (else the scenario's own)."""


def int_arg(name: str, value, low: int, high: int | None = None) -> int:
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


def number_arg(name: str, value) -> float:
    """``value`` as a finite float; bools and strings are rejected."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return float(value)


def bool_arg(name: str, value) -> bool:
    """``value`` as a bool; only True/False (and numpy bools) are accepted, not 0/1 or strings."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def reset_options(options, known: tuple[str, ...]) -> dict:
    """``reset(options=...)`` as a dict: None gives ``{}``, anything but a mapping is a TypeError. Keys other than
    ``known`` are warned about and ignored, by every env kind alike: PettingZoo's API test passes
    ``options={"options": 1}`` to every env, so they cannot be an error."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise TypeError(f"reset(options=...) must be a dict or None, got {type(options).__name__}")
    unknown = sorted(set(options) - set(known), key=str)
    if unknown:
        gymnasium.logger.warn(f"reset(options=...): ignoring unknown option(s) {unknown}; known: {list(known)}")
    return dict(options)


def copy_seeds(seed, b: int) -> np.ndarray:
    """Per-copy seeds: from ``np.random.SeedSequence(seed)`` for an int, as given for a sequence of b ints (any
    size, as Gymnasium's seeding takes them: an int64 array, or an object array of Python ints beyond 2**63 - 1)."""
    if np.ndim(seed) == 0:
        return np.random.SeedSequence(int_arg("seed", seed, 0)).generate_state(b).astype(np.int64)
    seeds = [int_arg("seed", s, 0) for s in seed]
    if len(seeds) != b:
        raise ValueError(f"reset(seed=...) needs an int or {b} ints (one per copy), got {len(seeds)}")
    return np.array(seeds, dtype=np.int64 if max(seeds, default=0) < 2 ** 63 else object)


def vector_reset_options(options: dict | None, b: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``options["scene_seed"]`` as b ints and ``options["reset_mask"]`` as b bools (None without them); other
    keys are warned about and ignored (:func:`~covert_env.envs.arguments.reset_options`)."""
    options = reset_options(options, ("scene_seed", "reset_mask"))
    mask = options.get("reset_mask")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (b,) or mask.dtype != np.bool_:
            raise ValueError(f"options['reset_mask'] must be {b} bools (one per copy), got {options['reset_mask']!r}")
    return scene_seeds(options.get("scene_seed"), b), mask


def scene_seeds(seeds, b: int) -> np.ndarray | None:
    """``options["scene_seed"]`` as b ints in [0, MAX_SCENE_SEED] (None without it)."""
    if seeds is None:
        return None
    arr = np.broadcast_to(np.asarray(seeds), (b,)) if np.ndim(seeds) == 0 else np.asarray(seeds)
    if arr.shape != (b,) or arr.dtype.kind not in "iu" or (arr < 0).any() or (arr > MAX_SCENE_SEED).any():
        raise ValueError(f"options['scene_seed'] must be an integer in [0, {MAX_SCENE_SEED}] (2**63 - 1) or {b} of "
                         f"them (one per copy), got {short_repr(seeds)}")
    return arr
