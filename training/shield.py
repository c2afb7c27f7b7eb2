"""The separation shield of the learned waypoint teams: the UAVs choose their next nodes one after another, and a
UAV may not choose a node whose path comes near a path a teammate has already chosen (eq. 2, d_safe1).

Why a shield and not only a penalty: with one shared actor the UAVs of a team score the lattice nodes alike and
converge on the same best node. With a separation penalty alone (1 per slot by default, or a Lagrangian multiplier),
a MAPPO team comes closer than d_safe1 in a large share of its slots
(docs/decisions/learning.md#separation-shield-for-learned-teams has the figures). Eq. 2 is a hard constraint of the
paper's problem, and the DP team meets it the same way: by priority negotiation, each UAV planning around the plans
of the UAVs before it (``baselines.dp.DPTeamPlanner``). The shield is that negotiation for one slot: the team shares
its chosen paths, as the DP team shares its plans.

It acts on the action masks only, so it is part of the policy (training and evaluation use it alike, and PPO's
probability ratios are taken under the masks the actions were sampled with); the environment is unchanged.

* Every UAV's allowed nodes are flown once per slot (the env's ``waypoint_paths``: the same manoeuvre and the
  same sample times as ``step``), and a candidate's path is tested against the teammates' chosen paths at the
  same times, as the env measures separation (``separation_path``). Sample 0, where the UAVs are now, is left
  out: no choice changes it.
* A UAV that can reach no lattice node (its env mask then allows every node, flown as a best effort) is far
  from the zone, and flying all L of its best-effort paths would cost more than the rest of the step: it
  chooses by rejection instead (a node whose path comes too close is removed and it chooses again, up to
  ``free_tries`` times).
* A node whose path comes closer than ``min_distance`` is removed from the UAV's mask. With ``end_margin``, so
  is a node whose path ends closer than ``min_distance + end_margin`` to a teammate's end, where another node
  is left: the next slot then starts with room to part (most dead ends start from cramped ends). If that leaves no node,
  the team tries again with that UAV choosing first (the DP team's order rule,
  :func:`covert_env.geometry.separation.priority_negotiation`: each UAV promoted at most once, at most U tries; the UAVs
  fly at up to 50 m/s with a bounded turn rate, so a teammate's path can cut off every path of a UAV that chose after
  it). If every try leaves some UAV without a node, the last try stands and that UAV chooses among the nodes whose
  paths come least close (the shield never leaves a UAV without an action); such team choices are counted in
  ``fallbacks``.

With ``lookahead``, a team choice that no order settles is negotiated again with each UAV also looking one teammate
ahead: it keeps only the separated nodes that leave every later teammate some node separated from its path and from
the paths chosen before it, ahead of the end-margin preference (where no separated node does, or the teammate has no
room left anyway, its mask is unchanged). A UAV's first pick is greedy for itself, so two UAVs converging on each
other can each, whichever goes first, choose the path that cuts off all the other's; the look-ahead is the pairwise
test that rules those paths out (:func:`leaves_room`: at most an (M, M) comparison of candidate paths per UAV pair,
searched a slice of the teammate's nodes at a time). It is paid only by the copies the negotiation left unsettled (a
few percent of team choices), which negotiate again as a batch of their own; the result replaces the first
negotiation's only where it settles every UAV (counted in ``rescued``). Free UAVs do not look ahead (they choose by
rejection).

With ``onward`` (the viability rule, the env's ``onward_reach``), a UAV also avoids a node from which it could reach
no lattice node in the next slot: from there it would leave the zone. With ``min_reach`` above 1, a node from which
fewer than ``min_reach`` nodes are reachable counts as a dead end too, where the UAV has a node that reaches that
many (where none does, the bar is what its best node reaches): a UAV left one or two nodes has no room to part from
a teammate, and two such UAVs can be left the same node. The end of the path to its chosen node (position, and
heading along the path's last step) is tested. If it is below the bar, every node of its mask (and its separated
nodes that the end-margin preference left out) is tested, the nodes below the bar leave the mask and the UAV chooses
again, among roomy nodes where there are any (the bar comes before the end margin); if every node reaches none, its
choice stands (counted in ``dead_ends``). Only a UAV whose first choice is a dead end pays for testing all its nodes
(about 250 with the kinematic mask). The price is a bias in training: the actions are samples of the policy
restricted to the viable nodes, but where the first choice was viable the stored mask still holds the dead ends, so
PPO takes those samples' probabilities under a wider mask than they were drawn from. Storing the exact mask would
mean testing every node of every UAV in every slot.

All copies of a batch go through it at once; the loops are over the UAVs of a team and over the tries, because
the choices are sequential by design (a UAV needs the paths of the UAVs before it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from covert_env.geometry.separation import priority_negotiation, separation

__all__ = ["SeparationShield", "end_poses", "leaves_room"]

#: Teammate nodes the look-ahead tries at once per candidate path (a strided slice of the teammate's reach).
LOOKAHEAD_SLICE = 32


def end_poses(paths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where paths ``(..., P, 2)`` end: positions ``(..., 2)`` and headings ``(...)`` along their last step (the
    manoeuvre ends on its straight leg, whose heading this is; a path that turns to its end is off by half the
    last step's turn)."""
    d = paths[..., -1, :] - paths[..., -2, :]
    return paths[..., -1, :], np.arctan2(d[..., 1], d[..., 0])


