"""The command line of ``covert-env reproduce``: its flags, their checks and the job that writes the outputs."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

from baselines.prediction_study import write_study
from baselines.reproduce.figures import PAPER_FIGURE_KINDS, PAPER_FIGURES, write_figures
from baselines.reproduce.report import aggregate, metrics_markdown
from baselines.reproduce.runs import QUICK_POOL, QUICK_SCENES, QUICK_SLOTS, most_shadowed_scenes, run_all, specs_for
from baselines.reproduce.sensitivity import SENSITIVITY_SCENES, SENSITIVITY_SLOTS, sensitivity
from covert_env.command_line import (
    MAX_JOBS,
    MAX_SCENES,
    UsageError,
    int_range,
    load_config,
    output_dir,
    positive_int,
    run_main,
)
from covert_env.world.config import Config
from covert_env.world.families import FAMILIES, family_config


def output_files(args: argparse.Namespace) -> tuple[str, ...]:
    """The files :func:`main` writes into ``--out`` with these arguments (checked before the runs: a folder in
    the place of one is an error)."""
    names = ["metrics.json", "metrics.md"]
    if not args.no_figures:
        names += [f"fig{no:02d}_{kind}_{u}uav.png" for u, nos in PAPER_FIGURES.items()
                  for kind, no in zip(PAPER_FIGURE_KINDS, nos, strict=True)]
        names += ["fig_heldout.png", "fig_los_between_slots.png"]
    if args.sensitivity:
        names.append("sensitivity.md")
    if args.prediction_study:
        names += ["prediction_study.md", "prediction_study.json"] + ([] if args.no_figures else ["fig_prediction.png"])
    return tuple(names)


def build_parser(prog: str = "covert-env reproduce") -> argparse.ArgumentParser:

    p = argparse.ArgumentParser(prog=prog, description=sys.modules[__package__].__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--quick", action="store_true",
                   help=f"small version ({QUICK_SLOTS} slots, {QUICK_SCENES} held-out scenes) where the paper's "
                        f"effects show: the held-out scenes are the ones of the first {QUICK_POOL} whose zone is "
                        "most in shadow")
    p.add_argument("--scenes", type=int_range(0, MAX_SCENES), default=None,
                   help=f"number of held-out scenes, in [0, {MAX_SCENES}] (default: 20; with --quick "
                        f"{QUICK_SCENES}, at most {QUICK_POOL})")
    p.add_argument("--slots", type=positive_int, default=None,
                   help="slots per episode, in [1, n_slots] (default: n_slots of the config, 70 with the paper's "
                        f"parameters; with --quick {QUICK_SLOTS})")
    p.add_argument("--jobs", type=int_range(1, MAX_JOBS), default=None,
                   help=f"worker processes, in [1, {MAX_JOBS}] (default: the number of CPUs, at most 2)")
    p.add_argument("--path-uavs", type=int, nargs="*", default=[1], choices=[1, 3],
                   help="team sizes of the check_path runs on the held-out scenes (default: 1; '1 3' adds the "
                        "3-UAV runs, about 40%% more time; none to skip)")
    p.add_argument("--heading", choices=("inherited", "binned"), default="inherited",
                   help="DP heading variant: inherited is the paper's (default: inherited)")
    p.add_argument("--config", default=None, help="a Config JSON file (default: the paper's parameters)")
    p.add_argument("--family", choices=list(FAMILIES), default=None,
                   help="scene family (covert_env.world.families) of the held-out scenes; the paper scene stays the "
                        "paper's (default: the config's generator fields, which are the paper family's unless "
                        "--config changes them)")
    p.add_argument("--prediction-study", action="store_true",
                   help="also run baselines/prediction_study.py (prediction error b = 4 m: r_u = 0 vs the eroded "
                        "zone of eq. 5 with and without widened shadows, 3 UAVs; blocked LoS and zone violations "
                        "against the true target with 95%% CIs): prediction_study.md and .json in --out")
    p.add_argument("--sensitivity", action="store_true",
                   help="also write sensitivity.md: aware vs blind, 1 UAV, on the "
                        f"{SENSITIVITY_SCENES} most shadowed held-out scenes, {SENSITIVITY_SLOTS} slots, varying "
                        "grid step, r_u, h_min and target speed one at a time")
    p.add_argument("--no-figures", action="store_true", help="skip the figures (metrics only)")
    return p


def main(argv: list[str] | None = None, prog: str = "covert-env reproduce") -> int:

    parser = build_parser(prog)
    args = parser.parse_args(argv)
    return run_main(parser, lambda: _main(args))


def _main(args: argparse.Namespace) -> int:

    config = load_config(args.config) if args.config is not None else Config()
    n_scenes = args.scenes if args.scenes is not None else (QUICK_SCENES if args.quick else 20)
    n_slots = args.slots if args.slots is not None else (min(QUICK_SLOTS, config.n_slots) if args.quick
                                                          else config.n_slots)
    if not 1 <= n_slots <= config.n_slots:
        raise UsageError(f"--slots must be in [1, {config.n_slots}] (n_slots of the config), got {n_slots}")
    if args.quick and n_scenes > QUICK_POOL:
        raise UsageError(f"--scenes must be in [0, {QUICK_POOL}] with --quick (chosen among the first "
                         f"{QUICK_POOL} held-out scenes), got {n_scenes}")
    jobs = args.jobs if args.jobs is not None else min(os.cpu_count() or 1, 2)
    out = output_dir(args.out, files=output_files(args))
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    if args.family is not None:
        try:
            family_config(args.family, config)
        except ValueError as exc:
            raise UsageError(f"--family {args.family}: {exc}") from None
    seeds = (most_shadowed_scenes(n_scenes, n_slots, config, family=args.family) if args.quick and n_scenes
             else n_scenes)
    choose_s = time.perf_counter() - t0
    specs = specs_for(seeds, n_slots, args.heading, path_uavs=tuple(args.path_uavs), family=args.family)
    results = run_all(specs, config, jobs)
    runs_s = time.perf_counter() - t0 - choose_s
    records = [_finite(r) for s in specs for r in results[(s.kind, s.seed, s.n_uavs, s.method)]["records"]]
    (out / "metrics.json").write_text(json.dumps({"config": config.to_dict(), "records": records}, indent=1,
                                                 default=_json_default) + "\n")
    t1 = time.perf_counter()
    figures = [] if args.no_figures else write_figures(out, results, config, jobs)
    figures_s = time.perf_counter() - t1
    rows = aggregate(records)
    elapsed = time.perf_counter() - t0
    timing = {"jobs": jobs, "runs_s": runs_s, "figures_s": figures_s, "choose_s": choose_s,
              "planner_s": sum(r["timing"]["rollout_s"] for r in results.values()),
              "metrics_s": sum(r["timing"]["metrics_s"] for r in results.values())}
    (out / "metrics.md").write_text(metrics_markdown(rows, records, config, elapsed, args.quick, figures,
                                              (load0, os.getloadavg()[0]), timing))
    print(f"wrote {out}/metrics.json ({len(records)} records), metrics.md and {len(figures)} figures "
          f"in {elapsed:.0f} s (runs {runs_s:.0f} s: rollouts {timing['planner_s']:.0f} s and metrics "
          f"{timing['metrics_s']:.1f} s summed over {jobs} worker(s); figures {figures_s:.0f} s)", file=sys.stderr)
    if args.sensitivity:
        t2 = time.perf_counter()
        text = sensitivity(config, jobs, heading=args.heading)
        (out / "sensitivity.md").write_text(text)
        print(f"wrote {out}/sensitivity.md in {time.perf_counter() - t2:.0f} s", file=sys.stderr)
    print((out / "metrics.md").read_text().split("## The paper's claims")[1].split("Columns:")[0].strip())
    if args.prediction_study:
        t3 = time.perf_counter()
        print(write_study(out, config, quick=args.quick, jobs=jobs, figure=not args.no_figures))
        print(f"wrote {out}/prediction_study.md and .json in {time.perf_counter() - t3:.0f} s", file=sys.stderr)
    return 0


def _finite(rec: dict) -> dict:
    """JSON has no inf/NaN: such values (e.g. min_separation of a lone UAV) become null."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in rec.items()}


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        v = float(o)
        return v if math.isfinite(v) else None
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


