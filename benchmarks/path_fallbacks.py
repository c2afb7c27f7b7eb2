"""Where the path-checked DP team (``dp-path``) still loses LoS along its paths: per plan status of each move.

    python benchmarks/path_fallbacks.py [--task downtown-3uav] [--scenes 5] [--policy dp-path]

Flies the policy on the task's first ``--scenes`` held-out scenes (the suite's cells), records the status of every
UAV's first planned move (``ok``, ``truncated``, ``fallback``: no reachable node keeps the constraints, or
``safety``: the team's separation layer moved it; see ``baselines.dp.plan.DPPlan``), and tallies the UAV-slots whose
flown path has blocked LoS (the metric ``blocked_path_share`` > 0, :mod:`covert_env.world.metrics`) by that status. The
planner's own check covers every sample the metric takes (its 21 per slot contain the env's 11), so a planned move
that loses LoS would be a bug; fallbacks are the planner's best effort where no allowed move exists.
"""

from __future__ import annotations

import argparse
import collections
import shlex
import sys

from tqdm import tqdm

import covert_env
from baselines.policies import make_policy
from covert_env.world.metrics import slot_quantities
from covert_env.world.tasks import TASKS, get_task


def tally(task_name: str, scenes: int, policy: str = "dp-path", progress: bool = True) -> dict:
    """{status: [UAV-slots, UAV-slots with blocked LoS along the path, sum of their blocked shares]} and examples."""
    task = get_task(task_name)
    env = covert_env.parallel_env(task=task.name, action_mode="waypoint")
    pol = make_policy(policy)
    out: dict = collections.defaultdict(lambda: [0, 0, 0.0])
    examples = []
    for seed in tqdm(list(task.test_seeds)[:scenes], desc=f"{policy} on {task.name}", disable=not progress):
        obs, _ = env.reset(seed=seed, options={"scene_seed": seed})
        pol.reset(env, seed)
        status = []
        while env.agents:
            act = pol.act(obs, env)
            status.append([p.status for p in pol.last_plan.plans])
            obs, *_ = env.step(act)
        q = slot_quantities(env.engine.trajectory(), env.engine.terrain, env.config)
        for t, row in enumerate(status):
            for u, st in enumerate(row):
                share = float(q.blocked_path_share[t, u])
                out[st][0] += 1
                if share > 0:
                    out[st][1] += 1
                    out[st][2] += share
                    examples.append((seed, t, u, st, round(share, 2)))
    return {"by_status": dict(out), "examples": examples}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="downtown-3uav", choices=sorted(TASKS))
    p.add_argument("--scenes", type=int, default=5, help="held-out scenes (the suite's default: 5)")
    p.add_argument("--policy", default="dp-path", help="a planner spec of baselines.policies (dp, dp-path, ...)")
    a = p.parse_args(argv)
    if a.scenes < 1:
        p.error(f"--scenes {a.scenes}: must be >= 1")
    print("command:", shlex.join(sys.orig_argv if argv is None else [sys.executable, __file__, *argv]))
    res = tally(a.task, a.scenes, a.policy)
    n = sum(v[0] for v in res["by_status"].values())
    lost = sum(v[1] for v in res["by_status"].values())
    share = sum(v[2] for v in res["by_status"].values())
    print(f"{n} UAV-slots; blocked LoS along the path in {lost} ({lost / n:.2%}); share of the path {share / n:.2%}")
    print(f"{'status':<10} {'UAV-slots':>9} {'blocked':>8} {'share sum':>9}")
    for st, (k, b, s) in sorted(res["by_status"].items()):
        print(f"{st:<10} {k:>9} {b:>8} {s:>9.2f}")
    print("(scene, slot, UAV, status, share):", res["examples"][:12])


if __name__ == "__main__":
    main()
