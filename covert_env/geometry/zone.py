"""The feasible flight zone behind the target, its erosion under uncertainty, the visible zone and the
waypoint lattice (paper §2.1-2.2, eqs. 4, 5 and 10).

Feasible zone (eq. 4). In the UAV plane, the annular sector behind the target at q with heading phi::

    Phi(q, phi) = { p : r1 <= |p - q| <= r2  and  |wrap(atan2(p - q) - (phi + pi))| <= mu / 2 }

(mu is the full opening angle). Closer than r1 the target would notice the UAV, farther than r2 the
video is too poor, and staying behind the target keeps the UAV out of the driver's view.

Uncertainty (eq. 5). The prediction of q is only known to lie in the disk gamma(q) of radius r_u, and the
zone must hold for every q0 in that disk: ``Phi_gamma = ∩_{q0 in gamma(q)} Phi(q0)``. Translating q
translates the zone, so this intersection is the erosion ``Phi ⊖ disk(r_u)`` = the points of Phi at
distance >= r_u from its boundary. Erosion distributes over intersections, so it is the annulus
``r1 + r_u <= rho <= r2 - r_u`` intersected with the wedge eroded by r_u, whose sides are the two radial
lines moved inwards by r_u; in polar coordinates about q (theta measured from the backward axis
phi + pi)::

    r1 + r_u <= rho <= r2 - r_u   and   mu / 2 - |theta| >= asin(r_u / rho).

Both membership tests here use that exact form; polygons approximate the arcs by chords.

Visible zone (eq. 10). ``F = Phi_gamma minus the union of the shadows`` (:mod:`covert_env.world.visibility`).

Lattice. The planner's nodes and the environment's waypoint actions are one fixed lattice of offsets in
the target's frame (x forward along phi, y to the left), spacing ``step``, covering the sector's bounding
box. The offsets never depend on q or phi; membership in the zone (and later visibility) is a mask.

The functions take plain numbers, except :func:`feasible_zone_cfg`, :func:`lattice_offsets_cfg` and
:func:`zone_lattice`, which read them from a :class:`~covert_env.Config` (``r1``, ``r2``, ``mu``, ``r_u``,
``grid_step``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.separation import separation

MAX_LATTICE = 200_000
"""Most nodes of the waypoint lattice's bounding box (:func:`lattice_size`), about
``(2 r2 sin(mu / 2) / grid_step) * ((r2 - r1 cos(mu / 2)) / grid_step)`` for mu <= pi; 975 by default."""

__all__ = [
    "ARC_RESOLUTION",
    "arc_error",
    "feasible_zone",
    "feasible_zone_cfg",
    "grid_nodes",
    "in_feasible_zone",
    "lattice_offsets",
    "lattice_offsets_cfg",
    "to_target_frame",
    "to_world",
    "visible_zone",
    "zone_distance",
    "zone_mask", "zone_lattice", "lattice_size", "spread_nodes", "spread_picks", "zone_capacity"]

ARC_RESOLUTION = math.radians(0.25)
"""Default largest angle (rad) spanned by one chord of a polygon arc."""


def arc_error(radius: float, arc_resolution: float = ARC_RESOLUTION) -> float:
    """Largest gap (m) between an arc of ``radius`` and its chords: ``r (1 - cos(res / 2))``.

    Zone polygons lie inside the exact zone and every point of the exact zone is within this distance
    (at the outer radius) of them: 2.4e-4 m for r = 100 m at the default 0.25 degree resolution.
    """
    return float(radius * (1.0 - math.cos(arc_resolution / 2.0)))


# ----------------------------------------------------------------------------- polygon (eqs. 4-5)
def feasible_zone(q_xy, phi: float, r1: float, r2: float, mu: float, r_u: float = 0.0,
                  arc_resolution: float = ARC_RESOLUTION) -> Polygon:
    """The feasible zone as a polygon: the annular sector of eq. 4, eroded by ``disk(r_u)`` (eq. 5).

    Built exactly from the polar form in the module docstring rather than by ``buffer(-r_u)``: the
    eroded sides are straight lines, only the two arcs are discretised. Arc chords are placed so the
    polygon lies inside the exact zone (outer arc: vertices on the circle; inner arc: vertices on the
    circle of radius ``r / cos(step / 2)``, whose chords are tangent to the inner circle), within
    :func:`arc_error` of it.

    Args:
        q_xy: (2,) target position (horizontal).
        phi: target heading (rad); the zone lies around the bearing phi + pi.
        r1, r2: inner and outer radius (m), 0 <= r1 < r2.
        mu: full opening angle (rad), in (0, 2 pi).
        r_u: radius (m) of the prediction-uncertainty disk gamma(q); 0 gives eq. 4.
        arc_resolution: largest angle (rad) of one arc chord.

    Returns:
        A Polygon; empty when the erosion removes everything (e.g. 2 r_u >= r2 - r1).
    """
    qx, qy = (float(v) for v in np.asarray(q_xy, dtype=float).reshape(2))
    if not (0.0 <= r1 < r2 and 0.0 < mu < 2 * math.pi and r_u >= 0.0 and arc_resolution > 0.0):
        raise ValueError(f"need 0 <= r1 < r2, 0 < mu < 2 pi, r_u >= 0, arc_resolution > 0; got r1={r1}, "
                         f"r2={r2}, mu={mu}, r_u={r_u}, arc_resolution={arc_resolution}")
    rho_out, rho_in = r2 - r_u, r1 + r_u
    if rho_in >= rho_out:
        return Polygon()

    def half(rho: float) -> float:
        # Angular half-width at radius rho: the eroded side keeps distance r_u from the radial line.
        return mu / 2.0 - (math.asin(min(1.0, r_u / rho)) if rho > 0 else 0.0)

    h_out, h_in = half(rho_out), half(rho_in)
    if h_out <= 0.0:
        return Polygon()
    n_out = max(1, math.ceil(2 * h_out / arc_resolution))
    th = [np.linspace(-h_out, h_out, n_out + 1)]
    rr = [np.full(n_out + 1, rho_out)]
    if h_in > 0.0 and rho_in > 0.0:
        n_in = max(1, math.ceil(2 * h_in / arc_resolution))
        th.append(np.linspace(h_in, -h_in, n_in + 1))
        rr.append(np.full(n_in + 1, rho_in / math.cos(h_in / n_in)))
    elif rho_in > 0.0:
        # The eroded wedge's apex (r_u / sin(mu / 2) from q) lies beyond rho_in: no inner arc.
        th.append(np.zeros(1))
        rr.append(np.full(1, r_u / math.sin(mu / 2.0)))
    else:
        th.append(np.zeros(1))                           # r1 = r_u = 0: a plain circular sector
        rr.append(np.zeros(1))
    ang = phi + math.pi + np.concatenate(th)
    rho = np.concatenate(rr)
    return Polygon(np.column_stack([qx + rho * np.cos(ang), qy + rho * np.sin(ang)]))


def feasible_zone_cfg(q_xy, phi: float, config, *, uncertain: bool = True,
                      arc_resolution: float = ARC_RESOLUTION) -> Polygon:
    """:func:`feasible_zone` with ``config``'s r1, r2, mu and (if ``uncertain``) r_u (eq. 5, else eq. 4)."""
    return feasible_zone(q_xy, phi, config.r1, config.r2, config.mu, config.r_u if uncertain else 0.0,
                         arc_resolution)


