"""What every training script shares: its dataclass as a command line, run folders, checkpoints and resume.

Every script keeps its own readable ``Args`` dataclass (CleanRL style); :func:`parse_args` turns it into a CLI whose
``--help`` shows each field's docstring and whose values are checked before anything runs. A run lives in
``runs/{env}__{algo}__{seed}__{time}/`` (git-ignored) with its ``args.json`` (:func:`save_run`); ``--resume``
continues it from its newest checkpoint (:func:`resume_checkpoint`; an SB3 ``model.zip`` holds pickled parts, so it
is loaded only with ``--trust-checkpoint``: :mod:`training.trust`). The SB3 run itself is
:func:`training.sb3.run.train_sb3`.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import json
import re
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from covert_env.command_line import (  # noqa: F401  (ordered_results: importable here for one more release)
    UsageError,
    float_range,
    int_range,
    non_negative_int,
    ordered_results,
    output_dir,
    positive_int,
)
from covert_env.envs.settings import MAX_SCENE_POOL
from covert_env.envs.vector import MAX_NUM_ENVS
from covert_env.world.config import MAX_N_UAVS, Config, read_json
from training.trust import require_trust

__all__ = ["parse_args", "run_name", "setup_torch", "latest_checkpoint", "resume_checkpoint",
           "resumed_args", "save_run", "field_docs", "build_parser"]


def setup_torch(threads: int = 1) -> None:
    """One torch thread by default: more torch threads than free cores slow a run down (docs/training.md)."""
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


def _ranges() -> dict[str, tuple]:
    """Allowed values of the numeric (and choice) fields of the scripts' ``Args``, by field name: an argparse
    ``type=`` function naming its range, or ``("choices", (...))``. Every int/float field of every script must be
    listed (a test checks it)."""

    positive = float_range(0.0, lo_open=True)
    non_negative = float_range(0.0)
    unit = float_range(0.0, 1.0)
    return {
        "seed": non_negative_int, "n_uavs": int_range(1, MAX_N_UAVS), "n_copies": int_range(1, MAX_NUM_ENVS),
        "n_envs": int_range(1, MAX_NUM_ENVS), "max_cycles": positive_int, "scene_pool": int_range(1, MAX_SCENE_POOL),
        "total_timesteps": positive_int,
        "time_budget_minutes": non_negative, "learning_rate": positive, "lr": positive, "n_steps": int_range(2),
        "batch_size": int_range(2), "minibatch_size": int_range(2), "train_batch_size": int_range(2),
        "n_epochs": positive_int, "num_epochs": positive_int, "gamma": unit, "gae_lambda": unit, "lambda_": unit,
        "clip_range": positive, "ent_coef": non_negative, "vf_coef": non_negative, "max_grad_norm": positive,
        "log_std_init": float_range(-20.0, 2.0), "los_penalty": non_negative, "zone_penalty": non_negative,
        "separation_penalty": non_negative, "checkpoint_freq": non_negative_int, "checkpoint_every": non_negative_int,
        "torch_threads": int_range(1, 256), "verbose": int_range(0, 2), "buffer_size": positive_int,
        "learning_starts": non_negative_int, "gradient_steps": int_range(-1), "train_freq": positive_int,
        "tau": float_range(0.0, 1.0, lo_open=True), "iterations": positive_int, "num_env_runners": non_negative_int,
        "num_envs_per_env_runner": positive_int, "sample_timeout_s": positive,
        "net_arch": int_range(1, 65_536), "action_mode": ("choices", ("unicycle", "waypoint")),
        # training.mappo
        "algo": ("choices", ("mappo", "ippo")), "head": ("choices", ("node", "flat")),
        "num_envs": int_range(1, MAX_NUM_ENVS),
        "num_steps": int_range(2), "num_minibatches": positive_int, "update_epochs": positive_int,
        "clip_coef": positive, "hidden": int_range(1, 65_536), "node_hidden": int_range(1, 65_536),
        "cost_limit": non_negative, "lagrange_lr": non_negative, "shield_margin": non_negative,
        "shield_end_margin": non_negative, "map_size": int_range(2, 64), "lambda_max": non_negative,
        "actor_warmup_updates": non_negative_int, "viability_min_reach": int_range(1, 100_000),
        "init_temperature": float_range(0.01, 100.0),
        "target_path": int_range(0, Config().horizon),      # the envs' bound: every task plans over config.horizon
        # training.imitation
        "teacher": ("choices", ("dp", "dp-binned", "dp-path")), "episodes_per_task": int_range(1, 100_000),
        "val_episodes": int_range(0, 100_000), "dagger_rounds": int_range(0, 100),
        "dagger_episodes_per_task": int_range(1, 100_000), "epochs": int_range(1, 100_000), "jobs": int_range(1, 256),
    }


def _show_default(v: Any) -> str:
    """A default as it would be typed on the command line."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (tuple, list)):
        return " ".join(str(x) for x in v)
    if isinstance(v, str):
        return v if v else "''"
    return f"{v:_}" if isinstance(v, int) and abs(v) >= 10_000 else str(v)


