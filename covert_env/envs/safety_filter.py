"""The safety filter of waypoint teams: eqs. 2 and 3 along the whole flown path, and safe slots after it.

Any waypoint policy proposes one lattice node per UAV; the filter returns the team's nodes. It keeps a proposal
where the team stays safe, and otherwise moves UAVs to the safe nodes their policy prefers. A joint move is
**safe** when, at every one of the filter's ``samples`` instants of the slot (201 by default, the start excluded:
no choice changes it), every two UAVs are at least d_safe1 apart (eq. 2) and every UAV is at least d_safe2 from
every polytope top (eq. 3). It is **certified** when, from the poses where it ends, the team has safe joint moves
for the next ``depth`` slots too (recursive feasibility, as MPC safety filters have it): the filter plans them
with the same negotiation, each UAV keeping its place behind the target where it can, and keeps them as the
**backup plan**. The later lattices are the env's own predictions for those slots, so the plan is flown exactly
as it was checked: where a later slot finds no certified move, the plan's next move is safe
(docs/decisions/learning.md#safety-filter).

With ``min_reach`` (the viability rule, off by default), a UAV whose proposal ends where fewer than ``min_reach`` of
the next slot's nodes are reachable proposes its preferred node that reaches that many instead, and the search
ranks the dead ends so found last. Per slot and copy, in order, the first that exists:

1. a certified joint move among a few of the allowed nodes (the env's masks) per UAV, found by priority
   negotiation (:func:`~covert_env.geometry.separation.priority_negotiation`): each UAV takes its most preferred node
   that is clear of the tops and separated from the paths already settled, the proposal first. The search widens in
   stages, each for the copies the one before left without a certified move: the proposals alone (their
   certificate tries the 2 nodes per UAV and later slot that keep its place behind the target best); 8 nodes
   per UAV (certificates over 8); ``candidates`` nodes (certificates over ``certificate_candidates``, then over
   every reachable node). In the last, a UAV left without a move re-chooses together with a settled UAV (pair
   repair). Where a certificate fails, the nodes of the UAV it left stuck and of the teammate ending nearest to
   it are set aside and the team negotiates again, preferring roomy ends (ends d_safe1 + ``room`` apart and
   d_safe2 + ``end_margin`` from the tops), up to ``rounds`` times;
2. the same among every allowed node, then among every lattice node (a node outside the mask is flown as the env
   flies it, flagged infeasible by the env);
3. the backup plan's next move: ``backups``;
4. a safe joint move without a certificate: ``uncertified``;
5. the proposals, unchanged: an ``infeasible`` event (no safe joint move was found), counted with its copy and
   slot. The filter never fails silently.

The guarantee holds between the samples too: at the samples the filter asks for a little more than d_safe1 and
d_safe2 (:func:`sample_bounds`: 7 mm and 1 mm more at 201 samples and the default kinematics, 0.7 m and 0.1 m at 21),
enough that no flight can come closer in between. The backup plan's moves are checked at ``certificate_samples``
instants (21 by default) in the first stages, their start included (it was checked on the finer grid, with less
room), and at ``samples`` in the stages with pair repair: either way a safe move, with more room asked at fewer
instants.

Work per slot and copy: O(U^2 M P) distances per negotiation among M candidates per UAV, the flights of the
candidates, and per slot of the backup plan the same for its candidates. A copy whose proposals are kept costs
about 4 U flights (the proposals and 2 per UAV and later slot) and the distances between them; the later stages
run only for the copies the earlier leave without a certified move.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from covert_env.envs import batch
from covert_env.envs.joint_moves import (
    Flights,
    Plan,
    near_tops,
    nearest_nodes,
    negotiate,
    path_separation,
    sample_bounds,
    top_clearance_along,
)
from covert_env.envs.viability import ViabilityRule, dead_ends_after
from covert_env.envs.waypoint_queries import SafetyState
from covert_env.geometry.reach import reach_table
from covert_env.geometry.zone import to_target_frame

__all__ = ["FilterStats", "SafetyFilter", "SafetyFilteredVectorEnv", "ShieldedPolicy", "path_separation",
           "sample_bounds", "top_clearance_along"]


@dataclass
class FilterStats:
    """What the filter did, counted since construction (or :meth:`SafetyFilter.reset_stats`)."""

    team_slots: int = 0        # team choices filtered (one per copy and slot)
    changed: int = 0           # UAV choices the filter changed
    widened: int = 0           # team choices where the filter moved a UAV to a node outside its mask
    backups: int = 0           # team choices that flew the backup plan's next move
    uncertified: int = 0       # team choices safe for this slot, with no safe move known after it
    infeasible: int = 0        # team choices with no safe joint move found: the proposals were flown
    events: list = field(default_factory=list)   # (copy, slot) of every infeasible choice

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "events"}


class _Stage(NamedTuple):
    """One stage of the filter's search for a certified joint move."""

    widen: bool                 # every lattice node a candidate, not only the allowed ones
    candidates: int | None      # nodes tried per UAV for this slot (None: all)
    certificate: tuple          # nodes tried per UAV and slot of the backup plan, in turn (None: every reachable)
    rounds: int                 # negotiations whose certificate failed before the next stage
    repair: bool                # pair repair (joint_moves._repair) where a UAV is left without a move
    certificate_samples: int    # instants per slot at which the backup plan's moves are checked


