"""Checks along a manoeuvre between slot times: line of sight and zone (``check_path``), separation.

A transition's end node is checked by the stage (:mod:`baselines.dp.lattice`); what happens between two
slots is checked here on ``path_samples`` equally spaced instants of the manoeuvre, all candidate
manoeuvres at once:

* ``check_path`` (:class:`PathChecker`): at every interior instant the UAV is in the zone of eq. 4 around
  the target at that instant and outside its shadows (eqs. 8-9): a line-of-sight guarantee the paper
  does not give;
* team negotiation (:func:`separated`): at every instant the UAV keeps a distance from the manoeuvres
  other UAVs recorded at the same instants (eq. 2 along the path);
* always (``PathChecker.clearance``, :mod:`baselines.dp.clearance`): at every instant the UAV keeps
  ``d_safe2`` from the polytopes' highest points (eq. 3).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import shapely

from baselines.dp.clearance import TerrainClearance, take_manoeuvres
from baselines.dp.lattice import VISIBILITY_TOL
from covert_env.angles import wrap_angle
from covert_env.config import Config
from covert_env.dynamics import Manoeuvre
from covert_env.terrain import Terrain
from covert_env.visibility import line_of_sight, shadow_union_cfg
from covert_env.zone import in_feasible_zone

__all__ = ["FALLBACK_PENALTY", "PathChecker", "PathContext", "SHADOW_MARGIN", "separated"]

#: Growth (m) of the shadows used for ``check_path``: shadows equal the blocked set up to ~1e-8 m at their
#: boundary (tests/test_visibility.py checks 1 cm); a point within 1 cm of a shadow counts as blocked.
SHADOW_MARGIN = 0.01
#: Penalty per non-visible node in fallback level 2, for the last stage; earlier stages weigh 2x more
#: each, so keeping LoS sooner always wins. Far above any plan cost (|g| < ~1e4 per stage).
FALLBACK_PENALTY = 1e6


@dataclass
class PathContext:
    """Target samples between slots, for ``check_path``: per stage (P, 3) positions and (P,) headings."""

    target: np.ndarray
    phi: np.ndarray


class PathChecker:
    """``check_path``: line of sight and zone at the instants between slots, with a cache of shadow unions;
    and eq. 3 (``clearance``) at the nodes and along every manoeuvre."""

    def __init__(self, config: Config, terrain: Terrain, path_samples: int, cache_size: int):
        self.config, self.terrain, self.path_samples = config, terrain, int(path_samples)
        self.clearance = TerrainClearance(terrain, config.altitude, config.d_safe2, self.path_samples)
        self._max_shadows = 8 * int(cache_size) * self.path_samples
        self._shadows: OrderedDict = OrderedDict()

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
                  soft: bool):
        """``check_path`` for manoeuvres into stage j: clears ``ok`` where the path fails; returns extra costs.

        Strict (the DP proper): LoS and zone along the path are constraints. Soft (fallback level 2):
        only LoS counts, as a penalty equal to losing the visible zone at that stage.
        """
        if ctx is None or not ok.any():
            return 0.0
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
        pts = m.points(p).reshape(-1, p, 2)[ok][:, 1:-1]
        tq = ctx.target[j, 1:-1]
        good = np.ones(len(pts), bool)
        if zone:
            good = in_feasible_zone(pts, tq[:, :2], ctx.phi[j, 1:-1], c.r1, c.r2, c.mu, 0.0).all(axis=1)
        # One pass per instant (the target, hence the shadows, differ), each over every manoeuvre at once.
        for i in range(p - 2):
            idx = np.flatnonzero(good)
            if idx.size == 0:
                break
            if c.h_min is None:
                # Samples in the zone are within R2 of the target, where the shadows (eqs. 8-9, automatic
                # h_min) are exactly the blocked set; grown by 1 cm they are a conservative, fast test.
                shadow = self.shadow(tq[i])
                if shadow is not None:
                    good[idx] = ~shapely.intersects_xy(shadow, pts[idx, i, 0], pts[idx, i, 1])
            else:
                good[idx] = line_of_sight(self.terrain, pts[idx, i], c.altitude, tq[i], tol=VISIBILITY_TOL)
        return good

    def shadow(self, q):
        """Prepared union of the shadows at target position q, grown by 1 cm (None: no shadow); cached."""
        key = np.asarray(q, float).tobytes()
        if key in self._shadows:
            return self._shadows[key]
        geom = shadow_union_cfg(self.terrain, q, self.config)
        geom = None if geom.is_empty else geom.buffer(SHADOW_MARGIN, quad_segs=2)
        if geom is not None:
            shapely.prepare(geom)
        self._shadows[key] = geom
        while len(self._shadows) > self._max_shadows:
            self._shadows.popitem(last=False)
        return geom


def separated(m: Manoeuvre, ok: np.ndarray, avoid: np.ndarray, avoid_dist: float, uav: np.ndarray,
              j: int) -> np.ndarray:
    """For feasible manoeuvres into stage j: at least ``avoid_dist`` from every avoided path, sample by sample.

    ``avoid``: (U, M, N, P, 2) other UAVs' recorded path samples per UAV of the batch (NaN: none);
    ``uav``: the batch UAV of every manoeuvre.
    """
    out = np.ones(int(ok.sum()), bool)
    # Records exist only at the stages where conflicts were found: elsewhere there is nothing to check.
    has = ~np.isnan(avoid[:, :, j, -1, 0])          # (U, M)
    if not has.any():
        return out
    sel = np.flatnonzero(ok)
    mine = uav[sel]
    start = m.start.reshape(-1, 2)[sel]
    goal = m.goal.reshape(-1, 2)[sel]
    ell = np.asarray(m.length).reshape(-1)[sel]
    p = avoid.shape[-2]
    f = np.linspace(0.0, 1.0, p)[1:]
    near_rows, near_obs = [], []
    # Per UAV of the batch, against its own records only (a few), broadcast rather than copied per manoeuvre.
    for i in np.flatnonzero(has.any(axis=1)):
        rows = np.flatnonzero(mine == i)
        if rows.size == 0:
            continue
        obs = avoid[i, has[i], j, 1:]               # (M_i, P - 1, 2): sample 0 is the slot's start
        # The whole path lies within ell of its start: a record farther than that (plus avoid_dist, plus a
        # rounding margin) from the start, around its bounding circle, is safe without the sample test.
        centre = obs.reshape(-1, 2).mean(axis=0)
        radius = np.hypot(*(obs.reshape(-1, 2) - centre).T).max()
        far = np.hypot(*(start[rows] - centre).T) - radius - ell[rows] > avoid_dist + 1e-6
        rows = rows[~far]
        if rows.size == 0:
            continue
        a = start[rows][:, None, None, :]
        b = goal[rows][:, None, None, :]
        el = ell[rows][:, None, None]
        # At constant speed the sample at fraction f lies within ell f of the start and ell (1 - f) of the
        # goal: a sample whose obstacle is farther than avoid_dist from that lens is safe without flying it.
        gap = np.maximum(np.hypot(*(obs[None] - a).transpose(3, 0, 1, 2)) - el * f,
                         np.hypot(*(obs[None] - b).transpose(3, 0, 1, 2)) - el * (1 - f))
        near = (gap < avoid_dist).any(axis=(1, 2))
        if near.any():
            near_rows.append(rows[near])
            near_obs.append((obs, int(near.sum())))
    if not near_rows:
        return out
    pts = take_manoeuvres(m, sel[np.concatenate(near_rows)]).points(p)[:, 1:]
    o = 0
    for rows, (obs, k) in zip(near_rows, near_obs, strict=True):
        d = np.hypot(*(pts[o:o + k, None] - obs[None]).transpose(3, 0, 1, 2))
        out[rows] = ~(d < avoid_dist).any(axis=(1, 2))
        o += k
    return out
