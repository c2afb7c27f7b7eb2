"""The policies a spec can name, found through the entry point group ``covert_env.policies``.

A spec (:mod:`covert_env.evaluation.specs`) names a policy as ``NAME`` (a built-in policy: deterministic, built from
code) or ``PREFIX:ARGUMENT`` (a policy loaded from files, e.g. ``sb3:PATH``, ``pretrained:NAME``). Each NAME and
PREFIX is an entry point of the group, declared by the package that provides the policy in ``pyproject.toml``::

    [project.entry-points."covert_env.policies"]
    dp = "baselines.policies:builtin_policy"
    sb3 = "training.learned_policies:sb3_policy"

The entry point is a factory ``factory(spec, n_uavs, *, trust_checkpoint=False) -> (policy, settings)``. ``spec`` is
the policy's spec without ``@MODE`` and ``+shield`` (``sb3:runs/a``); ``settings`` are the env keywords the policy
acts with, at least ``n_uavs`` and ``action_mode``. A bad spec (a missing file, a policy that needs trust) raises
:class:`~covert_env.command_line.UsageError` naming it. A factory of ``PREFIX:ARGUMENT`` specs has an attribute
``argument``, the argument's name in messages (``"PATH"``, ``"NAME"``); a factory of a NAME has none.

The entry points are read from the installed metadata: after a change of ``pyproject.toml``, ``pip install -e .``
again.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable
from typing import Any

from covert_env.command_line import UsageError

__all__ = ["POLICY_GROUP", "PolicyFactory", "from_files", "policy_factory", "registered_policies", "spec_forms"]

POLICY_GROUP = "covert_env.policies"
"""The entry point group of the policy factories: spec NAME or PREFIX -> ``module:factory``."""

PolicyFactory = Callable[..., tuple[Any, dict]]
"""``factory(spec, n_uavs, *, trust_checkpoint=False) -> (policy, settings)``."""


def registered_policies() -> dict[str, importlib.metadata.EntryPoint]:
    """Spec NAME or PREFIX -> its factory's entry point (not loaded: nothing is imported)."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=POLICY_GROUP)}


def from_files(spec: str) -> bool:
    """Whether ``spec`` names a policy loaded from files (``PREFIX:ARGUMENT``): its weights may change behind the
    path (its results are never cached), it was trained in one action mode, and ``PREFIX:A1,A2`` is a seed group."""
    return ":" in spec


def spec_forms() -> list[str]:
    """The forms a spec can take: the registered names, sorted, then ``PREFIX:ARGUMENT`` for each prefix, sorted."""
    names, prefixed = [], []
    for name, ep in sorted(registered_policies().items()):
        argument = getattr(ep.load(), "argument", None)
        (names if argument is None else prefixed).append(name if argument is None else f"{name}:{argument}")
    return names + prefixed


def policy_factory(spec: str) -> PolicyFactory:
    """The factory of ``spec`` (without ``@MODE`` and ``+shield``): the entry point named by its NAME or PREFIX.

    An unknown spec raises :class:`~covert_env.command_line.UsageError` listing the registered forms."""
    key, colon, _ = spec.partition(":")
    entry = registered_policies().get(key)
    factory = entry.load() if entry is not None else None
    if factory is not None and bool(colon) == hasattr(factory, "argument"):
        return factory
    forms = spec_forms()
    if not forms:
        raise UsageError(f"unknown policy {spec!r}: no policy is registered (the entry point group {POLICY_GROUP} is "
                         "empty); reinstall covert_env (pip install -e .)")
    listed = forms[0] if len(forms) == 1 else f"{', '.join(forms[:-1])} or {forms[-1]}"
    raise UsageError(f"unknown policy {spec!r}; use one of {listed}")
