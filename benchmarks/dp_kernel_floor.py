"""How much a compiled kernel would gain on the DP planner's two hot spots (could a replan be 4x b549364's?).

Run ``python benchmarks/dp_kernel_floor.py`` (numba is a covert_env dependency: the line-of-sight kernel,
:mod:`covert_env.geometry.sight_kernel`; the planner itself is numpy). A 3-UAV team flies the paper scene at the
2 m grid (as ``benchmarks/dp.py``), and every call of the planner's two hot spots is recorded:

* the dense table bound of a UAV's stage (``ForwardRecursion._node_bounds``: one 577 x 577 block per UAV and
  stage, the first selection round included), and
* the exact manoeuvre solves (``solve_manoeuvre`` of eqs. 22-29, ~24 vectorised calls per replan).

Each is then replayed in the same run, with the planner's own numpy code and with a numba kernel written as
a compiled planner would (the bound and round 0 fused into one loop per target; the root solve of eq. 29 one
element at a time), and checked to give the same numbers. Printed: ms per replan for both, their ratio, the
measured team replan time, and the replan time projected with both kernels compiled (the rest unchanged, and
the rest 3x faster), against 1/4 of the b549364 planner's time (``--old-ms``, default: the same-run figure of
``benchmarks/dp.py --compare`` on the 2-core CI machine, 61.5 ms CPU).

The bound is a gather from the 3 MB manoeuvre table per node pair: memory-bound, so fusing its passes gains
~2x, not the ~4x of the solver, whose numpy cost is per-call overhead.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

try:
    import numba
except ImportError:                       # pragma: no cover - depends on the environment
    sys.exit("benchmarks/dp_kernel_floor.py needs numba (pip install numba), a covert_env dependency")

import baselines.dp.recursion as recursion  # noqa: E402
import baselines.dp.transitions as transitions  # noqa: E402
from baselines.dp import DPPlanner, DPTeamPlanner  # noqa: E402
from baselines.dp.selection import FIRST_BAND  # noqa: E402
from covert_env import Config, Engine, Scenario  # noqa: E402
from covert_env.geometry.dynamics import solve_manoeuvre  # noqa: E402

TWO_PI = 2.0 * math.pi


# ------------------------------------------------------------------------------------------ kernels
@numba.njit(cache=False)
def fused_bound(base, disguise, cost_grid, heading_cells, pen, table_lb, out, colmin):
    """The dense bound of one UAV's stage and round 0's band size, one pass per target (as _node_bounds)."""
    n = base.shape[0]
    band = 0
    for t in range(n):
        best = np.float32(np.inf)
        for s in range(n):
            if cost_grid[s] == np.inf:
                out[t, s] = np.inf
                continue
            v = table_lb[np.int32(base[t, s] - heading_cells[s])] + disguise[t, s] + pen[t] + cost_grid[s]
            out[t, s] = v
            best = min(best, v)
        colmin[t] = best
        for s in range(n):
            band += out[t, s] <= best + np.float32(FIRST_BAND)
    return band


@numba.njit(cache=False)
def _lateral(d2, b, r):
    return math.sqrt(max(d2 - 2.0 * b * r, 0.0))


@numba.njit(cache=False)
def _tau(a, b, r, lat):
    q = a > 0 and a + lat > 1e-6 * (b + r)
    a_minus_l = b * (2.0 * r - b) / (a + lat) if q else a - lat
    t = math.atan2(r * a_minus_l + lat * b, lat * a - r * (b - r))
    return t + TWO_PI if t < 0 else t


@numba.njit(cache=False)
def _phi(a, b, d2, r):
    lat = _lateral(d2, b, r)
    return lat * (lat * lat + r * b) / (r * r) + a


@numba.njit(cache=False)
def _newton_terms(a, b, d2, x, wd):
    """Eq. 29 as F(r) and dF/dr at r = x (covert_env.geometry.turn_root._residual_and_slope)."""
    lat = _lateral(d2, b, x)
    tau = _tau(a, b, x, lat)
    return x * tau + lat - wd * x, tau + (lat * (x - b) - a * x) / (lat * lat + x * x) - wd


@numba.njit(cache=False)
def scalar_solve(p, theta, g, v_max, w_max, delta, v_out, head_out):
    """covert_env.geometry.dynamics.solve_manoeuvre's speed and final heading, one element at a time (same steps)."""
    wd, r_max = w_max * delta, v_max / w_max
    for i in range(theta.size):
        v_out[i] = np.nan
        head_out[i] = np.nan
        c, s = math.cos(theta[i]), math.sin(theta[i])
        rx, ry = g[i, 0] - p[i, 0], g[i, 1] - p[i, 1]
        a, cross = c * rx + s * ry, c * ry - s * rx
        b = abs(cross)
        d2 = a * a + b * b
        d = math.sqrt(d2)
        if not (d > 1e-9 and d <= v_max * delta):
            continue
        if a > 0 and b <= 1e-12 * d:
            v_out[i], head_out[i] = d / delta, theta[i] % TWO_PI
            continue
        lo, hi = d / wd, min(d2 / (2.0 * b) if b > 0 else np.inf, r_max)
        if not lo < hi or (wd <= math.pi and a < 0):
            continue
        if a < 0:
            phi_lo = _phi(a, b, d2, lo)
            if phi_lo <= 0:
                continue
            if _phi(a, b, d2, hi) < 0:
                s_lo, s_hi = lo, hi
                for _ in range(60):
                    mid = 0.5 * (s_lo + s_hi)
                    if _phi(a, b, d2, mid) > 0:
                        s_lo = mid
                    else:
                        s_hi = mid
                hi = s_hi
        lat = _lateral(d2, b, hi)
        if hi * _tau(a, b, hi, lat) + lat - wd * hi > 0:
            continue
        x = lo
        f, fp = _newton_terms(a, b, d2, x, wd)
        dx_old = dx = hi - lo
        root = np.nan
        for _ in range(100):
            if f > 0:
                lo = x
            else:
                hi = x
            newton = x - f / fp
            bis = not (lo < newton < hi) or abs(2.0 * f) > abs(dx_old * fp)
            x_new = 0.5 * (lo + hi) if bis else newton
            dx_old, dx = dx, x_new - x
            if abs(dx) <= 1e-14 * x_new or f == 0 or hi - lo <= 1e-14 * hi:
                root = x_new - dx if f == 0 else x_new
                break
            x = x_new
            f, fp = _newton_terms(a, b, d2, x, wd)
        if not math.isfinite(root):
            continue
        lat = _lateral(d2, b, root)
        tau = min(_tau(a, b, root, lat), wd)
        h = (theta[i] + (1.0 if cross > 0 else -1.0) * tau) % TWO_PI
        v_out[i], head_out[i] = min(w_max * root, v_max), 0.0 if h >= TWO_PI else h


