"""Model cards: weights ``NAME.npz`` with the JSON card ``NAME.json`` beside them (or a run folder's ``model.npz``
and ``model.json``), and a card's ``env_kwargs`` checked by the env's own settings.

The loaders of weights from files (the learned actors of :mod:`training.pretrained`, the planner with a learned
cost of :mod:`baselines.learned_cost`) read their files through these, so every card problem is reported the same
way: the file, the field, the value.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from covert_env.command_line import read_run_json
from covert_env.envs.settings import EnvSettings

__all__ = ["check_env_kwargs", "weights_and_card"]


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


def check_env_kwargs(ekw, allowed: tuple[str, ...], card_path) -> None:
    """A card's ``env_kwargs``: only ``allowed`` fields, each valid for the env (its own checks, types included: no
    string is read as a number). A ``ValueError`` names the card, the field and the value."""
    if not isinstance(ekw, dict):
        raise ValueError(f"{card_path}: env_kwargs must be a JSON object, got {type(ekw).__name__}")
    unknown = sorted(set(ekw) - set(allowed))
    if unknown:
        raise ValueError(f"{card_path}: env_kwargs has unknown fields {unknown}; a card's env_kwargs are "
                         f"{list(allowed)}")
    try:
        EnvSettings(**ekw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{card_path}: env_kwargs: {exc}") from None
