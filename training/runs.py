"""The files of a training run read by the harness and the policy loaders: its JSON files (``args.json``, a model
card, a cache) and the env its settings build, each problem a :class:`~covert_env.command_line.UsageError` naming the
file and the field."""

from __future__ import annotations

from typing import Any

from covert_env.command_line import UsageError, read_run_json  # noqa: F401  (read_run_json: here for one more release)
from covert_env.envs.covert_sensing import CovertSensingParallelEnv

__all__ = ["run_env"]


def run_env(env_kwargs: Any, where: str, n_uavs: int = 1) -> tuple[dict, Any]:
    """The env settings (``n_uavs``, ``action_mode``, ``map_size``, ``target_path`` if set) of a run's
    ``env_kwargs`` (from ``where``, an ``args.json`` or model card; ``n_uavs`` defaults to ``n_uavs``) and the
    parallel env they build, in which the policy will act. A field the env rejects is a
    :class:`~covert_env.command_line.UsageError` naming the file, the field, the value and what is allowed (the
    env's own check)."""
    if not isinstance(env_kwargs, dict):
        raise UsageError(f"{where}: env_kwargs must be a JSON object, got {type(env_kwargs).__name__} "
                         f"{str(env_kwargs)[:60]}")
    settings = {"n_uavs": env_kwargs.get("n_uavs", n_uavs), "action_mode": env_kwargs.get("action_mode", "unicycle"),
                "map_size": env_kwargs.get("map_size", 8)}
    if env_kwargs.get("target_path", 0) != 0:          # 0 (or absent, in older cards) is the default observation
        settings["target_path"] = env_kwargs["target_path"]
    try:
        env = CovertSensingParallelEnv(**settings)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{where}: env_kwargs: {exc}") from None
    return settings, env
