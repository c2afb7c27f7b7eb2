"""Decentralised team planning with negotiation (paper §2.5): :class:`DPTeamPlanner`."""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from baselines.dp.continuation import secure_continuations
from baselines.dp.plan import TeamPlan
from baselines.dp.planner import DPPlanner
from baselines.dp.safety import secure_first_moves
from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.separation import separation
from covert_env.world.roles import EngineView

__all__ = ["Conflict", "DPTeamPlanner", "WORK_COUNTERS", "extrapolate_target"]

#: What :attr:`DPTeamPlanner.stats` counts per team replan. With U UAVs and R = ``max_rounds``:
#: ``dp_calls`` (batched DP runs) <= 1 + R; ``uav_plans`` (UAV plans inside them) <= U + R (U - 1);
#: ``conflict_checks`` (pairs of plans compared) <= (1 + R + 1) U (U - 1) / 2; ``safety_orders`` <= U;
#: ``safety_solves`` (one-slot candidate sets, L manoeuvres or best efforts each) <= U. With
#: ``best_effort_escape``: ``safety_orders`` <= U + 1 and ``safety_solves`` <= 2 U (each UAV's best efforts once
#: more; a pair re-choice then compares up to L^2 paths, in chunks). With
#: ``separated_continuation`` each UAV with a plan of depth 1 may add a candidate set, L + 2 end poses tested
#: (``continuation_solves``, L manoeuvres each) and U - 1 single-UAV replans, each checked for conflicts:
#: ``dp_calls`` <= 1 + R + U (U - 1), ``uav_plans`` <= U + R (U - 1) + U (U - 1), ``conflict_checks`` <=
#: (3 + R + U (U - 1)) U (U - 1) / 2, ``safety_solves`` <= 2 U (3 U with the escape), ``continuation_solves``
#: <= U (L + 2).
#: Polynomial in U: O(R U^2), O(U^4) comparisons with the look-ahead.
WORK_COUNTERS = ("dp_calls", "uav_plans", "conflict_checks", "safety_orders", "safety_solves", "continuation_solves")


class Conflict(NamedTuple):
    """Two UAVs closer than ``d_safe1 + separation_margin`` at a stage: at the nodes, or along the paths."""

    winner: int
    loser: int
    stage: int
    kind: str            # "node" | "path"


