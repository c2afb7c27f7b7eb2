"""Eq. 3 in the planner: every UAV keeps ``d_safe2`` from the highest point of every polytope.

A UAV flies at altitude h, so its 3D distance to a top at height z is at least ``h - z``: only tops higher
than ``h - d_safe2`` can violate eq. 3, and around such a top the excluded positions are the horizontal
disk of radius ``sqrt(d_safe2^2 - (h - z)^2)``. The random generator caps heights at ``h - d_safe2``, so
there the check excludes nothing and costs nothing; a loaded terrain (a mast, a tower) may have such tops.
Nodes are checked at the node, manoeuvres at their ``path_samples`` instants (the engine's metrics count
slot ends, :func:`covert_env.world.metrics.slot_quantities`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from covert_env.geometry.dynamics import Manoeuvre
from covert_env.world.metrics import top_clearance
from covert_env.world.terrain import Terrain

__all__ = ["TerrainClearance", "take_manoeuvres"]


class TerrainClearance:
    """The tops that can violate eq. 3 at altitude h, and which positions and manoeuvres keep clear of them."""

    def __init__(self, terrain: Terrain, altitude: float, d_safe2: float, path_samples: int):
        top = np.asarray(terrain.highest_points, float).reshape(-1, 3)
        dz = float(altitude) - top[:, 2]
        tall = dz < d_safe2
        self.altitude = float(altitude)
        self.tall_tops = top[tall]                      # (M', 3) the tops that matter
        self.tops = self.tall_tops[:, :2]               # (M', 2) their plan view
        self.dz2 = dz[tall] ** 2                        # (M',) squared vertical gap to the flight plane
        self.d_safe2 = float(d_safe2)
        self.radius = np.sqrt(self.d_safe2 ** 2 - self.dz2)
        self.path_samples = int(path_samples)

    @property
    def active(self) -> bool:
        """Whether some top is higher than ``h - d_safe2`` (otherwise every position is clear)."""
        return len(self.tops) > 0

    def distance(self, xy) -> np.ndarray:
        """(...) 3D distance from positions (..., 2) at altitude h to the nearest top that matters (inf if none).

        The metrics' computation (:func:`covert_env.world.metrics.top_clearance`) on these tops, so they agree at the
        boundary: the other tops are d_safe2 or farther from every position.
        """
        return top_clearance(np.asarray(xy, float), self.altitude, self.tall_tops)

    def clear(self, xy) -> np.ndarray:
        """(...) bool: positions (..., 2) at altitude h at least ``d_safe2`` from every top (eq. 3)."""
        return self.distance(xy) >= self.d_safe2

    def manoeuvres_clear(self, m: Manoeuvre, ok: np.ndarray) -> np.ndarray:
        """For the feasible manoeuvres (``ok``): clear of every top at each of the ``path_samples`` instants.

        The start is where the UAV already is, so it is not checked; and a UAV that starts closer than d_safe2
        (after a best-effort move, or placed there) is not held to its samples either, only to the clear node
        it flies to: it leaves by a planned manoeuvre instead of being left with no plan. (Requiring it never
        to come closer than it is would trap a UAV heading at the top: every manoeuvre starts by approaching.)
        """
        out = np.ones(int(ok.sum()), bool)
        if not self.active or not out.size:
            return out
        a = m.start.reshape(-1, 2)[ok]
        b = m.goal.reshape(-1, 2)[ok]
        ell = np.asarray(m.length).reshape(-1)[ok]
        # A path of length ell from a to b stays in the ellipse |x - a| + |x - b| <= ell, so a top with
        # |t - a| + |t - b| > ell + 2 radius is farther than its radius from the whole path: no need to fly it.
        foci = np.hypot(*(self.tops[None] - a[:, None]).transpose(2, 0, 1)) + \
            np.hypot(*(self.tops[None] - b[:, None]).transpose(2, 0, 1))
        near = (foci <= ell[:, None] + 2.0 * self.radius[None]).any(axis=1)
        if near.any():
            out[near] = self.paths_clear(take_manoeuvres(m, np.flatnonzero(ok)[near]).points(self.path_samples))
        return out

    def paths_clear(self, paths) -> np.ndarray:
        """(K,) bool: paths (K, P, 2) sampled from their start clear of every top at each later sample (a path
        starting closer than d_safe2 is held to nothing, as in :meth:`manoeuvres_clear`)."""
        paths = np.asarray(paths, float)
        if not self.active:
            return np.ones(len(paths), bool)
        need = np.where(self.distance(paths[:, 0]) >= self.d_safe2, self.d_safe2, -np.inf)
        return self.distance(paths[:, 1:]).min(axis=1) >= need


def take_manoeuvres(m: Manoeuvre, idx: np.ndarray) -> Manoeuvre:
    """The manoeuvres at flat indices ``idx`` of a batch, as a 1-D batch (to sample only those)."""
    def flat(a, k=()):
        return np.asarray(a).reshape((-1,) + k)[idx]
    return replace(m, feasible=flat(m.feasible), v=flat(m.v), turn=flat(m.turn), omega=flat(m.omega),
                   turn_time=flat(m.turn_time), heading_after=flat(m.heading_after), length=flat(m.length),
                   tangent=flat(m.tangent, (2,)), start=flat(m.start, (2,)), theta0=flat(m.theta0),
                   goal=flat(m.goal, (2,)))
