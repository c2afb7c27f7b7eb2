"""What every command line of the project shares: argparse ``type=`` functions with stated ranges, checks of the
files a command reads and writes, and :class:`UsageError`, the one exception a command turns into one ``error:``
line and exit status 2 (:func:`run_main`).

It also runs a command's work items in order, in this process or on a pool (:func:`ordered_results`), and reads
the JSON files a command is given (:func:`read_run_json`). ``covert_env.cli``, ``baselines.reproduce``, the
evaluation commands and the training scripts import it; it imports only the model's :mod:`covert_env.world.config`,
so no command line imports another.
"""

from __future__ import annotations

import argparse
import math
import stat as stat_
from collections.abc import Callable
from pathlib import Path
from typing import Any

from covert_env.world.config import Config, file_kind, read_json

__all__ = ["MAX_DPI", "MAX_JOBS", "MAX_SCENES", "UsageError", "float_range", "int_range", "load_config",
           "non_negative_int", "ordered_results", "output_dir", "output_file", "positive_int", "read_run_json",
           "regular_file", "run_main"]


class UsageError(ValueError):
    """A mistake in the command line or in a file it names: printed as one ``error:`` line, exit status 2.

    A ``ValueError``, so library callers (``covert_env.evaluation.evaluate.load_policy`` ...) can catch it as one."""


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
    try:
        return _output_dir(Path(path), flag, path, create, files, folders)
    except OSError as exc:                      # a name too long, a loop of links: what stat itself refuses
        raise UsageError(f"{flag} {str(path)[:80]}: cannot be used as a folder ({exc.strerror or exc})") from None


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
    return file_kind(p.stat().st_mode)


def output_file(path: str | Path, flag: str = "--out", suffixes: tuple[str, ...] | None = None) -> Path:
    """Check that ``path`` can be written as a file: its folder is created and written to (a temporary file), an
    existing ``path`` must be a regular file that can be opened for writing (it is not changed); ``suffixes`` lists
    the allowed file types. Any problem is a :class:`UsageError`."""
    _not_empty(path, flag)
    try:
        return _output_file(Path(path), flag, path, suffixes)
    except OSError as exc:                      # a name too long, a loop of links: what stat itself refuses
        raise UsageError(f"{flag} {str(path)[:80]}: cannot be used as a file ({exc.strerror or exc})") from None


def _output_file(p: Path, flag: str, path: str | Path, suffixes: tuple[str, ...] | None) -> Path:
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


def read_run_json(path: Path, what: str) -> Any:
    """A JSON file of a run (``args.json``, a model card, a cache), with every problem -- missing, not a regular
    file, too large, not UTF-8, invalid JSON -- as a :class:`~covert_env.command_line.UsageError` naming the file."""
    try:
        return read_json(path, what)
    except (OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None


def ordered_results(fn: Callable, work: list[tuple], jobs: int = 1, on_result: Callable | None = None) -> list:
    """``[fn(*w) for w in work]``, in that order, in this process (``jobs`` = 1) or on a pool of ``jobs`` spawned
    processes (a clean interpreter each, whatever the parent imported: torch, threads). ``on_result`` is called
    after each result, in order (a progress bar's update). The first failure cancels the work still queued and
    raises, so a bad input fails at once rather than after every other item has run."""
    out = []
    if jobs == 1:
        for w in work:
            out.append(fn(*w))
            if on_result is not None:
                on_result()
        return out
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(fn, *w) for w in work]
        try:
            for f in futures:
                out.append(f.result())
                if on_result is not None:
                    on_result()
        except BaseException:
            pool.shutdown(cancel_futures=True)
            raise
    return out
