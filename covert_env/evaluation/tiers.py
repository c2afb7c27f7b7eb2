"""The leaderboards' tiers: what a team reads to act (``covert-env list``, ``evaluate``'s and ``benchmark``'s
tables).

A policy's tier is declared by the package that provides it, on its factory in the entry point group
``covert_env.policies`` (:mod:`covert_env.evaluation.registry`): an attribute ``tier``, a key of :data:`TIERS` or
a function of the spec (a learned card's tier depends on the card).
"""

from __future__ import annotations

from covert_env.command_line import UsageError
from covert_env.evaluation.registry import policy_factory

__all__ = ["TIERS", "spec_tier"]

#: The leaderboard's tiers, by what a team reads to act.
TIERS = {"planner": "planner (reads the terrain and the target's predicted route)",
         "hybrid": "hybrid (a planner with a learned cost)",
         "learned": "learned from observations",
         "reference": "reference (random, heuristic)"}


def spec_tier(spec: str) -> str:
    """The tier (a key of :data:`TIERS`) of a policy spec of ``covert-env evaluate``: what its factory declares
    (``@MODE`` and ``+shield`` keep the tier). A spec no installed package provides (a results file from elsewhere)
    is ``reference``."""
    base = spec.removesuffix("+shield").split("@")[0]
    try:
        tier = getattr(policy_factory(base), "tier", "reference")
    except UsageError:
        return "reference"
    tier = tier(base) if callable(tier) else tier
    if tier not in TIERS:
        raise ValueError(f"the policy factory of {base!r} declares tier {tier!r}; a tier is one of {list(TIERS)}")
    return tier