def _prog(cls: type) -> str | None:
    """``python -m MODULE``: the settings class's ``PROG`` if it has one (settings kept in a package's submodule),
    else the module that defines it."""
    if getattr(cls, "PROG", None):
        return cls.PROG
    spec = getattr(sys.modules.get(cls.__module__), "__spec__", None)
    return f"python -m {spec.name}" if spec is not None and spec.name else None


def build_parser(cls: type, description: str | None = None, presets: dict[str, dict] | None = None,
                 prog: str | None = None) -> argparse.ArgumentParser:
    """The argparse CLI of dataclass ``cls``: ``--field-name value`` per field, its docstring as help, its allowed
    range (:func:`_ranges`) checked, and its default printed once (flags left out are ``None`` in the namespace,
    so that ``--recipe`` can tell them from explicit ones)."""
    docs = field_docs(cls)
    ranges = _ranges()
    p = argparse.ArgumentParser(prog=prog or _prog(cls), description=description)
    if presets:
        p.add_argument("--recipe", choices=sorted(presets), default=None,
                       help="named settings (training.recipes); they replace the defaults below, explicit flags "
                            "win (default: none)")
    for f in dataclasses.fields(cls):
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        typ = f.type if not isinstance(f.type, str) else eval(f.type, vars(sys.modules[cls.__module__]))  # noqa: S307
        kw: dict[str, Any] = {"default": None}
        origin = getattr(typ, "__origin__", None)
        check = ranges.get(f.name)
        if typ is bool:
            kw.update(type=_str2bool, nargs="?", const=True, metavar="BOOL")
        elif origin in (list, tuple):
            kw.update(type=check or typ.__args__[0], nargs="+")
        elif isinstance(check, tuple):
            kw.update(type=typ, choices=check[1])
        elif typ in (int, float):
            kw["type"] = check or typ
        elif typ is str:
            kw["type"] = str
        else:                                   # Optional[...] and friends: take the non-None member
            args = [t for t in getattr(typ, "__args__", ()) if t is not type(None)]
            kw["type"] = args[0] if args else str
        allowed = getattr(kw["type"], "__name__", "") if kw["type"] is check else ""
        help_ = docs.get(f.name, "").replace("%", "%%")
        extra = f"{allowed}; " if allowed else ""
        kw["help"] = f"{help_} ({extra}default: {_show_default(default).replace('%', '%%')})".lstrip()
        p.add_argument("--" + f.name.replace("_", "-"), dest=f.name, **kw)
    return p


