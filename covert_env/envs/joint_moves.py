"""Joint moves of a waypoint team over one slot, for the safety filter (:mod:`covert_env.envs.safety_filter`):
the candidate flights, eqs. 2 and 3 along them, the priority negotiation with its pair repair, and the backup
plans."""

from __future__ import annotations

import numba
import numpy as np

from covert_env.envs.waypoint_queries import SafetyState
from covert_env.geometry.angles import wrap_heading
from covert_env.geometry.flight import fly_waypoints
from covert_env.geometry.separation import priority_negotiation, separation
from covert_env.geometry.zone import to_world
from covert_env.world.metrics import top_clearance

__all__ = ["Flights", "Plan", "clear_along", "near_tops", "nearest_nodes", "negotiate", "path_separation",
           "sample_bounds", "separated_from", "top_clearance_along"]

#: Far-away stand-in for padded polytope tops (m below the plane): never within d_safe2 of a UAV.
_FAR = 1e9


def path_separation(paths: np.ndarray, others: np.ndarray, first: int = 1) -> np.ndarray:
    """Eq. 2's distance over a slot (:func:`~covert_env.geometry.separation.separation`) at the common instants from
    sample ``first`` on (1: after the start, which no choice changes) of ``paths`` and ``others`` (..., P, 2), broadcast
    against each other."""
    return separation(paths[..., first:, :], others[..., first:, :])


def top_clearance_along(paths: np.ndarray, tops: np.ndarray, altitude: float, first: int = 1) -> np.ndarray:
    """Eq. 3's distance over a slot (:func:`~covert_env.world.metrics.top_clearance`): from UAVs at ``altitude`` flying
    ``paths`` (N, M, P, 2) to the nearest of their copy's tops (N, T, 3), at the samples from ``first`` on; (N, M)."""
    return top_clearance(paths[:, :, first:], altitude, tops).min(axis=-1)


def separated_from(cand: np.ndarray, past: np.ndarray, need: float, first: int, ok: np.ndarray) -> None:
    """``ok &=`` eq. 2 at ``need`` over a slot: candidates ``cand`` (R, M, P, 2) of each copy against the paths
    ``past`` (R, I, P, 2) settled before them; a pair with a NaN sample (no path) counts as separated. The same
    answer as ``(nan_to_num(path_separation(cand[:, :, None], past[:, None], first), nan=inf) >= need).all(2)``
    without the (R, M, I, P) distances: a pair stops at its first sample within ``need``."""
    if past.shape[1]:
        _separated_from(np.ascontiguousarray(cand, np.float64), np.ascontiguousarray(past, np.float64), float(need),
                        int(first), ok)


@numba.njit(cache=True, nogil=True)
def _separated_from(cand, past, need, first, ok):
    """:func:`separated_from`'s loop. A distance well away from ``need`` is settled by its square; one near it is
    compared as ``hypot(dx, dy) >= need``, eq. 2's own test (:func:`~covert_env.geometry.separation.separation`). A pair
    too close still reads its remaining samples for a NaN, which makes it separated (the metric's NaN rule)."""
    r, m, p = cand.shape[:3]
    lo2, hi2 = (need * (1.0 - 1e-9)) ** 2, (need * (1.0 + 1e-9)) ** 2
    for i in range(r):
        for j in range(m):
            if not ok[i, j]:
                continue
            for q in range(past.shape[1]):
                close, nan = False, False
                for s in range(first, p):
                    dx = cand[i, j, s, 0] - past[i, q, s, 0]
                    dy = cand[i, j, s, 1] - past[i, q, s, 1]
                    if dx != dx or dy != dy:
                        nan = True
                        break
                    if not close:
                        d2 = dx * dx + dy * dy
                        if d2 < lo2 or (d2 < hi2 and not np.hypot(dx, dy) >= need):
                            close = True
                if close and not nan:
                    ok[i, j] = False
                    break


def clear_along(paths: np.ndarray, tops: np.ndarray, altitude: float, need: float, first: int = 1) -> np.ndarray:
    """Whether :func:`top_clearance_along` is at least ``need``: (N, M) bool, the same answer (NaN samples are not
    clear) without the (N, M, P, T) distances: a flight stops at its first sample within ``need`` of a top."""
    paths = np.ascontiguousarray(paths, np.float64)
    out = np.empty(paths.shape[:2], bool)
    _clear_along(paths, np.ascontiguousarray(tops, np.float64), float(altitude), float(need), int(first), out)
    return out