def leaves_room(rows: np.ndarray, cand: np.ndarray, paths_k: np.ndarray, later: list, past: np.ndarray,
                min_distance: float, slice_size: int = LOOKAHEAD_SLICE) -> np.ndarray:
    """The look-ahead for one UAV in the copies ``rows`` (B,): ``(B, M)`` whether each of its candidate
    ``paths_k`` (B, M, P, 2) marked in ``cand`` (B, M) leaves every UAV of ``later`` (a list of (nodes (B, M),
    paths (B, M, P, 2), free (B,)) of the UAVs after it) a node whose path keeps ``min_distance`` from it and from
    the ``past`` chosen paths (B, k, P, 2). True outside ``rows`` and ``cand``.

    A teammate's nodes are tried ``slice_size`` at a time (a strided slice, spread over its reach), and a
    candidate stops at the first slice that holds a node with room: most candidates stop at the first, so the work
    is far below the full (M, M) comparison, which only candidates that leave no room pay."""
    ok = np.ones(paths_k.shape[:2], bool)
    m = paths_k.shape[1]
    n_slices = -(-m // slice_size)
    for nodes_j, paths_j, free_j in later:
        r = np.nonzero(rows & ~free_j)[0]              # a free UAV chooses by rejection: nothing to leave it
        if len(r) == 0:
            continue
        room = nodes_j[r] >= 0                                                                # (R, M)
        if past.shape[1]:
            room &= separation(paths_j[r][:, :, None, 1:], past[r][:, None, :, 1:]).min(axis=2) >= min_distance
        keep = room.any(axis=1)                        # a teammate already without room: nothing to keep for it
        r, room = r[keep], room[keep]
        found = ~(cand[r] & ok[r])                                                            # (R, M)
        for c in range(n_slices):
            pr, pm = np.nonzero(~found)
            if len(pr) == 0:
                break
            sl = np.arange(c, m, n_slices)
            gap = separation(paths_k[r[pr], pm][:, None, 1:], paths_j[r[pr][:, None], sl, 1:])      # (n, S)
            hit = ((gap >= min_distance) & room[pr[:, None], sl]).any(axis=1)
            found[pr[hit], pm[hit]] = True
        ok[r] &= found
    return ok


def sub_batch(idx: np.ndarray, masks: np.ndarray, pick, paths_to, onward):
    """The shield's callbacks (``pick``, ``paths_to``, ``onward``: each takes and returns the whole batch of B
    copies) for the copies ``idx`` alone: the other copies ask for no node (a valid mask to pick under, no node to
    fly, no pose to test). ``onward`` may be None."""
    b = len(masks)

    def whole(k_sub):
        k = np.zeros(b, np.int64)
        k[idx] = k_sub
        return k

    def pick_sub(k_sub, m_sub):
        m = masks[np.arange(b), 0].copy()
        m[idx] = m_sub
        return pick(whole(k_sub), m)[idx]

    def paths_sub(nodes_sub):
        n = np.full((b, *nodes_sub.shape[1:]), -1)
        n[idx] = nodes_sub
        return paths_to(n)[idx]

    def onward_sub(k_sub, xy_sub, theta_sub):
        xy, theta = np.full((b, *xy_sub.shape[1:]), np.nan), np.zeros((b, *theta_sub.shape[1:]))
        xy[idx], theta[idx] = xy_sub, theta_sub
        return onward(whole(k_sub), xy, theta)[idx]

    return pick_sub, paths_sub, onward_sub if onward is not None else None


class SeparationShield:
    """Sequential node choice under the separation constraint (eq. 2) for waypoint-mode teams.

    Args:
        min_distance: a node is masked if the UAV's path to it comes closer than this (m) to a teammate's chosen
            path at a sample time: d_safe1 (a violation is a sample closer than d_safe1), plus a margin if wanted.
        end_margin: where it leaves a node, the UAV's path must also end at least ``min_distance + end_margin``
            (m) from the teammates' ends, so that the next slot starts with room to part (0: no such rule).
        lookahead: settle the team choices that no order settles once more, each UAV keeping only nodes that
            leave its later teammates a separated node (see the module docstring).
        min_reach: the viability rule's bar: a node from whose path's end fewer lattice nodes than this are
            reachable next slot counts as a dead end where the UAV has a node at or above the bar (elsewhere the
            bar is what its best node reaches; 1: only nodes that reach none).
    """

    def __init__(self, min_distance: float, end_margin: float = 0.0, lookahead: bool = False, min_reach: int = 1):
        for name, v in (("min_distance", min_distance), ("end_margin", end_margin)):
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0 (m), got {v!r}")
        if isinstance(min_reach, bool) or not isinstance(min_reach, (int, np.integer)) or min_reach < 1:
            raise ValueError(f"min_reach must be an integer >= 1 (lattice nodes), got {min_reach!r}")
        #: Under the viability rule, a node is a dead end if fewer lattice nodes than this are reachable from its
        #: path's end next slot (where another node of the UAV leaves that many).
        self.min_reach = int(min_reach)
        self.min_distance, self.end_margin = float(min_distance), float(end_margin)
        self.lookahead = bool(lookahead)
        #: How many nodes a free UAV (one that can reach no node) may try before it keeps a close one.
        self.free_tries = 12
        #: Team choices (one per copy and slot) where some UAV was left without a separated node after every
        #: try, and all team choices, since construction.
        self.fallbacks, self.choices = 0, 0
        #: Team choices the look-ahead settled after the negotiation could not, since construction.
        self.rescued = 0
        #: UAV choices where no allowed node reached any node next slot under the viability rule, since
        #: construction (in the team choices that stand, not in the negotiation's discarded passes).
        self.dead_ends = 0

    def restrict(self, mask: np.ndarray, nodes: np.ndarray, paths: np.ndarray, chosen_paths: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One UAV per copy: its mask ``(B, L)`` without the nodes whose paths come closer than ``min_distance``
        to the teammates' ``chosen_paths`` ``(B, k, P, 2)``, from its candidate ``nodes`` ``(B, M)`` (the mask's
        nodes, padded with -1) and their ``paths`` ``(B, M, P, 2)``. Returns the mask, the rows ``(B,)`` where no
        node was left (those keep the nodes whose paths come least close), and the mask before the end-margin
        preference (every separated node: where the viability rule finds no roomy node, it looks there)."""
        mask = np.asarray(mask, bool)
        empty = np.zeros(len(mask), bool)
        if chosen_paths.shape[1] == 0:
            return mask, empty, mask
        gap = separation(paths[:, :, None, 1:], chosen_paths[:, None, :, 1:]).min(axis=2)   # (B, M)
        gap[nodes < 0] = -1.0                                                   # padding: never kept
        keep = gap >= self.min_distance
        separated = keep.copy()
        if self.end_margin > 0:
            roomy = keep & (self._end_gap(paths, chosen_paths) >= self.min_distance + self.end_margin)
            has = roomy.any(axis=1)
            keep[has] = roomy[has]
        empty = ~keep.any(axis=1)
        if empty.any():
            keep[empty] = separated[empty] = gap[empty] >= gap[empty].max(axis=1, keepdims=True)
        return self._as_mask(mask, nodes, keep), empty, self._as_mask(mask, nodes, separated)

    @staticmethod
    def _as_mask(mask, nodes, keep):
        """The ``(B, L)`` mask of the candidate ``nodes`` ``(B, M)`` (-1 padded) that ``keep`` ``(B, M)`` marks."""
        out = np.zeros_like(mask)
        rows = np.broadcast_to(np.arange(len(mask))[:, None], nodes.shape)
        keep = keep & (nodes >= 0)
        out[rows[keep], nodes[keep]] = True
        return out

    @staticmethod
    def _end_gap(paths, chosen_paths):
        """Distance from each candidate path's end ``(B, M, P, 2)`` to the nearest teammate's end ``(B, k, P, 2)``:
        ``(B, M)``."""
        return separation(paths[:, :, None, -1:], chosen_paths[:, None, :, -1:]).min(axis=2)

    def _viable(self, a, k, sm, wide, rows, nodes_k, paths_k, onward, pick):
        """The viability rule for the UAVs ``k`` of ``rows`` (B,): where the chosen node ``a`` is a dead end
        (``onward`` finds fewer than ``min_reach`` nodes reachable from the end of its path next slot), every
        candidate of the UAV's mask ``sm`` and of ``wide`` (its separated nodes before the end-margin
        preference) is tested (``nodes_k`` (B, M), -1 padded, and their ``paths_k`` (B, M, P, 2)). ``sm`` (in
        place) becomes its viable nodes, the roomy ones where there are any, and the UAV chooses again (the
        bar drops to what the best node reaches where no node reaches it). Returns the actions; a row whose
        every node reaches none keeps its choice and its mask (returned too: ``(B,)`` bool)."""
        copies = np.arange(len(a))
        slot = np.argmax(nodes_k == a[:, None], axis=1)
        chosen = np.where(rows[:, None, None], paths_k[copies, slot], np.nan)[:, None]            # (B, 1, P, 2)
        count = onward(k, *end_poses(chosen))[:, 0]                                               # -1: not tested
        dead = rows & (count >= 0) & (count < self.min_reach)
        if not dead.any():
            return a, dead
        allowed = sm | wide
        tested = dead[:, None] & (nodes_k >= 0) & allowed[copies[:, None], np.maximum(nodes_k, 0)]     # (B, M)
        counts = onward(k, *end_poses(np.where(tested[..., None, None], paths_k, np.nan)))             # (B, M)
        # min_reach onward nodes where some node has them, else as many as the best node has (at least one).
        need = np.clip(counts.max(axis=1, keepdims=True), 1, self.min_reach)
        ok = counts >= need
        viable = np.zeros_like(sm)
        r, j = np.nonzero(ok)
        viable[r, nodes_k[r, j]] = True
        roomy = viable & sm
        viable = np.where(roomy.any(axis=1, keepdims=True), roomy, viable)
        some = dead & viable.any(axis=1)
        if some.any():
            sm[some] = viable[some]
            a = np.where(some, pick(k, sm), a)
        return a, dead & ~some

    def _pass(self, masks, nodes, paths, free, order, paths_to, pick, onward=None, careful=None):
        """One sequential choice in the per-copy UAV ``order`` ``(B, U)``: actions, shielded masks, per copy the
        first position whose UAV had no separated node (U if none), and per copy the UAVs left only dead ends
        (the viability rule). In the copies ``careful`` (B,) bool, each UAV looks ahead (:func:`leaves_room`)."""
        B, U, _ = masks.shape
        copies = np.arange(B)
        actions = np.zeros((B, U), np.int64)
        shielded = np.empty_like(masks)
        failed_at = np.full(B, U)
        dead_ends = np.zeros(B, np.int64)
        chosen = []
        for i in range(U):
            k = order[:, i]
            past = np.stack(chosen, axis=1) if chosen else np.zeros((B, 0, 1, 2))
            sm, empty, wide = self.restrict(masks[copies, k], nodes[copies, k], paths[copies, k], past)
            fk = free[copies, k]
            if careful is not None and i < U - 1:
                later = [(nodes[copies, j], paths[copies, j], free[copies, j]) for j in order[:, i + 1:].T]
                nk = nodes[copies, k]
                cand = (nk >= 0) & (sm | wide)[copies[:, None], np.maximum(nk, 0)]
                room = self._as_mask(sm, nk, leaves_room(careful & ~fk, cand, paths[copies, k], later, past,
                                                         self.min_distance))
                # Room for the teammates comes before the end-margin preference: a cramped end that leaves room
                # beats a roomy one that does not. A row where no separated node leaves room keeps its masks.
                in_sm, in_wide = sm & room, wide & room
                has_sm, has_wide = in_sm.any(axis=1), in_wide.any(axis=1)
                sm[has_sm] = in_sm[has_sm]
                cramped = has_wide & ~has_sm                   # every roomy end cuts a teammate off
                sm[cramped] = in_wide[cramped]
                wide[has_wide] = in_wide[has_wide]
            sm[fk], empty[fk] = masks[copies, k][fk], False
            a = pick(k, sm)
            if onward is not None and not fk.all():
                a, dead = self._viable(a, k, sm, wide, ~fk, nodes[copies, k], paths[copies, k], onward, pick)
                dead_ends += dead
            slot = np.argmax(nodes[copies, k] == a[:, None], axis=1)           # a is one of the candidates
            path = paths[copies, k, slot]
            if fk.any():
                a, path, blocked = self._free_choice(fk, k, a, path, sm, past, paths_to, pick, U)
                empty |= blocked
            failed_at[empty & (failed_at == U)] = i
            shielded[copies, k] = sm
            actions[copies, k] = a
            chosen.append(path)
        return actions, shielded, failed_at, dead_ends

    def _free_choice(self, fk, k, a, path, sm, past, paths_to, pick, U):
        """The choice of the free UAVs (rows ``fk``) by rejection: a node whose path comes too close to a
        teammate's is removed from the mask ``sm`` (in place) and the UAV chooses again, up to ``free_tries``
        times. Returns the actions, their paths (``path`` ``(B, P, 2)`` of the other rows kept), and the rows
        still too close (fallbacks)."""
        B = len(a)
        copies = np.arange(B)
        path = path.copy()
        pending = fk.copy()
        for attempt in range(self.free_tries + 1):
            one = np.full((B, U, 1), -1)
            one[copies[pending], k[pending], 0] = a[pending]
            p = paths_to(one)[copies, k, 0]                                    # (B, P, 2), NaN off pending
            path[pending] = p[pending]
            if past.shape[1] == 0:
                return a, path, np.zeros(B, bool)
            close = pending & (separation(p[:, None, 1:], past[:, :, 1:]).min(axis=1) < self.min_distance)
            if self.end_margin > 0 and attempt < self.free_tries // 2:         # the first tries want room too
                cramped = self._end_gap(p[:, None], past)[:, 0] < self.min_distance + self.end_margin
                close |= pending & cramped
            pending = close
            if not pending.any() or attempt == self.free_tries:
                break
            sm[pending, a[pending]] = False
            if not sm[pending].any(axis=1).all():                              # tried every node: stop
                sm[pending, a[pending]] = True
                break
            a = np.where(pending, pick(k, sm), a)
        return a, path, pending

    def _look_ahead(self, idx, masks, nodes, paths, free, paths_to, pick, test, out):
        """The copies ``idx`` that no order settled negotiate again, every UAV looking ahead, as a batch of their
        own (:func:`sub_batch`). Their results replace those in ``out`` (actions, shielded masks, dead ends; in
        place) where every UAV is settled. Returns the ``(B,)`` copies still unsettled."""
        B, U, _ = masks.shape
        pick_sub, paths_sub, test_sub = sub_batch(idx, masks, pick, paths_to, test)
        sub = masks[idx], nodes[idx], paths[idx], free[idx]
        careful = np.ones(len(idx), bool)
        result = {}

        def settle(order, rows):
            a, s, failed_at, dead = self._pass(*sub, order, paths_sub, pick_sub, test_sub, careful)
            for key, v in (("a", a), ("s", s), ("dead", dead)):
                result.setdefault(key, v.copy())[rows] = v[rows]
            return failed_at

        still = priority_negotiation(settle, len(idx), U)
        fixed = idx[~still]
        for target, key in zip(out, ("a", "s", "dead"), strict=True):
            target[fixed] = result[key][~still]
        self.rescued += len(fixed)
        unsettled = np.zeros(B, bool)
        unsettled[idx[still]] = True
        return unsettled

    def choose(self, masks: np.ndarray, paths_to: Callable[[np.ndarray], np.ndarray],
               pick: Callable[[np.ndarray, np.ndarray], np.ndarray],
               onward: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Choose the team's nodes, UAV 0 first, then again with a blocked UAV first where one was blocked (and,
        with ``lookahead``, once more looking ahead where no order settled the team).

        Args:
            masks: ``(B, U, L)`` the env's action masks.
            paths_to: ``paths_to(nodes (B, U, M)) -> (B, U, M, P, 2)``: the UAVs' paths to nodes in this slot
                (the env's ``waypoint_paths``).
            pick: ``pick(k (B,), mask (B, L)) -> (B,)``: the node of UAV ``k[b]`` of copy b under the shielded
                mask (sampling in training, the most likely node in evaluation).
            onward: the viability rule, or None: ``onward(xy (B, U, M, 2), theta (B, U, M)) -> (B, U, M)`` how many
                nodes a UAV ending this slot at each pose may reach in the next (-1 where xy is NaN; the env's
                ``onward_reach``).

        Returns:
            ``(actions (B, U) int64, shielded masks (B, U, L) bool)``.
        """
        masks = np.asarray(masks, bool)
        B, U, _ = masks.shape
        # A UAV whose mask allows every node can reach none (the env's rule): it chooses by rejection.
        free = masks.all(axis=2)
        # Every other UAV's allowed nodes, padded with -1 (no node, NaN paths), flown once.
        counts = np.where(free, 0, masks.sum(axis=2))
        m = max(int(counts.max()), 1)
        first = np.argsort(~masks, axis=2, kind="stable")[..., :m]
        nodes = np.where(np.arange(m) < counts[..., None], first, -1)
        paths = paths_to(nodes)
        actions, shielded = np.zeros((B, U), np.int64), np.empty_like(masks)
        dead_ends = np.zeros(B, np.int64)
        copies = np.arange(B)

        def test(k, xy, theta):
            """(B, m) onward counts of UAV k[b] at the poses xy[b] (m, 2), theta[b] (m,) (NaN: -1, not tested)."""
            at_xy = np.full((B, U, xy.shape[1], 2), np.nan)
            at_theta = np.zeros((B, U, xy.shape[1]))
            at_xy[copies, k], at_theta[copies, k] = xy, theta
            return onward(at_xy, at_theta)[copies, k]

        if onward is None:
            test = None

        def settle(order, rows):
            a, s, failed_at, dead = self._pass(masks, nodes, paths, free, order, paths_to, pick, test)
            actions[rows], shielded[rows], dead_ends[rows] = a[rows], s[rows], dead[rows]
            return failed_at

        unsettled = priority_negotiation(settle, B, U)
        if self.lookahead and unsettled.any():
            unsettled = self._look_ahead(np.nonzero(unsettled)[0], masks, nodes, paths, free, paths_to, pick, test,
                                         (actions, shielded, dead_ends))
        self.fallbacks += int(unsettled.sum())
        self.dead_ends += int(dead_ends.sum())
        self.choices += B
        return actions, shielded