def checked_main(cls: type, argv: list[str] | None, *, description: str, check: Callable[[Any], None],
                 run: Callable[[Any], Any], presets: dict[str, dict] | None = None):
    """A training script's ``main``: :func:`parse_args` into ``cls``, then ``check`` the settings (a ``ValueError``
    exits with status 2 and one line, ``python -m MODULE: error: ...``, before anything runs), then ``run`` them."""
    args = parse_args(cls, argv, description=description, presets=presets)
    try:
        check(args)
    except ValueError as exc:
        print(f"{_prog(cls)}: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return run(args)


def parse_args(cls: type, argv: list[str] | None = None, description: str | None = None,
               presets: dict[str, dict] | None = None, prog: str | None = None):
    """Build an argparse CLI from dataclass ``cls`` (``--field-name value``; booleans take true/false).

    ``presets`` (name -> overrides) adds ``--recipe NAME``: the preset is applied first, explicit flags win.
    Out-of-range values, a ``--resume`` folder that is not a run, whose saved ``args.json`` is damaged or out of
    range, or that cannot be written, a ``--runs-dir``/``--run-name`` that cannot be written, and, for scripts whose
    ``Args`` has ``trust_checkpoint``, a ``--resume`` that would load a pickled checkpoint without
    ``--trust-checkpoint`` exit with status 2 and one error line, before anything runs.
    """
    p = build_parser(cls, description, presets, prog)
    ns = p.parse_args(argv)
    values = {}
    if presets and ns.recipe:
        values.update(presets[ns.recipe])
    for f in dataclasses.fields(cls):
        v = getattr(ns, f.name)
        if v is not None:
            values[f.name] = type(getattr(cls(), f.name))(v) if isinstance(getattr(cls(), f.name), tuple) else v

    resume = values.get("resume")
    if resume:
        run = Path(resume)
        if not run.is_dir():
            p.error(f"--resume {resume}: no such folder")
        # The saved arguments the run continues with (resumed_args): checked like the command line's. An RLlib
        # checkpoint folder (with learner_group/) has them beside it, any other run in it.
        saved_path = run.parent / "args.json" if (run / "learner_group").is_dir() else run / "args.json"
        if not saved_path.is_file():
            p.error(f"--resume {resume}: not a run folder (no {saved_path})")
        if saved_path.is_file():
            try:
                problem = _saved_args_problem(cls, read_json(saved_path, "run arguments"))
            except (OSError, ValueError) as exc:
                problem = str(exc).removeprefix(f"run arguments {saved_path}: ")
            if problem:
                p.error(f"--resume {resume}: {saved_path}: {problem}")
        try:                                     # the run folder is written to (args.json, checkpoints, model)
            output_dir(run, "--resume", create=False, files=("args.json", "train_summary.json"))
        except UsageError as exc:
            p.error(str(exc))
        if "trust_checkpoint" in {f.name for f in dataclasses.fields(cls)}:
            trust = values.get("trust_checkpoint", False)
            try:
                if (run / "learner_group").is_dir():                   # an RLlib checkpoint (training.rllib_ppo)
                    require_trust(run, "an RLlib checkpoint", trust)
                else:
                    resume_checkpoint(run, trust_checkpoint=trust)
            except UsageError as exc:
                p.error(f"--resume {resume}: {exc}")
    elif any(f.name == "runs_dir" for f in dataclasses.fields(cls)):
        runs_dir = values.get("runs_dir", cls().runs_dir)
        try:                                     # probed now, not after the first checkpoint interval
            output_dir(runs_dir, "--runs-dir", create=False)
            name = values.get("run_name")
            if name and (Path(name).name != name or name in (".", "..")):
                # A run lives inside --runs-dir: a path here would write elsewhere (or over another folder).
                raise UsageError(f"--run-name {name!r}: must be a plain folder name inside --runs-dir "
                                 f"({runs_dir}), without '/' or '..'")
            if name:
                output_dir(Path(runs_dir) / name, "--run-name", create=False,
                           files=("args.json", "train_summary.json"))
        except UsageError as exc:
            p.error(str(exc))
    return cls(**values)


def _saved_args_problem(cls: type, saved: Any) -> str | None:
    """What is wrong with a run's saved arguments ``saved`` (its ``args.json``) for dataclass ``cls``, or None: each
    field a resumed run takes from it must have its default's type and pass the command line's range check."""
    if not isinstance(saved, dict):
        return f"must be a JSON object (a run's arguments), got {type(saved).__name__}"
    ranges = _ranges()
    defaults = cls()
    for f in dataclasses.fields(cls):
        if f.name not in saved or f.name in RESUME_OVERRIDES:
            continue
        v, default, check = saved[f.name], getattr(defaults, f.name), ranges.get(f.name)
        items = v if isinstance(default, tuple) and isinstance(v, list) else [v]
        kind = type(default[0] if isinstance(default, tuple) and default else default)
        fits = {bool: lambda x: isinstance(x, bool), int: lambda x: isinstance(x, int) and not isinstance(x, bool),
                float: lambda x: isinstance(x, (int, float)) and not isinstance(x, bool),
                str: lambda x: isinstance(x, str)}.get(kind, lambda x: True)
        if (isinstance(default, tuple) and not isinstance(v, list)) or not all(fits(x) for x in items):
            shape = f"a list of {kind.__name__}" if isinstance(default, tuple) else kind.__name__
            return f"{f.name} must be {shape}, got {v!r}"
        for x in items:
            if isinstance(check, tuple) and x not in check[1]:
                return f"{f.name} must be one of {', '.join(check[1])}, got {x!r}"
            if callable(check):
                try:
                    check(str(x))
                except argparse.ArgumentTypeError as exc:
                    return f"{f.name}: {exc}"
    return None


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
                              "torch_threads", "verbose", "address", "num_env_runners", "trust_checkpoint"})