@numba.njit(cache=True, nogil=True)
def _clear_along(paths, tops, altitude, need, first, out):
    """:func:`clear_along`'s loop. Each squared distance is summed as :func:`~covert_env.world.metrics.top_clearance`
    sums it; one well below ``need ** 2`` settles the flight, one near it is compared as ``sqrt(d2) < need``, the
    metric's own test (the square root is monotone and correctly rounded)."""
    n, m, p = paths.shape[:3]
    near2 = (need * (1.0 + 1e-9)) ** 2
    near_tops = np.empty(tops.shape[1], np.int64)
    for i in range(n):
        for j in range(m):
            # Broad phase: only the tops within ``need`` (and a margin) of the samples' bounding box can fail a
            # sample; a NaN sample keeps every top, and a top with a NaN coordinate is kept (neither is clear).
            lo_x, lo_y, hi_x, hi_y, nan = np.inf, np.inf, -np.inf, -np.inf, False
            for s in range(first, p):
                x, y = paths[i, j, s, 0], paths[i, j, s, 1]
                if x != x or y != y:
                    nan = True
                    break
                lo_x, hi_x = min(lo_x, x), max(hi_x, x)
                lo_y, hi_y = min(lo_y, y), max(hi_y, y)
            reach = need * (1.0 + 1e-6) + 1e-6
            k = 0
            for t in range(tops.shape[1]):
                tx, ty, tz = tops[i, t, 0], tops[i, t, 1], tops[i, t, 2]
                if (nan or tx != tx or ty != ty or tz != tz
                        or not (tx < lo_x - reach or tx > hi_x + reach or ty < lo_y - reach or ty > hi_y + reach)):
                    near_tops[k] = t
                    k += 1
            ok = True
            for s in range(first, p):
                x, y = paths[i, j, s, 0], paths[i, j, s, 1]
                for q in range(k):
                    t = near_tops[q]
                    dx = x - tops[i, t, 0]
                    dy = y - tops[i, t, 1]
                    dz = altitude - tops[i, t, 2]
                    d2 = dx * dx
                    d2 += dy * dy
                    d2 += dz * dz
                    if not d2 >= near2 and not np.sqrt(d2) >= need:
                        ok = False
                        break
                if not ok:
                    break
            out[i, j] = ok


def sample_bounds(config, samples: int) -> tuple[float, float]:
    """What the filter asks at its ``samples`` instants so that eqs. 2 and 3 hold at every instant of the slot:
    (UAV-UAV distance, distance to a top), m.

    Between two instants dt apart a UAV flies a chord of at most v_max dt and strays from it by at most
    v_max w_max dt^2 / 8 (its speed is constant over the slot, its turn rate at most w_max). Where both ends of a
    chord are at least D' from a point (a top, or, for two UAVs, the origin of their relative position, whose chord
    is at most twice as long and strays twice as far), the chord passes at least sqrt(D'^2 - chord^2 / 4) from it.
    So D' = sqrt((D + stray)^2 + chord^2 / 4) keeps D at every instant."""
    dt = config.delta / (samples - 1)
    chord, stray = config.v_max * dt, config.v_max * config.w_max * dt * dt / 8.0
    return (float(np.sqrt((config.d_safe1 + 2 * stray) ** 2 + chord ** 2)),
            float(np.sqrt((config.d_safe2 + stray) ** 2 + chord ** 2 / 4)))


def near_tops(tops: np.ndarray, altitude: float, d_safe2: float) -> np.ndarray:
    """The tops (B, T', 3) that can come within d_safe2 of the flight plane; padded far below it."""
    tops = np.asarray(tops, float)
    near = np.isfinite(tops).all(axis=-1) & (altitude - tops[..., 2] < d_safe2)
    t = int(near.sum(axis=1).max()) if near.size else 0
    out = np.zeros((len(tops), t, 3))
    out[..., 2] = -_FAR
    b, j = np.nonzero(near)
    slot = np.cumsum(near, axis=1)[b, j] - 1
    out[b, slot] = tops[b, j]
    return out


