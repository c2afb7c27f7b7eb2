"""Terrain shadows (paper §2.2, eqs. 8-9): where on the UAV plane a polytope blocks the line of sight.

A UAV at ``p = (x, y, h)`` sees the target at ``q = (x_q, y_q, z_q)`` unless the segment between them
meets the interior of some terrain polytope C_m (eq. 6). Seen from the target, each polytope casts on
the UAV plane z = h a *shadow* S_m: the set of UAV positions whose line of sight it blocks (eqs. 8-9).
The feasible zone minus the union of the shadows is the visible zone (eq. 10, :mod:`covert_env.geometry.zone`). The
environments and the planner decide visibility with the line of sight itself (:mod:`covert_env.world.visibility`); the
shadows are the pictures (:mod:`covert_env.render`) and the tested equivalence (a point is blocked iff it lies in a
shadow).

Why the shadow is a central projection
--------------------------------------
A point ``p`` of the plane z = h is blocked by C_m iff some ``x = q + t (p - q)``, 0 < t < 1, lies in the
interior of C_m. Such an ``x`` has height ``z_q < z_x < h`` (assuming the target is outside C_m and the
UAV plane above the target), and ``p`` is recovered from ``x`` by the central projection from q onto
z = h (eq. 9)::

    pi(x) = q + (h - z_q) / (z_x - z_q) * (x - q).

So the blocked set is exactly ``pi(C_m ∩ {z_q < z <= h})`` (up to its boundary, where the segment only
touches C_m and the line of sight counts as clear). A central projection maps segments in the half-space
z > z_q to segments, hence convex sets to convex sets, and the image of the convex polytope
``C_m ∩ {a <= z <= b}`` (a > z_q) is the convex hull of the images of its vertices: the paper's "convex
hull of the projected points" (eq. 9) is exact once the polytope is clipped to a slab above the target.

Truncation height h_min
-----------------------
Points just above the target's height project arbitrarily far away, so the paper keeps only points
above a height h_min (eq. 9). A point of C_m at height z and horizontal distance rho from q projects at
horizontal distance ``rho (h - z_q) / (z - z_q)``; every point of C_m is at least ``rho_min`` (the
distance from q to the footprint) away. Hence every point below ``h_min_m = z_q + (h - z_q) rho_min / R``
projects farther than R from the target, and the shadow of ``C_m ∩ {h_min_m <= z <= h}`` equals the
exact shadow within radius R. ``h_min=None`` (the default) uses that per-polytope height, so shadows
are exact where it matters; a number uses one fixed height for all polytopes, as the paper does, which
gives a subset of the exact shadow (possibly missing blocked points near the target).
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from covert_env.geometry.zone import ARC_RESOLUTION, feasible_zone_cfg, visible_zone
from covert_env.world.terrain import Terrain
from covert_env.world.visibility import terrain_arrays

__all__ = ["shadow_h_min", "shadow_polygons", "shadow_union", "shadow_union_cfg", "visible_zone_cfg"]


def _plan_distance(plan: np.ndarray, q_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal distance from ``q_xy`` to each plan-view polygon, and whether q lies inside (closed).

    Returns (M,) distances (0 inside) and (M,) booleans.
    """
    a = plan
    b = np.roll(plan, -1, axis=1)
    ab = b - a
    aq = q_xy - a
    ab2 = np.einsum("mvk,mvk->mv", ab, ab)
    t = np.clip(np.einsum("mvk,mvk->mv", aq, ab) / np.where(ab2 > 0, ab2, 1.0), 0.0, 1.0)
    d = np.linalg.norm(aq - t[..., None] * ab, axis=2).min(axis=1)
    cross = ab[..., 0] * aq[..., 1] - ab[..., 1] * aq[..., 0]   # >= 0 on the left of a CCW edge
    inside = np.all(cross >= 0.0, axis=1)
    return np.where(inside, 0.0, d), inside




def shadow_h_min(terrain: Terrain, target_xyz, altitude: float, radius: float) -> np.ndarray:
    """(M,) automatic truncation heights ``h_min_m = z_q + (h - z_q) rho_min_m / R`` (module docstring).

    Below h_min_m every point of C_m projects farther than ``radius`` from the target, so the shadow of
    ``C_m ∩ {h_min_m <= z <= h}`` is exact within ``radius``. Clamped just above z_q.
    """
    q = np.asarray(target_xyz, dtype=float)
    rho_min, _ = _plan_distance(terrain_arrays(terrain).plan, q[:2])
    hz = altitude - q[2]
    return np.maximum(q[2] + hz * rho_min / radius, q[2] + 1e-6 * hz)


