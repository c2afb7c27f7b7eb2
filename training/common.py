"""Shared plumbing of the SB3 scripts: dataclass -> argparse, run names, callbacks, checkpoints and resume.

Every script keeps its own readable ``Args`` dataclass (CleanRL style); this module only turns it into a CLI whose
``--help`` shows each field's docstring, and provides the callbacks every script uses:

* a tqdm progress bar (``mininterval`` 30 s when stdout is not a terminal, so logs stay small);
* :class:`TimeBudgetCallback`: stops ``learn()`` gracefully after a wall-clock budget (the model is then saved);
* SB3's ``CheckpointCallback`` every ``checkpoint_freq`` steps, with the VecNormalize statistics beside the model.

Run layout (git-ignored ``runs/``)::

    runs/{env}__{algo}__{seed}__{time}/
        args.json            # the exact arguments (the harness reads env settings from here)
        model.zip            # final model
        vecnormalize.pkl     # VecNormalize statistics of the final model (if used)
        checkpoints/         # {algo}_{steps}_steps.zip + {algo}_vecnormalize_{steps}_steps.pkl
        tb/                  # TensorBoard logs
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import json
import os
import re
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

__all__ = ["parse_args", "run_name", "setup_torch", "TimeBudgetCallback", "TqdmCallback", "make_callbacks",
           "latest_checkpoint", "save_run", "field_docs"]


def setup_torch(threads: int = 1) -> None:
    """One torch thread by default: on 2 busy cores, 2 torch threads can be up to 50x slower."""
    import torch

    torch.set_num_threads(max(1, int(threads)))


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each dataclass field (``x: int = 1`` followed by ``\"\"\"doc\"\"\"``)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        body = tree.body[0].body
        for a, b in zip(body, body[1:], strict=False):
            if isinstance(a, ast.AnnAssign) and isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant) \
                    and isinstance(b.value.value, str):
                docs[a.target.id] = " ".join(b.value.value.split())
    return docs


def _str2bool(s: str) -> bool:
    if s.lower() in ("1", "true", "yes", "y", "on"):
        return True
    if s.lower() in ("0", "false", "no", "n", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected a boolean, got {s!r}")


def parse_args(cls: type, argv: list[str] | None = None, description: str | None = None,
               presets: dict[str, dict] | None = None):
    """Build an argparse CLI from dataclass ``cls`` (``--field-name value``; booleans take true/false).

    ``presets`` (name -> overrides) adds ``--recipe NAME``: the preset is applied first, explicit flags win.
    """
    docs = field_docs(cls)
    p = argparse.ArgumentParser(description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    if presets:
        p.add_argument("--recipe", choices=sorted(presets), default=None, help="named settings, see training.recipes")
    for f in dataclasses.fields(cls):
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        typ = f.type if not isinstance(f.type, str) else eval(f.type, vars(sys.modules[cls.__module__]))  # noqa: S307
        kw: dict[str, Any] = {"help": docs.get(f.name, ""), "default": None}
        origin = getattr(typ, "__origin__", None)
        if typ is bool:
            kw.update(type=_str2bool, nargs="?", const=True, metavar="BOOL")
        elif origin in (list, tuple):
            kw.update(type=typ.__args__[0], nargs="+")
        elif typ in (int, float, str):
            kw["type"] = typ
        else:                                   # Optional[...] and friends: take the non-None member
            args = [t for t in getattr(typ, "__args__", ()) if t is not type(None)]
            kw["type"] = args[0] if args else str
        kw["help"] += f" (default: {default!r})"
        p.add_argument("--" + f.name.replace("_", "-"), dest=f.name, **kw)
    ns = p.parse_args(argv)
    values = {}
    if presets and ns.recipe:
        values.update(presets[ns.recipe])
    for f in dataclasses.fields(cls):
        v = getattr(ns, f.name)
        if v is not None:
            values[f.name] = type(getattr(cls(), f.name))(v) if isinstance(getattr(cls(), f.name), tuple) else v
    return cls(**values)


def run_name(env_id: str, algo: str, seed: int) -> str:
    """``{env}__{algo}__{seed}__{time}`` (CleanRL convention)."""
    env = re.sub(r"[^A-Za-z0-9_.-]+", "-", env_id).strip("-")
    return f"{env}__{algo}__{seed}__{int(time.time())}"


def save_run(run_dir: Path, args: Any, extra: dict | None = None) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    data = dataclasses.asdict(args) if dataclasses.is_dataclass(args) else dict(args)
    data.update(extra or {})
    (run_dir / "args.json").write_text(json.dumps(data, indent=2, default=str))


#: Arguments a resumed run takes from the command line rather than from the saved run.
RESUME_OVERRIDES = frozenset({"resume", "total_timesteps", "iterations", "time_budget_minutes", "progress_bar",
                              "torch_threads", "verbose", "address", "num_env_runners"})


def resumed_args(args: Any, run_dir: Path) -> Any:
    """``args`` with the saved run's settings (``run_dir/args.json``), except :data:`RESUME_OVERRIDES`."""
    saved = json.loads((Path(run_dir) / "args.json").read_text())
    names = {f.name for f in dataclasses.fields(args)}
    vals = {k: v for k, v in saved.items() if k in names and k not in RESUME_OVERRIDES}
    if "net_arch" in names:
        vals["net_arch"] = tuple(vals.get("net_arch", args.net_arch))
    return dataclasses.replace(args, **vals)


