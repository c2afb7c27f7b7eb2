"""The ``covert-env`` command line.

    covert-env reproduce --out outputs/reproduce            # the paper's experiments with the DP planner
    covert-env evaluate --help                               # score policies on held-out scenes
    covert-env benchmark --help                              # the task suite's protocol
    covert-env scene --seed 3 --slot 10 --out scene.png     # a picture of one slot (3D + top view)
    covert-env scene --paper --slot 0 --out paper.png        # the paper scenario
    covert-env animate                                       # the DP team flying: outputs/dp_team.gif
    covert-env animate --out docs/dp_team.gif                # regenerate the README's animation
    covert-env scene-set --family downtown --scenes 20 --out downtown20.json   # scenes as data, to share
    covert-env list                                          # the tasks, families, policies and shipped weights

``scene`` and ``scene-set`` are this module's; ``evaluate`` and ``benchmark`` are :mod:`covert_env.evaluation`'s.
``reproduce``, ``animate`` and ``list`` are provided by the packages above covert_env, through the entry point group
``covert_env.commands``
(:data:`COMMANDS_GROUP`, declared in ``pyproject.toml``): each names a ``main(argv, prog)`` that parses its own
arguments, ``--help`` included. The core package imports none of them by name; a command is loaded only when it
runs.

Mistakes in the command line or in the files it names (a missing or invalid ``--config``, or one that is not a
regular file; an unknown policy; an ``--out`` that is a file where a folder is expected, or that cannot be written,
checked before the run by writing a temporary file; a number out of range) print one ``error:`` line after the
usage and exit with status 2, without a traceback. Only those are caught: any other exception is a bug and keeps
its traceback. Code that validates user input raises :class:`~covert_env.command_line.UsageError`; the helpers of
:mod:`covert_env.command_line` (argparse ``type=`` functions, ``load_config``, ``output_dir``, ``output_file``) raise
it or argparse's own error. The subcommands' own modules (and matplotlib) are imported when a subcommand runs, so
that ``covert-env --help`` answers at once.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import sys

# Re-exported: the helpers lived here, and user scripts import them from covert_env.cli.
from covert_env.command_line import (  # noqa: F401
    MAX_DPI,
    MAX_JOBS,
    MAX_SCENES,
    UsageError,
    float_range,
    int_range,
    load_config,
    non_negative_int,
    output_dir,
    output_file,
    positive_int,
    regular_file,
    run_main,
)
from covert_env.world.config import Config
from covert_env.world.families import FAMILIES
from covert_env.world.scenario import Scenario

__all__ = ["main", "build_parser"]


# ---------------------------------------------------------------------- covert-env scene
IMAGE_SUFFIXES = ("png", "pdf", "svg", "jpg", "jpeg", "webp", "tif", "tiff", "eps")


def _scene(args: argparse.Namespace) -> int:
    config = load_config(args.config) if args.config is not None else Config()
    if args.slot > config.n_slots:
        raise UsageError(f"--slot must be in [0, {config.n_slots}]"
                         f"{' (n_slots of --config)' if args.config is not None else ''}, got {args.slot}")
    out = output_file(args.out, suffixes=IMAGE_SUFFIXES)

    import matplotlib

    matplotlib.use("Agg")
    from covert_env.render import scene_figure

    scenario = Scenario.paper(config) if args.paper else Scenario.random(args.seed, config)
    uav_xy = scenario.uav_xy if args.slot == 0 else None
    fig = scene_figure(scenario, args.slot, uav_xy=uav_xy)
    fig.savefig(out, dpi=args.dpi)
    import matplotlib.pyplot as plt

    plt.close(fig)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB): {scenario.name}, slot {args.slot}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="covert-env", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    # Listed for --help; main() hands their arguments to the provided command (COMMANDS_GROUP).
    sub.add_parser("reproduce", help="run the paper's experiments (DP shadow-aware vs shadow-blind), "
                                     "write figures and metrics (see: covert-env reproduce --help)")
    sub.add_parser("evaluate", help="score policies on held-out scenes and write a leaderboard "
                                    "(see: covert-env evaluate --help)")
    sub.add_parser("benchmark", help="the task suite's protocol: every task x policy x scene, normalised scores, "
                                     "IQM with intervals, profiles (see: covert-env benchmark --help)")
    sub.add_parser("list", help="the tasks, scene families, policies and shipped weights the commands accept "
                                "(covert-env list [tasks|families|policies|weights])")
    p = sub.add_parser("scene", help="draw terrain, road, target, zone, shadows and visible zone at one slot",
                       description="Draw terrain, road, target, zone, shadows and visible zone at one slot.")
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="scene seed (terrain + road), an integer >= 0; ignored with --paper (default: 0)")
    p.add_argument("--paper", action="store_true", help="draw the paper scenario instead of a random one")
    p.add_argument("--slot", type=non_negative_int, default=0,
                   help="slot k to draw, in [0, n_slots] (70 with the paper's parameters) (default: 0)")
    p.add_argument("--out", default="outputs/scene.png",
                   help="image file to write (.png, .pdf, .svg, ...; its folder is created) "
                        "(default: outputs/scene.png)")
    p.add_argument("--config", default=None, help="a Config JSON file (default: the paper's parameters)")
    p.add_argument("--dpi", type=int_range(10, MAX_DPI), default=110,
                   help=f"resolution, in [10, {MAX_DPI}] (default: 110)")
    p.set_defaults(func=_scene, subparser=p)
    sub.add_parser("animate", help="fly the DP team on the paper scene and write an animated GIF")
    p = sub.add_parser("scene-set",
                       help="write a scene family's held-out scenes to a JSON file (covert_env.world.scene_set)",
                       description="Write a scene family's first held-out scenes (or given seeds) to one JSON file: "
                                   "terrain, road, target track and starts, read back bit for bit by "
                                   "SceneSet.load and by covert-env evaluate --scene-set.")
    p.add_argument("--family", choices=list(FAMILIES), default="paper", help="scene family (default: paper)")
    p.add_argument("--scenes", type=int_range(1, MAX_SCENES), default=None,
                   help=f"the family's first held-out scenes, in [1, {MAX_SCENES}]; not with --seeds (default: 20)")
    p.add_argument("--seeds", type=non_negative_int, nargs="+", default=None,
                   help="these scene seeds instead of the first held-out ones")
    p.add_argument("--n-uavs", type=int_range(1, 64), default=3, help="team size of the starts (default: 3)")
    p.add_argument("--out", required=True, help="JSON file to write (its folder is created)")
    p.set_defaults(func=_scene_set, subparser=p)
    for name in provided_commands():
        if name not in sub.choices:
            sub.add_parser(name, help=f"(see: covert-env {name} --help)")
    return parser


def _scene_set(args: argparse.Namespace) -> int:
    from covert_env.world.scene_set import SceneSet

    if args.scenes is not None and args.seeds is not None:
        raise UsageError(f"--scenes {args.scenes} and --seeds {' '.join(map(str, args.seeds))}: give the number of "
                         "held-out scenes or the seeds, not both")
    out = output_file(args.out, suffixes=("json",))
    try:
        scenes = SceneSet.generate(args.family, 20 if args.scenes is None else args.scenes, seeds=args.seeds,
                                   config=Config(n_uavs=args.n_uavs))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    scenes.save(out)
    print(f"wrote {out}: {len(scenes)} scenes of family {args.family} (seeds {scenes.seeds[0]} .. "
          f"{scenes.seeds[-1]}), {out.stat().st_size / 1e6:.1f} MB")
    return 0


#: The entry point group of the subcommands provided by the packages above covert_env: NAME = "module:main", where
#: ``main(argv, prog)`` parses ``argv`` (``--help`` included), names itself ``prog`` and returns an exit status.
COMMANDS_GROUP = "covert_env.commands"
#: The provided subcommands this distribution declares (``covert-env --help`` lists them with its own help lines).
DECLARED_COMMANDS = ("reproduce", "animate", "list")
#: The subcommands of this module, which never look up COMMANDS_GROUP.
OWN_COMMANDS = ("scene", "scene-set")
#: The subcommands of covert_env's evaluation package: name -> the module whose ``main(argv, prog)`` runs it.
EVALUATION_COMMANDS = {"evaluate": "covert_env.evaluation.evaluate", "benchmark": "covert_env.evaluation.benchmark"}


def provided_commands() -> dict[str, importlib.metadata.EntryPoint]:
    """Subcommand name -> its entry point, from the installed metadata (not loaded: nothing is imported)."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=COMMANDS_GROUP)}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in EVALUATION_COMMANDS:
        # Everything after the name (including --help) goes to the command's own parser, under our name.
        main_of = importlib.import_module(EVALUATION_COMMANDS[argv[0]]).main
        return main_of(argv[1:], prog=f"covert-env {argv[0]}") or 0
    if argv and not argv[0].startswith("-") and argv[0] not in OWN_COMMANDS:
        commands = provided_commands()
        if argv[0] in commands:
            # Everything after the name (including --help) goes to the command's own parser, under our name.
            return commands[argv[0]].load()(argv[1:], prog=f"covert-env {argv[0]}") or 0
        if argv[0] in DECLARED_COMMANDS:
            installed = ", ".join(sorted(commands)) or "none"
            build_parser().error(f"the {argv[0]} command is not in the installed metadata (entry point group "
                                 f"{COMMANDS_GROUP} has: {installed}); reinstall covert_env (pip install -e .)")
    args = build_parser().parse_args(argv)
    return run_main(args.subparser, lambda: args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
