"""The runs of ``covert-env reproduce``: the scenes (the paper's and the held-out ones, the ``--quick`` choice of
the most shadowed), one run of the DP team and its records, and every run of a list in worker processes."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from baselines.rollout import rollout
from covert_env.render import (
    shadow_share,
)
from covert_env.world.config import Config
from covert_env.world.families import HELD_OUT_SEEDS, family_config
from covert_env.world.metrics import episode_metrics, slot_quantities
from covert_env.world.scenario import Scenario

#: Held-out scene seeds are HELDOUT_SEED_BASE + i (outside any training pool of the environments).
HELDOUT_SEED_BASE = HELD_OUT_SEEDS.start
#: Planner settings of each compared method.
METHODS = {
    "aware": dict(shadow_aware=True),                      # the paper's method (eq. 10 zone)
    "blind": dict(shadow_aware=False),                     # the earlier method [1]
    "aware-path": dict(shadow_aware=True, check_path=True),  # + LoS and zone along every manoeuvre
}


@dataclass(frozen=True)
class RunSpec:
    """One episode: scene kind ("paper" or "random"), scene seed, team size, method (key of METHODS); a random
    scene of scene family ``family`` (:mod:`covert_env.world.families`; None: the config as given)."""

    kind: str
    seed: int
    n_uavs: int
    method: str
    n_slots: int = 70
    heading: str = "inherited"
    family: str | None = None

    @property
    def label(self) -> str:
        scene = "paper" if self.kind == "paper" else f"seed{self.seed}"
        return f"{scene}-{self.n_uavs}uav-{self.method}"


def make_scenario(kind: str, seed: int, n_uavs: int, config: Config | None = None,
                  family: str | None = None) -> Scenario:
    """The scene of a run, built as the environments build it (``config.n_uavs`` = ``n_uavs``): the paper's, or a
    random one (of scene family ``family`` if given; the paper scene is always the paper's)."""
    cfg = (config or Config()).replace(n_uavs=int(n_uavs))
    if kind == "paper":
        return Scenario.paper(cfg)
    return Scenario.random(int(seed), cfg if family is None else family_config(family, cfg))


#: ``--quick``: slots per episode (the paper scene's zone is in shadow at slots 11-15), number of held-out
#: scenes, and the pool (the full job's first scenes) they are chosen from by :func:`most_shadowed_scenes`.
QUICK_SLOTS = 15
QUICK_SCENES = 2
QUICK_POOL = 20
#: Percentile bootstrap over scenes: resamples and seed (fixed: metrics.md is reproducible).
def zone_shadow_shares(scenario: Scenario, slots) -> np.ndarray:
    """Share of the feasible zone in shadow at each of ``slots`` (:func:`covert_env.render.shadow_share`)."""
    return np.array([shadow_share(scenario, int(k)) for k in slots])


def most_shadowed_scenes(n: int, n_slots: int, config: Config | None = None, pool: int = QUICK_POOL,
                         n_uavs: int = 1, family: str | None = None) -> list[int]:
    """``--quick``'s held-out scenes: the ``n`` seeds among the first ``pool`` held-out scenes whose feasible
    zone is most in shadow, on average over slots 1..``n_slots`` (ties: lower seed). Purely geometric (no
    planner run), so the choice is deterministic and cheap; a zone in shadow is where the shadow-blind planner
    can lose the line of sight. Returned in seed order."""
    config = config or Config()
    share = [zone_shadow_shares(make_scenario("random", HELDOUT_SEED_BASE + i, n_uavs, config, family),
                                range(1, n_slots + 1)).mean() for i in range(pool)]
    best = sorted(range(pool), key=lambda i: (-share[i], i))[:n]
    return sorted(HELDOUT_SEED_BASE + i for i in best)


def figure_slot(blind_los: np.ndarray, shares: np.ndarray) -> int:
    """The slot k (1-based) that figs. 10/14 show: where the shadow-blind planner's LoS is blocked for the most
    UAVs, ties broken by the larger share of the zone in shadow; with no blocked slot, the most shadowed slot.

    Args:
        blind_los: (T, U) LoS of the shadow-blind run at slot times 1..T.
        shares: (T,) share of the zone in shadow at slots 1..T.
    """
    blocked = (~np.asarray(blind_los, bool)).sum(axis=1)
    order = np.lexsort((-np.asarray(shares), -blocked))    # last key first: most blocked, then most shadow
    return int(order[0]) + 1


def run(spec: RunSpec, config: Config | None = None) -> dict:
    """Run one :class:`RunSpec`; returns per-UAV records and the per-slot series the figures need."""
    # The scene is built for the config's full episode (its road length, hence its terrain, depends on
    # n_slots); a shorter run flies only the first spec.n_slots slots of the same scene.
    sc = make_scenario(spec.kind, spec.seed, spec.n_uavs, config, spec.family)
    t0 = time.perf_counter()
    out = rollout(sc, heading=spec.heading, n_slots=spec.n_slots, **METHODS[spec.method])
    wall = time.perf_counter() - t0
    traj = out["trajectory"]
    t1 = time.perf_counter()
    q = slot_quantities(traj, sc.terrain, sc.config)
    metrics = episode_metrics(traj, sc.terrain, sc.config, q)
    metrics_s = time.perf_counter() - t1
    tt = out["team_time"] * 1e3
    records = []
    for i, m in enumerate(metrics):
        st = out["status"][:, i]
        rec = {"run": spec.label, "scene": "paper" if spec.kind == "paper" else "heldout", "seed": spec.seed,
               "family": None if spec.kind == "paper" else spec.family, "n_uavs": spec.n_uavs,
               "method": spec.method, "heading": spec.heading, "uav": i,
               "slots": int(traj.n_slots)}
        rec.update(m)
        rec.update({
            "blocked_slots": int((~q.los[:, i]).sum()),
            "blocked_unflagged": int((~q.los[:, i] & ~traj.infeasible[:, i]).sum()),
            "blocked_path_slots": int((~q.los_path[:, i]).sum()),
            "blocked_path_unflagged": int((~q.los_path[:, i] & ~traj.infeasible[:, i]).sum()),
            # Clear at the slot time but blocked somewhere along the manoeuvre before it.
            "lost_between_slots": int((q.los[:, i] & ~q.los_path[:, i]).sum()),
            "truncated_slots": int((st == "truncated").sum()),
            "team_time_ms_median": float(np.median(tt)),
            "team_time_ms_p90": float(np.percentile(tt, 90)),
            "negotiation_rounds": int(out["rounds"].sum()),
            "unresolved_conflicts": int(out["conflicts"].sum()),
            "wall_s": wall,
        })
        records.append(rec)
    series = {"los": q.los, "los_path": q.los_path, "kappa": q.kappa, "infeasible": traj.infeasible,
              "uav_xy": traj.uav_xy, "target_xyz": traj.target_xyz, "target_phi": traj.target_phi}
    return {"spec": spec, "records": records, "series": series,
            "timing": {"rollout_s": wall, "metrics_s": metrics_s}}


def run_job(args):
    spec, cfg_dict = args
    res = run(spec, Config.from_dict(cfg_dict))
    # Paths are only needed for the paper runs' figures; keep the result small for the other runs.
    if spec.kind != "paper":
        res["series"] = {k: v for k, v in res["series"].items() if k in ("los", "los_path", "kappa", "infeasible")}
    return res


def specs_for(scenes, n_slots: int, heading: str = "inherited", path_uavs=(1,),
              family: str | None = None) -> list[RunSpec]:
    """The runs: paper scene and held-out scenes, 1 and 3 UAVs, aware and blind; aware-path for ``path_uavs``.

    ``scenes``: a number n (seeds HELDOUT_SEED_BASE + 0..n-1) or the held-out seeds themselves; ``family``: the
    held-out scenes' scene family."""
    seeds = [HELDOUT_SEED_BASE + i for i in range(scenes)] if isinstance(scenes, int) else list(scenes)
    specs = [RunSpec("paper", 0, u, m, n_slots, heading) for u in (1, 3) for m in ("aware", "blind")]
    for seed in seeds:
        for u in (1, 3):
            for m in ("aware", "blind") + (("aware-path",) if u in path_uavs else ()):
                specs.append(RunSpec("random", seed, u, m, n_slots, heading, family))
    return specs


def run_all(specs: list[RunSpec], config: Config, jobs: int) -> dict:
    """Run every spec (``jobs`` spawned worker processes); results keyed by (kind, seed, n_uavs, method)."""
    results = {}
    for res in run_pairs([(s, config) for s in specs], jobs):
        s = res["spec"]
        results[(s.kind, s.seed, s.n_uavs, s.method)] = res
    return results


def run_pairs(pairs: list[tuple[RunSpec, Config]], jobs: int) -> list[dict]:
    """Run (spec, config) pairs in ``jobs`` spawned worker processes; results in the order of ``pairs``."""
    # Longest runs first keeps both workers busy to the end.
    order = sorted(range(len(pairs)), key=lambda i: (-pairs[i][0].n_uavs, pairs[i][0].method != "aware-path"))
    jobs_args = [(i, pairs[i][0], pairs[i][1].to_dict()) for i in order]
    results = [None] * len(pairs)
    bar = _progress(len(pairs))
    if jobs > 1 and len(pairs) > 1:
        import multiprocessing as mp
        import signal

        def _terminate(signum, frame):
            # Leaving the `with` block by an exception terminates the workers (a bare kill would orphan them).
            raise SystemExit(128 + signum)

        signal.signal(signal.SIGTERM, _terminate)
        with mp.get_context("spawn").Pool(min(jobs, len(pairs))) as pool:
            for i, res in pool.imap_unordered(_run_indexed, jobs_args):
                results[i] = res
                _tick(bar, res)
    else:
        for a in jobs_args:
            i, res = _run_indexed(a)
            results[i] = res
            _tick(bar, res)
    bar.close()
    return results


def _run_indexed(args):
    i, spec, cfg_dict = args
    return i, run_job((spec, cfg_dict))


def _progress(total: int):
    """A tqdm bar on stderr."""
    from tqdm import tqdm

    return tqdm(total=total, desc="reproduce", unit="run", file=sys.stderr)


def _tick(bar, res: dict) -> None:
    bar.set_postfix_str(res["spec"].label)
    bar.update(1)


