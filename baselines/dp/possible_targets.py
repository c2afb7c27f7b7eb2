"""Line of sight to a target known only up to its prediction error: :class:`PossibleTargets`.

The paper's visible zone (eq. 10) keeps the nodes with a clear line of sight (eq. 6) to the *predicted*
target q[k+j]. The zone erosion of eq. 5 absorbs a prediction error up to r_u for zone membership, but not
for the line of sight: a node next to a shadow edge sees the prediction and may not see the true target a
few metres along the road. With a prediction error (``Config.prediction_error > 0``) the planner therefore
keeps a node only if its line of sight is clear to every position the true target may have
(docs/decisions/model.md#prediction-los):

* with the target's road (the error is speed noise along it, docs/decisions/model.md#prediction-error): the piece
  of road within arc length ``margin`` of the prediction, clamped to the road's ends as the track is;
* without a road: the disk gamma(q) of radius ``margin`` of eq. 5 at the target's height (any direction; a
  superset of the road piece, so also safe, only more conservative).

The continuous set is checked through finitely many samples, exactly enough to prove it (not a heuristic):
every possible position p lies within ``cover`` of a sample s, and the line of sight to s is checked against
the polytopes grown by ``cover``. A point x = u + t (p - u), t in [0, 1], of the segment from the UAV u to
p lies within t |p - s| <= ``cover`` of the point u + t (s - u) of the segment to s; so if x is inside a
polytope C_m, the segment to s meets C_m grown by ``cover`` and the node is dropped. Road samples are at
most 2 ``cover`` apart in arc length (a road point between two samples is within ``cover`` of one along the
road, hence in the plane); disk samples are a square grid of spacing sqrt(2) ``cover`` (covering radius
``cover``) over the disk grown by ``cover``. "Grown" is implemented conservatively: a (segment, polytope)
pair counts as blocked when the segment meets both the polytope's faces pushed out by ``cover`` (unit
normals, so this contains every point within ``cover`` of C_m) and the vertical cylinder of its footprint
circle widened by ``cover`` below its top raised by ``cover`` (which also contains them). The price is that
a node whose segment to some possible position passes within ``cover`` of a polytope is dropped too.
"""

from __future__ import annotations

import weakref

import numpy as np

from covert_env.geometry.sight_kernel import blocked_segments
from covert_env.world.road import Road
from covert_env.world.terrain import Terrain
from covert_env.world.visibility import terrain_arrays

__all__ = ["ON_ROAD_TOL", "PossibleTargets", "SAMPLE_COVER", "clear_to_all"]

#: Covering radius (m) of the samples: every possible true position lies within this distance of one, and the
#: polytopes are grown by it. 0.25 m: 17 road samples for a 4 m margin, an eighth of the 2 m lattice step.
SAMPLE_COVER = 0.25
#: Largest distance (m) of a predicted target position from the road given to :class:`PossibleTargets`
#: (predictions are points of the road, up to round-off).
ON_ROAD_TOL = 1e-6
_RADII: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _plan_radii(terrain: Terrain) -> np.ndarray:
    """(M,) radius about each footprint centroid of a circle enclosing the whole polytope in plan view, its top
    included (validation lets a top overhang its base by up to 1e-6 of the footprint's size). Once per terrain."""
    r = _RADII.get(terrain)
    if r is None:
        r = np.array([np.hypot(*(p.vertices[:, :2] - c).T).max() for p, c in zip(terrain, terrain.centroids_xy,
                                                                                     strict=True)])
        _RADII[terrain] = r
    return r


