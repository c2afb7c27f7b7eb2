"""The safety filter of waypoint teams: eqs. 2 and 3 along the whole flown path, and a safe slot after it.

Any waypoint policy proposes one lattice node per UAV; the filter returns the team's nodes. It keeps a proposal
where the team stays safe, and otherwise moves the fewest UAVs it can to the safe nodes their policy prefers. A
joint move is **safe** when, at every one of the filter's ``samples`` instants of the slot (201 by default, the
start excluded: no choice changes it), every two UAVs are at least d_safe1 apart (eq. 2) and every UAV is at least
d_safe2 from every polytope top (eq. 3). It is **certified** when, from the poses where it ends, the team has a
safe joint move in the next slot too (recursive feasibility, as MPC safety filters have it): the filter finds one
with the same negotiation and keeps it as the **backup** of the next slot. The next slot's lattice is the env's
own prediction at k+1, so the backup is flown exactly as it was checked: where the next slot finds no certified
move, the backup is safe (docs/decisions.md#safety-filter).

Per slot and copy, in order, the first that exists:

1. a certified joint move among the allowed nodes (the env's masks), found by priority negotiation
   (:func:`~covert_env.separation.priority_negotiation`): each UAV takes its most preferred node that is clear of
   the tops and separated from the paths already settled, the proposal first. Where the certificate fails, the
   nodes of the UAV it left stuck and of the teammate ending nearest to it are set aside and the team negotiates
   again (``rounds`` times);
2. the same among all lattice nodes (a node outside the mask is flown as the env flies it, flagged infeasible by
   the env): ``widened``;
3. the backup certified in the previous slot: ``backups``;
4. a safe joint move without a certificate: ``uncertified``;
5. the proposals, unchanged: an ``infeasible`` event (no safe joint move was found). It is counted, never silent.

The samples are the instants the metric of a ``path_samples=201`` env measures. Between two of them the distance
of two UAVs can dip by at most (2 v_max dt)^2 / (8 d_safe1) + v_max w_max dt^2 / 4, about 1 cm at the defaults.

Candidates per UAV: at most ``candidates`` nodes (the proposal, the allowed nodes the policy prefers, and a spread
of the rest); for the certificate ``certificate_candidates`` of the nodes the UAV can reach next slot, the ones
that keep its place behind the target first. Work per slot: the candidates' flights, O(U^2 M P) distances per
negotiation, and the same again for the certificate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from covert_env.angles import wrap_heading
from covert_env.envs import batch
from covert_env.envs.waypoint_queries import SafetyState
from covert_env.reach import reach_table
from covert_env.metrics import top_clearance
from covert_env.separation import priority_negotiation, separation

__all__ = ["FilterStats", "SafetyFilter", "ShieldedPolicy", "path_separation", "top_clearance_along"]

#: Far-away stand-in for padded polytope tops (m below the plane): never within d_safe2 of a UAV.
_FAR = 1e9


def path_separation(paths: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Eq. 2's distance over a slot (:func:`~covert_env.separation.separation`) at the common instants after the
    start (samples 1 to P - 1) of ``paths`` and ``others`` (..., P, 2), broadcast against each other."""
    return separation(paths[..., 1:, :], others[..., 1:, :])


def top_clearance_along(paths: np.ndarray, tops: np.ndarray, altitude: float) -> np.ndarray:
    """Eq. 3's distance over a slot (:func:`~covert_env.metrics.top_clearance`): from UAVs at ``altitude`` flying
    ``paths`` (N, M, P, 2) to the nearest of their copy's tops (N, T, 3), at the samples after the start; (N, M)."""
    return top_clearance(paths[:, :, 1:], altitude, tops).min(axis=-1)


def _near_tops(tops: np.ndarray, altitude: float, d_safe2: float) -> np.ndarray:
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


