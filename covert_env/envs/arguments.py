"""Checks of the envs' arguments at the boundary: a clear error naming the argument, the value and the allowed range."""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping

import gymnasium
import numpy as np

__all__ = ["CONSTRUCTION_SETTINGS", "ConstructionSetting", "ConstructionSettings", "bool_arg", "int_arg", "number_arg",
           "reset_options"]

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
    """Base of the envs: :data:`CONSTRUCTION_SETTINGS` as :class:`ConstructionSetting` attributes."""

    config = ConstructionSetting()
    action_mode = ConstructionSetting()
    mask_mode = ConstructionSetting()
    task = ConstructionSetting()
    family = ConstructionSetting()
    map_size = ConstructionSetting()
    target_path = ConstructionSetting()
    dict_obs = ConstructionSetting()
    scenario_spec = ConstructionSetting()
    scene_pool = ConstructionSetting()
    path_samples = ConstructionSetting()
    random_starts = ConstructionSetting()


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