# ----------------------------------------------------------------------------- analytic membership
def _polar(xy, q_xy, phi):
    """Distance rho and angle theta from the backward axis phi + pi, wrapped into (-pi, pi]."""
    d = np.asarray(xy, dtype=float) - np.asarray(q_xy, dtype=float)
    rho = np.hypot(d[..., 0], d[..., 1])
    # Wrapped, so a zone straddling the +-pi cut of atan2 (target heading near 0) needs no special case.
    th = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - (np.asarray(phi, dtype=float) + np.pi))
    return rho, th


def in_feasible_zone(xy, q_xy, phi, r1: float, r2: float, mu: float, r_u: float = 0.0) -> np.ndarray:
    """Whether points lie in the (eroded) feasible zone, exactly (eqs. 4-5), vectorised.

    ``r1 + r_u <= rho <= r2 - r_u and mu / 2 - |theta| >= asin(r_u / rho)`` (module docstring), which is
    the same as ``zone_distance(...) <= -r_u``. Boundaries are included.

    Args:
        xy: (..., 2) points; q_xy (..., 2) and phi (...) broadcast against them.

    Returns:
        bool array of the broadcast leading shape.
    """
    rho, th = _polar(xy, q_xy, phi)
    with np.errstate(divide="ignore"):
        gap = np.arcsin(np.minimum(1.0, r_u / rho)) if r_u > 0 else 0.0
    return (rho >= r1 + r_u) & (rho <= r2 - r_u) & (mu / 2.0 - np.abs(th) >= gap)