@dataclass
class FilterStats:
    """What the filter did, counted since construction (or :meth:`SafetyFilter.reset_stats`)."""

    team_slots: int = 0        # team choices filtered (one per copy and slot)
    changed: int = 0           # UAV choices the filter changed
    widened: int = 0           # team choices that needed a node outside the masks
    backups: int = 0           # team choices that flew the previous slot's backup
    uncertified: int = 0       # team choices safe for this slot, with no safe move known after it
    infeasible: int = 0        # team choices with no safe joint move found: the proposals were flown
    events: list = field(default_factory=list)   # (copy, slot) of every infeasible choice

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "events"}


class _Flights:
    """Candidate moves of B copies' U UAVs to M nodes each: paths (B, U, M, P, 2), end poses, clearance of eq. 3."""

    def __init__(self, flt: SafetyFilter, xy, theta, q, phi, nodes, tops):
        c = flt.config
        self.nodes = nodes                                                   # (B, U, M), -1: none
        ci, ui, mi = np.nonzero(nodes >= 0)
        b, u, m = nodes.shape
        self.paths = np.full((b, u, m, len(flt.times), 2), np.nan)
        self.end_theta = np.full((b, u, m), np.nan)
        if len(ci):
            goals = batch.to_world_batch(flt.lattice[nodes[ci, ui, mi]][:, None], q[ci], phi[ci])   # (N, 1, 2)
            path, end_theta, *_ = batch.fly_waypoints(xy[ci, ui][:, None], theta[ci, ui][:, None], goals, c,
                                                      flt.times)
            self.paths[ci, ui, mi] = path[:, 0]
            self.end_theta[ci, ui, mi] = wrap_heading(end_theta[:, 0])
        self.clear = np.zeros((b, u, m), bool)
        self.clear[ci, ui, mi] = True
        self.roomy = self.clear.copy()          # and ends end_margin clear of the tops: room to turn away next slot
        if tops.shape[1] and len(ci):
            gap = top_clearance_along(self.paths.reshape(b, u * m, -1, 2), tops, c.altitude).reshape(b, u, m)
            self.clear &= gap >= c.d_safe2
            end = top_clearance(self.paths[:, :, :, -1], c.altitude, tops)                     # (B, U, M)
            self.roomy &= self.clear & (end >= c.d_safe2 + flt.end_margin)