# ------------------------------------------------------------------------------------------ recording
def record(slots: int):
    """Fly the 3-UAV paper scene; return (replan CPU times, bound calls, solve calls) of replans 2..slots."""
    bounds, solves = [], []
    node_bounds, solve = recursion.ForwardRecursion._node_bounds, transitions.solve_manoeuvre

    def spy_bounds(self, pair, pen, layer, *rest):
        bounds.append((self, pair, pen, layer, rest))
        return node_bounds(self, pair, pen, layer, *rest)

    def spy_solve(p, theta, goals, **kw):
        shape = np.shape(goals)[:-1]
        solves.append((np.broadcast_to(p, shape + (2,)).reshape(-1, 2).copy(),
                       np.broadcast_to(theta, shape).reshape(-1).copy(), np.reshape(goals, (-1, 2)).copy(), kw))
        return solve(p, theta, goals, **kw)

    recursion.ForwardRecursion._node_bounds, transitions.solve_manoeuvre = spy_bounds, spy_solve
    try:
        cfg = Config(grid_step=2.0, n_uavs=3)
        sc = Scenario.paper(cfg)
        team, eng, cpu = DPTeamPlanner(DPPlanner(cfg, sc.terrain)), Engine(sc), []
        for s in range(slots + 1):
            if s == 1:                     # the first replan fills the caches: left out, as in benchmarks/dp.py
                bounds.clear()
                solves.clear()
            c0 = time.process_time()
            plan = team.plan_engine(eng)
            cpu.append(time.process_time() - c0)
            eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
    finally:
        recursion.ForwardRecursion._node_bounds, transitions.solve_manoeuvre = node_bounds, solve
    return np.array(cpu[1:]), bounds, solves