class DPTeamPlanner:
    """Decentralised team planning with negotiation (paper §2.5); see :mod:`baselines.dp`.

    Args:
        planner: the per-UAV :class:`DPPlanner` (shared, so are its caches).
        max_rounds: negotiation rounds before giving up on future-slot conflicts (reported in the result);
            a conflict left in the slot that is flown is always removed by the safety layer
            (:func:`baselines.dp.safety.secure_first_moves`).
        separation_margin: metres added to d_safe1 in the conflict test.
        path_samples: instants per slot at which manoeuvres are compared (21 contains the engine's 11).
        separated_continuation: also look one slot past every plan that ends after the slot flown, and move
            its UAV where a separated move remains in the next slot
            (:func:`baselines.dp.continuation.secure_continuations`). Off by default: the paper's planner, and
            the suite's reference, plan without it.
        best_effort_escape: where no priority order of the safety layer separates the team with its moves, let a
            UAV left without a separated move fly its best effort toward a node it cannot reach (flagged
            infeasible; :meth:`baselines.dp.safety._FirstSlot.escape`). Off by default, as for the look-ahead.
    """

    def __init__(self, planner: DPPlanner, *, max_rounds: int = 5, separation_margin: float = 0.5,
                 path_samples: int = 21, separated_continuation: bool = False, best_effort_escape: bool = False):
        for name, flag in (("separated_continuation", separated_continuation),
                           ("best_effort_escape", best_effort_escape)):
            if not isinstance(flag, (bool, np.bool_)):
                raise ValueError(f"DPTeamPlanner: {name} must be True or False, got {flag!r}")
        self.planner = planner
        self.config = planner.config
        self.max_rounds = int(max_rounds)
        self.margin = float(separation_margin)
        self.path_samples = int(path_samples)
        self.separated_continuation = bool(separated_continuation)
        self.best_effort_escape = bool(best_effort_escape)
        #: Work done by the last :meth:`plan` (the negotiation's cost in U, see :data:`WORK_COUNTERS`).
        self.stats = dict.fromkeys(WORK_COUNTERS, 0)

    @property
    def separation(self) -> float:
        """The distance the team keeps between UAVs: ``d_safe1`` (eq. 2) plus the margin."""
        return self.config.d_safe1 + self.margin

    def plan(self, uav_xy, uav_theta, target_xyz, target_phi, *, target_path=None) -> TeamPlan:
        """Plan every UAV, then negotiate conflicts (lower index keeps its plan) until none remain.

        For every conflict (winner, loser, stage t) the loser records, for stage t, the winner's node and its
        sampled manoeuvre into it; it then replans with, at each recorded stage, the nodes within
        ``d_safe1 + separation_margin`` of a recorded node removed and the transitions whose samples come
        that close to a recorded manoeuvre (at the same instants) removed. Records only accumulate, so a
        replan may reuse its previous DP layers up to the first newly constrained stage.

        Args:
            uav_xy: (U, 2) positions; uav_theta: (U,) headings.
            target_xyz, target_phi, target_path: as in :meth:`DPPlanner.plan` (shared by the team).
        """
        t0 = time.perf_counter()
        xy = np.asarray(uav_xy, float).reshape(-1, 2)
        th = np.asarray(uav_theta, float).reshape(-1)
        u = len(xy)
        n = len(np.asarray(target_xyz).reshape(-1, 3)) - 1
        L = len(self.planner.lattice)
        lim = self.separation
        kw = dict(target_path=target_path)
        self.stats = dict.fromkeys(WORK_COUNTERS, 0)
        self.stats["dp_calls"] += 1
        self.stats["uav_plans"] += u
        plans = self.planner.plan_batch(xy, th, target_xyz, target_phi, **kw)
        n_exact, n_bounded = plans[0].n_exact, plans[0].n_bounded
        blocked = np.zeros((u, n, L), bool)
        records: list[list[list[np.ndarray]]] = [[[] for _ in range(n)] for _ in range(u)]
        rounds = replans = 0
        conflicts = self.conflicts(plans)
        stages = None
        while conflicts and rounds < self.max_rounds:
            rounds += 1
            if stages is None:
                tq = np.asarray(target_xyz, float).reshape(-1, 3)
                tp = np.asarray(target_phi, float).reshape(-1)
                stages = [self.planner.cache.stage(tq[j], tp[j]) for j in range(1, n + 1)]
            first: dict[int, int] = {}
            for win, lose, t, _ in conflicts:
                pw = plans[win]
                blocked[lose, t] |= separation(stages[t].xy[:, None], pw.waypoints[t][None, None]) < lim
                records[lose][t].append(pw.path_points(self.path_samples)[t])
                first[lose] = min(first.get(lose, n), t)
            losers = sorted(first)
            avoid = self._avoid_array(records, losers, n)
            idx = np.array(losers)
            new = self.planner.plan_batch(xy[idx], th[idx], target_xyz, target_phi, blocked=blocked[idx], avoid=avoid,
                                          avoid_dist=lim, resume=([plans[i] for i in losers], min(first.values())),
                                          **kw)
            for i, p in zip(losers, new, strict=True):
                plans[i] = p
            replans += len(losers)
            self.stats["dp_calls"] += 1
            self.stats["uav_plans"] += len(losers)
            n_exact += new[0].n_exact
            n_bounded += new[0].n_bounded
            conflicts = self.conflicts(plans)
        if any(c.stage == 0 for c in conflicts):
            plans = secure_first_moves(self, plans, xy=xy, th=th, target_xyz=target_xyz, target_phi=target_phi,
                                       target_path=target_path)
            conflicts = self.conflicts(plans)
        if self.separated_continuation:
            plans = secure_continuations(self, plans, xy=xy, th=th, target_xyz=target_xyz, target_phi=target_phi,
                                         target_path=target_path)
            conflicts = self.conflicts(plans)
        return TeamPlan(plans=plans, nodes=np.array([p.nodes[0] for p in plans]),
                        waypoints=np.array([p.waypoints[0] for p in plans]),
                        infeasible=np.array([p.infeasible for p in plans]), rounds=rounds, conflicts=len(conflicts),
                        replans=replans, time=time.perf_counter() - t0, n_exact=n_exact, n_bounded=n_bounded,
                        work=dict(self.stats))

    def _avoid_array(self, records, losers: list[int], n: int) -> np.ndarray:
        """(losers, M, N, P, 2) the recorded winners' path samples per loser and stage (NaN-padded)."""
        m = max(len(records[i][t]) for i in losers for t in range(n))
        avoid = np.full((len(losers), m, n, self.path_samples, 2), np.nan)
        for s_, i in enumerate(losers):
            for t in range(n):
                for o, pts in enumerate(records[i][t]):
                    avoid[s_, o, t] = pts
        return avoid

    def plan_engine(self, engine: EngineView, horizon: int | None = None, known_slots: int | None = None) -> TeamPlan:
        """:meth:`plan` for the current state of an engine (:class:`covert_env.world.engine.Engine`, or a vector env's
        copy: any :class:`covert_env.world.roles.EngineView`), from its track's predictions over ``horizon`` slots
        (default the config's N; at most N, since the route is built for the config's horizon). With
        ``known_slots`` k, only the first k predicted slots are read and the rest extrapolated from them
        (:func:`extrapolate_target`): a planner that sees as far ahead as the default observation (k = 1)."""
        if horizon is not None and not 1 <= horizon <= engine.config.horizon:
            raise ValueError(f"plan_engine: horizon must be in [1, config.horizon = {engine.config.horizon}], got "
                             f"{horizon!r} (the route reaches N slots past the episode's last)")
        if known_slots is not None and (isinstance(known_slots, bool) or not isinstance(known_slots, (int, np.integer))
                                        or known_slots < 1):
            raise ValueError(f"plan_engine: known_slots must be None or an integer >= 1, got {known_slots!r}")
        q_pred, phi_pred = engine.predict(horizon)
        if known_slots is not None and known_slots < len(phi_pred):
            if self.planner.check_path:
                raise ValueError("plan_engine: known_slots does not go with check_path (the path's samples are the "
                                 "track's prediction)")
            q_pred, phi_pred = extrapolate_target(engine.target_xyz, engine.target_phi, q_pred[:known_slots],
                                                  phi_pred[:known_slots], len(phi_pred))
        tq = np.vstack([engine.target_xyz[None], q_pred])
        tp = np.concatenate([[engine.target_phi], phi_pred])
        path = None
        if self.planner.samples_path:
            f = np.linspace(0.0, 1.0, self.planner.path_samples)
            path = engine.track.predict_between(engine.k, len(phi_pred), f)   # the prediction, not the truth
        return self.plan(engine.uav_xy, engine.uav_theta, tq, tp, target_path=path)

    def conflicts(self, plans) -> list[Conflict]:
        """Every pair of UAVs too close at some stage, at the nodes or along the manoeuvres (lower index wins).

        All pairs at once: the plans' path samples are stacked (NaN past a plan's depth, which compares False).
        """
        u = len(plans)
        if u < 2:
            return []
        lim = self.separation
        self.stats["conflict_checks"] += u * (u - 1) // 2
        n = len(plans[0].nodes)
        wp = np.full((u, n, 2), np.nan)
        pts = np.full((u, n, self.path_samples - 1, 2), np.nan)
        for i, p in enumerate(plans):
            wp[i, :p.depth] = p.waypoints[:p.depth]
            # Sample 0 of a slot is the previous slot's last one, or the current positions: nothing to plan.
            pts[i, :p.depth] = p.path_points(self.path_samples)[:, 1:]
        i, k = np.triu_indices(u, 1)
        node = separation(wp[i, :, None], wp[k, :, None])                           # (pairs, N)
        path = separation(pts[i], pts[k])                                           # (pairs, N)
        node_hit = node < lim
        hit = node_hit | (path < lim)
        pair, t = np.nonzero(hit)
        return [Conflict(int(i[q]), int(k[q]), int(s), "node" if node_hit[q, s] else "path")
                for q, s in zip(pair.tolist(), t.tolist(), strict=True)]


