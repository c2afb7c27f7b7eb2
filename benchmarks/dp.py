"""Timing of the DP planner (baselines.dp): team replanning time and transition throughput.

Run ``python benchmarks/dp.py`` (``--help`` for options). For every grid step (1, 2, 5 m), team size
(1, 3 UAVs) and heading variant (the paper's inherited heading; binned with B = 16), a receding-horizon
rollout of the paper scenario (shadow-aware, decentralised negotiation included) is flown for
``--slots`` slots and every team replan (:meth:`DPTeamPlanner.plan_engine`: all UAVs' plans plus the
negotiation) is timed. Printed per row:

* team replan wall time, median and p90 (ms), and the CPU time median (less sensitive to other load);
* transitions per second: transitions bounded through the manoeuvre table plus manoeuvres solved
  exactly, divided by planning time; and the exact solves per replan on their own;
* negotiation rounds per replan.

The first replan of a run (cold caches: the lookup table, all stage pairs) is reported separately; the
others reuse N - 1 stages. The machine's load average is printed: timings on a shared machine are upper
bounds.

Then (``--compare REV``, default b549364, a planner without the speed-ups of this one; ``--compare ''`` skips
it): the same rollouts (2 m grid; 1 and 3 UAVs on the paper scene, 5 on random scene 11; ``--compare-uavs``
adds 8, slow on the old side: its safety layer tries every priority order) with this checkout and with REV's
code (``git archive``), each in a fresh subprocess, alternating, ``--reps`` times; the CPU-time ratio old /
new is the figure to quote on a shared machine (both sides suffer the same load), the wall-time ratio the one
for ``--threads 2`` (the dense bound on two threads, ``COVERT_DP_THREADS``) on idle cores. Then team slot
times for U = 5 and 8 with the negotiation's work counters, and (``--profile``) where a 3-UAV replan's time
goes. ``--optimality`` adds the small-lattice comparison with the brute force (tests/test_dp.py).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from baselines.dp import DPPlanner, DPTeamPlanner, brute_force_plan, evaluate_plan  # noqa: E402
from covert_env import Config, Engine, Scenario  # noqa: E402
from covert_env.geometry.zone import to_world, zone_lattice  # noqa: E402


def bench(grid: float, n_uavs: int, heading: str, slots: int, bins: int = 16) -> dict:
    cfg = Config(grid_step=grid, n_uavs=n_uavs)
    sc = Scenario.paper(cfg)
    planner = DPPlanner(cfg, sc.terrain, heading=heading, heading_bins=bins)
    team = DPTeamPlanner(planner)
    eng = Engine(sc)
    wall, cpu, trans, exact, rounds = [], [], [], [], []
    for _ in range(slots):
        c0 = time.process_time()
        plan = team.plan_engine(eng)
        cpu.append(time.process_time() - c0)
        wall.append(plan.time)
        trans.append(plan.n_bounded + plan.n_exact)
        exact.append(plan.n_exact)
        rounds.append(plan.rounds)
        eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
    w = np.array(wall[1:]) * 1e3
    return {"grid": grid, "nodes": len(planner.lattice), "U": n_uavs,
            "variant": heading if heading == "inherited" else f"binned B={bins}",
            "cold_ms": wall[0] * 1e3, "median_ms": float(np.median(w)), "p90_ms": float(np.percentile(w, 90)),
            "cpu_median_ms": float(np.median(cpu[1:]) * 1e3),
            "trans_per_s": float(np.sum(trans[1:]) / np.sum(wall[1:])),
            "exact_per_replan": float(np.median(exact[1:])), "rounds": float(np.mean(rounds[1:]))}


#: One rollout's replan times, run in a subprocess against whichever code PYTHONPATH points to (the old
#: planner is a module, baselines/dp.py; the new one a package: the same public API).
ROLLOUT_WORKER = """
import json, sys, time
from baselines.dp import DPPlanner, DPTeamPlanner
from covert_env import Config, Engine, Scenario
u, slots, seed = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
cfg = Config(grid_step=2.0, n_uavs=u)
sc = Scenario.paper(cfg) if seed < 0 else Scenario.random(seed, cfg)
team = DPTeamPlanner(DPPlanner(cfg, sc.terrain))
eng = Engine(sc)
cpu, wall, nodes = [], [], []
for _ in range(slots):
    c0, w0 = time.process_time(), time.perf_counter()
    plan = team.plan_engine(eng)
    cpu.append(time.process_time() - c0)
    wall.append(time.perf_counter() - w0)
    nodes.append([int(x) for x in plan.nodes])
    eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