def zone_distance(xy, q_xy, phi, r1: float, r2: float, mu: float) -> np.ndarray:
    """Signed distance (m) from points to the boundary of the uneroded zone (eq. 4); negative inside.

    The boundary is two arcs (radii r1, r2, angular half-width mu / 2 about the backward axis) and two
    radial segments from r1 to r2. Useful for shaping rewards and for the least-bad move when the zone
    is unreachable: a point is in the zone eroded by r_u iff ``zone_distance <= -r_u``.

    Args:
        xy: (..., 2) points; q_xy (..., 2) and phi (...) broadcast against them.
    """
    rho, th = _polar(xy, q_xy, phi)
    within = np.abs(th) <= mu / 2.0
    # An arc is nearest through its interior only when the point's bearing lies in the arc's range;
    # otherwise the nearest arc point is an end point, which the radial segments already cover.
    d_arc = np.where(within, np.minimum(np.abs(rho - r1), np.abs(rho - r2)), np.inf)
    # Fold onto the upper side (the zone is symmetric about its axis): a point there is never nearer
    # the lower radial side than the upper one, so one segment distance suffices.
    a, b = rho * np.cos(th), rho * np.sin(np.abs(th))
    c, s = math.cos(mu / 2.0), math.sin(mu / 2.0)
    t = np.minimum(np.maximum(a * c + b * s, r1), r2)     # np.clip's wrapper costs more than the maths here
    d_seg = np.hypot(a - t * c, b - t * s)
    dist = np.minimum(d_arc, d_seg)
    inside = within & (rho >= r1) & (rho <= r2)
    return np.where(inside, -dist, dist)


# ----------------------------------------------------------------------------- visible zone (eq. 10)
def visible_zone(zone: BaseGeometry, shadows) -> BaseGeometry:
    """The visible feasible zone ``F = zone minus the union of the shadows`` (eq. 10).

    Args:
        zone: the (eroded) feasible zone, e.g. from :func:`feasible_zone`.
        shadows: a geometry (e.g. :func:`~covert_env.world.shadows.shadow_union`) or an iterable of
            polygons (e.g. :func:`~covert_env.world.shadows.shadow_polygons`).

    Returns:
        A Polygon or MultiPolygon, possibly empty: shadows can split the zone or cover it.
    """
    if not isinstance(shadows, BaseGeometry):
        shadows = [s for s in shadows if not s.is_empty]
        if not shadows:
            return zone
        shadows = shapely.union_all(shadows)
    if shadows.is_empty:
        return zone
    return zone.difference(shadows)


