"""``covert-env list``: what can be named on the command line. The tasks, scene families, policies and shipped
weights, from the registries that the commands themselves read.

    covert-env list                     # everything
    covert-env list tasks               # or: families, policies, weights
"""

from __future__ import annotations

import argparse
import os
import sys

from covert_env.evaluation.tiers import TIERS
from covert_env.world.families import FAMILIES
from covert_env.world.tasks import DEFAULT_TASKS, SUITE_VERSION, TASKS

__all__ = ["build_parser", "main", "tier_of", "weights_table"]

SECTIONS = ("tasks", "families", "policies", "weights")


def tier_of(card: dict) -> str:
    """A shipped card's tier (:data:`~covert_env.evaluation.tiers.TIERS`): ``hybrid`` for a planner with a learned
    cost, ``learned`` for an actor that acts from observations."""
    from baselines.learned_cost import KIND

    return "hybrid" if card.get("kind") == KIND else "learned"


def _tasks() -> list[str]:
    lines = [f"Tasks ({SUITE_VERSION}; --task NAME, covert-env benchmark --tasks NAME ... | core | all; * = core):"]
    for t in TASKS.values():
        lines.append(f"  {'*' if t.name in DEFAULT_TASKS else ' '} {t.name:<26} family {t.family:<9} "
                     f"{t.n_uavs} UAV{'s' if t.n_uavs > 1 else ' '}  target {t.target}")
    return lines


def _families() -> list[str]:
    return ["Scene families (--family NAME):", *(f"  {f.name:<9} {f.description}" for f in FAMILIES.values())]


def _policies() -> list[str]:
    from baselines.policies import ALIASES, POLICIES

    alias = {v: k for k, v in ALIASES.items()}
    names = [f"{n} (or {alias[n]})" if n in alias else n for n in POLICIES]
    return ["Policies (covert-env evaluate / benchmark --policies SPEC, optionally SPEC@unicycle or SPEC@waypoint):",
            f"  built in: {', '.join(names)}",
            "  from files: pretrained:NAME (below), mappo:PATH, sb3:PATH and rllib:PATH (these two hold pickles: "
            "--trust-checkpoint)",
            "  SPEC+shield: a waypoint team flown through the safety filter, which keeps eqs. 2 and 3 on the flown "
            "path (e.g. random@waypoint+shield, dp-path+shield)"]


def _weights() -> list[str]:
    from covert_env.command_line import read_run_json
    from training.pretrained import PRETRAINED_DIR, pretrained_names

    lines = ["Shipped weights (pretrained:NAME; cards in training/pretrained/NAME.json; reward IQM [95 % interval] on "
             "the held-out paper scenes):",
             *(f"  tier {k}: {v}" for k, v in TIERS.items() if k in ("hybrid", "learned"))]
    for name in pretrained_names():
        card = read_run_json(PRETRAINED_DIR / f"{name}.json", "model card")
        s = card.get("scores", {})
        lo, hi = s.get("reward_iqm_ci95_over_scenes", (float("nan"),) * 2)
        lines.append(f"  {name:<26} {tier_of(card):<8} {card.get('algorithm', '?'):<6} {card.get('env_id', '?'):<26} "
                     f"{s.get('reward_iqm', float('nan')):6.1f} [{lo:.1f}, {hi:.1f}]")
    return lines


def weights_table() -> str:
    """The shipped weights as a markdown table (the documentation's cards page): tier, algorithm, the env and
    version a card's scores were measured on, the team size, the training budget and the reward on the held-out
    paper scenes."""
    from covert_env.command_line import read_run_json
    from training.pretrained import PRETRAINED_DIR, pretrained_names

    lines = ["| `pretrained:NAME` | tier | algorithm | scored on | UAVs | trained | reward IQM [95 % CI], held-out "
             "paper scenes |", "|---|---|---|---|---|---|---|"]
    for name in pretrained_names():
        card = read_run_json(PRETRAINED_DIR / f"{name}.json", "model card")
        s, t = card.get("scores", {}), card.get("training", {})
        lo, hi = s.get("reward_iqm_ci95_over_scenes", (float("nan"),) * 2)
        minutes = t.get("train_minutes", t.get("wall_time_minutes"))
        budget = ", ".join(([f"{t['env_steps']:,} env-steps"] if "env_steps" in t else [])
                           + ([f"{minutes:.0f} min"] if minutes is not None else [])) or "-"
        team = card.get("recipe", {}).get("n_uavs", "any")
        lines.append(f"| `{name}` | {tier_of(card)} | {card.get('algorithm', '?')} | {card.get('env_id', '?')}, "
                     f"covert_env {card.get('covert_env_version', '?')} | {team} | "
                     f"{budget} | {s.get('reward_iqm', float('nan')):.1f} [{lo:.1f}, {hi:.1f}] |")
    return "\n".join(lines)


def build_parser(prog: str = "python -m training.catalogue") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="List the tasks, scene families, policies and shipped weights "
                                "that the commands accept.")
    p.add_argument("what", nargs="*", metavar="SECTION", help=f"only these sections: {', '.join(SECTIONS)} "
                   "(default: all)")
    return p


def main(argv: list[str] | None = None, prog: str = "python -m training.catalogue") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    for w in args.what:
        if w not in SECTIONS:
            parser.error(f"unknown section {w!r}; use any of {', '.join(SECTIONS)}")
    show = [s for s in SECTIONS if not args.what or s in args.what]
    parts = {"tasks": _tasks, "families": _families, "policies": _policies, "weights": _weights}
    try:
        print("\n\n".join("\n".join(parts[s]()) for s in show), flush=True)
    except BrokenPipeError:             # covert-env list | head: the reader left; say nothing more
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
