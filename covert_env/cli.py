"""The ``covert-env`` command line.

    covert-env reproduce --out outputs/reproduce            # the paper's experiments with the DP planner
    covert-env evaluate --help                               # score policies on held-out scenes
    covert-env scene --seed 3 --slot 10 --out scene.png     # a picture of one slot (3D + top view)
    covert-env scene --paper --slot 0 --out paper.png        # the paper scenario
    covert-env animate                                       # the DP team flying: outputs/dp_team.gif
    covert-env animate --out docs/dp_team.gif                # regenerate the README's animation

``reproduce`` and ``evaluate`` live in ``baselines`` and ``training`` (imported only when called).

Mistakes in the command line or in the files it names (a missing or invalid ``--config``, or one that is not a
regular file; an unknown policy; an ``--out`` that is a file where a folder is expected, or that cannot be written,
checked before the run by writing a temporary file; a number out of range) print one ``error:`` line after the
usage and exit with status 2, without a traceback. Only those are caught: any other exception is a bug and keeps
its traceback. Code that validates user input raises :class:`UsageError`; the helpers below (argparse ``type=``
functions, :func:`load_config`, :func:`output_dir`, :func:`output_file`) raise it or argparse's own error.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

__all__ = ["main", "build_parser", "UsageError", "int_range", "float_range", "positive_int", "non_negative_int",
           "load_config", "regular_file", "output_dir", "output_file", "run_main"]


class UsageError(ValueError):
    """A mistake in the command line or in a file it names: printed as one ``error:`` line, exit status 2.

    A ``ValueError``, so library callers (``training.evaluate.load_policy`` ...) can catch it as one."""


# ---------------------------------------------------------------------- argparse type= functions
def _bounds_text(lo, hi, lo_open: bool = False, hi_open: bool = False) -> str:
    if hi is None:
        return f"{'>' if lo_open else '>='} {lo:g}" if isinstance(lo, float) else f">= {lo}"
    if lo is None:
        return f"{'<' if hi_open else '<='} {hi:g}" if isinstance(hi, float) else f"<= {hi}"
    left, right = "(" if lo_open else "[", ")" if hi_open else "]"
    return f"in {left}{lo:g}, {hi:g}{right}" if isinstance(lo, float) else f"in [{lo}, {hi}]"


def int_range(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse ``type=``: an integer in ``[lo, hi]`` (``None``: unbounded); the error names the range."""
    text = _bounds_text(lo, hi)

    def parse(s: str) -> int:
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer {text}, got {s!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be an integer {text}, got {v}")
        return v

    parse.__name__ = f"integer {text}"
    return parse


def float_range(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
                hi_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type=``: a finite number in the interval (``lo_open``/``hi_open``: bound excluded)."""
    lo = None if lo is None else float(lo)
    hi = None if hi is None else float(hi)
    text = _bounds_text(lo, hi, lo_open, hi_open)

    def parse(s: str) -> float:
        try:
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number {text}, got {s!r}") from None
        bad = not math.isfinite(v)
        if lo is not None:
            bad |= v <= lo if lo_open else v < lo
        if hi is not None:
            bad |= v >= hi if hi_open else v > hi
        if bad:
            raise argparse.ArgumentTypeError(f"must be a number {text}, got {s}")
        return v

    parse.__name__ = f"number {text}"
    return parse


positive_int = int_range(1)
non_negative_int = int_range(0)

#: Upper bounds of the CLI's counts: far above any sensible run, low enough that a typo cannot exhaust memory.
MAX_SCENES = 100_000
MAX_JOBS = 256
MAX_DPI = 1000


# ---------------------------------------------------------------------- files named on the command line
def load_config(path: str | Path, flag: str = "--config"):
    """``Config.from_json(path)`` with a missing, unreadable or invalid file as a :class:`UsageError`. A path that
    is not a regular file (a folder, ``/dev/zero``, a named pipe) is refused before anything is read."""
    from covert_env.config import Config

    _not_empty(path, flag)
    regular_file(path, flag, "a Config JSON file")
    p = Path(path)
    try:
        return Config.from_json(p)
    except (OSError, ValueError, RecursionError) as exc:   # Config's own validation raises ValueError
        raise UsageError(f"{flag} {path}: {exc}") from None


def regular_file(path: str | Path, flag: str, expected: str = "a file") -> Path:
    """``path`` if it names an existing regular file; else a :class:`UsageError` saying what it is instead (missing,
    a folder, a device such as ``/dev/zero``, a named pipe). Uses ``stat`` only: nothing is opened or read."""
    import stat as stat_

    from covert_env.config import file_kind

    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise UsageError(f"{flag} {path}: no such file") from None
    except OSError as exc:
        raise UsageError(f"{flag} {path}: cannot be read ({exc.strerror or exc})") from None
    if not stat_.S_ISREG(mode):
        raise UsageError(f"{flag} {path}: is {file_kind(mode)}, expected {expected}")
    return p


def _not_empty(path: str | Path, flag: str) -> None:
    if isinstance(path, str) and not path.strip():
        raise UsageError(f"{flag} {path!r}: empty; give a path")


def _file_in_the_way(p: Path) -> Path | None:
    """The first existing non-folder among ``p``'s parents (then ``p`` cannot be created), or None."""
    for q in reversed(p.absolute().parents):
        if q.exists() and not q.is_dir():
            return q
    return None


def _probe(folder: Path, flag: str, path: str | Path) -> None:
    """Create and remove a temporary file in the existing folder ``folder``: a :class:`UsageError` if that fails.
    Only writing tells: ``os.access`` says yes to root on a read-only filesystem, in ``/proc`` or ``/sys``."""
    import os
    import tempfile

    try:
        fd, name = tempfile.mkstemp(dir=folder, prefix=".covert-env-write-test-")
    except OSError as exc:
        raise UsageError(f"{flag} {path}: cannot write in {folder} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(name)


def _nearest_existing(p: Path) -> Path:
    for q in (p.absolute(), *p.absolute().parents):
        if q.exists():
            return q
    return Path(p.absolute().anchor)


def output_dir(path: str | Path, flag: str = "--out", create: bool = True, files: tuple[str, ...] = (),
               folders: tuple[str, ...] = ()) -> Path:
    """Create the output folder ``path`` (and its parents) and check that files can be written in it (a temporary
    file is created and removed); a file in the way or a folder that cannot be written is a :class:`UsageError`.
    ``files`` and ``folders`` name what the command will write inside: one already there as the other kind (a
    folder where a file goes, a file where a folder goes) is a :class:`UsageError` too.
    ``create=False`` only checks, writing the temporary file in the nearest existing folder (so that later checks
    can fail before anything is written). An empty or blank ``path`` is a :class:`UsageError` (``Path('')`` would
    be the current folder)."""
    _not_empty(path, flag)
    return _output_dir(Path(path), flag, path, create, files, folders)


def _output_dir(p: Path, flag: str, path: str | Path, create: bool = True, files: tuple[str, ...] = (),
                folders: tuple[str, ...] = ()) -> Path:
    """:func:`output_dir` of folder ``p``; errors name ``flag`` and ``path``, the value given on the command line."""
    if p.exists() and not p.is_dir():
        raise UsageError(f"{flag} {path}: is a file, expected a folder (it is created if missing)")
    blocker = _file_in_the_way(p)
    if blocker is not None:
        raise UsageError(f"{flag} {path}: {blocker} is a file, not a folder")
    for name in files:
        q = p / name
        if q.exists() and not q.is_file():
            raise UsageError(f"{flag} {path}: {q} is {_kind(q)}, but the command writes the file {name} there; "
                             f"move it away or choose another {flag}")
    for name in folders:
        q = p / name
        if q.exists() and not q.is_dir():
            raise UsageError(f"{flag} {path}: {q} is a file, but the command writes into a folder {name} there; "
                             f"move it away or choose another {flag}")
    if not create:
        _probe(_nearest_existing(p), flag, path)
        return p
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{flag} {path}: cannot create the folder ({exc.strerror or exc})") from None
    _probe(p, flag, path)
    return p


def _kind(p: Path) -> str:
    from covert_env.config import file_kind

    return file_kind(p.stat().st_mode)


def output_file(path: str | Path, flag: str = "--out", suffixes: tuple[str, ...] | None = None) -> Path:
    """Check that ``path`` can be written as a file: its folder is created and written to (a temporary file), an
    existing ``path`` must be a regular file that can be opened for writing (it is not changed); ``suffixes`` lists
    the allowed file types. Any problem is a :class:`UsageError`."""
    _not_empty(path, flag)
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{flag} {path}: is a folder, expected a file name")
    if suffixes is not None and p.suffix.lower().lstrip(".") not in suffixes:
        raise UsageError(f"{flag} {path}: unknown file type {p.suffix or '(none)'!r}; use one of "
                         + ", ".join("." + s for s in suffixes))
    blocker = _file_in_the_way(p)
    if blocker is not None:
        raise UsageError(f"{flag} {path}: {blocker} is a file, not a folder")
    if p.exists() and not p.is_file():
        raise UsageError(f"{flag} {path}: is {_kind(p)}, expected a regular file name")
    _output_dir(p.parent, flag, path)
    if p.exists():
        try:
            with open(p, "r+b"):                    # opened for writing, nothing written
                pass
        except OSError as exc:
            raise UsageError(f"{flag} {path}: cannot be overwritten ({exc.strerror or exc})") from None
    return p


def run_main(parser: argparse.ArgumentParser, fn: Callable[[], int | None]) -> int:
    """``fn()``, with a :class:`UsageError` turned into ``parser.error`` (usage, one error line, exit 2)."""
    try:
        return fn() or 0
    except UsageError as exc:
        parser.error(str(exc))


# ---------------------------------------------------------------------- covert-env scene
IMAGE_SUFFIXES = ("png", "pdf", "svg", "jpg", "jpeg", "webp", "tif", "tiff", "eps")


def _scene(args: argparse.Namespace) -> int:
    from covert_env.config import Config

    config = load_config(args.config) if args.config else Config()
    if args.slot > config.n_slots:
        raise UsageError(f"--slot must be in [0, {config.n_slots}]"
                         f"{' (n_slots of --config)' if args.config else ''}, got {args.slot}")
    out = output_file(args.out, suffixes=IMAGE_SUFFIXES)

    import matplotlib

    matplotlib.use("Agg")
    from covert_env.render import scene_figure
    from covert_env.scenario import Scenario

    scenario = Scenario.paper(config) if args.paper else Scenario.random(args.seed, config)
    uav_xy = scenario.uav_xy if args.slot == 0 else None
    fig = scene_figure(scenario, args.slot, uav_xy=uav_xy)
    fig.savefig(out, dpi=args.dpi)
    import matplotlib.pyplot as plt

    plt.close(fig)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB): {scenario.name}, slot {args.slot}")
    return 0


# ---------------------------------------------------------------------- covert-env animate
def _animate(args: argparse.Namespace) -> int:
    from covert_env.config import Config

    config = load_config(args.config) if args.config else Config()
    n_slots = config.n_slots if args.slots is None else args.slots
    if n_slots > config.n_slots:
        raise UsageError(f"--slots must be in [1, {config.n_slots}]{' (n_slots of --config)' if args.config else ''}"
                         f", got {n_slots}")
    out = output_file(args.out, suffixes=("gif",))

    import matplotlib

    matplotlib.use("Agg")
    from baselines.reproduce import write_gif

    info = write_gif(out, n_uavs=args.uavs, method=args.method, n_slots=n_slots,
                     frames_per_slot=args.frames_per_slot, size=args.size, dpi=args.dpi, fps=args.fps, config=config)
    print(f"wrote {out} ({info['bytes'] / 1024:.0f} KiB, {info['frames']} frames, {info['slots']} slots)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="covert-env", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    # Listed for --help; main() forwards their arguments to baselines.reproduce / training.evaluate.
    sub.add_parser("reproduce", help="run the paper's experiments (DP shadow-aware vs shadow-blind), "
                                     "write figures and metrics (see: covert-env reproduce --help)")
    sub.add_parser("evaluate", help="score policies on held-out scenes and write a leaderboard "
                                    "(see: covert-env evaluate --help)")
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
    p = sub.add_parser("animate", help="fly the DP team on the paper scene and write an animated GIF",
                       description="Fly the DP team planner on the paper scene and write an animated GIF (top view "
                                   "following the target: zone, shadows, visible zone, lines of sight).")
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
    p.set_defaults(func=_animate, subparser=p)
    return parser


_FORWARDED = {"reproduce": "baselines.reproduce", "evaluate": "training.evaluate"}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in _FORWARDED:
        # Forward everything (including --help) to the subcommand's own parser, under our name.
        import importlib

        module = importlib.import_module(_FORWARDED[argv[0]])
        return module.main(argv[1:], prog=f"covert-env {argv[0]}") or 0
    args = build_parser().parse_args(argv)
    return run_main(args.subparser, lambda: args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
