"""The planner with a learned cost: the paper's DP whose stage cost also charges LoS lost along each manoeuvre.

The paper's planner (:mod:`baselines.dp`) checks line of sight at slot times only; the env's reward also charges
the share of the flown path without it (``reward_los_path``). :mod:`training.dp_cost` learns, from episodes on the
training scenes, how much the planner's search should charge for that share at each stage of its horizon
(``path_cost``, :class:`~baselines.dp.DPPlanner`), with the cross-entropy method. The team is the paper's
decentralised DP in every other respect: the same negotiation and safety layer, so it keeps the same constraints,
and the same nodes, the visible zone's, unless the card says ``shadow_aware: false``: then it plans over every zone
node clear of the tops, shadowed or not (the kinematic mask's), and only the learned cost keeps it out of the
shadows (docs/decisions/planner.md#a-learned-cost-in-the-planners-search).

Files (no pickle: ``np.load(..., allow_pickle=False)`` and JSON):

* ``NAME.npz``: ``path_cost``, (N,) float, m of stage cost per unit of blocked path share, stage 1 first;
* ``NAME.json``: the card: ``kind`` = ``"dp-cost"``, ``planner`` (``heading``; ``separated_continuation``, the
  team's look-ahead, and ``best_effort_escape``, the safety layer's escape, both off where absent;
  ``shadow_aware``, true where absent: false plans over the kinematic mask's nodes, shadowed ones too, and flies in
  envs with ``mask_mode="kinematic"``), the learned parameters, how they were learned, and for shipped files the
  scores.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from baselines.policies import DPPolicy
from covert_env.command_line import read_run_json
from covert_env.evaluation.cards import check_env_kwargs, weights_and_card
from covert_env.world.config import Config

__all__ = ["KIND", "is_cost_planner_card", "load_cost_planner", "path_cost_of"]

KIND = "dp-cost"
"""The ``kind`` field of a learned-cost planner's card (MAPPO cards have none)."""
#: Largest weights file read (bytes unpacked): the file holds config.horizon numbers.
MAX_BYTES = 1 << 16
#: The fields of a card's ``planner``.
PLANNER_FIELDS = ("heading", "separated_continuation", "best_effort_escape", "shadow_aware")


def path_cost_of(scale: float, decay: float, horizon: int) -> np.ndarray:
    """The learned parametrisation: ``path_cost[j] = 100 * scale * decay ** j`` (m), j = 0 .. horizon - 1.

    100 m of stage cost is what the env's default reward charges for a slot flown entirely without LoS
    (``los_path_penalty * reward_scale``), so ``scale = 1, decay = 1`` charges in the planner what the reward
    charges; ``decay < 1`` trusts the prediction's later stages less.
    """
    return 100.0 * float(scale) * float(decay) ** np.arange(horizon)


def is_cost_planner_card(npz: Path) -> bool:
    """Whether the card beside ``npz`` (``NAME.json``, or ``model.json`` in a run folder) is a learned-cost
    planner's."""
    npz = Path(npz)
    card = (npz / "model.json") if npz.is_dir() else npz.with_suffix(".json")
    if not card.is_file():
        return False
    data = read_run_json(card, "model card")
    return isinstance(data, dict) and data.get("kind") == KIND


def load_cost_planner(path: str | Path) -> DPPolicy:
    """The :class:`~baselines.policies.DPPolicy` of a learned-cost planner's weights (``NAME.npz`` with its card, or
    a :mod:`training.dp_cost` run folder). ``env_settings`` gives the env it acts in (waypoint mode). Raises
    ``ValueError`` naming the file and the field on anything malformed."""
    path = Path(path)
    npz, card_path, card = weights_and_card(path, "learned-cost planner", "training.dp_cost")
    if not isinstance(card, dict) or card.get("kind") != KIND:
        raise ValueError(f"{card_path}: not the card of a learned-cost planner (kind must be {KIND!r})")
    planner = card.get("planner", {})
    unknown = sorted(set(planner) - set(PLANNER_FIELDS)) if isinstance(planner, dict) else ["(not an object)"]
    if unknown:
        raise ValueError(f"{card_path}: planner has unknown fields {unknown}; a planner's fields are "
                         f"{list(PLANNER_FIELDS)}")
    heading = planner.get("heading")
    if heading not in ("inherited", "binned"):
        raise ValueError(f"{card_path}: planner.heading must be 'inherited' or 'binned', got {heading!r}")
    # Cards written before the look-ahead or the escape existed fly without them, as they were scored.
    flags = {name: planner.get(name, False) for name in ("separated_continuation", "best_effort_escape")}
    flags["shadow_aware"] = planner.get("shadow_aware", True)       # cards before the kinematic-mask planner
    for name, flag in flags.items():
        if not isinstance(flag, bool):
            raise ValueError(f"{card_path}: planner.{name} must be true or false, got {flag!r}")
    mask = "visible" if flags["shadow_aware"] else "kinematic"
    env_kwargs = card.get("env_kwargs", {"action_mode": "waypoint"})
    check_env_kwargs(env_kwargs, ("action_mode", "mask_mode"), card_path)
    if env_kwargs.get("action_mode", "waypoint") != "waypoint":
        raise ValueError(f"{card_path}: env_kwargs.action_mode must be 'waypoint' (the planner flies waypoints), got "
                         f"{env_kwargs['action_mode']!r}")
    stated = env_kwargs.get("mask_mode", mask)
    if stated != mask:
        raise ValueError(f"{card_path}: env_kwargs.mask_mode {stated!r} contradicts planner.shadow_aware "
                         f"{flags['shadow_aware']} (a shadow-aware planner flies with the 'visible' mask, a blind one "
                         "with 'kinematic')")
    try:
        with zipfile.ZipFile(npz) as z:
            unpacked = sum(info.file_size for info in z.infolist())
        if unpacked > MAX_BYTES:
            raise ValueError(f"{unpacked} bytes of arrays, more than the {MAX_BYTES} this file may hold")
        with np.load(npz, allow_pickle=False) as data:
            raw = data["path_cost"]
        if raw.dtype.kind not in "fiu":
            raise ValueError(f"path_cost must hold numbers, got dtype {raw.dtype}")
        w = raw.astype(float)
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{npz}: not a learned-cost planner's weights ({exc})") from None
    horizon = Config().horizon
    if w.ndim != 1 or len(w) != horizon or not np.all(np.isfinite(w)) or np.any(w < 0) or np.any(w > 1e6):
        raise ValueError(f"{npz}: path_cost must be {horizon} numbers in [0, 1e6], one per stage of the planner's "
                         f"horizon (config.horizon = {horizon}), got {w.tolist()!r}")
    stated_cost = card.get("path_cost")
    if stated_cost is not None and (not isinstance(stated_cost, list) or len(stated_cost) != len(w)
                                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                               for x in stated_cost)
                                    or not np.allclose(stated_cost, w, rtol=1e-12, atol=0.0)):
        raise ValueError(f"{card_path}: path_cost {stated_cost!r} is not the weights' {w.tolist()!r} ({npz})")
    pol = DPPolicy(heading=heading, path_cost=w, **flags)
    pol.name = f"learned-cost({npz.stem if npz.stem != 'model' else npz.parent.name})"
    pol.env_settings = {"action_mode": "waypoint", "mask_mode": mask}
    pol.card = card
    return pol
