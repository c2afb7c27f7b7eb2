"""The leaderboards' tiers: what a team reads to act (``covert-env list``, ``evaluate``'s and ``benchmark``'s
tables)."""

from __future__ import annotations

from pathlib import Path

from training.pretrained import PRETRAINED_DIR
from training.pretrained.learned_cost import KIND, is_cost_planner_card

__all__ = ["TIERS", "spec_tier", "tier_of"]

#: The leaderboard's tiers, by what a team reads to act.
TIERS = {"planner": "planner (reads the terrain and the target's predicted route)",
         "hybrid": "hybrid (a planner with a learned cost)",
         "learned": "learned from observations",
         "reference": "reference (random, heuristic)"}


def tier_of(card: dict) -> str:
    """A shipped card's tier: ``hybrid`` for a planner with a learned cost, ``learned`` for an actor that acts from
    observations."""
    return "hybrid" if card.get("kind") == KIND else "learned"


def spec_tier(spec: str) -> str:
    """The tier (a key of :data:`TIERS`) of a policy spec of ``covert-env evaluate``: ``planner`` for the ``dp*``
    planners, ``hybrid`` or ``learned`` for weights by their card (a seed group by its first run), ``learned`` for
    ``sb3:`` and ``rllib:`` checkpoints, ``reference`` for the rest. ``@MODE`` and ``+shield`` keep the tier."""
    base = spec.removesuffix("+shield").split("@")[0]
    if base.startswith("pretrained:"):
        path = PRETRAINED_DIR / f"{base[len('pretrained:'):].split(',')[0]}.npz"
    elif base.startswith("mappo:"):
        path = Path(base[len("mappo:"):].split(",")[0])
    elif base.startswith(("sb3:", "rllib:")):
        return "learned"
    else:
        return "planner" if base.startswith("dp") else "reference"
    return "hybrid" if is_cost_planner_card(path) else "learned"