def nearest_nodes(reach: np.ndarray, available: np.ndarray, lattice: np.ndarray, place: np.ndarray,
                  n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n`` nodes (at most 2) nearest to ``place`` (R, U, 2) among each UAV's ``reach`` (R, U, L) bool, or
    among its copy's ``available`` (R, L) where it reaches none, with their distances: nodes (R, U, n) (-1 padded)
    and distances (R, U, n) (inf padded). The same as ranking ``hypot(lattice - place)`` over those nodes and
    taking the first ``n`` (ties: the lower node), without the (R, U, L) distances (a backup plan's slot asks this
    of every UAV, over the whole lattice)."""
    if not 1 <= n <= 2:
        raise ValueError(f"nearest_nodes: n must be 1 or 2, got {n}")
    r, u, _ = reach.shape
    nodes, dist = np.empty((r, u, n), np.int64), np.empty((r, u, n))
    _nearest_nodes(np.ascontiguousarray(reach), np.ascontiguousarray(available), np.ascontiguousarray(lattice, float),
                   np.ascontiguousarray(place, float), nodes, dist)
    return nodes, dist


@numba.njit(cache=True, nogil=True)
def _nearest_nodes(reach, available, lattice, place, nodes, dist):  # pragma: no cover
    """:func:`nearest_nodes`' loop: one pass over the lattice per UAV, keeping the best ``n`` (strictly smaller
    distance wins, so the lower node keeps a tie, as a stable sort does)."""
    r, u, lat = reach.shape
    n = nodes.shape[2]
    for i in range(r):
        for k in range(u):
            any_reach = False
            for j in range(lat):
                if reach[i, k, j] and available[i, j]:
                    any_reach = True
                    break
            px, py = place[i, k, 0], place[i, k, 1]
            b0, b1, d0, d1 = -1, -1, np.inf, np.inf
            for j in range(lat):
                if not available[i, j] or (any_reach and not reach[i, k, j]):
                    continue
                d = np.hypot(lattice[j, 0] - px, lattice[j, 1] - py)
                if d < d0:
                    b1, d1 = b0, d0
                    b0, d0 = j, d
                elif d < d1:
                    b1, d1 = j, d
            nodes[i, k, 0], dist[i, k, 0] = b0, d0
            if n == 2:
                nodes[i, k, 1], dist[i, k, 1] = b1, d1


class Flights:
    """Candidate moves of B copies' U UAVs to M nodes each: paths (B, U, M, P, 2) at ``samples`` instants (one of
    the filter's :attr:`~covert_env.envs.safety_filter.SafetyFilter.grids`), end poses, clearance of eq. 3, and
    what eqs. 2 and 3 ask at those instants (``sep_need``, ``top_need``: :func:`sample_bounds`). ``flt`` here and
    below is the :class:`~covert_env.envs.safety_filter.SafetyFilter` whose settings apply."""

    def __init__(self, flt, xy, theta, q, phi, nodes, tops, samples: int):
        c = flt.config
        times, self.sep_need, self.top_need = flt.grids[samples]
        # The first instant checked. A flight starts where the last move ended, which was checked on the fine grid
        # (sample_bounds of the filter's samples): a coarser grid asks more, so it checks its start as well, or the
        # margin between its first two instants would rest on an end that lacks it.
        self.first = 1 if samples == flt.samples else 0
        self.nodes = nodes                                                   # (B, U, M), -1: none
        ci, ui, mi = np.nonzero(nodes >= 0)
        b, u, m = nodes.shape
        self.paths = np.full((b, u, m, len(times), 2), np.nan)
        self.end_theta = np.full((b, u, m), np.nan)
        if len(ci):
            goals = to_world(flt.lattice[nodes[ci, ui, mi]][:, None], q[ci], phi[ci])   # (N, 1, 2)
            path, end_theta, *_ = fly_waypoints(xy[ci, ui][:, None], theta[ci, ui][:, None], goals, c, times)
            self.paths[ci, ui, mi] = path[:, 0]
            self.end_theta[ci, ui, mi] = wrap_heading(end_theta[:, 0])
        self.clear = np.zeros((b, u, m), bool)
        self.clear[ci, ui, mi] = True
        self.roomy = self.clear.copy()          # and ends end_margin clear of the tops: room to turn away next slot
        if tops.shape[1] and len(ci):
            self.clear &= clear_along(self.paths.reshape(b, u * m, -1, 2), tops, c.altitude, self.top_need,
                                      self.first).reshape(b, u, m)
            end = top_clearance(self.paths[:, :, :, -1], c.altitude, tops)                     # (B, U, M)
            self.roomy &= self.clear & (end >= c.d_safe2 + flt.end_margin)

    def take(self, idx: np.ndarray) -> Flights:
        """The flights of the copies ``idx`` alone."""
        sub = object.__new__(Flights)
        for name in ("nodes", "paths", "end_theta", "clear", "roomy"):
            setattr(sub, name, getattr(self, name)[idx])
        sub.sep_need, sub.top_need, sub.first = self.sep_need, self.top_need, self.first
        return sub


def negotiate(flt, fl: Flights, rank: np.ndarray, rows: np.ndarray, room: float = 0.0,
               strict: bool = False, repair: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Priority negotiation over the candidates of the copies ``rows`` (B,) bool: per UAV the index (into M) of its
    best-ranked candidate (``rank`` (B, U, M), inf: not a candidate) that is clear and separated from the UAVs
    settled before it; with ``room`` > 0, one that also ends at least d_safe1 + room from their ends where it has
    one (a cramped end leaves the next slot little to choose from). Returns the choices (B, U) (-1 where a UAV had
    none) and the copies left unsettled (B,). ``strict``: only moves that end ``end_margin`` clear of the tops
    (a UAV that ends on the edge of a top's d_safe2, heading at it, has no clear move left). ``repair``: a UAV
    left without a move re-chooses together with a settled UAV (:func:`_repair`); off, the copy stays unsettled."""
    full = np.full(rank.shape[:2], -1)
    idx = np.nonzero(rows)[0]
    if len(idx) == 0:
        return full, np.zeros(len(rows), bool)
    if len(idx) < len(rows):                          # only the copies asked about: negotiate on them alone
        choice, unsettled = negotiate(flt, fl.take(idx), rank[idx], np.ones(len(idx), bool), room, strict, repair)
        full[idx] = choice
        out = np.zeros(len(rows), bool)
        out[idx] = unsettled
        return full, out
    b, u, m = rank.shape
    choice = full
    usable = (fl.roomy if strict else fl.clear) & np.isfinite(rank)

    def settle(order, redo):
        rows = np.nonzero(redo)[0]                       # work on the copies to settle alone
        at = np.arange(len(rows))
        use, rk, od = usable[rows], rank[rows], order[rows]
        pick = np.full((len(rows), u), -1)
        stuck = np.full(len(rows), u)
        chosen = np.full((len(rows), u, fl.paths.shape[3], 2), np.nan)
        for i in range(u):
            k = od[:, i]
            ok, cand = use[at, k], fl.paths[rows, k]                                     # (R, M), (R, M, P, 2)
            if i:
                past = chosen[at[:, None], od[:, :i]]                                     # (R, i, P, 2)
                separated_from(cand, past, fl.sep_need, fl.first, ok)
                if room > 0:
                    end = cand[:, :, None, -1] - past[:, None, :, -1]                       # (R, M, i, 2)
                    roomy = ok & (np.nan_to_num(np.hypot(end[..., 0], end[..., 1]), nan=np.inf)
                                  >= flt.config.d_safe1 + room).all(axis=2)
                    ok = np.where(roomy.any(axis=1, keepdims=True), roomy, ok)
            r = np.where(ok, rk[at, k], np.inf)
            best = np.argmin(r, axis=1)
            has = np.isfinite(r[at, best])
            pick[at, k] = np.where(has, best, -1)
            chosen[at[has], k[has]] = cand[at[has], best[has]]
            # A UAV left without a move re-chooses together with one settled UAV (rare: a loop over those copies).
            for j in np.nonzero(~has)[0] if i and repair else ():
                has[j] = _repair(flt, fl, rank, usable, rows[j], int(k[j]), od[j, :i], pick[j], chosen[j])
            stuck[~has & (stuck == u)] = i
        choice[rows] = pick
        stuck_at = np.full(b, u)
        stuck_at[rows] = stuck
        return stuck_at

    unsettled = priority_negotiation(settle, b, u)
    return choice, unsettled | (choice < 0).any(axis=1)