# ----------------------------------------------------------------------------- lattice / grid nodes
def _lattice_range(r1: float, r2: float, mu: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Float index bounds (i0, i1) per axis of the lattice: the multiples of step in the sector's box."""
    # Extreme points of the sector around the backward axis (angle pi in the target frame): the four
    # corners plus the arcs' crossings of the coordinate axes that fall inside the angular range.
    ang = [math.pi - mu / 2.0, math.pi + mu / 2.0]
    ang += [k * math.pi / 2.0 for k in range(5) if abs(k * math.pi / 2.0 - math.pi) <= mu / 2.0]
    ang = np.array(ang)
    pts = np.concatenate([r * np.column_stack([np.cos(ang), np.sin(ang)]) for r in (r1, r2)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    # Multiples of step, anchored at the target so the lattice is symmetric about the backward axis.
    return np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9)


def lattice_size(r1: float, r2: float, mu: float, step: float) -> float:
    """Number of nodes :func:`lattice_offsets` would hold, computed without building it (a float, so
    absurd inputs give a large number instead of an integer overflow)."""
    i0, i1 = _lattice_range(float(r1), float(r2), float(mu), float(step))
    return float(np.prod(np.maximum(i1 - i0 + 1.0, 0.0)))


def _lattice_uncached(r1: float, r2: float, mu: float, step: float) -> np.ndarray:
    i0, i1 = (a.astype(int) for a in _lattice_range(r1, r2, mu, step))
    xs = step * np.arange(i0[0], i1[0] + 1)
    ys = step * np.arange(i0[1], i1[1] + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    out = np.column_stack([gx.ravel(), gy.ravel()])
    out.setflags(write=False)
    return out


_lattice = lru_cache(maxsize=64)(_lattice_uncached)


def lattice_offsets(r1: float, r2: float, mu: float, step: float) -> np.ndarray:
    """(L, 2) the fixed waypoint lattice in the target's frame (x forward along phi, y to the left).

    All multiples of ``step`` in both coordinates inside the bounding box of the uneroded sector
    (eq. 4) -- the zone lies around the backward direction, so x <= 0 mostly. Ordered by x, then y,
    ascending. Independent of q and phi, so the same index is the same move at every slot; use
    :func:`zone_mask` for membership. The returned array is shared and read-only.
    """
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    size = lattice_size(r1, r2, mu, step)
    if not size <= MAX_LATTICE:     # also catches NaN radii
        raise ValueError(f"the lattice for r1={r1:g}, r2={r2:g}, mu={mu:g}, step={step:g} would have {size:.4g} "
                         f"nodes, more than {MAX_LATTICE}; use a larger step or a smaller r2")
    return _lattice(float(r1), float(r2), float(mu), float(step))


def lattice_offsets_cfg(config) -> np.ndarray:
    """:func:`lattice_offsets` with ``config``'s r1, r2, mu and grid_step."""
    return lattice_offsets(config.r1, config.r2, config.mu, config.grid_step)


#: How far (m) inside the uneroded zone a lattice node must lie: a node on its boundary (possible with r_u = 0) could
#: be rounded out of the zone when it is rotated to world coordinates, where the zone cost is decided.
ZONE_MARGIN = 1e-6


def zone_mask(offsets, r1: float, r2: float, mu: float, r_u: float = 0.0) -> np.ndarray:
    """(L,) which target-frame offsets lie in the (eroded) zone, and at least :data:`ZONE_MARGIN` inside the
    uneroded one (which only matters for r_u < ZONE_MARGIN).

    Decided in the target frame (q = 0, phi = 0), so the mask does not depend on q or phi -- not even
    through rounding of the rotation.
    """
    inside = in_feasible_zone(offsets, (0.0, 0.0), 0.0, r1, r2, mu, r_u)
    return inside & (zone_distance(offsets, (0.0, 0.0), 0.0, r1, r2, mu) <= -ZONE_MARGIN)


def to_target_frame(d, cs, sn) -> np.ndarray:
    """World displacements ``d`` (..., 2) from a target of heading phi in its frame, ``R(-phi) d`` (..., 2), with
    ``cs``, ``sn`` = cos, sin(phi) given, broadcast against ``d[..., 0]``: x forward, y to the left."""
    return np.stack([cs * d[..., 0] + sn * d[..., 1], cs * d[..., 1] - sn * d[..., 0]], axis=-1)


def to_world(offsets, q_xy, phi) -> np.ndarray:
    """World positions of target-frame offsets: ``q + R(phi) offset``, batch-first.

    The one target-frame-to-world transform of the library: the lattice's nodes and the maps' cells at every slot
    of every scene, the waypoints the UAVs fly to, the reach table's exact goals.

    Args:
        offsets: (..., L, 2) target-frame offsets: L per target, e.g. one lattice (L, 2) shared by every target,
            or (B, L, 2) a set per copy.
        q_xy: (..., 2) target position(s); phi: (...) heading(s); their leading axes broadcast with the
            offsets' (those before L).

    Returns:
        (..., L, 2); (L, 2) for one target.
    """
    off = np.asarray(offsets, dtype=float)
    q = np.asarray(q_xy, dtype=float)
    ph = np.asarray(phi, dtype=float)
    c, s = np.cos(ph)[..., None], np.sin(ph)[..., None]
    x = q[..., 0, None] + c * off[..., 0] - s * off[..., 1]
    y = q[..., 1, None] + s * off[..., 0] + c * off[..., 1]
    return np.stack([x, y], axis=-1)


def grid_nodes(q_xy, phi: float, step: float, r1: float, r2: float, mu: float,
               r_u: float = 0.0) -> np.ndarray:
    """(K, 2) world positions of the lattice points inside the (eroded) zone: the DP planner's nodes.

    ``to_world(lattice_offsets(...)[zone_mask(...)], q_xy, phi)``, in lattice order.
    """
    off = lattice_offsets(r1, r2, mu, step)
    return to_world(off[zone_mask(off, r1, r2, mu, r_u)], q_xy, phi)


def zone_lattice(config) -> np.ndarray:
    """(L, 2) target-frame offsets of the lattice nodes inside the eroded zone (eq. 5).

    THE node set shared by the DP planner (its states at every stage) and the waypoint environments
    (their discrete actions): node j at slot k is ``to_world(zone_lattice(c)[j], q[k], phi[k])``.
    """
    off = lattice_offsets_cfg(config)
    return off[zone_mask(off, config.r1, config.r2, config.mu, config.r_u)]


# ----------------------------------------------------------------------------- start placement
def spread_picks(points, order, valid, min_dist: float, k: int) -> np.ndarray:
    """Greedy picks of up to ``k`` points pairwise at least ``min_dist`` apart (eq. 2), for B candidate lists at once.

    In each list the first candidate of ``order`` not closer than ``min_dist`` to an earlier pick is taken, k times:
    the same picks as testing each candidate in turn against all earlier picks, vectorised over candidates and
    lists (the start picker of every copy of a vector env at once; :func:`spread_nodes` is one list).

    Args:
        points: (B, n, 2) positions; order: (B, m) indices into each list's points, scanned in this order;
        valid: (B, m) bool, the entries of ``order`` to scan (a list may be shorter than m).

    Returns:
        (B, k) indices into ``points``, in pick order; -1 where a list has fewer than k picks.
    """
    order = np.asarray(order, dtype=np.intp)
    rows = np.arange(len(order))
    cand = np.asarray(points, dtype=float)[rows[:, None], order]                  # (B, m, 2)
    picked = np.full((len(order), k), -1, dtype=np.intp)
    alive = np.array(valid, dtype=bool)
    for j in range(k if order.shape[1] else 0):
        first = alive.argmax(axis=1)
        has = alive[rows, first]
        if not has.any():
            break
        picked[has, j] = order[has, first[has]]
        alive[rows, first] = False                    # taken (also where min_dist is 0)
        # Eq. 2 between each list's pick and its candidates: np.hypot(*(p - o)) per pair.
        alive &= separation(cand[:, :, None], cand[rows, first][:, None, None]) >= min_dist
    return picked


def spread_nodes(points, order, min_dist: float, k: int) -> np.ndarray:
    """Greedy pick of up to ``k`` points pairwise at least ``min_dist`` apart, scanning ``order``: one list of
    :func:`spread_picks`.

    Args:
        points: (n, 2) positions; order: (m,) indices into them, scanned in this order.

    Returns:
        (<= k,) indices into ``points``, in pick order.
    """
    order = np.asarray(order, dtype=np.intp)
    picked = spread_picks(np.asarray(points, dtype=float)[None], order[None], np.ones((1, len(order)), bool),
                          min_dist, k)[0]
    return picked[picked >= 0].astype(int)


#: Relative margin on the separation in target-frame placement: rotating the offsets into the world
#: moves distances by ~1e-13, which must not bring two starts below d_safe1.
SPREAD_MARGIN = 1e-9


@lru_cache(maxsize=256)
def zone_capacity(r1: float, r2: float, mu: float, step: float, r_u: float, min_dist: float,
                  k: int) -> tuple[int, int]:
    """(L, n): the number L of lattice nodes in the eroded zone (:func:`zone_lattice`) and how many of up
    to ``k`` of them :func:`spread_nodes` places in lattice order at least ``min_dist (1 + SPREAD_MARGIN)``
    apart. A function of numbers only (cached), so checking a config holds nothing alive."""
    off = _lattice_uncached(float(r1), float(r2), float(mu), float(step))
    off = off[zone_mask(off, r1, r2, mu, r_u)]
    n = len(spread_nodes(off, np.arange(len(off)), min_dist * (1.0 + SPREAD_MARGIN), k))
    return len(off), n