class SafetyFilter:
    """Keeps eqs. 2 and 3 along the flown path for any waypoint team (see the module docstring).

    Args:
        config: the env's :class:`~covert_env.world.config.Config`; lattice: its waypoint lattice (L, 2).
        samples: instants per slot at which eqs. 2 and 3 are checked (start and end included), >= 2.
        certificate_samples: the same for the backup plan's moves in the first stages, in [2, samples]; default
            21 (``samples`` if fewer).
        depth: slots after this one that a certificate plans safe moves for (the backup plan), >= 1.
        candidates: nodes tried per UAV and slot; certificate_candidates: per UAV and slot of the backup plan.
        rounds: negotiations per slot whose certificate failed before the filter tries more nodes.
        room: after a failed certificate, ends at least d_safe1 + room (m) apart are preferred (so are the backup
            plan's); end_margin: and ends at least d_safe2 + end_margin (m) from the tops.
        min_reach: the viability rule (0: off): a UAV whose proposal ends where fewer than ``min_reach`` of the
            next slot's lattice nodes are reachable has every allowed node tested and proposes its most preferred
            node that reaches that many (where none does, one that reaches most); the search ranks the nodes below
            that bar last, and may still fly one where safety asks for it. A team that keeps the zone needs it
            (docs/decisions/learning.md#safety-filter).
    """

    def __init__(self, config, lattice, *, samples: int = 201, certificate_samples: int | None = None, depth: int = 3,
                 candidates: int = 48, certificate_candidates: int = 32, rounds: int = 4, room: float = 5.0,
                 end_margin: float = 2.0, min_reach: int = 0):
        if certificate_samples is None:
            certificate_samples = min(21, samples) if isinstance(samples, (int, np.integer)) else samples
        for name, v, lo in (("samples", samples, 2), ("certificate_samples", certificate_samples, 2),
                            ("depth", depth, 1), ("candidates", candidates, 2),
                            ("certificate_candidates", certificate_candidates, 1), ("rounds", rounds, 1),
                            ("min_reach", min_reach, 0)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"SafetyFilter: {name} must be an integer >= {lo}, got {v!r}")
        if certificate_samples > samples:
            raise ValueError(f"SafetyFilter: certificate_samples must be at most samples ({samples}), got "
                             f"{certificate_samples}")
        for name, v in (("room", room), ("end_margin", end_margin)):
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not 0 <= v < np.inf:
                raise ValueError(f"SafetyFilter: {name} must be a finite number >= 0 (m), got {v!r}")
        lattice = np.asarray(lattice, float)
        if lattice.ndim != 2 or lattice.shape[1] != 2 or not len(lattice) or not np.isfinite(lattice).all():
            raise ValueError(f"SafetyFilter: lattice must be finite target-frame offsets of shape (L, 2), L >= 1, "
                             f"got shape {lattice.shape}")
        self.config, self.lattice = config, lattice
        self.samples, self.certificate_samples = int(samples), int(certificate_samples)
        self.depth, self.candidates = int(depth), int(candidates)
        self.certificate_candidates, self.rounds = int(certificate_candidates), int(rounds)
        self.room, self.end_margin = float(room), float(end_margin)
        self.min_reach = int(min_reach)
        #: Per number of instants: the instants (s) and what eqs. 2 and 3 ask there (m, :func:`sample_bounds`).
        self.grids = {n: (np.linspace(0.0, 1.0, n) * config.delta, *sample_bounds(config, n))
                      for n in {self.samples, self.certificate_samples}}
        self._reach = reach_table(config.v_max, config.w_max, config.delta)
        #: The viability rule (None: off).
        self.viability = ViabilityRule(config, lattice, self.min_reach, self.grids[self.certificate_samples][0],
                                       self._reach) if self.min_reach else None
        self.stats = FilterStats()
        self._plan = Plan(0, 0, self.depth)
        full, coarse, fine = (self.certificate_candidates, None), self.certificate_samples, self.samples
        # Cheapest first; most copies are done by the first stage, whose work is a few flights per UAV.
        self._search = (_Stage(False, 1, (2,), 1, False, coarse),            # the proposals, keeping places after
                        _Stage(False, 8, (8,), 2, False, coarse),            # a few alternatives
                        _Stage(False, self.candidates, (self.certificate_candidates,), self.rounds, False, coarse),
                        _Stage(False, self.candidates, full, self.rounds, True, fine),
                        _Stage(False, None, full, self.rounds, True, fine),  # every allowed node
                        _Stage(True, None, full, self.rounds, True, fine))   # every lattice node

    def reset_stats(self) -> None:
        """Start the counts of :attr:`stats` again."""
        self.stats = FilterStats()

    def forget(self) -> None:
        """Drop the backup plans (call when copies start new episodes)."""
        self._plan = Plan(0, 0, self.depth)

    # ------------------------------------------------------------------ candidates
    @staticmethod
    def _spread(allowed: np.ndarray, pref: np.ndarray, n: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Up to ``n`` (None: all) nodes per row of ``allowed`` (R, L): half the most preferred (``pref`` (R, L),
        finite, lower first), half spread evenly over the rest. Nodes (R, n) (-1 padded) and their ranks (R, n)."""
        key = np.where(allowed, pref, np.inf)
        count, l = allowed.sum(axis=1), allowed.shape[1]
        if n is not None and n <= 2:                      # the best two are the spread of two: no full sort
            rows, key, best = np.arange(len(key)), key.copy(), []
            for _ in range(n):                            # argmin takes the first of equals, as a stable sort
                best.append(np.argmin(key, axis=1))
                key[rows, best[-1]] = np.inf
            nodes = np.stack(best, axis=1)
            keep = np.arange(n) < count[:, None]
            return np.where(keep, nodes, -1), np.where(keep, np.take_along_axis(pref, nodes, axis=1), np.inf)
        order = np.argsort(key, axis=1, kind="stable")
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
        """(B, U, L) finite preference (lower first): minus the policy's scores (a score of -inf or NaN: last), or
        the distance to the proposed node; the proposal itself first."""
        if scores is not None:
            pref = -np.asarray(scores, float)
            pref = np.where(np.isfinite(pref), pref, 1e300)
        else:
            diff = self.lattice[None, None] - self.lattice[proposed][:, :, None]
            pref = np.hypot(diff[..., 0], diff[..., 1])
        b, u = proposed.shape
        pref[np.arange(b)[:, None], np.arange(u)[None], proposed] = -1e300
        return pref

    def _check(self, state: SafetyState, proposed, scores) -> np.ndarray:
        """``proposed`` as checked integer nodes (B, U); ``scores`` and ``state`` checked against the filter."""
        proposed = np.asarray(proposed)
        b, u = state.xy.shape[:2]
        lat = len(self.lattice)
        if state.masks.shape != (b, u, lat):
            raise ValueError(f"SafetyFilter.filter: the state's masks have shape {state.masks.shape}, the filter's "
                             f"lattice {lat} nodes; make the filter with the env's config and lattice")
        if proposed.shape != (b, u) or not np.issubdtype(proposed.dtype, np.integer):
            raise ValueError(f"SafetyFilter.filter: proposed must be integer nodes of shape {(b, u)}, got "
                             f"{proposed.dtype} {proposed.shape}")
        if proposed.size and (proposed.min() < 0 or proposed.max() >= lat):
            raise ValueError(f"SafetyFilter.filter: proposed nodes must be in [0, {lat - 1}], got "
                             f"[{proposed.min()}, {proposed.max()}]")
        if scores is not None and (np.shape(scores) != (b, u, lat) or np.asarray(scores).dtype.kind not in "fiu"):
            raise ValueError(f"SafetyFilter.filter: scores must be real numbers of shape {(b, u, lat)} (copies, UAVs, "
                             f"nodes), got {np.asarray(scores).dtype} {np.shape(scores)}")
        if state.q_ahead.shape[1] < self.depth:
            raise ValueError(f"SafetyFilter.filter: the state looks {state.q_ahead.shape[1]} slot(s) ahead, the "
                             f"filter plans {self.depth}; pass env.safety_state(depth={self.depth})")
        return proposed

    # ------------------------------------------------------------------ the filter
    def filter(self, state: SafetyState, proposed, scores=None, available=None) -> np.ndarray:
        """The team's nodes (B, U) for the proposals ``proposed`` (B, U) (lattice indices), under ``state`` (the
        env's :meth:`~covert_env.envs.vector.CovertSensingVectorEnv.safety_state` with ``depth`` >= this
        filter's). ``scores`` (B, U, L), higher preferred (e.g. a policy's logits; -inf: last), orders the
        alternatives; default: the nodes nearest to the proposal first. ``available`` (B, L) bool: the nodes a copy
        may fly to at all, where the filter looks beyond the masks (default: every lattice node; a mix of tasks
        whose lattices differ passes each copy's own)."""
        proposed = self._check(state, proposed, scores)
        b, u = proposed.shape
        if available is None:
            available = np.ones((b, len(self.lattice)), bool)
        elif np.shape(available) != (b, len(self.lattice)) or np.asarray(available).dtype != bool:
            raise ValueError(f"SafetyFilter.filter: available must be bools of shape {(b, len(self.lattice))} "
                             f"(copies, nodes), got {np.asarray(available).dtype} {np.shape(available)}")
        available = np.asarray(available)
        off = ~available[np.arange(b)[:, None], proposed]
        if off.any():
            c, i = np.argwhere(off)[0]
            raise ValueError(f"SafetyFilter.filter: copy {c}'s UAV {i} proposed node {proposed[c, i]}, which is not "
                             "among its available nodes")
        tops = near_tops(state.tops, self.config.altitude, max(g[2] for g in self.grids.values()))
        given = proposed
        scores = None if scores is None else np.asarray(scores)
        demoted = None
        if self.viability is not None:
            proposed, demoted = self.viability.apply(
                state, given, lambda c, i: self._proposal_pref(given[c], None if scores is None else
                                                               scores[c])[np.arange(len(c)), i], available)
        out, plan = proposed.copy(), Plan(b, u, self.depth)
        pending = np.ones(b, bool)
        # The preferences over the lattice, for the copies still pending when a stage first needs them (later
        # stages and the uncertified search take fewer).
        pref, have = np.empty((b, u, len(self.lattice))), np.zeros(b, bool)

        def preferences(idx, dead_last=False):
            new = idx[~have[idx]]
            if len(new):
                pref[new] = self._proposal_pref(proposed[new], None if scores is None else scores[new])
                have[new] = True
            if dead_last and demoted is not None:        # the viability rule's dead ends, after the masks' others
                return dead_ends_after(pref[idx], demoted[idx])
            return pref[idx]

        for stage in self._search:
            idx = np.nonzero(pending)[0]
            if not len(idx):
                break
            if stage.candidates == 1:                    # the proposals alone, each its UAV's first choice
                nodes, rank = proposed[idx][..., None], np.full((len(idx), u, 1), -1e300)
            else:
                allowed = np.repeat(available[idx, None], u, axis=1) if stage.widen else state.masks[idx]
                allowed[np.arange(len(idx))[:, None], np.arange(u)[None], proposed[idx]] = True
                nodes, rank = self._spread(allowed.reshape(len(idx) * u, -1),
                                           preferences(idx, not stage.widen).reshape(len(idx) * u, -1),
                                           stage.candidates)
                nodes, rank = nodes.reshape(len(idx), u, -1), rank.reshape(len(idx), u, -1)
                if self.viability is not None and stage.candidates is not None:
                    rank = self.viability.dead_ends_last(SafetyState(*(f[idx] for f in state)), nodes, rank,
                                                         available[idx])
            pending[idx[self._certified(state, tops, idx, nodes, rank, out, plan, stage, available)]] = False
        held = pending & self._plan.holds(state)                      # the backup plan's next move
        if held.any():
            out[held] = self._plan.nodes[held, 0]
            plan.shift_from(self._plan, held)
            pending &= ~held
        if pending.any():
            self._uncertified(state, tops, preferences(np.nonzero(pending)[0]), pending, out, available)
        self._plan = plan
        moved = out != given
        self.stats.team_slots += b
        self.stats.changed += int(moved.sum())
        self.stats.backups += int(held.sum())
        off_mask = ~np.take_along_axis(state.masks, out[..., None], axis=2)[..., 0]
        self.stats.widened += int((moved & off_mask).any(axis=1).sum())
        return out

    def _certified(self, state, tops, idx, nodes, rank, out, plan, stage: _Stage, available) -> np.ndarray:
        """Certified joint moves for the copies ``idx`` among their candidates ``nodes`` (R, U, M) ranked by
        ``rank`` (lower first, inf: none; changed in place); fills ``out`` and the next slots' backup ``plan``,
        returns which of them are done (R,)."""
        u = nodes.shape[1]
        fl = Flights(self, state.xy[idx], state.theta[idx], state.q_next[idx], state.phi_next[idx], nodes, tops[idx],
                     self.samples)
        done, todo = np.zeros(len(idx), bool), np.ones(len(idx), bool)
        uavs = np.arange(u)
        for attempt in range(stage.rounds):
            choice, unsettled = negotiate(self, fl, rank, todo, room=self.room if attempt else 0.0,
                                           strict=attempt > 0, repair=stage.repair)
            todo &= ~unsettled
            if not todo.any():
                break
            ok, plan_nodes, plan_starts, stuck = self._certificate(state, tops, idx, fl, choice, todo, stage,
                                                                   available)
            j = np.nonzero(ok)[0]
            out[idx[j]] = np.take_along_axis(nodes[j], choice[j][..., None], axis=2)[..., 0]
            plan.set(idx[j], state.slot[idx[j]] + 1, plan_starts[j], plan_nodes[j])
            done |= ok
            todo &= ~ok
            if not todo.any():
                break
            # Set aside the stuck UAV's node and that of the teammate ending nearest to it, and negotiate again.
            r = np.nonzero(todo)[0]
            ends = fl.paths[r[:, None], uavs, choice[r], -1]                                      # (R, U, 2)
            gap = np.hypot(*np.moveaxis(ends - ends[np.arange(len(r)), stuck[r]][:, None], -1, 0))
            gap[np.arange(len(r)), stuck[r]] = np.inf
            for who in (stuck[r], np.argmin(gap, axis=1)):
                rank[r, who, choice[r, who]] = np.inf
        return done

    def _certificate(self, state, tops, idx, fl, choice, rows, stage: _Stage, available):
        """For the copies ``rows`` (of ``idx``) whose joint move ``choice`` is settled: a backup plan of safe joint
        moves for the next ``depth`` slots (those the episode has) from where it ends, among the ``available``
        nodes (B, L). Returns ok (R,), the plan's
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
            nodes, good, ends, end_th, stuck_uav = self._safe_step(xy[sub], th[sub], q, phi, tops[idx[j[sub]]],
                                                                   stage, available[idx[j[sub]]])
            plan_nodes[j[sub[good]], d] = nodes[good]
            xy[sub[good]], th[sub[good]] = ends[good], end_th[good]
            alive[sub[~good]] = False
            stuck[j[sub[~good]]] = stuck_uav[~good]
        ok = np.zeros(r, bool)
        ok[j[alive]] = True
        return ok, plan_nodes, plan_starts, stuck

    def _safe_step(self, xy, th, q, phi, tops, stage: _Stage, available):
        """One slot of a backup plan from poses (R, U): a safe joint move among ``stage.certificate`` of the
        ``available`` nodes (R, L) each UAV can reach (lattice at q, phi), the nodes that keep its place behind the
        target first, roomy ends where there are.
        Returns nodes (R, U), found (R,), end positions (R, U, 2) and headings (R, U), the stuck UAV (R,)."""
        r, u = th.shape
        lat = len(self.lattice)
        reach = self._reach.reachable(xy, th, q, phi, self.lattice, exact=False)                 # (R, U, L)
        place = to_target_frame(xy - q[:, None], np.cos(phi)[:, None], np.sin(phi)[:, None])      # (R, U, 2)
        pref = None
        out = np.full((r, u), -1)
        found = np.zeros(r, bool)
        stuck = np.zeros(r, np.int64)
        ends, end_th = np.full((r, u, 2), np.nan), np.full((r, u), np.nan)
        todo = np.ones(r, bool)
        for n in stage.certificate:
            sub = np.nonzero(todo)[0]
            if n is not None and n <= 2:                 # the nearest alone: no (R, U, L) distances
                nodes, rank = nearest_nodes(reach[sub], available[sub], self.lattice, place[sub], n)
            else:
                if pref is None:                         # no node reachable: best efforts toward every node
                    reach &= available[:, None]
                    none = ~reach.any(axis=2)
                    reach[none] = np.broadcast_to(available[:, None], reach.shape)[none]
                    diff = self.lattice[None, None] - place[:, :, None]
                    pref = np.hypot(diff[..., 0], diff[..., 1])
                nodes, rank = self._spread(reach[sub].reshape(-1, lat), pref[sub].reshape(-1, lat), n)
                nodes, rank = nodes.reshape(len(sub), u, -1), rank.reshape(len(sub), u, -1)
            nf = Flights(self, xy[sub], th[sub], q[sub], phi[sub], nodes, tops[sub], stage.certificate_samples)
            pick, unsettled = negotiate(self, nf, rank, np.ones(len(sub), bool), room=self.room, strict=True,
                                        repair=stage.repair)
            if unsettled.any():
                again, unsettled2 = negotiate(self, nf, rank, unsettled, repair=stage.repair)
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

    def _uncertified(self, state, tops, pref, rows, out, available) -> None:
        """A safe joint move without a certificate for the copies ``rows``, or the proposals (infeasible events);
        ``pref`` (R, U, L): their preferences."""
        u = state.xy.shape[1]
        idx = np.nonzero(rows)[0]
        allowed = np.repeat(available[idx], u, axis=0)
        nodes, rank = self._spread(allowed, pref.reshape(len(idx) * u, -1), None)
        nodes, rank = nodes.reshape(len(idx), u, -1), rank.reshape(len(idx), u, -1)
        fl = Flights(self, state.xy[idx], state.theta[idx], state.q_next[idx], state.phi_next[idx], nodes, tops[idx],
                     self.samples)
        choice, unsettled = negotiate(self, fl, rank, np.ones(len(idx), bool))
        j = np.nonzero(~unsettled)[0]
        out[idx[j]] = np.take_along_axis(nodes[j], choice[j][..., None], axis=2)[..., 0]
        self.stats.uncertified += len(j)
        self.stats.infeasible += int(unsettled.sum())
        self.stats.events += [(int(c), int(state.slot[c])) for c in idx[unsettled]]


class ShieldedPolicy:
    """Any waypoint policy of the harness's interface (``reset(env, seed)``, ``act(observations, env)``) flown
    through a :class:`SafetyFilter` on the PettingZoo parallel env: the spec suffix ``+shield``. Where the policy
    leaves its node scores in ``last_logits`` (U, L) (the learned teams of ``training.pretrained`` do) and
    ``use_scores`` is True, the filter orders each UAV's alternatives by them; otherwise by the distance to the
    proposed node (as :class:`SafetyFilteredVectorEnv` does in training unless it is given scores)."""

    def __init__(self, policy, *, use_scores: bool = True, **filter_kw):
        self.policy, self.filter_kw, self.use_scores = policy, filter_kw, use_scores
        self.name = f"{getattr(policy, 'name', 'policy')}+shield"
        self.env_settings = getattr(policy, "env_settings", None)
        if hasattr(policy, "card"):                 # a shipped team flown through the filter is still its card's
            self.card = policy.card
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
        if self.safety is None:
            raise RuntimeError(f"{self.name}: episode_counts() before reset(); call reset(env) first")
        now = self.safety.stats.as_dict()
        return {k: v - self._at_reset[k] for k, v in now.items()}

    def act(self, observations, env):
        if self.safety is None:
            raise RuntimeError(f"{self.name}: act() before reset(); call reset(env) first")
        par = self._parallel(env)
        acts = self.policy.act(observations, env)
        agents = list(par.possible_agents)
        if not isinstance(acts, dict):                                      # a Gymnasium single-UAV env
            return int(self.safety.filter(par.safety_state(self.safety.depth), np.array([[int(acts)]]))[0, 0])
        if not par.agents:                                                  # the episode has ended
            return acts
        if set(acts) != set(agents):
            raise ValueError(f"{self.name}: the policy acted for {sorted(acts)}, the team is {agents}; the filter "
                             "needs one node for every UAV")
        proposed = np.array([[int(acts[a]) for a in agents]])
        scores = getattr(self.policy, "last_logits", None) if self.use_scores else None
        if scores is not None and np.shape(scores) != (len(agents), len(par.lattice)):
            scores = None
        safe = self.safety.filter(par.safety_state(self.safety.depth), proposed,
                                  None if scores is None else np.asarray(scores, float)[None])[0]
        return {a: int(safe[i]) for i, a in enumerate(agents)}


class SafetyFilteredVectorEnv:
    """A waypoint vector env (:func:`covert_env.vector_env`) whose actions fly through a :class:`SafetyFilter`:
    the env a learner trains in when the filter is part of the world (action projection).

    ``step(actions)`` takes the learner's nodes (B, U) as proposals and steps the env with the filter's nodes, so
    the rewards, costs and next observations are those of the moves actually flown; a learner keeps the
    probabilities of its own proposals. Everything else is the wrapped env's (attributes are forwarded). The infos
    gain, per copy and UAV:

    ============================  ==============================================================================
    ``shield_node`` (int64)        the node flown
    ``shield_changed`` (bool)      the filter replaced the proposal
    ``shield_infeasible`` (bool)   the copy's team had no safe joint move this slot (the proposals were flown)
    ============================  ==============================================================================

    Args:
        venv: a :class:`~covert_env.envs.vector.CovertSensingVectorEnv` in waypoint mode, or an env with the same
            waypoint interface (``safety_state``, ``step``; ``available_nodes`` (B, L) where copies' lattices
            differ, as in a mix of tasks).
        **filter_kw: :class:`SafetyFilter`'s settings (``samples``, ``depth``, ``candidates``, ...).
    """

    def __init__(self, venv, **filter_kw):
        if getattr(venv, "action_mode", None) != "waypoint":
            raise ValueError(f"SafetyFilteredVectorEnv: the safety filter is for waypoint teams, got an env with "
                             f"action_mode={getattr(venv, 'action_mode', None)!r}")
        self.env = venv
        #: The filter; its ``stats`` count what it did since construction.
        self.safety = SafetyFilter(venv.config, venv.lattice, **filter_kw)

    def __getattr__(self, name):
        if name == "env":                                   # before __init__ set it (copy, pickle)
            raise AttributeError(name)
        return getattr(self.env, name)

    def reset(self, *, seed=None, options=None):
        """The env's ``reset``; a copy reset here starts without a backup plan."""
        return self.env.reset(seed=seed) if options is None else self.env.reset(seed=seed, options=options)

    def step(self, actions, scores=None):
        """One slot with the filter's nodes for the proposals ``actions`` (B, U); see the class docstring.
        ``scores`` (B, U, L), higher preferred (e.g. the learner's logits), order each UAV's alternatives
        (:meth:`SafetyFilter.filter`); default: the nodes nearest to the proposal first."""
        b, u = self.env.num_envs, len(self.env.possible_agents)
        proposed = batch.waypoint_actions(actions, (b, u), len(self.env.lattice), self.env.possible_agents)
        before = len(self.safety.stats.events)
        flown = self.safety.filter(self.env.safety_state(self.safety.depth), proposed, scores,
                                   available=getattr(self.env, "available_nodes", None))
        obs, rewards, terminations, truncations, infos = self.env.step(flown)
        infeasible = np.zeros((b, u), bool)
        for copy, _ in self.safety.stats.events[before:]:
            infeasible[copy] = True
        infos = dict(infos, shield_node=flown, shield_changed=flown != proposed, shield_infeasible=infeasible)
        return obs, rewards, terminations, truncations, infos

    def close(self) -> None:
        self.env.close()
