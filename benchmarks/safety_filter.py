"""The safety filter's guarantee, tested as an outsider would: masked-random waypoints flown through it on every task.

    python benchmarks/safety_filter.py [--episodes 4] [--tasks paper-6uav towers-6uav ...] [--policy random]
        [--min-reach 0]
    python benchmarks/safety_filter.py --throughput [--sizes 16 64] [--samples 201 21] [--depth 3 1]
    python benchmarks/safety_filter.py --training [--sizes 256] [--steps 80] [--seed 0] [--min-reach 0]

Flies ``--policy`` (default masked-random waypoints) through :class:`covert_env.envs.safety_filter.ShieldedPolicy`
on each task's first ``--episodes`` held-out scenes (``reset(seed=s, options={"scene_seed": s})``, s from the
task's test seeds, as the suite does), in an env with 201 path samples per slot, and counts on the env's recorded
path:

* team-slots where two UAVs came closer than d_safe1 at some sample (eq. 2),
* team-slots where a UAV came closer than d_safe2 to a polytope top at some sample (eq. 3),

beside what the filter did (``FilterStats``: changed choices, widened to nodes outside the masks, backup plans
flown, uncertified moves, infeasible events). It prints one row per task and the totals, and exits with status 1
if a violation happened in a slot the filter did not report as infeasible (a silent failure).

``--training`` flies masked-random proposals through
:class:`~covert_env.envs.safety_filter.SafetyFilteredVectorEnv` as the ``3uav-suite`` recipe trains: its eight tasks
as one vector env of ``--sizes`` copies, training scenes, the kinematic mask, automatic resets, ``--steps`` slots
(the recipe's own batch and viability bar: ``--sizes 256 --min-reach 10``); it prints every team-slot with a
separation or terrain cost (its task, its slot, whether the filter reported it infeasible) and the totals.

``--throughput`` instead measures what the filter costs a learner: env-steps per CPU-second of the waypoint vector
env (``--task``, kinematic mask, masked-random actions, automatic resets) with and without
:class:`~covert_env.envs.safety_filter.SafetyFilteredVectorEnv`, in the same run, per B and filter setting.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time

import numpy as np
from tqdm import tqdm

import covert_env
from baselines.policies import make_policy
from covert_env.envs.safety_filter import FilterStats, SafetyFilteredVectorEnv, ShieldedPolicy
from covert_env.geometry.separation import team_separation
from covert_env.world.metrics import top_clearance
from covert_env.world.tasks import TASKS, get_task

COLUMNS = ("team_slots", "sep_slots", "terrain_slots", "min_sep", "changed", "widened", "backups", "uncertified",
           "infeasible", "silent")


def fly_task(task_name: str, episodes: int, policy: str = "random", samples: int = 201, shield: bool = True,
             min_reach: int = 0) -> dict:
    """One task's row: the counts above over its first ``episodes`` held-out scenes (``shield=False``: the policy
    flown without the filter, whose columns are then 0; ``min_reach``: the filter's viability rule, 0: off)."""
    task = get_task(task_name)
    env = covert_env.parallel_env(task=task.name, action_mode="waypoint", path_samples=samples)
    pol = ShieldedPolicy(make_policy(policy), min_reach=min_reach) if shield else _Unfiltered(make_policy(policy))
    row = dict.fromkeys(COLUMNS, 0)
    row["min_sep"] = np.inf
    c = env.config
    for seed in list(task.test_seeds)[:episodes]:
        obs, _ = env.reset(seed=seed, options={"scene_seed": seed})
        pol.reset(env, seed)
        before = len(pol.safety.stats.events)
        while env.agents:
            obs, *_ = env.step(pol.act(obs, env))
        path = env.engine.trajectory().path_xy[:, :, 1:]                                  # (T, U, P - 1, 2)
        sep = team_separation(path).min(axis=1)
        clear = top_clearance(path, c.altitude, env.scenario.terrain.highest_points).min(axis=(1, 2))
        bad = (sep < c.d_safe1) | (clear < c.d_safe2)
        reported = {slot for _, slot in pol.safety.stats.events[before:]}
        row["silent"] += len(set(np.flatnonzero(bad).tolist()) - reported)
        row["sep_slots"] += int((sep < c.d_safe1).sum())
        row["terrain_slots"] += int((clear < c.d_safe2).sum())
        row["min_sep"] = min(row["min_sep"], float(sep.min()))
    stats = pol.safety.stats.as_dict()
    for key in ("team_slots", "changed", "widened", "backups", "uncertified", "infeasible"):
        row[key] = stats[key]
    env.close()
    return row


