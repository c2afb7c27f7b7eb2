"""Terrain: M convex polytopes C_m (buildings, hills) standing on flat ground z = 0 (paper §2.1, Fig. 2).

Each polytope is the convex hull of a base polygon Q_m at z = 0 (convex, counter-clockwise) and a top
polygon D_m with the same number of vertices, each with its own height z > 0 (a top may be slanted).
Geometry code uses the half-space form ``n . x + d <= 0`` of every polytope, padded into arrays so
that line-of-sight tests vectorise over polytopes and faces.

Three ways to get a terrain:

* ``Terrain([Polytope(base, top), ...])``: every polytope is validated on construction (finite, >= 3
  vertices, convex simple base of positive area, matching top with z > 0 inside the footprint) and the
  footprints must not overlap. A clockwise base is accepted and reoriented to counter-clockwise, with
  the top reordered the same way. Heights are checked against the flight altitude h by
  ``validate(altitude)`` (the loaders and the generator do this).
* ``Terrain.random(seed, road)``: the paper's generator (§3): M polytopes scattered along the road.
* ``Terrain.load(path)`` / ``Terrain.from_geojson(obj)``: a GeoJSON FeatureCollection of Polygon
  footprints in local metres with ``properties.height`` (flat top) or ``properties.top`` (slanted).
"""

from __future__ import annotations

import json
import math
import numbers
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from scipy.spatial import ConvexHull
from shapely.geometry import LinearRing, Polygon

from covert_env.config import MAX_N_POLYTOPES, Config, check_coordinates, read_json, short_repr
from covert_env.generation import BUILDING_SHRINK, HILL_FRACTION, HILL_SHRINK, HILL_TILT, MIN_GAP
from covert_env.road import Road

__all__ = ["Polytope", "Terrain"]


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


