"""The team's one-slot look-ahead: a UAV whose plan ends after the slot it flies must end that slot where it can
still move clear of its teammates in the next one (docs/decisions/planner.md#separated-continuation)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from baselines.dp.lattice import Stage
from baselines.dp.safety import _clear_of, _FirstSlot
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.flight import fly_waypoints
from covert_env.geometry.separation import separation
from covert_env.geometry.ties import first_argmax

__all__ = ["secure_continuations"]

#: Candidate end poses tested per batch (each against every node of the next slot: CHUNK x L manoeuvres).
CHUNK = 64


def secure_continuations(team, plans, *, xy, th, target_xyz, target_phi, target_path=None) -> list:
    """Replace the first move of every one-stage plan that leaves its UAV without a separated move next slot.

    A plan of depth 1 (``"truncated"``, ``"fallback"`` or ``"safety"``) says nothing about the slot after the one
    flown, so the negotiation never compares it there. Two UAVs can then end the slot ``d_safe1`` apart but
    flying at each other, where no pair of next moves keeps eq. 2. For such a UAV i this measures, from the pose
    its first move ends in, its *room*: over the flyable manoeuvres (eq. 3 along them) to the nodes of the next
    slot's lattice, the largest smallest distance from each teammate's planned move of that slot (teammates whose
    plan reaches it), at every sample. If the room is below ``d_safe1 + separation_margin``, i takes instead, among
    the safety layer's one-slot candidates separated from the teammates' first moves, the one whose end pose has
    that room: to an allowed node if one has, the lowest stage cost first; if none has it, the one with the most
    room, if that is more than the plan's (``status="safety"``; flagged if it leaves the allowed nodes). A UAV that
    reaches no node chooses among the engine's best efforts the same way (flagged). If i still lacks the room, a
    teammate makes way (:func:`_make_way`): it replans around one of i's next moves, reserved at its stage 2.

    Limits: a depth-1 plan is checked against the teammates whose plans reach the next slot, not against another
    depth-1 plan; a reserved continuation is not carried to the next UAV checked, and a room checked earlier is not
    checked again after a teammate made way (docs/decisions/planner.md#separated-continuation).

    Cost: one manoeuvre solve per node of the next slot per depth-1 plan; when its room is short, the same for
    each of its separated candidates (at most L), in batches of :data:`CHUNK`, stopping at the first that has the
    room; then at most U - 1 single-UAV replans. ``team.stats`` counts ``continuation_solves`` (end poses tested)
    and the replans in ``dp_calls`` and ``uav_plans`` (bounds: :data:`baselines.dp.team.WORK_COUNTERS`).
    """
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    tp = np.asarray(target_phi, float).reshape(-1)
    if len(plans) < 2 or len(tq) < 3 or all(p.depth > 1 for p in plans):
        return plans
    plans = list(plans)
    nxt = team.planner.cache.stage(tq[2], tp[2])
    n = team.path_samples
    slot = None
    for i, plan in enumerate(plans):
        ahead = [p.path_points(n)[1][1:] for j, p in enumerate(plans) if j != i and p.depth > 1]
        if plan.depth != 1 or not ahead:
            continue
        end_xy, end_th = _end_pose(plan, team.config, n)
        room = _room(team, nxt, end_xy[None], np.array([end_th]), ahead)[0]
        if room >= team.separation:
            continue
        if slot is None:
            slot = _FirstSlot(team, plans, xy, th, target_xyz, target_phi, target_path)
        move = _move_with_room(slot, i, nxt, ahead, room)
        if move is not None:
            plans[i] = slot.safety_plan(plan, i, move)
            slot.own[i] = slot.path_of(i, move)
            if move.room >= team.separation:
                continue
        made = _make_way(team, plans, i, nxt, target_xyz, target_phi, target_path, xy, th)
        if made is not None:
            h, plans[h] = made
            slot.own[h] = plans[h].path_points(n)[0][1:]
    return plans


def _end_pose(plan, config, n: int) -> tuple[np.ndarray, float]:
    """Where the plan's first move ends, and the heading there (a best effort flown as the engine flies it)."""
    if np.isfinite(plan.headings[0]):
        return plan.waypoints[0], float(plan.headings[0])
    times = np.linspace(0.0, config.delta, n)
    path, theta = fly_waypoints(plan.start_xy.reshape(1, 1, 2), np.array([[plan.start_theta]]),
                                plan.waypoints[0].reshape(1, 1, 2), config, times)[:2]
    return path[0, 0, -1], float(theta[0, 0])


def _room(team, nxt: Stage, end_xy: np.ndarray, end_th: np.ndarray, ahead: list) -> np.ndarray:
    """(K,) for end poses (K, 2), (K,): the largest, over flyable moves to the nodes of ``nxt``, smallest distance
    from the teammates' planned samples in ``ahead`` (each (P - 1, 2)); -inf where no move is flyable."""
    ok, pts = _next_moves(team, nxt, end_xy, end_th)
    return np.where(ok, _gap(pts, ahead), -np.inf).max(axis=1)


def _next_moves(team, nxt: Stage, end_xy: np.ndarray, end_th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From end poses (K, 2), (K,) to every node of ``nxt``: (K, L) flyable (eq. 3 along the way) and the (K, L, P, 2)
    path samples (the start first)."""
    team.stats["continuation_solves"] += len(end_xy)
    c, clearance = team.config, team.planner.paths.clearance
    m = solve_manoeuvre(end_xy[:, None], end_th[:, None], nxt.xy[None], v_max=c.v_max, w_max=c.w_max,
                        delta=c.delta)
    ok = np.asarray(m.feasible, bool).reshape(-1).copy()
    if clearance.active:
        ok &= np.broadcast_to(clearance.clear(nxt.xy)[None], m.feasible.shape).reshape(-1)
        ok[ok] = clearance.manoeuvres_clear(m, ok)
    return ok.reshape(m.feasible.shape), m.points(n=team.path_samples)


def _gap(pts: np.ndarray, ahead: list) -> np.ndarray:
    """(...) smallest distance of paths ``pts`` (..., P, 2), samples after the start, from the samples ``ahead``
    (the safety layer's :func:`~baselines.dp.safety._clear_of` on any batch shape)."""
    after = pts[..., 1:, :]
    return _clear_of(after.reshape(-1, *after.shape[-2:]), ahead).reshape(pts.shape[:-2])


class _RoomyMove(NamedTuple):
    node: int
    infeasible: bool
    room: float
    escaped: bool = False          # never: the look-ahead chooses among the UAV's own candidates (_FirstSlot.path_of)


def _move_with_room(slot: _FirstSlot, i: int, nxt: Stage, ahead: list, room: float) -> _RoomyMove | None:
    """UAV i's best separated move whose end pose has the team's separation as :func:`_room`, else the one with
    the most room if more than ``room``; None otherwise."""
    cand = slot.candidates(i)
    others = [slot.own[j] for j in range(len(slot.own)) if j != i]
    idx = np.flatnonzero(cand.flyable & (_clear_of(cand.samples, others) >= slot.min_distance))
    idx = idx[np.lexsort((cand.cost[idx], ~cand.allowed[idx]))]            # allowed first, then cheapest
    best, best_room = None, room
    for s in range(0, len(idx), CHUNK):
        k = idx[s:s + CHUNK]
        r = _room(slot.team, nxt, cand.samples[k, -1], _end_headings(slot, i, cand, k), ahead)
        if (r >= slot.min_distance).any():
            q = int(np.argmax(r >= slot.min_distance))
            best, best_room = int(k[q]), float(r[q])
            break
        if r.max() > best_room:
            best, best_room = int(k[first_argmax(r)]), float(r.max())
    return None if best is None else _RoomyMove(best, bool(not cand.allowed[best]), best_room)


def _make_way(team, plans: list, i: int, nxt: Stage, target_xyz, target_phi, target_path, xy, th):
    """``(h, plan)``: teammate h replanned to leave UAV i a separated next move; None if no teammate can.

    i keeps its first move. For each teammate h whose plan reaches the next slot (the lowest priority first),
    i's continuation is reserved: of its flyable next moves separated from the other teammates' planned ones, the
    one farthest from h's. h then replans its horizon from scratch (:meth:`DPPlanner.plan_batch`), with records in
    the negotiation's form at its first two stages only: the teammates' first moves, and the others' next moves,
    the reserved one included. Its negotiation records at later stages are not kept, so conflicts there may come
    back (the negotiation leaves those too, after ``max_rounds``). The replan is taken if it reaches the next slot
    (a level-2 fallback plan counts) and leaves no conflict in the slot flown.
    """
    n, lim, u = team.path_samples, team.separation, len(plans)
    end_xy, end_th = _end_pose(plans[i], team.config, n)
    ok, pts = _next_moves(team, nxt, end_xy[None], np.array([end_th]))
    ok, pts = ok[0], pts[0]
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    now = team.planner.cache.stage(tq[1], np.asarray(target_phi, float).reshape(-1)[1]).xy
    horizon, lattice = len(tq) - 1, len(nxt.xy)
    for h in sorted((j for j in range(u) if j != i and plans[j].depth > 1), reverse=True):
        rest = [j for j in range(u) if j not in (i, h) and plans[j].depth > 1]
        free = ok & (_gap(pts, [plans[j].path_points(n)[1][1:] for j in rest]) >= lim)
        if not free.any():
            continue
        mine = plans[h].path_points(n)[1][1:]
        keep = first_argmax(np.where(free, _gap(pts, [mine]), -np.inf))
        avoid = np.full((1, u, horizon, n, 2), np.nan)
        blocked = np.zeros((1, horizon, lattice), bool)
        for o, j in enumerate(j for j in range(u) if j != h):
            avoid[0, o, 0] = plans[j].path_points(n)[0]
            blocked[0, 0] |= separation(now[:, None], plans[j].waypoints[0][None, None]) < lim
        for o, j in enumerate([*rest, i]):
            path = pts[keep] if j == i else plans[j].path_points(n)[1]
            avoid[0, o, 1] = path
            blocked[0, 1] |= separation(nxt.xy[:, None], path[-1][None, None]) < lim
        team.stats["dp_calls"] += 1
        team.stats["uav_plans"] += 1
        new = team.planner.plan_batch(xy[[h]], th[[h]], target_xyz, target_phi, blocked=blocked, avoid=avoid,
                                      avoid_dist=lim, target_path=target_path)[0]
        if new.depth < 2:
            continue
        trial = [new if j == h else p for j, p in enumerate(plans)]
        if not any(c.stage == 0 for c in team.conflicts(trial)):
            return h, new
    return None


def _end_headings(slot: _FirstSlot, i: int, cand, k: np.ndarray) -> np.ndarray:
    """(len(k),) headings at the end of UAV i's candidate moves ``k`` (a best effort's as the engine flies it)."""
    if not cand.best_effort:
        return cand.heading[k]
    times = np.linspace(0.0, slot.config.delta, slot.n_samples)
    start = np.broadcast_to(slot.xy[i], (1, len(k), 2))
    theta = np.full((1, len(k)), slot.th[i])
    return fly_waypoints(start, theta, slot.stage.xy[k][None], slot.config, times)[1][0]