def _negotiate(flt: SafetyFilter, fl: _Flights, rank: np.ndarray, rows: np.ndarray, room: float = 0.0,
               strict: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Priority negotiation over the candidates of the copies ``rows`` (B,) bool: per UAV the index (into M) of its
    best-ranked candidate (``rank`` (B, U, M), inf: not a candidate) that is clear and separated from the UAVs
    settled before it; with ``room`` > 0, one that also ends at least d_safe1 + room from their ends where it has
    one (a cramped end leaves the next slot little to choose from). Returns the choices (B, U) (-1 where a UAV had
    none) and the copies left unsettled (B,). ``strict``: only moves that end ``end_margin`` clear of the tops
    (a UAV that ends on the edge of a top's d_safe2, heading at it, has no clear move left)."""
    b, u, m = rank.shape
    copies = np.arange(b)
    choice = np.full((b, u), -1)
    usable = (fl.roomy if strict else fl.clear) & np.isfinite(rank) & rows[:, None, None]

    def settle(order, redo):
        pick = np.full((b, u), -1)
        stuck_at = np.full(b, u)
        chosen = np.full((b, u, fl.paths.shape[3], 2), np.nan)
        for i in range(u):
            k = order[:, i]
            ok = usable[copies, k] & redo[:, None]                                         # (B, M)
            if i:
                past = chosen[copies[:, None], order[:, :i]]                                # (B, i, P, 2)
                gap = path_separation(fl.paths[copies, k][:, :, None], past[:, None])      # (B, M, i)
                ok &= (np.nan_to_num(gap, nan=np.inf) >= flt.config.d_safe1).all(axis=2)
                if room > 0:
                    end = fl.paths[copies, k][:, :, None, -1] - past[:, None, :, -1]          # (B, M, i, 2)
                    roomy = ok & (np.nan_to_num(np.hypot(end[..., 0], end[..., 1]), nan=np.inf)
                                  >= flt.config.d_safe1 + room).all(axis=2)
                    ok = np.where(roomy.any(axis=1, keepdims=True), roomy, ok)
            r = np.where(ok, rank[copies, k], np.inf)
            best = np.argmin(r, axis=1)
            has = np.isfinite(r[copies, best])
            pick[copies, k] = np.where(has, best, -1)
            chosen[copies[has], k[has]] = fl.paths[copies[has], k[has], best[has]]
            # A UAV left without a move re-chooses together with one settled UAV (rare: a loop over those copies).
            for j in np.nonzero(redo & ~has)[0] if i else ():
                has[j] = _repair(flt, fl, rank, usable, j, int(k[j]), order[j, :i], pick, chosen)
            stuck_at[(~has) & redo & (stuck_at == u)] = i
        choice[redo] = pick[redo]
        return stuck_at

    unsettled = priority_negotiation(settle, b, u) & rows
    return choice, unsettled | (rows & (choice < 0).any(axis=1))


def _repair(flt, fl: _Flights, rank, usable, j: int, k: int, settled: np.ndarray, pick, chosen) -> bool:
    """Copy ``j``'s UAV ``k`` has no move separated from the ``settled`` UAVs: re-choose it together with one of
    them (every pair of their candidates, the nearest settled UAV first); ``pick`` and ``chosen`` change in place.
    Pairs are screened at every fourth sample, then checked at all of them, the best-ranked pair first."""
    d1 = flt.config.d_safe1
    near = np.hypot(*(fl.paths[j, k, 0, 0] - chosen[j, settled, 0]).T) if len(settled) else np.zeros(0)
    for h in settled[np.argsort(near, kind="stable")]:
        rest = settled[settled != h]
        ok_k, ok_h = usable[j, k].copy(), usable[j, h].copy()
        if len(rest):
            ok_k &= (np.nan_to_num(path_separation(fl.paths[j, k][:, None], chosen[j, rest][None]), nan=np.inf)
                     >= d1).all(axis=1)
            ok_h &= (np.nan_to_num(path_separation(fl.paths[j, h][:, None], chosen[j, rest][None]), nan=np.inf)
                     >= d1).all(axis=1)
        ck, ch = np.nonzero(ok_k)[0], np.nonzero(ok_h)[0]
        if not len(ck) or not len(ch):
            continue
        coarse = path_separation(fl.paths[j, k, ck][:, None, ::4], fl.paths[j, h, ch][None, :, ::4]) >= d1
        a, b = np.nonzero(coarse)
        if not len(a):
            continue
        score = rank[j, k, ck[a]] + rank[j, h, ch[b]]
        order = np.argsort(score, kind="stable")
        for start in range(0, len(order), 256):
            sel = order[start:start + 256]
            exact = path_separation(fl.paths[j, k, ck[a[sel]]], fl.paths[j, h, ch[b[sel]]]) >= d1
            if exact.any():
                first = sel[np.argmax(exact)]
                pick[j, k], pick[j, h] = ck[a[first]], ch[b[first]]
                chosen[j, k], chosen[j, h] = fl.paths[j, k, pick[j, k]], fl.paths[j, h, pick[j, h]]
                return True
    return False


class SafetyFilter:
    """Keeps eqs. 2 and 3 along the flown path for any waypoint team (see the module docstring).

    Args:
        config: the env's :class:`~covert_env.config.Config`; lattice: its waypoint lattice (L, 2).
        samples: instants per slot at which eqs. 2 and 3 are checked (start and end included), >= 2.
        depth: slots after this one that a certificate plans safe moves for (the backup plan), >= 1.
        candidates: nodes tried per UAV and slot; certificate_candidates: per UAV and slot of the backup plan.
        rounds: negotiations per slot whose certificate failed before the filter tries more nodes.
        room: after a failed certificate, ends at least d_safe1 + room (m) apart are preferred (so are the backup
            plan's); end_margin: and ends at least d_safe2 + end_margin (m) from the tops.
    """

    def __init__(self, config, lattice, *, samples: int = 201, depth: int = 3, candidates: int = 48,
                 certificate_candidates: int = 32, rounds: int = 4, room: float = 5.0, end_margin: float = 2.0):
        for name, v, lo in (("samples", samples, 2), ("depth", depth, 1), ("candidates", candidates, 2),
                            ("certificate_candidates", certificate_candidates, 1), ("rounds", rounds, 1)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"SafetyFilter: {name} must be an integer >= {lo}, got {v!r}")
        for name, v in (("room", room), ("end_margin", end_margin)):
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"SafetyFilter: {name} must be a finite number >= 0 (m), got {v!r}")
        self.config, self.lattice = config, np.asarray(lattice, float)
        self.samples, self.depth, self.candidates = int(samples), int(depth), int(candidates)
        self.certificate_candidates, self.rounds = int(certificate_candidates), int(rounds)
        self.room, self.end_margin = float(room), float(end_margin)
        self.times = np.linspace(0.0, 1.0, self.samples) * config.delta
        self._reach = reach_table(config.v_max, config.w_max, config.delta)
        self.stats = FilterStats()
        #: Per copy: (slot, starts (D', U, 2), nodes (D', U)), the backup plan of the slots from ``slot`` on.
        self._backup: dict[int, tuple] = {}

    def reset_stats(self) -> None:
        """Start the counts of :attr:`stats` again."""
        self.stats = FilterStats()

    def forget(self) -> None:
        """Drop the backup plans (call when copies start new episodes)."""
        self._backup = {}

    # ------------------------------------------------------------------ candidates
    @staticmethod
    def _spread(allowed: np.ndarray, pref: np.ndarray, n: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Up to ``n`` (None: all) nodes per row of ``allowed`` (R, L): half the most preferred (``pref`` (R, L),
        lower first), half spread evenly over the rest. Nodes (R, n) (-1 padded) and their ranks (R, n) (inf)."""
        key = np.where(allowed, pref, np.inf)
        order = np.argsort(key, axis=1, kind="stable")
        count, l = allowed.sum(axis=1), allowed.shape[1]
        if n is None or n >= count.max():
            n = max(int(count.max()), 1)
            nodes = order[:, :n]
        else:
            # Rows with at most n allowed nodes take them all; the others the top half and an even spread (a
            # stride above 1, so no node twice).
            top, pos = (n + 1) // 2, np.arange(n)
            rest = top + ((pos - top) * np.maximum(count - top, 0)[:, None]) // max(n - top, 1)
            idx = np.where((count[:, None] <= n) | (pos < top), pos, rest)
            nodes = np.take_along_axis(order, np.minimum(idx, l - 1), axis=1)
        keep = (nodes >= 0) & (np.arange(n) < count[:, None])
        ranks = np.take_along_axis(key, np.maximum(nodes, 0), axis=1)
        return np.where(keep, nodes, -1), np.where(keep, ranks, np.inf)

    def _proposal_pref(self, proposed: np.ndarray, scores) -> np.ndarray:
        """(B, U, L) preference (lower first): minus the policy's scores, or the distance to the proposed node;
        the proposal itself first."""
        if scores is not None:
            pref = -np.asarray(scores, float)
        else:
            diff = self.lattice[None, None] - self.lattice[proposed][:, :, None]
            pref = np.hypot(diff[..., 0], diff[..., 1])
        pref = pref.copy()
        b, u = proposed.shape
        pref[np.arange(b)[:, None], np.arange(u)[None], proposed] = -1e300          # first, and a candidate
        return pref

    # ------------------------------------------------------------------ the filter
    def filter(self, state: SafetyState, proposed, scores=None) -> np.ndarray:
        """The team's nodes (B, U) for the proposals ``proposed`` (B, U) (lattice indices), under ``state`` (the
        env's :meth:`~covert_env.envs.waypoint_queries.WaypointQueries.safety_state` with ``depth`` >= this
        filter's). ``scores`` (B, U, L), higher preferred (e.g. a policy's logits), orders the alternatives;
        default: the nodes nearest to the proposal first."""
        proposed = np.asarray(proposed)
        b, u = state.xy.shape[:2]
        if proposed.shape != (b, u) or not np.issubdtype(proposed.dtype, np.integer):
            raise ValueError(f"SafetyFilter.filter: proposed must be integer nodes of shape {(b, u)}, got "
                             f"{proposed.dtype} {proposed.shape}")
        if proposed.size and (proposed.min() < 0 or proposed.max() >= len(self.lattice)):
            raise ValueError(f"SafetyFilter.filter: proposed nodes must be in [0, {len(self.lattice) - 1}], got "
                             f"[{proposed.min()}, {proposed.max()}]")
        if state.q_ahead.shape[1] < self.depth:
            raise ValueError(f"SafetyFilter.filter: the state looks {state.q_ahead.shape[1]} slot(s) ahead, the "
                             f"filter plans {self.depth}; pass env.safety_state(depth={self.depth})")
        c = self.config
        tops = _near_tops(state.tops, c.altitude, c.d_safe2)
        pref = self._proposal_pref(proposed, scores)
        out = proposed.copy()
        pending = np.ones(b, bool)
        plans: dict[int, tuple] = {}
        # A few candidates first; every allowed node where they leave no certified move; then every node.
        for widen, n in ((False, self.candidates), (False, None), (True, None)):
            if not pending.any():
                break
            allowed = np.ones_like(state.masks) if widen else state.masks.copy()
            allowed[np.arange(b)[:, None], np.arange(u)[None], proposed] = True
            done = self._certified(state, tops, allowed, pref, pending, out, plans, n)
            if widen:
                self.stats.widened += int(done.sum())
            pending &= ~done
        for j in np.nonzero(pending)[0]:                         # the backup plan (rare: a loop over those copies)
            held = self._backup.get(int(j))
            if held is not None and held[0] == int(state.slot[j]) and np.allclose(held[1][0], state.xy[j], atol=1e-6):
                out[j] = held[2][0]
                pending[j] = False
                self.stats.backups += 1
                if len(held[2]) > 1:
                    plans[int(j)] = (held[0] + 1, held[1][1:], held[2][1:])
        if pending.any():
            self._uncertified(state, tops, pref, pending, out)
        self._backup = plans
        self.stats.team_slots += b
        self.stats.changed += int((out != proposed).sum())
        return out

    def _certified(self, state, tops, allowed, pref, rows, out, plans, n) -> np.ndarray:
        """Certified joint moves for the copies ``rows`` among ``n`` (None: all) of the ``allowed`` nodes per UAV;
        fills ``out`` and the next slots' backup ``plans``, returns the copies done."""
        b, u, _ = allowed.shape
        idx = np.nonzero(rows)[0]
        nodes, rank = self._spread(allowed[idx].reshape(len(idx) * u, -1), pref[idx].reshape(len(idx) * u, -1), n)
        nodes, rank = nodes.reshape(len(idx), u, -1), rank.reshape(len(idx), u, -1)
        fl = _Flights(self, state.xy[idx], state.theta[idx], state.q_next[idx], state.phi_next[idx], nodes, tops[idx])
        done, todo = np.zeros(len(idx), bool), np.ones(len(idx), bool)
        uavs = np.arange(u)
        for attempt in range(self.rounds):
            choice, unsettled = _negotiate(self, fl, rank, todo, room=self.room if attempt else 0.0,
                                           strict=attempt > 0)
            todo &= ~unsettled
            if not todo.any():
                break
            ok, plan_nodes, plan_starts, stuck = self._certificate(state, tops, idx, fl, choice, todo)
            for j in np.nonzero(ok)[0]:
                out[idx[j]] = nodes[j, uavs, choice[j]]
                d = int((plan_nodes[j] >= 0).all(axis=1).sum())
                if d:
                    plans[int(idx[j])] = (int(state.slot[idx[j]]) + 1, plan_starts[j, :d], plan_nodes[j, :d])
            done |= ok
            todo &= ~ok
            if not todo.any():
                break
            # Set aside the stuck UAV's node and that of the teammate ending nearest to it, and negotiate again.
            for j in np.nonzero(todo)[0]:
                ends = fl.paths[j, uavs, choice[j], -1]
                d = np.hypot(*(ends - ends[stuck[j]]).T)
                d[stuck[j]] = np.inf
                rank[j, [stuck[j], int(np.argmin(d))], choice[j, [stuck[j], int(np.argmin(d))]]] = np.inf
        result = np.zeros(b, bool)
        result[idx[done]] = True
        return result

    def _certificate(self, state, tops, idx, fl, choice, rows):
        """For the copies ``rows`` (of ``idx``) whose joint move ``choice`` is settled: a backup plan of safe joint
        moves for the next ``depth`` slots (those the episode has) from where it ends. Returns ok (R,), the plan's
        nodes (R, D, U) and start positions (R, D, U, 2), and per failed copy the UAV left stuck (R,)."""
        r, u = choice.shape
        plan_nodes, plan_starts = np.full((r, self.depth, u), -1), np.full((r, self.depth, u, 2), np.nan)
        stuck = np.zeros(r, np.int64)
        j = np.nonzero(rows)[0]
        xy = fl.paths[j[:, None], np.arange(u), choice[j], -1]                                  # (R', U, 2)
        th = fl.end_theta[j[:, None], np.arange(u), choice[j]]
        alive = np.ones(len(j), bool)
        for d in range(self.depth):
            sub = np.nonzero(alive & (state.slots_left[idx[j]] > d))[0]
            if not len(sub):
                break
            plan_starts[j[sub], d] = xy[sub]
            q, phi = state.q_ahead[idx[j[sub]], d], state.phi_ahead[idx[j[sub]], d]
            nodes, good, ends, end_th, stuck_uav = self._safe_step(xy[sub], th[sub], q, phi, tops[idx[j[sub]]])
            plan_nodes[j[sub[good]], d] = nodes[good]
            xy[sub[good]], th[sub[good]] = ends[good], end_th[good]
            alive[sub[~good]] = False
            stuck[j[sub[~good]]] = stuck_uav[~good]
        ok = np.zeros(r, bool)
        ok[j[alive]] = True
        return ok, plan_nodes, plan_starts, stuck

    def _safe_step(self, xy, th, q, phi, tops):
        """One slot of a backup plan from poses (R, U): a safe joint move among the nodes each UAV can reach
        (lattice at q, phi), the nodes that keep its place behind the target first, roomy ends where there are.
        Returns nodes (R, U), found (R,), end positions (R, U, 2) and headings (R, U), the stuck UAV (R,)."""
        r, u = th.shape
        lat = len(self.lattice)
        reach = self._reach.reachable(xy, th, q, phi, self.lattice, exact=False)                  # (R, U, L)
        reach[~reach.any(axis=2)] = True                 # no node reachable: best efforts toward every node
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        dx, dy = xy[..., 0] - q[:, None, 0], xy[..., 1] - q[:, None, 1]
        place = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)                          # target frame
        diff = self.lattice[None, None] - place[:, :, None]
        pref = np.hypot(diff[..., 0], diff[..., 1])
        out = np.full((r, u), -1)
        found = np.zeros(r, bool)
        stuck = np.zeros(r, np.int64)
        ends, end_th = np.full((r, u, 2), np.nan), np.full((r, u), np.nan)
        todo = np.ones(r, bool)
        for n in (self.certificate_candidates, None):          # a few nodes, then every reachable one
            sub = np.nonzero(todo)[0]
            nodes, rank = self._spread(reach[sub].reshape(-1, lat), pref[sub].reshape(-1, lat), n)
            nodes, rank = nodes.reshape(len(sub), u, -1), rank.reshape(len(sub), u, -1)
            nf = _Flights(self, xy[sub], th[sub], q[sub], phi[sub], nodes, tops[sub])
            pick, unsettled = _negotiate(self, nf, rank, np.ones(len(sub), bool), room=self.room, strict=True)
            if unsettled.any():
                again, unsettled2 = _negotiate(self, nf, rank, unsettled)
                pick[unsettled], unsettled = again[unsettled], unsettled2
            good = ~unsettled
            g = sub[good]
            sel = pick[good]
            out[g] = nodes[good][np.arange(len(g))[:, None], np.arange(u), sel]
            ends[g] = nf.paths[good][np.arange(len(g))[:, None], np.arange(u), sel, -1]
            end_th[g] = nf.end_theta[good][np.arange(len(g))[:, None], np.arange(u), sel]
            found[g] = True
            stuck[sub[~good]] = np.argmax(pick[~good] < 0, axis=1)
            todo[g] = False
            if not todo.any():
                break
        return out, found, ends, end_th, stuck

    def _uncertified(self, state, tops, pref, rows, out) -> None:
        """A safe joint move without a certificate for the copies ``rows``, or the proposals (infeasible events)."""
        u = state.xy.shape[1]
        idx = np.nonzero(rows)[0]
        allowed = np.ones((len(idx) * u, len(self.lattice)), bool)
        nodes, rank = self._spread(allowed, pref[idx].reshape(len(idx) * u, -1), None)
        nodes, rank = nodes.reshape(len(idx), u, -1), rank.reshape(len(idx), u, -1)
        fl = _Flights(self, state.xy[idx], state.theta[idx], state.q_next[idx], state.phi_next[idx], nodes, tops[idx])
        choice, unsettled = _negotiate(self, fl, rank, np.ones(len(idx), bool))
        for j in range(len(idx)):
            if unsettled[j]:
                self.stats.infeasible += 1
                self.stats.events.append((int(idx[j]), int(state.slot[idx[j]])))
            else:
                out[idx[j]] = nodes[j, np.arange(u), choice[j]]
                self.stats.uncertified += 1