print(json.dumps(dict(cpu=cpu[1:], wall=wall[1:], nodes=nodes, work=getattr(plan, "work", {}))))
"""


def _worker(path: str, u: int, slots: int, seed: int = -1, threads: int = 1) -> dict:
    env = dict(os.environ, PYTHONPATH=path, OMP_NUM_THREADS="1", COVERT_DP_THREADS=str(threads))
    out = subprocess.run([sys.executable, "-c", ROLLOUT_WORKER, str(u), str(slots), str(seed)], env=env,
                         capture_output=True, text=True, check=True, cwd=tempfile.gettempdir())
    return json.loads(out.stdout.strip().splitlines()[-1])


#: Team sizes of the same-run comparison and their scenes: the paper scene has 3 UAVs' starts; U = 5 and
#: 8 fly random scene 11 (as :func:`large_teams`).
COMPARE_SCENES = {1: -1, 3: -1, 5: 11, 8: 11}


def compare(rev: str, slots: int, reps: int, sizes=(1, 3, 5), threads: int = 1) -> None:
    """Replan CPU / wall times of this checkout and of ``rev`` in the same run, alternating subprocesses.

    ``threads``: COVERT_DP_THREADS of this checkout's runs (the old planner has one thread).
    """
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as old:
        archive = subprocess.run(["git", "-C", str(root), "archive", rev], capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", old], input=archive.stdout, check=True)
        paper = [u for u in sizes if COMPARE_SCENES.get(u, 11) < 0]
        rand = [u for u in sizes if COMPARE_SCENES.get(u, 11) >= 0]
        scenes = ([f"U = {paper}: paper scene, {slots - 1} replans"] if paper else []) + (
            [f"U = {rand}: random scene 11, {max(4, slots // 2)} replans"] if rand else [])
        print(f"\nSame-run comparison with {rev} (2 m grid; {'; '.join(scenes)}; x {reps} alternating runs each; "
              f"ms per team replan, negotiation included; new: {threads} bound thread(s)):")
        print(f"  {'U':>2} {'new cpu med':>11} {'p90':>6} {'wall med':>9} {'p90':>6} | {'old cpu med':>11} {'p90':>6} "
              f"{'wall med':>9} {'p90':>6} | {'old/new cpu':>11} {'wall':>6} {'same plans':>10}")
        for u in sizes:
            seed = COMPARE_SCENES.get(u, 11)
            n = slots if seed < 0 else max(4, slots // 2) + 1
            runs = {"new": [], "old": []}
            for _ in range(reps):
                runs["new"].append(_worker(str(root), u, n, seed, threads))
                runs["old"].append(_worker(old, u, n, seed))
            fig = {}
            for k, rs in runs.items():
                cpu = np.concatenate([r["cpu"] for r in rs]) * 1e3
                wall = np.concatenate([r["wall"] for r in rs]) * 1e3
                fig[k] = (np.median(cpu), np.percentile(cpu, 90), np.median(wall), np.percentile(wall, 90))
            same = all(a["nodes"] == b["nodes"] for a, b in zip(runs["new"], runs["old"], strict=True))
            nw, o = fig["new"], fig["old"]
            print(f"  {u:2d} {nw[0]:11.1f} {nw[1]:6.1f} {nw[2]:9.1f} {nw[3]:6.1f} | {o[0]:11.1f} {o[1]:6.1f} "
                  f"{o[2]:9.1f} {o[3]:6.1f} | {o[0] / nw[0]:11.2f} {o[2] / nw[2]:6.2f} {str(same):>10}", flush=True)


def large_teams(sizes, slots: int, seed: int = 11, threads: int = 1) -> None:
    """Team slot times (CPU and wall) for larger U on a random scene, with the negotiation's work."""
    root = str(Path(__file__).resolve().parents[1])
    print(f"\nLarger teams (random scene {seed}, 2 m grid, {slots - 1} slots; ms per team slot):")
    for u in sizes:
        r = _worker(root, u, slots, seed, threads)
        cpu, wall = np.array(r["cpu"]) * 1e3, np.array(r["wall"]) * 1e3
        print(f"  U = {u}: cpu median {np.median(cpu):7.1f}, p90 {np.percentile(cpu, 90):7.1f}, max {cpu.max():7.1f}; "
              f"wall median {np.median(wall):7.1f}, max {wall.max():7.1f}; last slot's work {r['work']}", flush=True)