class PossibleTargets:
    """The true target positions a prediction allows, sampled so that the LoS check covers all of them.

    Args:
        margin: the prediction-error radius (m), > 0: the planner's r_u (docs/decisions/model.md#prediction-los).
        road: the target's route, or None for the disk gamma(q) of eq. 5.
        cover: covering radius of the samples (m), > 0 (module docstring).
    """

    def __init__(self, margin: float, road: Road | None = None, cover: float = SAMPLE_COVER):
        for name, v in (("margin", margin), ("cover", cover)):
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                    or not (np.isfinite(v) and v > 0):
                raise ValueError(f"PossibleTargets: {name} must be a finite number > 0 (m), got {v!r}")
        if road is not None and not isinstance(road, Road):
            raise TypeError(f"PossibleTargets: road must be a covert_env.world.road.Road or None, got "
                            f"{type(road).__name__}")
        self.margin, self.road, self.cover = float(margin), road, float(cover)
        if road is None:
            g = np.sqrt(2.0) * self.cover
            r = self.margin + self.cover
            n = int(np.ceil(r / g))
            gx, gy = np.meshgrid(np.arange(-n, n + 1) * g, np.arange(-n, n + 1) * g)
            keep = np.hypot(gx, gy) <= r
            self._offsets = np.column_stack([gx[keep], gy[keep]])
        else:
            n = int(np.ceil(self.margin / self.cover)) + 1
            self._offsets = np.linspace(-self.margin, self.margin, n)      # arc-length steps <= 2 cover

    def samples(self, q) -> np.ndarray:
        """(S, 3) points covering the possible true positions of a target predicted at ``q`` (3,)."""
        q = np.asarray(q, dtype=float).reshape(3)
        if self.road is None:
            xy = q[:2] + self._offsets
        else:
            s = np.clip(road_arcs(self.road, q[:2])[:, None] + self._offsets, 0.0, self.road.length)
            xy = self.road.point_at(s.reshape(-1))
        return np.column_stack([xy, np.full(len(xy), q[2])])

    def visible(self, terrain: Terrain, xy: np.ndarray, altitude: float, q, tol: float) -> np.ndarray:
        """(L,) bool: the line of sight from each node ``xy`` (L, 2) at ``altitude`` is clear to every possible
        true position of a target predicted at ``q``; ``tol`` as in
        :func:`covert_env.world.visibility.line_of_sight`."""
        return clear_to_all(terrain, xy, altitude, self.samples(q), self.cover - tol)


def road_arcs(road: Road, xy: np.ndarray) -> np.ndarray:
    """Arc length(s) of the road point ``xy``: one, or several where the road passes there more than once.

    Raises:
        ValueError: ``xy`` is farther than :data:`ON_ROAD_TOL` from the road (not the target's road).
    """
    a = road.points[:-1]
    ab = np.diff(road.points, axis=0)
    seg = np.hypot(ab[:, 0], ab[:, 1])
    t = np.clip(np.einsum("sk,sk->s", xy - a, ab) / seg ** 2, 0.0, 1.0)
    dist = np.hypot(*(a + t[:, None] * ab - xy).T)
    if dist.min() > ON_ROAD_TOL:
        raise ValueError(f"PossibleTargets: the predicted target {xy.tolist()} is {dist.min():.3g} m from the road "
                         f"(at most {ON_ROAD_TOL:g} m allowed): give the target's own road, or road=None")
    on = np.flatnonzero(dist <= ON_ROAD_TOL)
    return np.unique(road.cumulative_length[on] + t[on] * seg[on])


def clear_to_all(terrain: Terrain, xy, altitude: float, targets, grow: float) -> np.ndarray:
    """(L,) bool: the segments from every node ``xy`` (L, 2) at ``altitude`` to every target (S, 3) miss every
    polytope grown by ``grow`` >= 0 metres (in the conservative sense of the module docstring).

    The line-of-sight kernel (:func:`~covert_env.geometry.sight_kernel.blocked_segments`) with the faces pushed out by
    ``grow`` (``tol = -grow``) and, as its per-pair test, the footprint circles of :func:`_plan_radii` widened by
    ``grow`` below the tops raised by ``grow``: a pair is blocked where the segment meets both.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    tq = np.asarray(targets, dtype=float).reshape(-1, 3)
    h = float(altitude)
    if not grow >= 0:
        raise ValueError(f"clear_to_all: grow must be >= 0 (m), got {grow!r}")
    if not np.all(tq[:, 2] < h):
        raise ValueError(f"clear_to_all: the UAV altitude ({h:g} m) must be above every target height "
                         f"(highest {tq[:, 2].max():g} m)")
    n_nodes, m = len(xy), len(terrain)
    if m == 0 or n_nodes == 0:
        return np.ones(n_nodes, dtype=bool)
    centre = terrain.centroids_xy
    # Every (target, node) segment, grouped by target; growth 1 per polytope: circles and tops widened by grow.
    points = np.broadcast_to(xy, (len(tq), n_nodes, 2)).reshape(-1, 2)
    blocked = blocked_segments(terrain_arrays(terrain).hs[None], centre[None, :, 0], centre[None, :, 1],
                               _plan_radii(terrain)[None], np.asarray(terrain.z_max, float)[None], np.ones((1, m)),
                               tq, np.zeros(len(tq), np.int64), np.arange(len(tq) + 1) * n_nodes,
                               points, h, -float(grow))
    return ~blocked.reshape(len(tq), n_nodes).any(axis=0)