class _Unfiltered:
    """A policy flown as it is, with the filter's counts at zero (the baseline of ``--no-filter``)."""

    def __init__(self, policy):
        self.policy, self.safety = policy, None
        self._events: list = []

    def reset(self, env, seed=None):
        self.policy.reset(env, seed)
        self.safety = self.safety or type("Stats", (), {"stats": FilterStats()})()

    def act(self, observations, env):
        self.safety.stats.team_slots += 1
        return self.policy.act(observations, env)


def throughput(b: int, task: str, seconds: float, **filter_kw) -> float:
    """Env-steps per CPU-second of ``b`` copies of ``task`` (kinematic mask, masked-random actions), through the
    filter with ``filter_kw`` (None: the raw env), after one warm-up step."""
    venv = covert_env.vector_env(num_envs=b, task=task, action_mode="waypoint", mask_mode="kinematic")
    if filter_kw.pop("filtered", True):
        venv = SafetyFilteredVectorEnv(venv, **filter_kw)
    venv.reset(seed=list(range(b)))
    rng = np.random.default_rng(0)

    def step():
        masks = venv.action_masks().astype(bool)
        venv.step(np.argmax(np.where(masks, rng.random(masks.shape), -1.0), axis=2))

    step()
    t0, n = time.process_time(), 0
    while time.process_time() - t0 < seconds:
        step()
        n += 1
    rate = b * n / (time.process_time() - t0)
    venv.close()
    return rate


def _training(args) -> int:
    from training.recipes import MAPPO_RECIPES

    tasks = MAPPO_RECIPES["3uav-suite"]["tasks"].split(",")
    print("| B | seed | steps | team-slots | separation | terrain | infeasible team-slots | of them after slot 4 |")
    print("|---|---|---|---|---|---|---|---|")
    for b in args.sizes:
        env = SafetyFilteredVectorEnv(covert_env.vector_env(num_envs=b, task=tasks, action_mode="waypoint",
                                                            mask_mode="kinematic"), min_reach=args.min_reach)
        env.reset(seed=args.seed)
        rng = np.random.default_rng(args.seed)
        sep = ter = infeasible = late = 0
        for t in range(args.steps):
            masks = env.action_masks().astype(bool)
            _, _, _, _, infos = env.step(np.argmax(np.where(masks, rng.random(masks.shape), -1.0), axis=2))
            last = {k: infos[k] for k in ("cost_separation", "cost_terrain", "slot")}
            if "final_info" in infos:                        # the ended copies' last slot, not their reset
                ended = infos["_final_info"]
                for k in last:
                    last[k] = np.where(ended[:, None], infos["final_info"][k], last[k])
            bad = (last["cost_separation"] > 0) | (last["cost_terrain"] > 0)
            for c in np.flatnonzero(bad.any(axis=1)):
                print(f"  step {t}: copy {c} ({tasks[env.task_mix.copy_task[c]]}), slot {last['slot'][c, 0]}, "
                      f"infeasible {bool(infos['shield_infeasible'][c].any())}", file=sys.stderr)
            sep += int((last["cost_separation"] > 0).sum())
            ter += int((last["cost_terrain"] > 0).sum())
            hit = infos["shield_infeasible"].any(axis=1)
            infeasible += int(hit.sum())
            late += int((hit & (last["slot"][:, 0] > 4)).sum())
        print(f"| {b} | {args.seed} | {args.steps} | {b * args.steps:,} | {sep} | {ter} | {infeasible} | {late} |",
              flush=True)
        env.close()
    return 0