def _repair(flt, fl: Flights, rank, usable, j: int, k: int, settled: np.ndarray, pick, chosen) -> bool:
    """Copy ``j``'s UAV ``k`` has no move separated from the ``settled`` UAVs: re-choose it together with one of
    them (every pair of their candidates, the nearest settled UAV first); the copy's ``pick`` (U,) and ``chosen``
    paths (U, P, 2) change in place. The pair taken is the best-ranked one separated at every fourth sample from the
    start and at every sample from ``first`` (:func:`_first_separated_pair`)."""
    d1 = fl.sep_need
    near = np.hypot(*(fl.paths[j, k, 0, 0] - chosen[settled, 0]).T) if len(settled) else np.zeros(0)
    for h in settled[np.argsort(near, kind="stable")]:
        rest = settled[settled != h]
        ok_k, ok_h = usable[j, k][None].copy(), usable[j, h][None].copy()
        if len(rest):
            separated_from(fl.paths[j, k][None], chosen[rest][None], d1, fl.first, ok_k)
            separated_from(fl.paths[j, h][None], chosen[rest][None], d1, fl.first, ok_h)
        ck, ch = np.nonzero(ok_k[0])[0], np.nonzero(ok_h[0])[0]
        if not len(ck) or not len(ch):
            continue
        # Every pair, the best-ranked first (ties in the order of (k's candidate, h's candidate)).
        score = (rank[j, k, ck][:, None] + rank[j, h, ch][None]).reshape(-1)
        order = np.argsort(score, kind="stable")
        found = _first_separated_pair(fl.paths[j, k, ck], fl.paths[j, h, ch], order, d1, fl.first)
        if found >= 0:
            pick[k], pick[h] = ck[found // len(ch)], ch[found % len(ch)]
            chosen[k], chosen[h] = fl.paths[j, k, pick[k]], fl.paths[j, h, pick[h]]
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _first_separated_pair(a, b, order, need, first):
    """The first pair ``order[i]`` (pair ``n`` is ``a[n // len(b)]`` with ``b[n % len(b)]``, paths (P, 2)) whose
    distance is at least ``need`` at every fourth sample from 0 and at every sample from ``first``; -1 if none.
    Compared as eq. 2 compares (``hypot(dx, dy) >= need``, a NaN sample is too close); a square well away from
    ``need ** 2`` settles a sample without the square root."""
    nb, p = b.shape[0], a.shape[1]
    lo2, hi2 = (need * (1.0 - 1e-9)) ** 2, (need * (1.0 + 1e-9)) ** 2
    for i in range(len(order)):
        n = order[i]
        u, v = n // nb, n % nb
        ok = True
        for s in range(p):
            if s % 4 != 0 and s < first:
                continue
            dx = a[u, s, 0] - b[v, s, 0]
            dy = a[u, s, 1] - b[v, s, 1]
            d2 = dx * dx + dy * dy
            if not d2 >= hi2 and (d2 < lo2 or not np.hypot(dx, dy) >= need):
                ok = False
                break
        if ok:
            return n
    return -1


class Plan:
    """The backup plans of B copies: from slot ``slot`` on, ``length`` joint moves ``nodes`` (B, D, U), each flown
    from ``starts`` (B, D, U, 2)."""

    def __init__(self, b: int, u: int, depth: int):
        self.slot, self.length = np.full(b, -1), np.zeros(b, np.int64)
        self.nodes, self.starts = np.full((b, depth, u), -1), np.full((b, depth, u, 2), np.nan)

    def set(self, idx, slot, starts, nodes) -> None:
        """Plans for the copies ``idx``: their leading steps with a node for every UAV."""
        self.slot[idx], self.starts[idx], self.nodes[idx] = slot, starts, nodes
        self.length[idx] = np.cumprod((nodes >= 0).all(axis=2), axis=1).sum(axis=1)

    def holds(self, state: SafetyState) -> np.ndarray:
        """(B,) the copies whose plan starts at this slot where their UAVs are (not a plan of an earlier episode)."""
        if self.slot.shape != state.slot.shape or self.nodes.shape[2] != state.xy.shape[1]:
            return np.zeros(len(state.slot), bool)
        where = np.abs(self.starts[:, 0] - state.xy) <= 1e-6
        return (self.slot == state.slot) & (self.length >= 1) & where.all(axis=(1, 2))

    def shift_from(self, old: Plan, idx) -> None:
        """The copies ``idx`` keep the rest of ``old``'s plans (their first move is being flown)."""
        idx = np.nonzero(idx)[0]
        self.slot[idx] = old.slot[idx] + 1
        self.length[idx] = old.length[idx] - 1
        self.nodes[idx, :-1], self.starts[idx, :-1] = old.nodes[idx, 1:], old.starts[idx, 1:]
        self.nodes[idx, -1], self.starts[idx, -1] = -1, np.nan
