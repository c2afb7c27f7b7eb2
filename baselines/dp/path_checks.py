"""Checks along a manoeuvre between slot times: line of sight and zone (``check_path``), separation.

A transition's end node is checked by the stage (:mod:`baselines.dp.lattice`); what happens between two
slots is checked here on ``path_samples`` equally spaced instants of the manoeuvre, all candidate
manoeuvres at once:

* ``check_path`` (:class:`PathChecker`): at every interior instant the UAV is in the zone of eq. 4 around
  the target at that instant and sees it (eq. 6, the env's line-of-sight kernel): a guarantee the paper
  does not give;
* team negotiation (:func:`separated`): at every instant the UAV keeps a distance from the manoeuvres
  other UAVs recorded at the same instants (eq. 2 along the path);
* always (``PathChecker.clearance``, :mod:`baselines.dp.clearance`): at every instant the UAV keeps
  ``d_safe2`` from the polytopes' highest points (eq. 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from baselines.dp.clearance import TerrainClearance, take_manoeuvres
from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.dynamics import Manoeuvre, unicycle_arc
from covert_env.geometry.separation import separation
from covert_env.geometry.zone import in_feasible_zone
from covert_env.world.config import Config
from covert_env.world.terrain import Terrain
from covert_env.world.visibility import SAFE_LOS_TOLERANCE, line_of_sight_rows

__all__ = ["FALLBACK_PENALTY", "PathChecker", "PathContext", "record_circles", "separated"]

#: Consecutive samples of a recorded path bounded by one circle in the separation test (:func:`separated`).
SEPARATION_RUN = 5
#: Penalty per non-visible node in fallback level 2, for the last stage; earlier stages weigh 2x more
#: each, so keeping LoS sooner always wins. Far above any plan cost (|g| < ~1e4 per stage).
FALLBACK_PENALTY = 1e6


@dataclass
class PathContext:
    """Target samples between slots, for ``check_path``: per stage (P, 3) positions and (P,) headings."""

    target: np.ndarray
    phi: np.ndarray


class PathChecker:
    """``check_path``: line of sight and zone at the instants between slots; and eq. 3 (``clearance``) at the
    nodes and along every manoeuvre."""

    def __init__(self, config: Config, terrain: Terrain, path_samples: int):
        self.config, self.terrain, self.path_samples = config, terrain, int(path_samples)
        self.clearance = TerrainClearance(terrain, config.altitude, config.d_safe2, self.path_samples)

    def context(self, tq, tphi, target_path) -> PathContext:
        """Target samples per slot: ``target_path`` (N, P, 3), or linear between the slot positions."""
        n, p = len(tq) - 1, self.path_samples
        f = np.linspace(0.0, 1.0, p)
        if target_path is None:
            tp = tq[:-1, None, :] * (1 - f[:, None]) + tq[1:, None, :] * f[:, None]
        else:
            tp = np.asarray(target_path, float).reshape(n, p, 3)
        dphi = wrap_angle(tphi[1:] - tphi[:-1])
        ph = tphi[:-1, None] + dphi[:, None] * f[None, :]
        return PathContext(tp, ph)

    def penalties(self, m: Manoeuvre, ok: np.ndarray, ctx: PathContext | None, j: int, n_stages: int,
                  soft: bool, path_cost=None):
        """``check_path`` for manoeuvres into stage j: clears ``ok`` where the path fails; returns extra costs.

        Strict (the DP proper): LoS and zone along the path are constraints. Soft (fallback level 2):
        only LoS counts, as a penalty equal to losing the visible zone at that stage. ``path_cost`` (per stage,
        without ``check_path``): LoS along the path is a cost, ``path_cost[j]`` times :meth:`blocked_share`.
        """
        if ctx is None or not ok.any():
            return 0.0
        if path_cost is not None and not soft:
            extra = np.zeros(len(ok))
            if path_cost[j] > 0:
                extra[ok] = path_cost[j] * self.blocked_share(m, ok, ctx, j)
            return extra
        if not soft:
            ok[ok] = self.keeps_sight(m, ok, ctx, j)
            return 0.0
        extra = np.zeros(len(ok))
        extra[ok] = np.where(self.keeps_sight(m, ok, ctx, j, zone=False), 0.0,
                             FALLBACK_PENALTY * 2.0 ** (n_stages - 1 - j))
        return extra

    def keeps_sight(self, m: Manoeuvre, ok: np.ndarray, ctx: PathContext, j: int, zone: bool = True) -> np.ndarray:
        """For feasible manoeuvres into stage j (0-based): LoS (and zone, eq. 4) at the interior samples."""
        c = self.config
        p = self.path_samples
        if p <= 2:
            return np.ones(int(ok.sum()), bool)
        # Only the feasible manoeuvres are flown (sampling is most of the cost of this check).
        pts = take_manoeuvres(m, np.flatnonzero(ok)).points(p, by_instant=True)[1:-1]          # (P - 2, K, 2)
        tq = ctx.target[j, 1:-1]
        good = np.ones(pts.shape[1], bool)
        if zone:
            good = in_feasible_zone(pts, tq[:, None, :2], ctx.phi[j, 1:-1, None], c.r1, c.r2, c.mu, 0.0).all(axis=0)
        if good.any():
            good[good] = ~self._blocked(pts[:, good], tq).any(axis=0)
        return good

    def blocked_share(self, m: Manoeuvre, ok: np.ndarray, ctx: PathContext, j: int) -> np.ndarray:
        """For feasible manoeuvres into stage j: the share of the samples after the start (the end included)
        with LoS to the target at the same instant blocked -- the env's ``cost_los_path`` on the planner's
        samples and its predicted target (docs/decisions/planner.md#a-learned-cost-in-the-planners-search)."""
        p = self.path_samples
        pts = take_manoeuvres(m, np.flatnonzero(ok)).points(p, by_instant=True)[1:]      # (P - 1, K, 2)
        return self._blocked(pts, ctx.target[j, 1:]).sum(axis=0) / (p - 1)

    def _blocked(self, by_instant: np.ndarray, tq: np.ndarray) -> np.ndarray:
        """(S, K) whether sample i of manoeuvre k, ``by_instant[i, k]``, is out of sight of the target at that
        instant, ``tq[i]``: eq. 6 exactly, every (manoeuvre, instant) in one call of the line-of-sight kernel, at
        :data:`~covert_env.world.visibility.SAFE_LOS_TOLERANCE` (a sample called visible stays visible when the
        env scores it). Instant-major, as the kernel groups points by target."""
        return ~line_of_sight_rows(self.terrain, by_instant, self.config.altitude, tq, tol=SAFE_LOS_TOLERANCE)


def record_circles(avoid: np.ndarray, avoid_dist: float, j: int) -> tuple:
    """What :func:`separated` needs from the records alone at stage j (the same for every manoeuvre tested
    against them, so a problem computes it once per stage): the records' samples after the start
    ``rec`` (U, M, P - 1, 2), which records exist ``has`` (U, M), the first and last sample of every run
    of ``SEPARATION_RUN`` samples, and each run's bounding circle (centre, radius + ``avoid_dist`` + 1 um).
    """
    rec = avoid[:, :, j, 1:]                        # (U, M, P - 1, 2): sample 0 is the slot's start
    has = ~np.isnan(rec[:, :, -1, 0])               # (U, M)
    p = rec.shape[-2] + 1
    runs = np.array_split(np.arange(p - 1), max(1, (p - 1) // SEPARATION_RUN))
    cut = np.array([r[0] for r in runs])
    last = np.array([r[-1] for r in runs])
    if not has.any():
        return rec, has, cut, last, None, None
    centre = np.stack([rec[:, :, r].mean(axis=2) for r in runs], axis=2)        # (U, M, R, 2)
    radius = np.stack([np.hypot(*(rec[:, :, r] - centre[:, :, h, None]).transpose(3, 0, 1, 2)).max(axis=2)
                       for h, r in enumerate(runs)], axis=2) + (avoid_dist + 1e-6)  # (U, M, R)
    return rec, has, cut, last, centre, radius


def separated(m: Manoeuvre, ok: np.ndarray, avoid: np.ndarray, avoid_dist: float, uav: np.ndarray,
              j: int, circles: tuple | None = None) -> np.ndarray:
    """For feasible manoeuvres into stage j: at least ``avoid_dist`` from every avoided path, sample by sample.

    ``avoid``: (U, M, N, P, 2) other UAVs' recorded path samples per UAV of the batch (NaN: none);
    ``uav``: the batch UAV of every manoeuvre; ``circles``: :func:`record_circles` of these records at stage j
    if already computed.

    At constant speed the sample at fraction f lies within ell f of the start and ell (1 - f) of the goal
    (a lens), so an obstacle sample farther than avoid_dist from that lens cannot be too close. The test
    narrows in three steps, all pairs at once: (manoeuvre, run of ``SEPARATION_RUN`` consecutive samples
    of a record) around the run's bounding circle, then (manoeuvre, sample) against the lens, and only the
    pairs left are flown (:func:`sample_points`) and measured. Distances compare with a 1 um margin until
    that last step, so rounding can only keep a pair for it: the result is the sample-by-sample test's.
    """
    out = np.ones(int(ok.sum()), bool)
    rec, has, cut, last, centre, radius = circles if circles is not None else record_circles(avoid, avoid_dist, j)
    # Records exist only at the stages where conflicts were found: elsewhere there is nothing to check.
    if centre is None:
        return out
    sel = np.flatnonzero(ok)
    t, o = np.nonzero(has[uav[sel]])                # (manoeuvre, record) pairs of the same batch UAV
    if t.size == 0:
        return out
    p = rec.shape[-2] + 1
    f = np.linspace(0.0, 1.0, p)[1:]
    slack = avoid_dist + 1e-6
    start = m.start.reshape(-1, 2)[sel]
    goal = m.goal.reshape(-1, 2)[sel]
    ell = np.asarray(m.length).reshape(-1)[sel]
    owner = uav[sel][t]
    # Every (manoeuvre, record, run) against the run's bounding circle at once.
    c = centre[owner, o]                                                         # (K, R, 2)
    rad = radius[owner, o]
    el = ell[t][:, None]
    close = ((np.hypot(*(start[t][:, None] - c).transpose(2, 0, 1)) < el * f[last] + rad)
             & (np.hypot(*(goal[t][:, None] - c).transpose(2, 0, 1)) < el * (1 - f[cut]) + rad))
    pair, run = np.nonzero(close)
    if pair.size == 0:
        return out
    # Every sample of the close runs against the lens.
    width = int((last - cut).max()) + 1
    k = cut[run][:, None] + np.arange(width)[None]                               # (K', C) sample index
    valid = k <= last[run][:, None]
    k = np.minimum(k, p - 2)
    tt, oo = t[pair][:, None], o[pair][:, None]
    q = rec[uav[sel][tt], oo, k]                                                 # (K', C, 2)
    er, fk = ell[tt], f[k]
    qa = q - start[tt]
    qb = q - goal[tt]
    lens = (valid & (qa[..., 0] ** 2 + qa[..., 1] ** 2 < (slack + er * fk) ** 2)
            & (qb[..., 0] ** 2 + qb[..., 1] ** 2 < (slack + er * (1 - fk)) ** 2))
    a_, b_ = np.nonzero(lens)
    if a_.size == 0:
        return out
    rows, ks, qs = tt[a_, 0], k[a_, b_] + 1, q[a_, b_]
    # Fly only the (manoeuvre, instant) pairs some obstacle sample may be near, each once.
    key, inv = np.unique(rows * p + ks, return_inverse=True)
    pts = sample_points(take_manoeuvres(m, sel[key // p]), key % p, p)
    too_close = separation(pts[inv, None], qs[:, None]) < avoid_dist
    out[rows[too_close]] = False
    return out


def sample_points(m: Manoeuvre, k: np.ndarray, n: int) -> np.ndarray:
    """(K, 2) position of manoeuvre i of a 1-D batch at its k[i]-th of n equally spaced instants: the
    numbers of ``m.points(n)[i, k[i]]``, computed only where needed."""
    t = np.linspace(0.0, m.delta, n)[k]
    v, om, tt = (np.asarray(x, dtype=float) for x in (m.v, m.omega, m.turn_time))
    in_turn = t <= tt
    x1, y1, _ = unicycle_arc(m.start[:, 0], m.start[:, 1], np.asarray(m.theta0, float), v, om, np.minimum(t, tt),
                             heading=False)
    x2, y2, _ = unicycle_arc(m.tangent[:, 0], m.tangent[:, 1], np.asarray(m.heading_after, float), v, 0.0,
                             np.maximum(t - tt, 0.0), heading=False)
    return np.stack([np.where(in_turn, x1, x2), np.where(in_turn, y1, y2)], axis=-1)
