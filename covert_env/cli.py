"""The ``covert-env`` command line.

    covert-env reproduce --out outputs/reproduce            # the paper's experiments with the DP planner
    covert-env evaluate --help                               # score policies on held-out scenes
    covert-env scene --seed 3 --slot 10 --out scene.png     # a picture of one slot (3D + top view)
    covert-env scene --paper --slot 0 --out paper.png        # the paper scenario

``reproduce`` and ``evaluate`` live in ``baselines`` and ``training`` (imported only when called).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main"]


def _scene(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    from covert_env.config import Config
    from covert_env.render import scene_figure
    from covert_env.scenario import Scenario

    config = Config.from_json(args.config) if args.config else Config()
    scenario = Scenario.paper(config) if args.paper else Scenario.random(args.seed, config)
    if not 0 <= args.slot <= config.n_slots:
        raise SystemExit(f"covert-env scene: --slot must be in [0, {config.n_slots}], got {args.slot}")
    uav_xy = scenario.uav_xy if args.slot == 0 else None
    fig = scene_figure(scenario, args.slot, uav_xy=uav_xy)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=args.dpi)
    import matplotlib.pyplot as plt

    plt.close(fig)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB): {scenario.name}, slot {args.slot}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="covert-env", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    # Listed for --help; main() forwards their arguments to baselines.reproduce / training.evaluate.
    sub.add_parser("reproduce", help="run the paper's experiments (DP shadow-aware vs shadow-blind), "
                                     "write figures and metrics (see: covert-env reproduce --help)")
    sub.add_parser("evaluate", help="score policies on held-out scenes and write a leaderboard "
                                    "(see: covert-env evaluate --help)")
    p = sub.add_parser("scene", help="draw terrain, road, target, zone, shadows and visible zone at one slot")
    p.add_argument("--seed", type=int, default=0, help="scene seed (terrain + road); ignored with --paper")
    p.add_argument("--paper", action="store_true", help="draw the paper scenario instead of a random one")
    p.add_argument("--slot", type=int, default=0, help="slot k to draw")
    p.add_argument("--out", default="outputs/scene.png", help="PNG file to write")
    p.add_argument("--config", default=None, help="a Config JSON file (default: the paper's parameters)")
    p.add_argument("--dpi", type=int, default=110)
    p.set_defaults(func=_scene)
    return parser


_FORWARDED = {"reproduce": "baselines.reproduce", "evaluate": "training.evaluate"}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in _FORWARDED:
        # Forward everything (including --help) to the subcommand's own parser.
        import importlib

        return importlib.import_module(_FORWARDED[argv[0]]).main(argv[1:]) or 0
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