def shadow_polygons(terrain: Terrain, target_xyz, altitude: float, radius: float,
                    h_min: float | None = None) -> list[Polygon]:
    """The shadow S_m of every polytope on the UAV plane z = ``altitude``, eqs. 8-9.

    Each polytope is clipped to the slab ``h_min_m <= z <= altitude`` and the vertices of the clipped
    polytope are projected from the target onto z = h (eq. 9, ``psi = q + (h - z_q)/(z - z_q) (v - q)``);
    the shadow is their convex hull. The clipped polytope's vertices are found exactly: the original
    vertices inside the slab plus the crossings of every vertex-vertex segment with the two slab planes
    (a superset of the edge crossings; all lie in C_m, so the hull is unchanged).

    Args:
        terrain: the polytopes.
        target_xyz: (3,) target position q.
        altitude: UAV plane height h (> z_q).
        radius: horizontal radius R about the target inside which the shadows must be exact when
            ``h_min`` is None (use at least R2, e.g. ``r2 + shadow_margin``).
        h_min: None for the per-polytope exact truncation (:func:`shadow_h_min`); a number for the
            paper's single fixed truncation height (shadows are then subsets of the exact ones;
            a value at or below z_q is raised to just above it, where the projection exists).

    Returns:
        One polygon per polytope, in terrain order; an empty Polygon when C_m casts no shadow within
        ``radius`` (auto h_min) or nothing above ``h_min``.

    Raises:
        ValueError: if the target is inside (or under) a polytope's footprint that is taller than the
            target, where the line of sight is blocked everywhere and no projection exists. Roads keep a
            clearance from footprints, so this signals a broken scene.
    """
    q = np.asarray(target_xyz, dtype=float).reshape(3)
    h = float(altitude)
    if not h > q[2]:
        raise ValueError(f"altitude ({h:g}) must be above the target height z_q ({q[2]:g})")
    m = len(terrain)
    if m == 0:
        return []
    arr = terrain_arrays(terrain)
    rho_min, inside = _plan_distance(arr.plan, q[:2])
    under = (inside | (rho_min < 1e-9)) & (arr.z_max > q[2])
    if np.any(under):
        raise ValueError(f"target {q.tolist()} lies inside/under the footprint of polytope(s) "
                         f"{np.flatnonzero(under).tolist()}: line of sight is blocked everywhere")
    if h_min is None:
        lo = shadow_h_min(terrain, q, h, radius)
    else:
        lo = np.full(m, max(float(h_min), q[2] + 1e-6 * (h - q[2])))
    hi = np.full(m, h)

    v = arr.verts                                          # (M, W, 3)
    z = v[..., 2]
    pts = [v]
    ok = [(z >= lo[:, None]) & (z <= hi[:, None])]
    vi, vj = v[:, arr.pair_i], v[:, arr.pair_j]            # (M, P, 3)
    zi, zj = vi[..., 2], vj[..., 2]
    for c in (lo, hi):
        c = c[:, None]
        cross = (zi - c) * (zj - c) < 0
        with np.errstate(divide="ignore", invalid="ignore"):   # level pairs: masked out by `cross`
            w = (c - zi) / (zj - zi)
            x = vi + w[..., None] * (vj - vi)
        x[..., 2] = c                                      # on the plane exactly, not up to rounding
        pts.append(x)
        ok.append(cross)
    pts = np.concatenate(pts, axis=1)
    ok = np.concatenate(ok, axis=1)
    idx, _ = np.nonzero(ok)
    p = pts[ok]
    scale = (h - q[2]) / (p[:, 2] - q[2])
    psi = q[:2] + scale[:, None] * (p[:, :2] - q[:2])
    out = [Polygon() for _ in range(m)]
    if len(idx) == 0:
        return out
    present = np.unique(idx)
    remap = np.searchsorted(present, idx)
    hulls = shapely.convex_hull(shapely.multipoints(psi, indices=remap))
    for i, g in zip(present, hulls, strict=True):
        if shapely.get_type_id(g) == 3 and g.area > 0:     # 3 = Polygon; points/lines block nothing
            out[i] = g
    return out


def shadow_union(terrain: Terrain, target_xyz, altitude: float, radius: float, h_min: float | None = None):
    """The union of all shadows (:func:`shadow_polygons`) as one Polygon or MultiPolygon."""
    polys = [p for p in shadow_polygons(terrain, target_xyz, altitude, radius, h_min) if not p.is_empty]
    if not polys:
        return Polygon()
    return shapely.union_all(polys)


def shadow_union_cfg(terrain: Terrain, target_xyz, config):
    """:func:`shadow_union` with the config's altitude, ``h_min`` and radius ``r2 + shadow_margin``."""
    return shadow_union(terrain, target_xyz, config.altitude, config.r2 + config.shadow_margin, config.h_min)


def visible_zone_cfg(terrain, target_xyz, phi: float, config, *, uncertain: bool = True,
                     arc_resolution: float = ARC_RESOLUTION) -> BaseGeometry:
    """Eq. 10 in one call: the eroded zone minus the shadows, with ``config``'s parameters.

    Shadows use ``config.altitude``, ``config.h_min`` and radius ``r2 + shadow_margin``.
    """
    q = np.asarray(target_xyz, dtype=float)
    zone = feasible_zone_cfg(q[:2], phi, config, uncertain=uncertain, arc_resolution=arc_resolution)
    return visible_zone(zone, shadow_union_cfg(terrain, q, config))