def profile(slots: int) -> None:
    """Where a 3-UAV team replan's CPU time goes (paper scene, 2 m grid), by planner stage."""
    import baselines.dp.recursion as recursion
    import baselines.dp.team as team_mod
    import baselines.dp.transitions as transitions
    from baselines.dp.lattice import StageCache

    acc = collections.Counter()

    def timed(owner, name, label):
        f = getattr(owner, name)

        def g(*a, **k):
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                acc[label] += time.process_time() - t
        setattr(owner, name, g)
        return owner, name, f

    patched = [timed(recursion.ForwardRecursion, "_node_bounds", "table bounds (dense, per UAV) + round 0"),
               timed(recursion, "first_round", "round 0 candidates (in the bound chunks)"),
               timed(recursion, "select_per_node", "selection incl. exact solves"),
               timed(transitions, "solve_manoeuvre", "exact manoeuvre solves (eq. 29)"),
               timed(transitions, "separated", "negotiation: separation along paths"),
               timed(transitions.SolvedTransitions, "winners", "recursion: winners per node"),
               timed(recursion.ForwardRecursion, "first_layer", "first layer (eq. 19)"),
               timed(StageCache, "pair", "stage pairs (cached, 1 new per slot)"),
               timed(StageCache, "stage", "stages + LoS of lattice nodes (cached)"),
               timed(team_mod.DPTeamPlanner, "conflicts", "negotiation: conflict checks"),
               timed(team_mod, "secure_first_moves", "safety layer")]
    try:
        cfg = Config(grid_step=2.0, n_uavs=3)
        sc = Scenario.paper(cfg)
        team = DPTeamPlanner(DPPlanner(cfg, sc.terrain))
        eng = Engine(sc)
        total = 0.0
        for s in range(slots):
            if s == 1:
                acc.clear()
            c0 = time.process_time()
            plan = team.plan_engine(eng)
            total += (time.process_time() - c0) if s else 0.0
            eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
    finally:
        for owner, name, f in patched:
            setattr(owner, name, f)
    n = slots - 1
    print(f"\nWhere a 3-UAV team replan's CPU time goes (paper scene, 2 m grid, mean of {n}; nested rows indented):")
    print(f"  {'total':44s} {total / n * 1e3:6.1f} ms")
    for label, v in sorted(acc.items(), key=lambda x: -x[1]):
        indent = "    " if label.startswith(("exact", "negotiation: sep", "round 0")) else "  "
        print(f"{indent}{label:{46 - len(indent)}s} {v / n * 1e3:6.1f} ms")


