"""Policy specs: how ``covert-env evaluate`` and ``covert-env benchmark`` name a policy, ``SPEC[@MODE][+shield]``.

* ``SPEC`` is ``NAME`` (a built-in policy, ``dp``, ``random`` ...) or ``PREFIX:ARGUMENT`` (a policy loaded from
  files, ``sb3:PATH``, ``pretrained:NAME`` ...), resolved through :mod:`covert_env.evaluation.registry`.
* ``@MODE`` (``unicycle`` or ``waypoint``) picks the env's action mode; a policy from files acts only in the mode
  it was trained in.
* ``+shield`` flies a waypoint policy through the safety filter (:mod:`covert_env.envs.safety_filter`).
* ``PREFIX:A1,A2,...[@MODE][+shield]`` is a seed group: one run per training seed, reported as one row.
"""

from __future__ import annotations

from typing import Any

from covert_env.command_line import UsageError
from covert_env.envs.safety_filter import ShieldedPolicy
from covert_env.evaluation.registry import from_files, policy_factory

__all__ = ["ACTION_MODES", "SHIELD_SUFFIX", "load_policy", "split_seeds"]

SHIELD_SUFFIX = "+shield"
"""The spec suffix that flies a waypoint policy through the safety filter."""
ACTION_MODES = ("unicycle", "waypoint")
"""The ``@MODE`` a spec may end in (before ``+shield``)."""


def load_policy(spec: str, n_uavs: int, *, trust_checkpoint: bool = False) -> tuple[Any, dict]:
    """A policy object and its env settings (``n_uavs``, ``action_mode``, ...) from a spec.

    A bad spec (unknown name or mode, missing path, team size or action mode that do not fit) raises
    :class:`covert_env.command_line.UsageError` (a ``ValueError``) naming it, and so do specs of pickled
    checkpoints unless ``trust_checkpoint=True``. A spec ending in ``+shield`` flies the policy through the safety
    filter (:class:`covert_env.envs.safety_filter.ShieldedPolicy`; waypoint teams only).
    """
    if spec.endswith(SHIELD_SUFFIX):
        inner = spec[:-len(SHIELD_SUFFIX)]
        pol, settings = load_policy(inner, n_uavs, trust_checkpoint=trust_checkpoint)
        if settings["action_mode"] != "waypoint":
            raise UsageError(f"{spec}: the safety filter is for waypoint teams, and {inner} acts in "
                             f"{settings['action_mode']} mode (use {inner.split('@')[0]}@waypoint{SHIELD_SUFFIX})")
        return (pol if isinstance(pol, ShieldedPolicy) else ShieldedPolicy(pol)), settings
    mode = None
    if "@" in spec:
        spec, mode = spec.rsplit("@", 1)
        if mode not in ACTION_MODES:
            raise UsageError(f"unknown action mode {mode!r} in policy spec {spec}@{mode} (use @unicycle or @waypoint)")
    pol, settings = policy_factory(spec)(spec, n_uavs, trust_checkpoint=trust_checkpoint)
    settings = dict(settings)
    if mode is not None:
        if from_files(spec) and mode != settings["action_mode"]:
            raise UsageError(f"{spec} was trained in {settings['action_mode']} mode; it cannot act in {mode} mode")
        settings["action_mode"] = mode
    if settings["n_uavs"] != n_uavs:
        raise UsageError(f"{spec} acts for teams of {settings['n_uavs']} UAV(s) but --n-uavs is {n_uavs}; "
                         f"pass --n-uavs {settings['n_uavs']}")
    return pol, settings


def split_seeds(spec: str) -> list[str]:
    """The member specs of a seed group ``PREFIX:A1,A2[@MODE][+shield]`` (a one-element list for any other
    spec)."""
    if not from_files(spec) or "," not in spec:
        return [spec]
    shield = SHIELD_SUFFIX if spec.endswith(SHIELD_SUFFIX) else ""
    prefix, rest = spec[:len(spec) - len(shield)].split(":", 1)
    mode = ""
    if "@" in rest:
        rest, mode = rest.rsplit("@", 1)
        mode = "@" + mode
    return [f"{prefix}:{part}{mode}{shield}" for part in rest.split(",") if part]