class ShieldedPolicy:
    """Any waypoint policy of the harness's interface (``reset(env, seed)``, ``act(observations, env)``) flown
    through a :class:`SafetyFilter` on the PettingZoo parallel env: the spec suffix ``+shield``. Where the policy
    leaves its node scores in ``last_logits`` (U, L) (the learned teams of ``training.pretrained`` do), the filter
    orders each UAV's alternatives by them; otherwise by the distance to the proposed node."""

    def __init__(self, policy, **filter_kw):
        self.policy, self.filter_kw = policy, filter_kw
        self.name = f"{getattr(policy, 'name', 'policy')}+shield"
        self.env_settings = getattr(policy, "env_settings", None)
        self.safety: SafetyFilter | None = None

    @staticmethod
    def _parallel(env):
        """The PettingZoo parallel env of ``env`` (itself, or the one inside a Gymnasium single-UAV env)."""
        inner = getattr(env, "unwrapped", env)
        return getattr(inner, "par", inner)

    def reset(self, env, seed: int | None = None) -> None:
        self.policy.reset(env, seed)
        par = self._parallel(env)
        if par.action_mode != "waypoint":
            raise ValueError(f"{self.name}: the safety filter is for waypoint teams (action_mode='waypoint'), got "
                             f"{par.action_mode!r}")
        if self.safety is None or self.safety.config != par.config:
            self.safety = SafetyFilter(par.config, par.lattice, **self.filter_kw)
        self.safety.forget()
        self._at_reset = self.safety.stats.as_dict()

    def episode_counts(self) -> dict:
        """What the filter did since the last ``reset`` (the keys of :class:`FilterStats`, without the events)."""
        now = self.safety.stats.as_dict()
        return {k: v - self._at_reset[k] for k, v in now.items()}

    def act(self, observations, env):
        par = self._parallel(env)
        acts = self.policy.act(observations, env)
        agents = list(par.possible_agents)
        if not isinstance(acts, dict):                                      # a Gymnasium single-UAV env
            return int(self.safety.filter(par.safety_state(self.safety.depth), np.array([[int(acts)]]))[0, 0])
        if any(a not in acts for a in agents):                              # the episode is ending
            return acts
        proposed = np.array([[int(acts[a]) for a in agents]])
        scores = getattr(self.policy, "last_logits", None)
        if scores is not None and np.shape(scores) != (len(agents), len(par.lattice)):
            scores = None
        safe = self.safety.filter(par.safety_state(self.safety.depth), proposed,
                                  None if scores is None else np.asarray(scores, float)[None])[0]
        return {a: int(safe[i]) for i, a in enumerate(agents)}