def resumed_args(args: Any, run_dir: Path) -> Any:
    """``args`` with the saved run's settings (``run_dir/args.json``), except :data:`RESUME_OVERRIDES`."""
    saved = json.loads((Path(run_dir) / "args.json").read_text())
    names = {f.name for f in dataclasses.fields(args)}
    vals = {k: v for k, v in saved.items() if k in names and k not in RESUME_OVERRIDES}
    if "net_arch" in names:
        vals["net_arch"] = tuple(vals.get("net_arch", args.net_arch))
    return dataclasses.replace(args, **vals)


def latest_checkpoint(run_dir: Path) -> tuple[Path, Path | None] | None:
    """The newest ``(model.zip, vecnormalize.json or None)`` in ``run_dir/checkpoints`` or the final model.

    A run of an older version with only pickled statistics (``.pkl``) gives the ``.pkl`` path, which
    :func:`training.sb3.vec_env.load_vecnormalize` refuses with the command that converts it.
    """
    run_dir = Path(run_dir)

    def stats(path: Path) -> Path | None:
        for p in (path, path.with_suffix(".pkl")):
            if p.exists():
                return p
        return None

    best: tuple[int, Path] | None = None
    for p in (run_dir / "checkpoints").glob("*_steps.zip"):
        m = re.search(r"_(\d+)_steps\.zip$", p.name)
        if m and (best is None or int(m.group(1)) > best[0]):
            best = (int(m.group(1)), p)
    final = run_dir / "model.zip"
    if best is None and not final.exists():
        return None
    if best is None or (final.exists() and final.stat().st_mtime > best[1].stat().st_mtime):
        return final, stats(run_dir / "vecnormalize.json")
    steps, path = best
    prefix = path.name[: -len(f"_{steps}_steps.zip")]
    return path, stats(path.parent / f"{prefix}_vecnormalize_{steps}_steps.json")


def resume_checkpoint(run_dir: Path, *, trust_checkpoint: bool = False) -> tuple[Path, Path | None] | None:
    """:func:`latest_checkpoint` of a run to resume. Its model is an SB3 ``.zip``, which holds pickles: unless
    ``trust_checkpoint=True`` a run that has one is refused (:func:`training.trust.require_trust`), before
    anything is loaded."""
    ckpt = latest_checkpoint(run_dir)
    if ckpt is not None:
        require_trust(ckpt[0], "an SB3 model", trust_checkpoint)
    return ckpt
