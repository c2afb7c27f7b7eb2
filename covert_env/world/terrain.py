"""Terrain: M convex polytopes C_m (buildings, hills) standing on flat ground z = 0 (paper §2.1, Fig. 2).

Each polytope (:class:`covert_env.world.polytope.Polytope`) is the convex hull of a base polygon Q_m at z = 0 (convex,
counter-clockwise) and a top polygon D_m with the same number of vertices, each with its own height z > 0 (a top
may be slanted). Geometry code uses the half-space form ``n . x + d <= 0`` of every polytope, padded into arrays so
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
from shapely.geometry import Polygon

from covert_env.world.config import MAX_N_POLYTOPES, Config, read_json, short_repr
from covert_env.world.generation import BUILDING_SHRINK, HILL_FRACTION, HILL_SHRINK, HILL_TILT, MIN_GAP
from covert_env.world.polytope import Polytope, _check_altitude, _check_polytope, _check_size, _first_overlap
from covert_env.world.road import Road

__all__ = ["Polytope", "Terrain"]


# ---------------------------------------------------------------------------------- random generator
# The generators' shared rules (one home: covert_env.world.generation).
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
            _check_altitude(p.top, altitude, where=f"Terrain: polytope {i}: ")
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
                # rng.choice((-1.0, 1.0)) draws this same integer; indexing is the cheaper call.
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
        and :data:`~covert_env.world.polytope.MAX_TERRAIN_VERTICES` (100,000) footprint vertices, checked before any is
        parsed; every coordinate within ``MAX_COORDINATE`` (1,000 km). Errors are ValueErrors naming the feature
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