def latest_checkpoint(run_dir: Path) -> tuple[Path, Path | None] | None:
    """The newest ``(model.zip, vecnormalize.pkl or None)`` in ``run_dir/checkpoints`` or the final model."""
    run_dir = Path(run_dir)
    best: tuple[int, Path] | None = None
    for p in (run_dir / "checkpoints").glob("*_steps.zip"):
        m = re.search(r"_(\d+)_steps\.zip$", p.name)
        if m and (best is None or int(m.group(1)) > best[0]):
            best = (int(m.group(1)), p)
    final = run_dir / "model.zip"
    if best is None and not final.exists():
        return None
    if best is None:
        vn = run_dir / "vecnormalize.pkl"
        return final, vn if vn.exists() else None
    steps, path = best
    prefix = path.name[: -len(f"_{steps}_steps.zip")]
    vn = path.parent / f"{prefix}_vecnormalize_{steps}_steps.pkl"
    if final.exists() and final.stat().st_mtime > path.stat().st_mtime:
        vnf = run_dir / "vecnormalize.pkl"
        return final, vnf if vnf.exists() else None
    return path, vn if vn.exists() else None


def _callback_base():
    from stable_baselines3.common.callbacks import BaseCallback

    return BaseCallback


class TimeBudgetCallback(_callback_base()):
    """Stop training gracefully once ``minutes`` of wall-clock time have passed (0 or less: no budget)."""

    def __init__(self, minutes: float):
        super().__init__()
        self.minutes = float(minutes)
        self.t0 = time.monotonic()
        self.stopped = False

    def _on_training_start(self) -> None:
        self.t0 = time.monotonic()

    def _on_step(self) -> bool:
        if self.minutes > 0 and time.monotonic() - self.t0 > 60.0 * self.minutes:
            if not self.stopped:
                print(f"time budget of {self.minutes:g} min reached at {self.num_timesteps} steps: stopping",
                      flush=True)
            self.stopped = True
            return False
        return True


class TqdmCallback(_callback_base()):
    """A tqdm progress bar over timesteps (starts at the resumed step count)."""

    def __init__(self, total: int):
        super().__init__()
        self.total = int(total)
        self.bar = None

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        tty = sys.stderr.isatty()
        self.bar = tqdm(total=self.total, initial=self.model.num_timesteps, unit="step", dynamic_ncols=True,
                        mininterval=0.5 if tty else 30.0, smoothing=0.05)

    def _on_step(self) -> bool:
        if self.bar is not None:
            self.bar.n = self.model.num_timesteps
            self.bar.update(0)
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.n = self.model.num_timesteps
            self.bar.close()


def make_callbacks(run_dir: Path, algo: str, total_timesteps: int, num_envs: int, checkpoint_freq: int,
                   time_budget_minutes: float, progress_bar: bool = True) -> tuple[list, TimeBudgetCallback]:
    """Checkpoints every ``checkpoint_freq`` steps (with VecNormalize stats), a time budget and a progress bar."""
    from stable_baselines3.common.callbacks import CheckpointCallback

    budget = TimeBudgetCallback(time_budget_minutes)
    cbs: list = [budget]
    if checkpoint_freq > 0:
        cbs.append(CheckpointCallback(save_freq=max(checkpoint_freq // num_envs, 1),
                                      save_path=str(Path(run_dir) / "checkpoints"), name_prefix=algo,
                                      save_vecnormalize=True))
    if progress_bar:
        cbs.append(TqdmCallback(total_timesteps))
    return cbs, budget


def env_flag(name: str, default: str) -> str:
    return os.environ.get(name, default)