def _throughput(args) -> int:
    print("| B | filter | env-steps per CPU-second | / raw env |")
    print("|---|---|---|---|")
    for b in args.sizes:
        raw = throughput(b, args.task, args.seconds, filtered=False)
        print(f"| {b} | none (raw env) | {raw:,.0f} | 1.00 |", flush=True)
        for samples in args.filter_samples:
            for depth in args.depth:
                rate = throughput(b, args.task, args.seconds, samples=samples, depth=depth)
                print(f"| {b} | samples {samples}, depth {depth} | {rate:,.0f} | {rate / raw:.2f} |", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), help="suite tasks (default: all 36)")
    parser.add_argument("--episodes", type=int, default=4, help="held-out scenes per task (default 4: 10,080 "
                        "team-slots over the 36 tasks)")
    parser.add_argument("--policy", default="random", help="a built-in waypoint policy (default random: masked)")
    parser.add_argument("--samples", type=int, default=201, help="path samples per slot of the env (default 201)")
    parser.add_argument("--no-filter", action="store_true", help="fly the policy without the filter (the baseline)")
    parser.add_argument("--throughput", action="store_true", help="measure env-steps/s with and without the filter")
    parser.add_argument("--task", default="paper-3uav", help="--throughput's task (default paper-3uav)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 64], help="--throughput's B (default 16 64)")
    parser.add_argument("--filter-samples", type=int, nargs="+", default=[201, 21],
                        help="--throughput's filter samples per slot (default 201 21)")
    parser.add_argument("--depth", type=int, nargs="+", default=[3, 1], help="--throughput's plan depths (default 3 1)")
    parser.add_argument("--seconds", type=float, default=5.0, help="--throughput's CPU-seconds per row (default 5)")
    parser.add_argument("--training", action="store_true", help="masked random through the filter as the 3uav-suite "
                        "recipe trains (training scenes, kinematic mask, one vector env of its tasks)")
    parser.add_argument("--steps", type=int, default=80, help="--training's slots (default 80)")
    parser.add_argument("--seed", type=int, default=0, help="--training's reset seed (default 0)")
    parser.add_argument("--min-reach", type=int, default=0, help="the filter's viability rule (default 0: off)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    print("command:", shlex.join(["python", "benchmarks/safety_filter.py", *(argv or sys.argv[1:])]))
    if args.throughput:
        return _throughput(args)
    if args.training:
        if args.sizes == [16, 64]:
            args.sizes = [256]
        return _training(args)
    print("| task | " + " | ".join(COLUMNS) + " |")
    print("|---" * (len(COLUMNS) + 1) + "|")
    total = dict.fromkeys(COLUMNS, 0)
    total["min_sep"] = np.inf
    for name in tqdm(args.tasks, desc="tasks", disable=args.no_progress, file=sys.stderr):
        row = fly_task(name, args.episodes, args.policy, args.samples, shield=not args.no_filter,
                       min_reach=args.min_reach)
        print(f"| {name} | " + " | ".join(f"{row[k]:.2f}" if k == "min_sep" else str(row[k]) for k in COLUMNS) + " |",
              flush=True)
        for k in COLUMNS:
            total[k] = min(total[k], row[k]) if k == "min_sep" else total[k] + row[k]
    print("| **total** | " + " | ".join(f"{total[k]:.2f}" if k == "min_sep" else str(total[k]) for k in COLUMNS)
          + " |")
    return 1 if total["silent"] and not args.no_filter else 0


if __name__ == "__main__":
    sys.exit(main())