def optimality(n: int = 200) -> None:
    """The brute-force comparison of tests/test_dp.py on more instances (N = 3, <= 12 nodes per stage)."""
    cfg = Config(grid_step=14.0, horizon=3)
    lat = zone_lattice(cfg)
    rng = np.random.default_rng(7)
    scenes = [Scenario.random(1_000_000 + i, cfg) for i in range(10)]
    gaps = {"inherited": [], 4: [], 16: [], 64: []}
    count = 0
    while count < n:
        sc = scenes[int(rng.integers(len(scenes)))]
        k = int(rng.integers(0, 60))
        ks = np.arange(k, k + cfg.horizon + 1)
        tq, tp = sc.track.position(ks), np.asarray(sc.track.heading(ks))
        p = to_world(lat[[rng.integers(len(lat))]], tq[0, :2], tp[0])[0] + rng.normal(0, 4.0, 2)
        th = float(rng.uniform(0, 2 * np.pi))
        pl = DPPlanner(cfg, sc.terrain)
        allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, cfg.horizon + 1)])
        jstar, _ = brute_force_plan(cfg, p, th, tq, tp, allowed)
        if not np.isfinite(jstar):
            continue
        count += 1
        for key in gaps:
            kw = {"heading": "inherited"} if key == "inherited" else {"heading": "binned", "heading_bins": key}
            plan = DPPlanner(cfg, sc.terrain, **kw).plan(p, th, tq, tp)
            cost = evaluate_plan(cfg, p, th, tq, tp, plan.waypoints) if plan.depth == cfg.horizon else np.inf
            gaps[key].append((cost - jstar) / abs(jstar))
    print(f"\nOptimality vs brute force ({n} instances, N = 3, {len(lat)} nodes per stage, continuous heading):")
    for key, g in gaps.items():
        g = np.array(g)
        miss = g > 1e-9
        name = "inherited (paper)" if key == "inherited" else f"binned B={key}"
        finite = g[np.isfinite(g) & miss]
        mean, worst = (finite.mean(), finite.max()) if finite.size else (0.0, 0.0)
        print(f"  {name:18s}: misses J* on {miss.mean():6.1%} (dead ends {np.isinf(g).mean():.1%}); "
              f"gap when missing: mean {mean:6.2%}, max {worst:6.2%}; within 1% of J*: {(g <= 0.01).mean():6.1%}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--slots", type=int, default=20, help="replans per run at 2 and 5 m (1 m: a third)")
    ap.add_argument("--grids", type=float, nargs="+", default=[1.0, 2.0, 5.0])
    ap.add_argument("--uavs", type=int, nargs="+", default=[1, 3])
    ap.add_argument("--variants", nargs="+", default=["inherited", "binned"], choices=["inherited", "binned"])
    ap.add_argument("--optimality", action="store_true", help="also run the brute-force comparison")
    ap.add_argument("--compare", default="b549364", help="git revision to time in the same run ('' to skip)")
    ap.add_argument("--reps", type=int, default=3, help="alternating runs per side in the comparison")
    ap.add_argument("--compare-uavs", type=int, nargs="+", default=[1, 3, 5],
                    help="team sizes of the comparison (1, 3: paper scene; others: random scene 11). U = 8 is "
                         "opt-in: b549364's safety layer tries every priority order, minutes per slot at U = 8")
    ap.add_argument("--threads", type=int, default=1,
                    help="COVERT_DP_THREADS of this checkout in the comparison and large-team runs")
    ap.add_argument("--large", type=int, nargs="*", default=[5, 8], help="larger team sizes to time")
    ap.add_argument("--profile", action="store_true", help="also show where a 3-UAV replan's time goes")
    args = ap.parse_args(argv)
    print(f"load average at start: {os.getloadavg()[0]:.2f} (CPUs: {os.cpu_count()})")
    hdr = (f"{'grid':>5} {'nodes':>6} {'U':>2} {'variant':>14} {'cold ms':>8} {'median ms':>10} {'p90 ms':>8} "
           f"{'cpu med':>8} {'transitions/s':>14} {'exact/replan':>13} {'rounds':>7}")
    print(hdr)
    print("-" * len(hdr))
    for grid in args.grids:
        slots = max(4, args.slots // 3) if grid < 1.5 else args.slots
        for u in args.uavs:
            for v in args.variants:
                r = bench(grid, u, v, slots)
                print(f"{r['grid']:5.0f} {r['nodes']:6d} {r['U']:2d} {r['variant']:>14} {r['cold_ms']:8.0f} "
                      f"{r['median_ms']:10.1f} {r['p90_ms']:8.1f} {r['cpu_median_ms']:8.1f} "
                      f"{r['trans_per_s']:14.3g} {r['exact_per_replan']:13.0f} {r['rounds']:7.2f}", flush=True)
    if args.compare:
        compare(args.compare, args.slots + 1, args.reps, args.compare_uavs, args.threads)
    if args.large:
        large_teams(args.large, max(4, args.slots // 2) + 1, threads=args.threads)
    if args.profile:
        profile(args.slots + 1)
    print(f"load average at end: {os.getloadavg()[0]:.2f}")
    if args.optimality:
        optimality()
    return 0


if __name__ == "__main__":
    sys.exit(main())