def _check_altitude(top: np.ndarray, altitude: float | None, top_name: str = "top") -> None:
    if altitude is None:
        return
    # A NaN altitude would make every comparison false and pass every polytope.
    if isinstance(altitude, bool) or not isinstance(altitude, numbers.Real) or not 0 < altitude < math.inf:
        raise ValueError(f"altitude must be a positive finite number or None, got {altitude!r}")
    high = top[:, 2] >= altitude
    if high.any():
        j = int(np.argmax(high))
        raise ValueError(f"{top_name} vertex {j} has z = {top[j, 2]:g} >= altitude h = {altitude:g}; "
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
        checks of ``__post_init__`` (~0.2 ms each, most of a scene's build time). ``base`` must already be
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
        try:
            _check_altitude(self.top, altitude)
        except ValueError as exc:
            raise ValueError(f"Polytope: {exc}") from None
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


# ---------------------------------------------------------------------------------- random generator
# The generators' shared rules (one home: covert_env.generation).
_MIN_GAP, _HILL_FRACTION = MIN_GAP, HILL_FRACTION
_BUILDING_SHRINK, _HILL_SHRINK, _HILL_TILT = BUILDING_SHRINK, HILL_SHRINK, HILL_TILT
_MAX_TRIES = 400


def _generator(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0:
        # A stream independent of Road.random(seed), which uses the plain seed.
        return np.random.default_rng([int(seed), 0x7E44A1])
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"Terrain.random: seed must be None, an integer >= 0 or a numpy Generator, "
                         f"got {seed!r} ({exc})") from None


def _random_footprint(rng: np.random.Generator, k: int, r: float) -> np.ndarray:
    """k vertices on an ellipse (semi-axes r, r * U(0.6, 1)) at jittered, increasing angles, randomly
    rotated, centred at the origin: strictly convex, counter-clockwise, circumradius <= r."""
    ang = 2 * np.pi * (np.arange(k) + rng.uniform(-0.3, 0.3, k)) / k
    pts = np.column_stack([r * np.cos(ang), r * rng.uniform(0.6, 1.0) * np.sin(ang)])
    rot = rng.uniform(0, 2 * np.pi)
    c, s = math.cos(rot), math.sin(rot)
    return pts @ np.array([[c, s], [-s, c]])


def _random_top(rng: np.random.Generator, base: np.ndarray, zmin: float, zmax: float) -> np.ndarray:
    """A top cut from the pyramid over ``base`` with its apex above the centroid by a plane.

    Flat tops (buildings) are a homothetic shrink of the base about its centroid. Slanted tops (hills)
    are where the slanted plane meets the pyramid's edges; the side faces lie in the pyramid's faces, so
    they stay planar (a homothetic shrink lifted onto a slanted plane would give twisted sides). The
    whole solid is then scaled vertically so that every top z lies in [zmin, zmax].
    """
    n = len(base)
    x, y = base[:, 0], base[:, 1]
    nxt = np.roll(base, -1, axis=0)                 # one roll for both coordinates (same values as two)
    x1, y1 = nxt[:, 0], nxt[:, 1]
    cross = x * y1 - x1 * y
    area = 0.5 * cross.sum()
    c = np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (6 * area)
    hill = rng.random() < _HILL_FRACTION
    f = rng.uniform(*(_HILL_SHRINK if hill else _BUILDING_SHRINK))
    z0 = 1.0 - f                                    # plane height above the centroid; apex at height 1
    slope_dir = rng.uniform(0, 2 * np.pi)
    q = (base - c) @ np.array([math.cos(slope_dir), math.sin(slope_dir)])
    tilt = rng.uniform(*_HILL_TILT) if hill else 0.0
    for _ in range(8):
        p = (tilt * z0 / max(np.abs(q).max(), 1e-12)) * q     # |p| <= tilt * z0 < 1
        lam = (z0 + p) / (1.0 + p)                  # where edge base_j -> apex meets the plane (= its z)
        ratio = lam.max() / lam.min()
        if zmin * ratio <= zmax:
            break
        tilt *= 0.5
    else:
        lam, ratio = np.full(n, z0), 1.0
    top_z = rng.uniform(zmin * ratio, zmax) if zmin * ratio < zmax else zmax
    z = np.minimum(np.maximum(lam * (top_z / lam.max()), zmin), zmax)
    xy = base + lam[:, None] * (c - base)
    return np.column_stack([xy, z])


# ---------------------------------------------------------------------------------- GeoJSON helpers
def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _label(i: int, feat) -> str:
    s = f"feature {i}"
    if isinstance(feat, dict):
        props = feat.get("properties")
        if feat.get("id") is not None:
            s += f" (id {feat['id']!r})"
        elif isinstance(props, dict) and props.get("name") is not None:
            s += f" (name {props['name']!r})"
    return s


def _ring_length(feat) -> int:
    """The vertex count of a feature's exterior ring, 0 if it is malformed (for the size check)."""
    try:
        return max(len(feat["geometry"]["coordinates"][0]) - 1, 0)
    except (KeyError, IndexError, TypeError):
        return 0


def _parse_feature(feat, altitude: float | None) -> Polytope:
    """One Feature -> Polytope; ValueError messages name the field (the caller adds the label)."""
    if not isinstance(feat, dict) or feat.get("type") != "Feature":
        raise ValueError("must be a GeoJSON object with type 'Feature'")
    geom = feat.get("geometry")
    gtype = geom.get("type") if isinstance(geom, dict) else None
    if gtype != "Polygon":
        raise ValueError(f"geometry.type must be 'Polygon', got {gtype!r}")
    rings = geom.get("coordinates")
    if not isinstance(rings, list) or not rings:
        raise ValueError("geometry.coordinates must be a non-empty list of linear rings")
    if len(rings) > 1:
        raise ValueError(f"geometry has {len(rings) - 1} hole(s); polygons with holes are not supported "
                         f"(a polytope's footprint is convex)")
    ring = rings[0]
    if not isinstance(ring, list) or len(ring) < 4:
        raise ValueError("geometry.coordinates[0] must be a closed ring of at least 4 positions "
                         "(3 distinct vertices, first repeated at the end)")
    for j, pos in enumerate(ring):
        if not isinstance(pos, list) or len(pos) not in (2, 3) or not all(_is_num(v) for v in pos):
            raise ValueError(f"geometry.coordinates[0][{j}] must be [x, y] (or [x, y, 0]) numbers, "
                             f"got {pos!r}")
        if len(pos) == 3 and pos[2] != 0:
            raise ValueError(f"geometry.coordinates[0][{j}] has z = {pos[2]!r}; footprints lie on the ground "
                             f"(z = 0; give heights in properties)")
    base = np.array([pos[:2] for pos in ring], dtype=float)
    if not np.array_equal(base[0], base[-1]):
        raise ValueError(f"geometry ring is not closed: first position {ring[0]!r} != last {ring[-1]!r} "
                         f"(GeoJSON rings repeat the first position at the end)")
    base = base[:-1]
    props = feat.get("properties")
    if props is None:
        props = {}
    if not isinstance(props, dict):
        raise ValueError("properties must be an object")
    has_h, has_t = props.get("height") is not None, props.get("top") is not None
    if has_h == has_t:
        raise ValueError("properties must give exactly one of 'height' (flat top) and 'top' "
                         f"(list of [x, y, z]); got {'both' if has_h else 'neither'}")
    if has_h:
        h = props["height"]
        rng_txt = f"(0, h={altitude:g})" if altitude is not None else "(0, inf)"
        if not _is_num(h) or not math.isfinite(h) or h <= 0 or (altitude is not None and h >= altitude):
            raise ValueError(f"properties.height must be in {rng_txt}, got {h!r}")
        top = np.column_stack([base, np.full(len(base), float(h))])
        top_name = "properties.height"
    else:
        top = props["top"]
        if not isinstance(top, list) or not all(
                isinstance(v, list) and len(v) == 3 and all(_is_num(u) for u in v) for v in top):
            raise ValueError("properties.top must be a list of [x, y, z] numbers")
        if len(top) != len(base):
            raise ValueError(f"properties.top has {len(top)} vertices but the footprint has {len(base)} "
                             f"distinct vertices; counts must match")
        top_name = "properties.top"
    b, t = _check_polytope(base, top, base_name="geometry", top_name=top_name)
    _check_altitude(t, altitude, top_name)
    return Polytope._prevalidated(b, t)     # checked just above: Polytope() would check it all again


# ---------------------------------------------------------------------------------- terrain
@dataclass(frozen=True, eq=False)
class Terrain:
    """A set of non-overlapping convex polytopes on flat ground.

    Attributes:
        polytopes: the polytopes C_1..C_M. Footprints may touch but not overlap (ValueError naming
            both indices otherwise).
    """

    polytopes: tuple[Polytope, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        try:
            polys = tuple(self.polytopes)
        except TypeError:
            raise TypeError(f"Terrain.polytopes must be an iterable of Polytope, got "
                            f"{type(self.polytopes).__name__}") from None
        for i, p in enumerate(polys):
            if not isinstance(p, Polytope):
                raise TypeError(f"Terrain: polytope {i} must be a Polytope, got {type(p).__name__}")
        _check_size([len(p.base) for p in polys], "Terrain")
        object.__setattr__(self, "polytopes", polys)
        hit = _first_overlap(polys)
        if hit is not None:
            i, j, area = hit
            raise ValueError(f"Terrain: polytopes {i} and {j}: footprints overlap (intersection area "
                             f"{area:.3g} m^2)")

    def __len__(self) -> int:
        return len(self.polytopes)

    def __iter__(self):
        return iter(self.polytopes)

    def __getitem__(self, i: int) -> Polytope:
        return self.polytopes[i]

    def validate(self, altitude: float | None = None) -> Terrain:
        """Check every polytope is lower than the flight altitude h; return self."""
        for i, p in enumerate(self.polytopes):
            try:
                _check_altitude(p.top, altitude)
            except ValueError as exc:
                raise ValueError(f"Terrain: polytope {i}: {exc}") from None
        return self

    # ------------------------------------------------------------------ random generator (paper §3)
    @classmethod
    def random(cls, seed: int | np.random.Generator | None = None, road: Road | None = None,
               n: int | None = None, config: Config | None = None, **overrides: Any) -> Terrain:
        """The paper's random terrain: ``n`` polytopes (default ``config.n_polytopes``) along ``road``.

        Polytope i is placed at a random arc length in the i-th of n equal stretches of the road (any
        stretch if that fails), on a random side, with its footprint at least ``road_clearance`` from
        the centreline and (radius permitting) within ``config.road_max_offset`` of it, and at least
        ``_MIN_GAP`` = 2 m from every other footprint (rejection sampling, ValueError if a polytope
        cannot be placed). Footprint: ``U{min_vertices..max_vertices}`` vertices on a randomly rotated
        ellipse of radius ``U(min_radius, max_radius)``. Top: 60 % flat-topped buildings (the base
        shrunk about its centroid by 0.8-0.95), 40 % slanted hills (a pyramid over the base cut by a
        slanted plane; see :func:`_random_top`), every top z in ``[min_height, max_polytope_height]``,
        every side face planar.

        Args:
            seed: int, Generator or None. Deterministic for a given int seed.
            road: the road; default ``Road.random(seed)`` (so an int seed reproduces the road too).
            n: number of polytopes; default ``config.n_polytopes``.
            config: a :class:`Config` (default ``Config()``); ``overrides`` replace its fields.
        """
        cfg = config if config is not None else Config()
        if not isinstance(cfg, Config):
            raise TypeError(f"Terrain.random: config must be a Config, got {type(cfg).__name__}")
        if overrides:
            cfg = cfg.replace(**overrides)
        n = cfg.n_polytopes if n is None else n
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= n <= MAX_N_POLYTOPES:
            raise ValueError(f"Terrain.random: n must be an integer >= 0 and <= {MAX_N_POLYTOPES}, got {n!r}")
        n = int(n)
        if road is not None and not isinstance(road, Road):
            raise TypeError(f"Terrain.random: road must be a Road or None, got {type(road).__name__}")
        rng = _generator(seed)                         # first: a bad seed is named as Terrain.random's
        if road is None:
            road = Road.random(seed)
        clear, length, line = cfg.road_clearance, road.length, road.linestring
        zmin, zmax = cfg.min_height, cfg.max_polytope_height
        polys: list[Polytope] = []
        centres = np.empty((0, 2))
        radii = np.empty(0)
        for i in range(n):
            for attempt in range(_MAX_TRIES):
                lo, hi = (i / n, (i + 1) / n) if attempt < _MAX_TRIES // 2 else (0.0, 1.0)
                s = rng.uniform(lo, hi) * length
                k = int(rng.integers(cfg.min_vertices, cfg.max_vertices + 1))
                r = rng.uniform(cfg.min_radius, cfg.max_radius)
                near = clear + r
                # rng.choice((-1.0, 1.0)) draws this same integer, at 5x the cost of the call.
                off = rng.uniform(near, max(near, cfg.road_max_offset - r)) * (-1.0, 1.0)[rng.integers(0, 2)]
                point, th = road.pose_at(s)
                centre = point + off * np.array([-math.sin(th), math.cos(th)])
                base = _random_footprint(rng, k, r) + centre
                close = np.flatnonzero(np.linalg.norm(centres - centre, axis=1) < radii + r + _MIN_GAP)
                fp = Polygon(base)
                if any(polys[j].footprint.distance(fp) < _MIN_GAP for j in close):
                    continue
                if line.distance(fp) < clear:   # the polygon's distance: also covers every vertex
                    continue
                polys.append(Polytope._prevalidated(base, _random_top(rng, base, zmin, zmax), fp, frustum=True))
                centres = np.vstack([centres, centre])
                radii = np.append(radii, r)
                break
            else:
                raise ValueError(
                    f"Terrain.random: could not place polytope {i} of {n} after {_MAX_TRIES} tries "
                    f"(road length {length:.0f} m); use fewer polytopes (n / Config.n_polytopes), a smaller "
                    f"max_radius ({cfg.max_radius:g}) or road_clearance ({cfg.road_clearance:g}), or a longer road")
        # Footprints are >= _MIN_GAP apart and tops in [zmin, zmax] with zmax < altitude (Config checks it) by
        # construction, so Terrain's overlap check and validate() are skipped (the tests run every generated
        # terrain through both).
        return cls._checked(tuple(polys)).validate(cfg.altitude) if cls is not Terrain else cls._checked(tuple(polys))

    @classmethod
    def _checked(cls, polys: tuple[Polytope, ...]) -> Terrain:
        """A terrain of polytopes whose footprints are already known not to overlap: skips that check
        (a subclass may check more in its __post_init__, so it gets the full constructor)."""
        if cls is not Terrain:
            return cls(polys)
        obj = object.__new__(cls)
        object.__setattr__(obj, "polytopes", polys)
        return obj

    # ------------------------------------------------------------------ GeoJSON
    @classmethod
    def from_geojson(cls, obj: dict, altitude: float | None = None) -> Terrain:
        """Build from a GeoJSON FeatureCollection (a dict) in local metres.

        Each feature is a Polygon footprint (exterior ring closed, no holes, [x, y] positions) with
        either ``properties.height`` (flat top at that height) or ``properties.top`` (the top's
        distinct vertices as [x, y, z], same count and order as the footprint's distinct vertices).
        The polytope is the hull of footprint and top. Rings may be clockwise (they are reoriented).
        With ``altitude`` every height must be < altitude. At most ``MAX_N_POLYTOPES`` (10,000) features
        and ``MAX_TERRAIN_VERTICES`` (100,000) footprint vertices, checked before any is parsed; every
        coordinate within ``MAX_COORDINATE`` (1,000 km). Errors are ValueErrors naming the feature
        (index, and ``id`` or ``properties.name`` when given) and the field.
        """
        if not isinstance(obj, dict) or obj.get("type") != "FeatureCollection":
            got = obj.get("type") if isinstance(obj, dict) else type(obj).__name__
            raise ValueError(f"GeoJSON terrain must be an object with type 'FeatureCollection', got {got!r}")
        feats = obj.get("features")
        if not isinstance(feats, list):
            raise ValueError("GeoJSON FeatureCollection.features must be a list")
        # Sizes first, before any feature is parsed: each costs geometry work, the overlap check more. A malformed
        # feature counts as none here; parsing it names its error.
        _check_size([_ring_length(feat) for feat in feats], "GeoJSON FeatureCollection")
        if altitude is not None and (isinstance(altitude, bool) or not isinstance(altitude, numbers.Real)
                                     or not 0 < altitude < math.inf):
            raise ValueError(f"altitude must be a positive number or None, got {altitude!r}")
        polys = []
        for i, feat in enumerate(feats):
            try:
                polys.append(_parse_feature(feat, altitude))
            except (ValueError, OverflowError) as exc:     # OverflowError: an integer beyond float's range
                raise ValueError(f"{_label(i, feat)}: {exc}") from None
        hit = _first_overlap(polys)
        if hit is not None:
            i, j, area = hit
            raise ValueError(f"{_label(i, feats[i])} and {_label(j, feats[j])}: footprints overlap "
                             f"(intersection area {area:.3g} m^2)")
        return cls._checked(tuple(polys))

    def to_geojson(self) -> dict:
        """A GeoJSON FeatureCollection (local metres, counter-clockwise rings, feature ids 0..M-1).

        A polytope whose top is its footprint raised to one height is written with ``height``; any
        other (shrunk or slanted top) with ``top``, so ``from_geojson(to_geojson())`` is exact.
        """
        feats = []
        for i, p in enumerate(self.polytopes):
            flat = bool(np.all(p.top[:, 2] == p.top[0, 2]) and np.array_equal(p.top[:, :2], p.base))
            props = {"height": float(p.top[0, 2])} if flat else {"top": p.top.tolist()}
            ring = p.base.tolist() + [p.base[0].tolist()]
            feats.append({"type": "Feature", "id": i, "properties": props,
                          "geometry": {"type": "Polygon", "coordinates": [ring]}})
        return {"type": "FeatureCollection", "features": feats}

    @classmethod
    def load(cls, path: str | Path, altitude: float | None = None) -> Terrain:
        """Read a GeoJSON file (see :meth:`from_geojson`).

        Errors name the file: FileNotFoundError if it is missing, ValueError for bytes that are not
        UTF-8, invalid or too deeply nested JSON, and everything :meth:`from_geojson` rejects.
        """
        if not isinstance(path, (str, Path)):
            raise TypeError(f"Terrain.load: path must be a str or pathlib.Path naming a GeoJSON file, got "
                            f"{short_repr(path)} ({type(path).__name__}); for a dict use Terrain.from_geojson")
        if not str(path).strip():
            raise ValueError("Terrain.load: path is empty; give the GeoJSON file's path")
        obj = read_json(path, "Terrain file")
        try:
            return cls.from_geojson(obj, altitude=altitude)
        except ValueError as exc:
            raise ValueError(f"Terrain file {path}: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_geojson` to ``path`` as JSON."""
        Path(path).write_text(json.dumps(self.to_geojson(), indent=1, allow_nan=False) + "\n")

    # ------------------------------------------------------------------ queries
    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of all footprints; NaNs for an empty terrain (as shapely does)."""
        if not self.polytopes:
            return (math.nan,) * 4
        pts = np.vstack([p.base for p in self.polytopes])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    @cached_property
    def _footprints(self) -> np.ndarray:
        out = np.empty(len(self.polytopes), dtype=object)
        for i, p in enumerate(self.polytopes):
            out[i] = p.footprint
        return out

    def polytopes_near(self, xy, radius: float) -> np.ndarray:
        """Indices (ascending) of polytopes whose footprint comes within ``radius`` of the point ``xy``."""
        xy = np.asarray(xy, dtype=float).reshape(2)
        if not self.polytopes:
            return np.empty(0, dtype=int)
        cand = np.flatnonzero(np.linalg.norm(self.centroids_xy - xy, axis=1) - self.radii_xy <= radius)
        if cand.size == 0:
            return cand
        d = shapely.distance(self._footprints[cand], shapely.Point(xy))
        return cand[d <= radius]

    # ------------------------------------------------------------------ padded arrays
    @cached_property
    def halfspace_array(self) -> np.ndarray:
        """(M, F_max, 4) faces of every polytope, padded with the always-true row ``0.x - 1 <= 0``."""
        m = len(self.polytopes)
        f = max((len(p.halfspaces) for p in self.polytopes), default=1)
        out = np.zeros((m, f, 4))
        out[:, :, 3] = -1.0
        for i, p in enumerate(self.polytopes):
            out[i, : len(p.halfspaces)] = p.halfspaces
        out.setflags(write=False)
        return out

    @cached_property
    def centroids_xy(self) -> np.ndarray:
        """(M, 2) footprint centroids."""
        return np.array([p.centroid_xy for p in self.polytopes]).reshape(-1, 2)

    @cached_property
    def radii_xy(self) -> np.ndarray:
        """(M,) radii of circles about the centroids enclosing each footprint."""
        return np.array([p.radius_xy for p in self.polytopes])

    @cached_property
    def z_max(self) -> np.ndarray:
        """(M,) height of each polytope's highest point."""
        return np.array([p.z_max for p in self.polytopes])

    @cached_property
    def highest_points(self) -> np.ndarray:
        """(M, 3) each polytope's highest point (eq. 3 measures the safety distance to it)."""
        return np.array([p.highest_point for p in self.polytopes]).reshape(-1, 3)
