"""A convex polytope C_m (a building or a hill, paper §2.1): its validation and its half-space form.

A polytope is the convex hull of a base polygon Q_m at z = 0 (convex, counter-clockwise) and a top polygon D_m with
the same number of vertices, each with its own height z > 0 (a top may be slanted). Line of sight (eq. 6) and
clearance (eq. 3) use its half-space form ``n . x + d <= 0``; a terrain (:class:`covert_env.world.terrain.Terrain`) is a
set of non-overlapping polytopes.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely
from scipy.spatial import ConvexHull
from shapely.geometry import LinearRing, Polygon

from covert_env.world.config import MAX_N_POLYTOPES, check_coordinates, short_repr

__all__ = ["MAX_FOOTPRINT_VERTICES", "MAX_TERRAIN_VERTICES", "Polytope"]


_AREA_TOL = 1e-6
"""Footprints whose intersection has more area than this (m^2) overlap; touching is allowed."""


# ---------------------------------------------------------------------------------- validation
#: Most vertices a polytope's base (footprint) may have; validation is quadratic in it (generator: <= 64).
MAX_FOOTPRINT_VERTICES = 1024
#: Most footprint vertices of a whole terrain (a terrain's line-of-sight arrays grow with it): 10,000
#: polytopes of 10 vertices, or 97 of 1024. Loading and the first reset stay within seconds.
MAX_TERRAIN_VERTICES = 100_000


def _check_size(counts, where: str) -> None:
    """At most MAX_N_POLYTOPES polytopes and MAX_TERRAIN_VERTICES footprint vertices in all (``counts``: the
    footprints' vertex counts); checked before any geometry work."""
    if len(counts) > MAX_N_POLYTOPES:
        raise ValueError(f"{where} has {len(counts)} polytopes, more than {MAX_N_POLYTOPES}; split the area "
                         f"into scenes")
    total = sum(counts)
    if total > MAX_TERRAIN_VERTICES:
        raise ValueError(f"{where} has {total} footprint vertices in all, more than {MAX_TERRAIN_VERTICES}; "
                         f"simplify the footprints (e.g. shapely's simplify) or split the area into scenes")


def _check_polytope(base, top, base_name: str = "base",
                    top_name: str = "top") -> tuple[np.ndarray, np.ndarray]:
    """Validate a (base, top) pair; return float copies with the base counter-clockwise.

    Raises ValueError whose message starts with ``base_name`` / ``top_name`` (the caller adds the
    polytope's or feature's label).
    """
    for name, v in ((base_name, base), (top_name, top)):
        # np.array(..., dtype=float) would parse strings ('10' -> 10.0) and take bools: numbers only.
        try:
            kind = np.asarray(v).dtype.kind
        except (TypeError, ValueError):
            kind = "O"
        if kind not in "iuf":
            raise ValueError(f"{name} must be an array of numbers (int or float), got {short_repr(v)}"
                             + (" (strings: convert them with float first)" if kind in "US" else ""))
    try:
        b = np.array(base, dtype=float)
        t = np.array(top, dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:     # OverflowError: an integer beyond float's range
        raise ValueError(f"{base_name} and {top_name} must be arrays of numbers ({exc})") from None
    if b.ndim != 2 or b.shape[1] != 2:
        raise ValueError(f"{base_name} must be an (n, 2) array of (x, y) vertices, got shape {b.shape}")
    n = len(b)
    if n < 3:
        raise ValueError(f"{base_name} must have at least 3 vertices, got {n}")
    if n > MAX_FOOTPRINT_VERTICES:
        # The convexity and face checks are quadratic in the vertex count: bound it so that a file with a
        # finely traced footprint fails here, not as a MemoryError.
        raise ValueError(f"{base_name} has {n} vertices, more than {MAX_FOOTPRINT_VERTICES}; simplify the footprint "
                         "(e.g. shapely's simplify) before loading it")
    bad = ~np.isfinite(b).all(axis=1)
    if bad.any():
        j = int(np.argmax(bad))
        raise ValueError(f"{base_name} vertex {j} is not finite (NaN or inf): {b[j].tolist()}")
    check_coordinates(b, base_name)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"{top_name} must be an (n, 3) array of (x, y, z) vertices, got shape {t.shape}")
    if len(t) != n:
        raise ValueError(f"{top_name} has {len(t)} vertices but {base_name} has {n}; counts must match")
    bad = ~np.isfinite(t).all(axis=1)
    if bad.any():
        j = int(np.argmax(bad))
        raise ValueError(f"{top_name} vertex {j} is not finite (NaN or inf): {t[j].tolist()}")
    check_coordinates(t, top_name)

    scale = max(float(np.ptp(b, axis=0).max()), 1e-12)
    nxt = np.append(np.arange(1, n), 0)      # x[nxt] is np.roll(x, -1, axis=0), at a fraction of its cost
    edges = b[nxt] - b
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    short = lengths <= 1e-9 * max(scale, 1.0)
    if short.any():
        j = int(np.argmax(short))
        raise ValueError(f"{base_name} vertices {j} and {(j + 1) % n} coincide (repeated vertex; "
                         f"give each vertex once, without closing the ring)")
    area = 0.5 * float(np.sum(b[:, 0] * b[nxt, 1] - b[nxt, 0] * b[:, 1]))
    sv = np.linalg.svd(b - b.mean(axis=0), compute_uv=False)
    if sv[-1] <= 1e-9 * sv[0]:
        raise ValueError(f"{base_name} has zero area (degenerate: all vertices collinear)")
    if not LinearRing(b).is_simple:
        raise ValueError(f"{base_name} is self-intersecting (its edges cross or overlap)")
    if abs(area) <= 1e-9 * scale * scale:
        raise ValueError(f"{base_name} has zero area (degenerate)")
    if area < 0:   # clockwise: reorient to counter-clockwise, keeping vertex 0 first; reorder the top alike
        order = (-np.arange(n)) % n
        b, t = b[order], t[order]
        edges = b[nxt] - b
        lengths = np.hypot(edges[:, 0], edges[:, 1])
    # sin of the turn at vertex j + 1 (between edge j and edge j + 1); negative = a right turn.
    turn = (edges[:, 0] * edges[nxt, 1] - edges[:, 1] * edges[nxt, 0]) / (lengths * lengths[nxt])
    if np.any(turn < -1e-9):
        j = (int(np.argmin(turn)) + 1) % n
        raise ValueError(f"{base_name} is not convex (reflex angle at vertex {j})")

    low = t[:, 2] <= 0
    if low.any():
        j = int(np.argmax(low))
        raise ValueError(f"{top_name} vertex {j} has z = {t[j, 2]:g}; top heights must be > 0")
    # Signed distance of every top vertex (plan view) to every base edge line; inside is >= 0.
    rel = t[None, :, :2] - b[:, None, :]                                      # (edge j, top vertex k, 2)
    dist = (edges[:, None, 0] * rel[..., 1] - edges[:, None, 1] * rel[..., 0]) / lengths[:, None]
    worst = dist.min(axis=0)
    outside = worst < -1e-6 * max(1.0, scale)
    if outside.any():
        k = int(np.argmax(outside))
        raise ValueError(f"{top_name} vertex {k} at (x, y) = ({t[k, 0]:g}, {t[k, 1]:g}) lies outside the "
                         f"footprint by {-worst[k]:.3g} m (the top's plan view must lie inside the base)")
    return b, t


def _check_altitude(top: np.ndarray, altitude: float | None, top_name: str = "top", where: str = "") -> None:
    """ValueError unless every vertex of ``top`` is lower than ``altitude`` (None: no check); ``where`` prefixes
    the message (``"Polytope: "``)."""
    if altitude is None:
        return
    # A NaN altitude would make every comparison false and pass every polytope.
    if isinstance(altitude, bool) or not isinstance(altitude, numbers.Real) or not 0 < altitude < math.inf:
        raise ValueError(f"{where}altitude must be a positive finite number or None, got {altitude!r}")
    high = top[:, 2] >= altitude
    if high.any():
        j = int(np.argmax(high))
        raise ValueError(f"{where}{top_name} vertex {j} has z = {top[j, 2]:g} >= altitude h = {altitude:g}; "
                         f"polytopes must be lower than the flight altitude")


def _first_overlap(polys) -> tuple[int, int, float] | None:
    """The first pair (i, j, area), i < j in lexicographic order, of footprints whose intersection has
    more area than ``_AREA_TOL``, else None.

    An R-tree (shapely's STRtree) finds the intersecting pairs in O(M log M + pairs), so a city of
    tens of thousands of buildings is checked in a fraction of a second (a dense M x M test needs
    M^2 memory); only those pairs have their intersection area computed, all at once.
    """
    if len(polys) < 2:
        return None
    geoms = np.empty(len(polys), dtype=object)
    geoms[:] = [p.footprint for p in polys]
    ii, jj = shapely.STRtree(geoms).query(geoms, predicate="intersects")
    keep = ii < jj
    ii, jj = ii[keep], jj[keep]
    order = np.lexsort((jj, ii))
    ii, jj = ii[order], jj[order]
    area = shapely.area(shapely.intersection(geoms[ii], geoms[jj]))
    hit = np.flatnonzero(area > _AREA_TOL)
    if hit.size == 0:
        return None
    k = int(hit[0])
    return int(ii[k]), int(jj[k]), float(area[k])


def _frustum_halfspaces(base: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Faces ``[nx, ny, nz, d]`` (unit outward normals, ``n.x + d <= 0`` inside) of a frustum: the base at
    z = 0, the planar top and one planar side per base edge (counter-clockwise base). (n + 2, 4)."""
    n = len(base)
    out = np.empty((n + 2, 4))
    # Cross products written out: np.cross costs more than the arithmetic on arrays this small.
    e = np.roll(base, -1, axis=0) - base                      # base edge j (z = 0)
    w = top - np.column_stack([base, np.zeros(n)])            # base vertex j -> top vertex j
    out[0, :3] = (0.0, 0.0, -1.0)                             # the base, z = 0
    t1 = np.roll(top, -1, axis=0)                             # Newell's normal of the planar top
    out[1, 0] = (top[:, 1] * t1[:, 2] - top[:, 2] * t1[:, 1]).sum()
    out[1, 1] = (top[:, 2] * t1[:, 0] - top[:, 0] * t1[:, 2]).sum()
    out[1, 2] = (top[:, 0] * t1[:, 1] - top[:, 1] * t1[:, 0]).sum()
    out[2:, 0] = e[:, 1] * w[:, 2]                            # e x w: outward for a CCW base, top above
    out[2:, 1] = -e[:, 0] * w[:, 2]
    out[2:, 2] = e[:, 0] * w[:, 1] - e[:, 1] * w[:, 0]
    out[:, :3] /= np.sqrt((out[:, :3] ** 2).sum(axis=1))[:, None]
    out[0, 3] = 0.0
    out[1, 3] = -(out[1, :3] @ top.mean(axis=0))
    out[2:, 3] = -(out[2:, 0] * base[:, 0] + out[2:, 1] * base[:, 1])
    return out


# ---------------------------------------------------------------------------------- polytope
@dataclass(frozen=True, eq=False)
class Polytope:
    """One convex polytope C_m: the convex hull of ``base`` (z = 0) and ``top``.

    Attributes:
        base: (n, 2) float array, the footprint Q_m, counter-clockwise, not closed.
        top: (n, 3) float array, the top D_m's vertices (x, y, z), same count and order as ``base``.

    Construction validates the pair and raises ValueError naming the field (see module docstring);
    a clockwise ``base`` is reversed to counter-clockwise (vertex 0 stays first) and ``top`` is
    reordered identically, so ``top[i]`` still sits above ``base[i]``. The top polygon itself is not
    required to be convex or non-degenerate: the polytope is defined as the hull.
    """

    base: np.ndarray
    top: np.ndarray

    def __post_init__(self) -> None:
        try:
            b, t = _check_polytope(self.base, self.top)
        except ValueError as exc:
            raise ValueError(f"Polytope: {exc}") from None
        b.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "base", b)
        object.__setattr__(self, "top", t)

    @classmethod
    def _prevalidated(cls, base: np.ndarray, top: np.ndarray, footprint: Polygon | None = None, *,
                      frustum: bool = False, halfspaces: np.ndarray | None = None) -> Polytope:
        """A polytope from arrays that are valid by construction (the random generator's), skipping the
        checks of ``__post_init__`` (most of a scene's build time). ``base`` must already be
        counter-clockwise; tests run every generated polytope through the full validator.

        ``frustum=True`` promises a planar top whose side quads ``base[j], base[j+1], top[j+1], top[j]`` are
        planar (a pyramid cut by a plane, see :func:`_random_top`): the faces are then written down
        directly instead of by a convex hull (tests compare them with the hull's, within 1e-8), or taken from
        ``halfspaces`` when the caller computed them (the batched generator)."""
        obj = object.__new__(cls)
        b, t = np.array(base, dtype=float), np.array(top, dtype=float)
        b.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(obj, "base", b)
        object.__setattr__(obj, "top", t)
        if footprint is not None:
            obj.__dict__["footprint"] = footprint      # the cached_property's slot
        if frustum:
            obj.__dict__["halfspaces"] = _frustum_halfspaces(b, t) if halfspaces is None else halfspaces
            obj.__dict__["plan_view"] = b               # the top is cut from a pyramid over the base
        return obj

    @classmethod
    def prism(cls, base, height: float) -> Polytope:
        """A flat-topped prism: the footprint ``base`` extruded to ``height`` (a simple building)."""
        if isinstance(height, bool) or not isinstance(height, numbers.Real):
            raise ValueError(f"Polytope.prism: height must be a number > 0 (m), got {height!r}")
        try:
            b = np.asarray(base, dtype=float)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValueError(f"Polytope: base must be an (n, 2) array of numbers ({exc})") from None
        ok = b.ndim == 2 and b.shape[1] == 2
        return cls(b, np.column_stack([b, np.full(len(b), float(height))]) if ok else np.empty((0, 3)))

    def validate(self, altitude: float | None = None) -> Polytope:
        """Check the heights against the flight altitude h (all top z < h); return self."""
        _check_altitude(self.top, altitude, where="Polytope: ")
        return self

    @property
    def n_vertices(self) -> int:
        return len(self.base)

    @cached_property
    def vertices(self) -> np.ndarray:
        """(2n, 3) array: base vertices at z = 0 followed by the top vertices (the paper's C_m set)."""
        return np.vstack([np.column_stack([self.base, np.zeros(len(self.base))]), self.top])

    @cached_property
    def halfspaces(self) -> np.ndarray:
        """(F, 4) array of faces ``[nx, ny, nz, d]`` with unit normals; the polytope is ``n.x + d <= 0``.

        Coplanar hull triangles are merged, so F is the number of planar faces.
        """
        eq = ConvexHull(self.vertices).equations
        # Merge coplanar triangles: round the plane equation (unit normal, offset in metres) and keep the
        # first triangle of each plane (a lexsort: np.unique(axis=0) costs as much as the hull itself).
        key = np.round(eq, 9)
        order = np.lexsort(key.T[::-1])
        first = np.ones(len(order), bool)
        first[1:] = np.any(key[order[1:]] != key[order[:-1]], axis=1)
        return eq[np.sort(order[first])]

    @cached_property
    def plan_view(self) -> np.ndarray:
        """(k, 2) the polytope's plan view (its shadow on the ground seen from above), counter-clockwise.

        The base, unless the top overhangs it (validation accepts up to 1e-6 of the footprint's size):
        then the convex hull of base and top."""
        b, t = self.base, self.top[:, :2]
        e = np.roll(b, -1, axis=0) - b
        rel = t[None, :, :] - b[:, None, :]
        if np.all(e[:, None, 0] * rel[..., 1] - e[:, None, 1] * rel[..., 0] >= 0.0):
            return b
        xy = self.vertices[:, :2]
        return xy[ConvexHull(xy).vertices]      # scipy returns 2-D hull vertices counter-clockwise

    @property
    def z_max(self) -> float:
        """Height of the highest point (the point the eq. 3 safety distance is measured to)."""
        return float(self.top[:, 2].max())

    @property
    def highest_point(self) -> np.ndarray:
        """(3,) the highest top vertex (first one on ties)."""
        return self.top[int(np.argmax(self.top[:, 2]))].copy()

    @cached_property
    def footprint(self) -> Polygon:
        """The base Q_m as a shapely polygon (plan view of the whole polytope)."""
        return Polygon(self.base)

    @cached_property
    def centroid_xy(self) -> np.ndarray:
        return np.asarray(self.footprint.centroid.coords[0])

    @cached_property
    def radius_xy(self) -> float:
        """Radius of a circle about ``centroid_xy`` enclosing the footprint."""
        return float(np.linalg.norm(self.base - self.centroid_xy, axis=1).max())
