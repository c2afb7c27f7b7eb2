"""What the planner's look-ahead is worth: the DP team with horizons 1..N beside learned teams, reward by term.

    python benchmarks/dp_horizon.py [--tasks paper-3uav downtown-3uav ...] [--scenes 3] [--horizons 1 2 3 4 5]
                                    [--known-slots 1] [--learned mappo:runs/<run> pretrained:mappo] [--jobs 2]
                                    [--figure out.png]

Each policy flies the first ``--scenes`` held-out scenes of every task (the suite's scenes, seeds
``Task.test_seeds``). The DP team plans over the first h slots of the target's predictions
(``DPPolicy(horizon=h)``); h = ``config.horizon`` (5) is the paper's planner. A learned team acts as the harness
runs it (``covert_env.evaluation.specs.load_policy``: a harness spec, the card's mask and shield). The table gives
the mean episode reward per UAV and its terms (``infos[agent]["reward_<term>"]``, docs/decisions/environments.md
"Environment rewards"): the disguise bonus, the path cost and each penalty. The horizon at which the planner's
reward passes a learned team's says how far ahead the team acts as if it planned.

``--known-slots k`` adds the DP team at the longest of ``--horizons`` that reads only the first k slots of the
target's predictions and extrapolates the rest at a constant speed and turn rate (``DPPolicy(known_slots=k)``):
with k = 1 it knows the target's future as far as the default observation shows it, so its reward against the
full planner's separates what the target's path is worth from what planning several slots ahead is worth (tasks
without prediction error only: the planner's possible targets lie on the road).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

import covert_env
from covert_env.command_line import ordered_results
from covert_env.world.tasks import get_task

TERMS = ("disguise", "path", "los", "los_path", "zone", "separation", "terrain")
CORE = ("sparse-3uav", "paper-3uav", "winding-3uav", "dense-3uav", "downtown-3uav", "towers-3uav",
        "paper-3uav-deviating", "downtown-3uav-deviating")


def episode_terms(spec: str, task: str, seed: int) -> dict:
    """One episode's reward per UAV and its terms, summed over slots and averaged over the team."""
    from baselines.policies import DPPolicy
    from covert_env.evaluation.evaluate import load_policy

    if spec.startswith("dp-h"):
        h, _, known = spec.removeprefix("dp-h").partition("-k")
        pol = DPPolicy(horizon=int(h), known_slots=int(known) if known else None)
        settings = {"action_mode": "waypoint"}
    else:
        pol, settings = load_policy(spec, get_task(task).n_uavs)
        settings = {k: v for k, v in settings.items() if k != "n_uavs"}
    env = covert_env.parallel_env(task=task, **settings)
    obs, _ = env.reset(seed=seed, options={"scene_seed": seed})
    pol.reset(env, seed)
    n = len(env.possible_agents)
    out = dict.fromkeys(("reward", *TERMS), 0.0)
    while env.agents:
        obs, rew, _, _, infos = env.step(pol.act(obs, env))
        for a in rew:
            out["reward"] += rew[a] / n
            for t in TERMS:
                out[t] += infos[a][f"reward_{t}"] / n
    env.close()
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", nargs="+", default=list(CORE), help="suite tasks (default: the eight 3-UAV core tasks)")
    p.add_argument("--scenes", type=int, default=3, help="held-out scenes per task (default 3)")
    p.add_argument("--horizons", nargs="+", type=int, default=[1, 2, 3, 4, 5], help="DP horizons (1..config.horizon)")
    p.add_argument("--known-slots", nargs="*", type=int, default=[],
                   help="also the DP team at the longest horizon reading only this many slots of the target's "
                        "predictions, extrapolating the rest (tasks without prediction error)")
    p.add_argument("--learned", nargs="*", default=[],
                   help="learned teams, as the harness names them: mappo:RUN_FOLDER or pretrained:NAME")
    p.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    p.add_argument("--figure", default=None, help="also draw the reward against the horizon to this PNG")
    a = p.parse_args(argv)
    for t in a.tasks:
        try:
            get_task(t)
        except (KeyError, ValueError) as exc:
            p.error(f"--tasks: {exc}")
    if not 1 <= a.scenes <= 20:
        p.error(f"--scenes {a.scenes}: must be in [1, 20] (the suite's held-out scenes per task)")
    for t in a.tasks:
        n = get_task(t).config().horizon
        if any(not 1 <= h <= n for h in a.horizons):
            p.error(f"--horizons {a.horizons}: each must be in [1, {n}] (the config.horizon of task {t})")
    for k in a.known_slots:
        if not 1 <= k < max(a.horizons):
            p.error(f"--known-slots {k}: must be in [1, {max(a.horizons) - 1}] (fewer than the longest of --horizons)")
    deviating = [t for t in a.tasks if get_task(t).config().prediction_error > 0]
    if a.known_slots and deviating:
        p.error(f"--known-slots needs tasks without prediction error, got {deviating} (the planner's possible "
                "targets lie on the road; an extrapolated path leaves it)")
    if a.jobs < 1:
        p.error(f"--jobs {a.jobs}: must be >= 1")
    from covert_env.evaluation.evaluate import load_policy

    for spec in a.learned:                      # a wrong spec, file or team size fails here, before any episode
        for t in {get_task(t).n_uavs: t for t in a.tasks}.values():        # one task per team size
            try:
                load_policy(spec, get_task(t).n_uavs)
            except ValueError as exc:
                p.error(f"--learned {spec} on task {t} ({get_task(t).n_uavs} UAVs): {exc}")
    if a.figure and not Path(a.figure).resolve().parent.is_dir():
        p.error(f"--figure {a.figure}: no such folder {Path(a.figure).resolve().parent}")
    specs = list(dict.fromkeys([f"dp-h{h}" for h in a.horizons]
                               + [f"dp-h{max(a.horizons)}-k{k}" for k in a.known_slots] + list(a.learned)))
    work = [(s, t, get_task(t).test_seeds.start + i) for s in specs for t in a.tasks for i in range(a.scenes)]
    t0 = time.perf_counter()
    from tqdm.auto import tqdm

    bar = tqdm(total=len(work), desc="episodes", file=sys.stderr, mininterval=5.0)
    rows = ordered_results(episode_terms, work, a.jobs, bar.update)
    bar.close()
    secs = time.perf_counter() - t0
    print(f"$ python benchmarks/dp_horizon.py {shlex.join(argv if argv is not None else sys.argv[1:])}")
    print(f"{len(a.tasks)} tasks x {a.scenes} held-out scenes, {secs:.0f} s on {a.jobs} processes\n")
    print("| policy | reward per UAV | " + " | ".join(TERMS) + " |")
    print("|---|---|" + "---|" * len(TERMS))
    means = {}
    for s in specs:
        mine = [r for r, w in zip(rows, work, strict=True) if w[0] == s]
        mean = {k: float(np.mean([r[k] for r in mine])) for k in mine[0]}
        h, _, known = s.removeprefix("dp-h").partition("-k")
        name = (s if not s.startswith("dp-h") else f"DP, horizon {h}" if not known
                else f"DP, horizon {h}, the target's path known for {known} slot(s)")
        print(f"| {name} | {mean['reward']:.1f} | " + " | ".join(f"{mean[t]:.2f}" for t in TERMS) + " |")
        means[s] = mean
    if a.figure:
        figure(means, a.horizons, a.figure)
    return 0


def figure(means: dict, horizons: list[int], path: str) -> None:
    """The DP team's reward per UAV against its horizon, the learned teams' as horizontal lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=110)
    ax.plot(horizons, [means[f"dp-h{h}"]["reward"] for h in horizons], "o-", color="k", label="DP team")
    known = [(s, m) for s, m in means.items() if s.startswith("dp-h") and "-k" in s]
    for j, (s, m) in enumerate(known):
        k = s.partition("-k")[2]
        ax.plot([max(horizons)], [m["reward"]], "sD^v"[j % 4], color=str(0.35 + 0.4 * j / max(len(known), 1)),
                ms=7, label=f"DP team, horizon {max(horizons)}, the target known {k} slot(s) ahead")
    for i, (s, m) in enumerate((s, m) for s, m in means.items() if not s.startswith("dp-h")):
        ax.axhline(m["reward"], ls="--", color=f"C{i}", label=s)
    ax.set_xlabel("DP horizon (slots planned ahead; the paper: 5)")
    ax.set_ylabel("episode reward per UAV")
    ax.set_xticks(horizons)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
