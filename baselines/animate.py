"""``covert-env animate``: the DP team planner flown on the paper scene, written as an animated GIF.

    covert-env animate                                       # outputs/dp_team.gif
    covert-env animate --out docs/dp_team.gif                # the README's animation

The frames are drawn by :func:`baselines.reproduce.write_gif` (top view following the target: zone, shadows,
visible zone, lines of sight). Bad arguments exit with status 2 and one error line.
"""

from __future__ import annotations

import argparse
import sys

from covert_env.command_line import (
    MAX_DPI,
    UsageError,
    int_range,
    load_config,
    output_file,
    positive_int,
    run_main,
)
from covert_env.world.config import Config

__all__ = ["build_parser", "main"]


def build_parser(prog: str = "covert-env animate") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="Fly the DP team planner on the paper scene and write an "
                                "animated GIF (top view following the target: zone, shadows, visible zone, lines of "
                                "sight).")
    p.add_argument("--out", default="outputs/dp_team.gif",
                   help="GIF file to write (its folder is created); the README's is docs/dp_team.gif "
                        "(default: outputs/dp_team.gif)")
    p.add_argument("--uavs", type=int_range(1, 3), default=3, help="team size, in [1, 3] (default: 3)")
    p.add_argument("--method", choices=("aware", "blind"), default="aware",
                   help="aware: the paper's shadow-aware planner; blind: the earlier one (default: aware)")
    p.add_argument("--slots", type=positive_int, default=None,
                   help="slots to fly, in [1, n_slots] (default: n_slots of the config, 70 with the paper's "
                        "parameters)")
    p.add_argument("--frames-per-slot", type=int_range(1, 10), default=2,
                   help="frames per slot, in [1, 10] (default: 2)")
    p.add_argument("--size", type=int_range(100, 2000), default=420,
                   help="frame width and height in pixels, in [100, 2000] (default: 420)")
    p.add_argument("--dpi", type=int_range(10, MAX_DPI), default=70, help=f"resolution, in [10, {MAX_DPI}] "
                   "(default: 70)")
    p.add_argument("--fps", type=int_range(1, 50), default=6, help="frames per second, in [1, 50] (default: 6)")
    p.add_argument("--config", default=None, help="a Config JSON file (default: the paper's parameters)")
    return p


def animate(args: argparse.Namespace) -> int:
    """Check ``args`` against the config, fly the team and write the GIF; print what was written."""
    config = load_config(args.config) if args.config is not None else Config()
    n_slots = config.n_slots if args.slots is None else args.slots
    if n_slots > config.n_slots:
        of = " (n_slots of --config)" if args.config is not None else ""
        raise UsageError(f"--slots must be in [1, {config.n_slots}]{of}, got {n_slots}")
    out = output_file(args.out, suffixes=("gif",))

    import matplotlib

    matplotlib.use("Agg")
    from baselines.reproduce import write_gif

    info = write_gif(out, n_uavs=args.uavs, method=args.method, n_slots=n_slots,
                     frames_per_slot=args.frames_per_slot, size=args.size, dpi=args.dpi, fps=args.fps, config=config)
    print(f"wrote {out} ({info['bytes'] / 1024:.0f} KiB, {info['frames']} frames, {info['slots']} slots)")
    return 0


def main(argv: list[str] | None = None, prog: str = "covert-env animate") -> int:
    """The command line (``prog``: the name in usage and error lines)."""
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    return run_main(parser, lambda: animate(args))


if __name__ == "__main__":
    sys.exit(main())
