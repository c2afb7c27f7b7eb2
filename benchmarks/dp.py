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
bounds. ``--optimality`` adds the small-lattice comparison with the brute force (tests/test_dp.py).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from baselines.dp import DPPlanner, DPTeamPlanner, brute_force_plan, evaluate_plan  # noqa: E402
from covert_env import Config, Engine, Scenario  # noqa: E402
from covert_env.zone import to_world, zone_lattice  # noqa: E402


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
    print(f"load average at end: {os.getloadavg()[0]:.2f}")
    if args.optimality:
        optimality()
    return 0


if __name__ == "__main__":
    sys.exit(main())
