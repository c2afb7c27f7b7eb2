"""The files of a training run read by the harness and the policy loaders: its JSON files (``args.json``, a model
card, a cache) and the env its settings build, each problem a :class:`~covert_env.command_line.UsageError` naming the
file and the field."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from covert_env.command_line import UsageError, read_run_json
from covert_env.envs.covert_sensing import CovertSensingParallelEnv

__all__ = ["run_env", "weights_and_card"]


def weights_and_card(path: str | Path, what: str, producer: str) -> tuple[Path, Path, Any]:
    """The weights ``NAME.npz`` (or a run folder's ``model.npz``) at ``path``, its card beside it and the card read:
    ``(npz, card_path, card)``. A missing file is a ``ValueError`` naming ``what`` (e.g. "learned actor") and the
    ``producer`` whose run folders hold them; an unreadable card a :class:`~covert_env.command_line.UsageError`."""
    path = Path(path)
    npz = path / "model.npz" if path.is_dir() else path
    card_path = npz.with_suffix(".json")
    if not npz.is_file() or not card_path.is_file():
        raise ValueError(f"no {what} at {path} (expected NAME.npz with NAME.json beside it, or a {producer} run "
                         "folder holding model.npz and model.json)")
    return npz, card_path, read_run_json(card_path, "model card")


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