def replay_bounds(bounds) -> tuple[float, float, int]:
    """CPU seconds of all recorded dense bounds with numpy (the planner's method) and with the fused kernel."""
    blocks = []
    for rec, pair, pen, layer, _ in bounds:
        base, disguise = pair.by_target()
        L = base.shape[0]
        for u, s, e in layer.blocks():
            cost_grid = np.full(L, np.inf, np.float32)
            heading = np.zeros(L, np.float32)
            cost_grid[layer.node[s:e]] = layer.J[s:e]
            heading[layer.node[s:e]] = layer.theta[s:e] * rec.table.psi_scale
            blocks.append((base, disguise, cost_grid, heading, pen[u if len(pen) > 1 else 0], rec.table.lb))
    out = np.empty_like(blocks[0][0])
    colmin = np.empty(out.shape[0], np.float32)
    fused_bound(*blocks[0], out, colmin)       # compile
    c0 = time.process_time()
    for rec, pair, pen, layer, rest in bounds:
        rec._node_bounds(pair, pen, layer, *rest)
    t_numpy = time.process_time() - c0
    c0 = time.process_time()
    for blk in blocks:
        fused_bound(*blk, out, colmin)
    return t_numpy, time.process_time() - c0, len(blocks)


def replay_solves(solves) -> tuple[float, float, float]:
    """CPU seconds of all recorded exact solves with numpy and with the scalar kernel; largest difference."""
    outs = [(np.empty(len(t)), np.empty(len(t))) for _, t, _, _ in solves]
    p, t, g, kw = solves[0]
    scalar_solve(p, t, g, kw["v_max"], kw["w_max"], kw["delta"], *outs[0])     # compile
    c0 = time.process_time()
    ref = [solve_manoeuvre(p, t, g, **kw) for p, t, g, kw in solves]
    t_numpy = time.process_time() - c0
    c0 = time.process_time()
    for (p, t, g, kw), (v, h) in zip(solves, outs, strict=True):
        scalar_solve(p, t, g, kw["v_max"], kw["w_max"], kw["delta"], v, h)
    t_numba = time.process_time() - c0
    diff = max(float(np.nanmax(np.abs(np.concatenate([m.v - v, m.heading_after - h])), initial=0.0))
               for m, (v, h) in zip(ref, outs, strict=True))
    same = all(np.array_equal(np.isfinite(m.v), np.isfinite(v)) for m, (v, _) in zip(ref, outs, strict=True))
    if not same:
        raise AssertionError("the scalar kernel disagrees with solve_manoeuvre on feasibility")
    return t_numpy, t_numba, diff


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--slots", type=int, default=20, help="team replans recorded (after one cold replan)")
    ap.add_argument("--old-ms", type=float, default=61.5,
                    help="b549364's 3-UAV replan CPU median (ms) from benchmarks/dp.py --compare on this machine")
    args = ap.parse_args(argv)
    print(f"load average at start: {os.getloadavg()[0]:.2f}; numba {numba.__version__}, numpy {np.__version__}")
    cpu, bounds, solves = record(args.slots)
    n = len(cpu)
    bn, bc, blocks = replay_bounds(bounds)
    sn, sc, diff = replay_solves(solves)
    total = float(np.mean(cpu)) * 1e3
    per = 1e3 / n
    print(f"\n3-UAV team, paper scene, 2 m grid, {n} replans (CPU ms per replan; team replan mean {total:.1f}, "
          f"median {np.median(cpu) * 1e3:.1f}):")
    print(f"  dense bounds + round 0 ({blocks / n:.1f} blocks): numpy {bn * per:6.2f}  compiled {bc * per:6.2f}  "
          f"({bn / bc:.2f}x)")
    print(f"  exact solves ({sum(len(t) for _, t, _, _ in solves) / n:.0f} in {len(solves) / n:.1f} calls): "
          f"numpy {sn * per:6.2f}  compiled {sc * per:6.2f}  ({sn / sc:.2f}x; largest difference {diff:.1e})")
    rest = total - (bn + sn) * per
    fast = (bc + sc) * per
    print(f"  projected replan with both compiled: {rest + fast:.1f} ms (rest unchanged), {rest / 3 + fast:.1f} ms "
          f"(rest 3x faster); 4x target: {args.old_ms / 4:.1f} ms ({args.old_ms} ms / 4)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