def extrapolate_target(q0: np.ndarray, phi0: float, q_known: np.ndarray, phi_known: np.ndarray,
                       horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """The target's poses at slots k+1..k+``horizon`` from its pose now (``q0`` (3,), ``phi0``) and its first k
    known predicted poses (``q_known`` (k, 3), ``phi_known`` (k,), k >= 1): the known ones, then the last known
    slot's step repeated, turned by the last known turn once more every slot (a constant speed and turn rate, off
    the road where it bends otherwise). Returns ((horizon, 3), (horizon,))."""
    q_known, phi_known = np.asarray(q_known, float), np.asarray(phi_known, float)
    k = len(phi_known)
    if q_known.shape != (k, 3) or phi_known.ndim != 1 or not 1 <= k <= horizon:
        raise ValueError(f"extrapolate_target: q_known (k, 3) and phi_known (k,) must hold the same k known slots, "
                         f"1 <= k <= horizon = {horizon}, got shapes {q_known.shape} and {phi_known.shape}")
    q = np.vstack([np.asarray(q0, float)[None], q_known])
    phi = np.concatenate([[float(phi0)], phi_known])
    more = horizon - k
    step, turn = q[-1, :2] - q[-2, :2], wrap_angle(phi[-1] - phi[-2])
    ang = turn * np.arange(1, more + 1)
    c, s = np.cos(ang), np.sin(ang)
    xy = q[-1, :2] + np.cumsum(np.stack([c * step[0] - s * step[1], s * step[0] + c * step[1]], axis=-1), axis=0)
    out_q = np.vstack([q[1:], np.column_stack([xy, np.full(more, q[-1, 2])])])
    return out_q, np.concatenate([phi[1:], phi[-1] + ang])
