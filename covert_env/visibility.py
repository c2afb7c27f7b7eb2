"""Line of sight and terrain shadows (paper §2.2, eqs. 6, 8-9).

A UAV at ``p = (x, y, h)`` sees the target at ``q = (x_q, y_q, z_q)`` unless the segment between them
meets the interior of some terrain polytope C_m (eq. 6). Seen from the target, each polytope casts on
the UAV plane z = h a *shadow* S_m: the set of UAV positions whose line of sight it blocks (eqs. 8-9).
The feasible zone minus the union of the shadows is the visible zone (eq. 10, :mod:`covert_env.zone`).

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

import math
import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from covert_env.angles import wrap_angle
from covert_env.terrain import Terrain
from covert_env.zone import ARC_RESOLUTION, feasible_zone_cfg, to_world, visible_zone

__all__ = [
    "LOS_TOLERANCE",
    "TerrainArrays",
    "TerrainRows",
    "grown",
    "clip_segments",
    "face_offsets",
    "face_values",
    "growth_factors",
    "line_of_sight",
    "line_of_sight_rows",
    "visible_nodes",
    "visible_nodes_rows",
    "visible_zone_cfg",
    "passes_near",
    "shadow_h_min",
    "shadow_polygons",
    "shadow_union",
    "shadow_union_cfg",
    "terrain_arrays",
]

LOS_TOLERANCE = 1e-8
"""Depth (m) a segment must reach inside a polytope to count as blocked.

The segment is clipped against the polytope shrunk by this distance (every face plane moved inwards),
so a segment that only touches a face, an edge or a vertex -- or passes within rounding error of
one -- is *clear*. 10 nm is far above float64 rounding of plane values for scenes of a few km and far
below any physical size."""

SAFE_LOS_TOLERANCE = -1e-6
"""Tolerance (m) of a line of sight promised ahead: the visible lattice nodes (:func:`visible_nodes`, the planner's
states and the waypoint action mask) and the planner's path checks. Negative: the polytopes are *grown* by 1 µm, so
a position called visible stays visible when the engine flies to it and rounds it (scored at
:data:`LOS_TOLERANCE`)."""


def _growth(arr: TerrainArrays, tol: float):
    """How far (m) each of the clip's polytopes reaches beyond the real one: 0 for ``tol >= 0``, else (M,) ``-tol``
    times :attr:`TerrainArrays.growth_factor`. Every broad phase widens its footprint circles, tops and wedges by it,
    so it never drops a pair the clip blocks."""
    return 0.0 if tol >= 0 else -float(tol) * arr.growth_factor

_BRUTE_PAIRS = 480  # (points x polytopes) up to which every pair is clipped without a broad phase
_CHUNK = 8192  # points per block: bounds the (K, M) and (pairs, F, 4) temporaries to a few MB


# ----------------------------------------------------------------------------- per-terrain cache
@dataclass(frozen=True)
class TerrainArrays:  # noqa: B903
    """Padded arrays derived once per terrain (cached by identity, see :func:`terrain_arrays`)."""

    hs: np.ndarray        # (M, F, 4) half-spaces, padded with the always-true row 0.x - 1 <= 0
    z_max: np.ndarray     # (M,)
    plan: np.ndarray      # (M, V, 2) plan-view hull (CCW), padded by repeating its last vertex
    centre: np.ndarray    # (M, 2) centre of the plan-view enclosing circle
    radius: np.ndarray    # (M,) radius of that circle
    verts: np.ndarray     # (M, W, 3) vertices, padded by repeating the last vertex
    pair_i: np.ndarray    # (P,) index pairs i < j over W: every vertex-vertex segment
    pair_j: np.ndarray

    @cached_property
    def _offsets(self) -> dict:
        return {}

    def offsets_at(self, z: float, tol: float) -> np.ndarray:
        """(F, M) :func:`face_offsets` at one height z, kept for the last few (z, tol) (the UAV plane)."""
        key = (float(z), float(tol))
        off = self._offsets.get(key)
        if off is None:
            if len(self._offsets) >= 8:
                self._offsets.clear()
            off = self._offsets[key] = face_offsets(self.faces[2], self.faces[3], key[0], key[1])
        return off

    @cached_property
    def growth_factor(self) -> np.ndarray:
        """(M,) ``R / r``: moving every face plane of a polytope out by g keeps it within ``g R / r`` of the polytope
        (the faces of ``{n.x + d <= g}`` meet beyond g at sharp edges, not on a sphere). With c the mean of the
        (padded) vertex list, a point inside the hull, r the radius of the ball about c inside the polytope
        (``min_f -(n_f.c + d_f)`` over the real faces, unit normals) and R the farthest vertex from c, the grown
        polytope lies inside the polytope scaled by ``1 + g / r`` about c."""
        return growth_factors(self.hs, self.verts)

    @cached_property
    def faces(self) -> np.ndarray:
        """(4, F, M) the half-spaces' columns n_x, n_y, n_z, d, faces first (for :func:`face_values` and
        :func:`clip_segments`, which reduces over the faces along the first axis)."""
        return np.ascontiguousarray(self.hs.transpose(2, 1, 0))



def growth_factors(hs: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """(..., M) :attr:`TerrainArrays.growth_factor` of polytopes with half-spaces ``hs`` (..., M, F, 4) and padded
    vertices ``verts`` (..., M, W, 3) (the batched generator's many scenes at once)."""
    c = verts.mean(axis=-2)                             # padding repeats a vertex: still inside the hull
    depth = -((hs[..., :3] * c[..., None, :]).sum(-1) + hs[..., 3])
    real = np.any(hs[..., :3] != 0.0, axis=-1)          # not the always-true padding rows
    r = np.where(real, depth, np.inf).min(axis=-1)
    big_r = np.sqrt(((verts - c[..., None, :]) ** 2).sum(-1)).max(axis=-1)
    return big_r / np.maximum(r, 1e-12)

_CACHE: weakref.WeakKeyDictionary[Terrain, TerrainArrays] = weakref.WeakKeyDictionary()


def terrain_arrays(terrain: Terrain) -> TerrainArrays:
    """The terrain's padded arrays (:class:`TerrainArrays`), built once per terrain object."""
    arr = _CACHE.get(terrain)
    if arr is None:
        arr = _build_arrays(terrain)
        _CACHE[terrain] = arr
    return arr


def register_terrain_arrays(terrain: Terrain, arrays: TerrainArrays) -> None:
    """Give :func:`terrain_arrays` the arrays of ``terrain`` built elsewhere (the batched generator builds them for
    many scenes at once); they must describe the same polytopes."""
    _CACHE[terrain] = arrays


def _build_arrays(terrain: Terrain) -> TerrainArrays:
    m = len(terrain)
    if m == 0:
        e2, e3 = np.zeros((0, 1, 2)), np.zeros((0, 1, 3))
        return TerrainArrays(np.zeros((0, 1, 4)), np.zeros(0), e2, np.zeros((0, 2)), np.zeros(0), e3,
                             np.zeros(0, int), np.zeros(0, int))
    plans = [p.plan_view for p in terrain]
    v = max(len(a) for a in plans)
    plan = np.stack([np.vstack([a, np.repeat(a[-1:], v - len(a), axis=0)]) for a in plans])
    centre = np.array([a.mean(axis=0) for a in plans])
    radius = np.linalg.norm(plan - centre[:, None, :], axis=2).max(axis=1)
    w = max(p.vertices.shape[0] for p in terrain)
    verts = np.stack([np.vstack([p.vertices, np.repeat(p.vertices[-1:], w - len(p.vertices), axis=0)])
                      for p in terrain])
    pi_, pj_ = np.triu_indices(w, k=1)
    return TerrainArrays(np.asarray(terrain.halfspace_array, float), np.asarray(terrain.z_max, float),
                         plan, centre, radius, verts, pi_, pj_)


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


# ----------------------------------------------------------------------------- the exact clip (eq. 6)
def face_offsets(n_z, d, z, tol: float = LOS_TOLERANCE):
    """``n_z z + (d + tol)``: the part of a face value that depends on the height only (all broadcast).

    With one height per call (the UAV plane, the target) it is computed once per face; see
    :func:`face_values`."""
    off = n_z * z
    off += d + tol
    return off


def face_values(n_x, n_y, offsets, x, y):
    """Face values ``n . p + d + tol`` of points ``p = (x, y, z)``: ``(n_x x + n_y y) + offsets`` with
    ``offsets = face_offsets(n_z, d, z, tol)`` (all broadcast).

    The one formula of every line-of-sight path (eq. 6): a point lies in the polytope shrunk by ``tol``
    iff all its face values are <= 0. Written out in this order, not as a matrix product, so that a
    value does not depend on the layout of the batch (a BLAS product may sum in another order, with
    another rounding): every path, and every env that batches copies differently, decides a segment
    that grazes a face alike. (Computed in place: ``n_y * y`` and ``offsets`` must broadcast to the shape of
    ``n_x * x``.)"""
    val = n_x * x
    val += n_y * y
    val += offsets
    return val


def clip_segments(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Cyrus-Beck clipping (eq. 6): whether the segment meets the shrunk polytope, from the face values
    ``start``, ``end`` (F, ...) at its two ends (:func:`face_values`), faces along the first axis; returns (...)
    bool, True = blocked.

    Along the segment ``x(s) = u + s (t - u)`` each face value is ``start + s (end - start)``, linear in s,
    so the part inside the polytope is ``[max of entering bounds, min of leaving bounds] ∩ [0, 1]``; the
    segment is blocked iff that interval is non-empty. The one clipping routine behind every LoS path. (Faces
    first: a reduction over a short last axis costs numpy about 15 times more than one over the first.)"""
    den = end - start
    s = np.negative(start)
    with np.errstate(divide="ignore", invalid="ignore"):
        s /= den                                        # the crossing of each face plane
    entering = den < 0
    # den == 0 lands on the leaving side: s = -inf (start > 0: empty), +inf (start < 0: no bound) or NaN
    # (segment exactly on the shrunk plane: no bound, ignored by fmin).
    s_in = np.maximum.reduce(s, axis=0, where=entering, initial=0.0)
    np.copyto(s, 1.0, where=entering)
    s_out = np.minimum(np.fmin.reduce(s, axis=0), 1.0)
    return s_in <= s_out


def passes_near(ux, uy, ex, ey, s0, s1, cx, cy, radius) -> np.ndarray:
    """Whether the 2-D part ``s in [s0, s1]`` of the segment ``u + s e`` comes within ``radius`` (+1 nm) of the
    centre (the broad phases' footprint-circle test; components written out, all arguments broadcast)."""
    acx = cx - (ux + s0 * ex)
    acy = cy - (uy + s0 * ey)
    abx, aby = (s1 - s0) * ex, (s1 - s0) * ey
    ab2 = abx * abx + aby * aby
    w = np.clip((acx * abx + acy * aby) / np.where(ab2 > 0, ab2, 1.0), 0.0, 1.0)
    dx, dy = acx - w * abx, acy - w * aby
    return dx * dx + dy * dy <= (radius + 1e-9) ** 2


def _low_part(z_max, uz, dz):
    """Parameter range [s0, s1] along u -> t (s = 0 at the UAV) where the segment is lower than ``z_max``:
    s >= sc going down, s <= sc going up (dz = t_z - u_z). A level segment (dz = 0) is nudged to a tiny
    slope, which keeps the whole segment (or none of it: a degenerate end range, harmless in a broad phase)."""
    down = dz <= 0
    with np.errstate(over="ignore", divide="ignore"):
        sc = (z_max - uz) / np.where(dz == 0, -1e-300, dz)
    return np.clip(np.where(down, sc, 0.0), 0.0, 1.0), np.clip(np.where(down, 1.0, sc), 0.0, 1.0)


# ----------------------------------------------------------------------------- line of sight
def line_of_sight(terrain: Terrain, uav_xy, altitude, target_xyz, *,
                  tol: float = LOS_TOLERANCE) -> np.ndarray:
    """Whether each UAV position sees the target (True = clear line of sight), eq. 6, exactly.

    The segment from the UAV ``(x, y, altitude)`` to the target ``(x_q, y_q, z_q)`` is blocked iff it
    meets the interior of some polytope C_m. Each polytope is ``{x : n_f . x + d_f <= 0}``; along the
    segment each face value is linear, so the segment's part inside C_m is an interval (Cyrus-Beck
    clipping in 3D, :func:`clip_segments`). Blocked iff that interval is non-empty for the polytope
    shrunk by ``tol`` metres (:data:`LOS_TOLERANCE`): touching a face, an edge or a vertex is clear.

    A cheap broad phase keeps only (point, polytope) pairs that can intersect, so the exact clip runs on
    few pairs: with one target and one altitude, the point's bearing from the target must lie in the
    polytope's angular interval and the part of the segment lower than the polytope's top must reach
    its footprint; otherwise the 2-D part of the segment lower than the top must pass within the
    footprint's enclosing circle. Every path clips with the same face values (:func:`face_values`), so the
    broad phase never changes a result.

    Args:
        terrain: the polytopes.
        uav_xy: (..., 2) UAV horizontal positions.
        altitude: UAV height h (scalar, or an array broadcastable with ``uav_xy[..., 0]``).
        target_xyz: (3,) one target, or (..., 3) broadcastable with the points (e.g. one per point).
        tol: shrink distance (m) of the polytopes, see :data:`LOS_TOLERANCE`.

    Returns:
        bool array of shape ``uav_xy.shape[:-1]`` (broadcast with the target's leading shape).
    """
    uav_xy = np.asarray(uav_xy, dtype=float)
    target = np.asarray(target_xyz, dtype=float)
    alt = np.asarray(altitude, dtype=float)
    if uav_xy.shape[-1:] != (2,) or target.shape[-1:] != (3,):
        raise ValueError(f"uav_xy must be (..., 2) and target_xyz (..., 3); "
                         f"got {uav_xy.shape}, {target.shape}")
    one_target = target.size == 3 and target.ndim <= uav_xy.ndim and alt.ndim == 0
    if one_target:                      # the common case, without broadcast_shapes' cost on tiny inputs
        shape = uav_xy.shape[:-1]
    else:
        shape = np.broadcast_shapes(uav_xy.shape[:-1], target.shape[:-1], alt.shape)
    if len(terrain) == 0:
        return np.ones(shape, dtype=bool)
    arr = terrain_arrays(terrain)
    if math.prod(shape) * len(terrain) <= _BRUTE_PAIRS:
        # Few points (an env step): the broad phase's fixed cost exceeds clipping every pair.
        if one_target:
            return _los_brute(arr, uav_xy.reshape(-1, 2), alt, target.reshape(1, 3), tol).reshape(shape)
        t = np.empty(shape + (3,))
        t[...] = target
        xy = np.broadcast_to(uav_xy, shape + (2,)).reshape(-1, 2)
        return _los_brute(arr, xy, np.broadcast_to(alt, shape).reshape(-1, 1), t.reshape(-1, 3), tol).reshape(shape)
    if target.ndim == 1 and alt.ndim == 0 and float(alt) > target[2]:
        pts = np.broadcast_to(uav_xy, shape + (2,)).reshape(-1, 2)
        out = np.ones(len(pts), dtype=bool)
        for s in range(0, len(pts), _CHUNK):
            out[s:s + _CHUNK] = _los_single(arr, pts[s:s + _CHUNK], float(alt), target, tol)
        return out.reshape(shape)
    u = np.concatenate([np.broadcast_to(uav_xy, shape + (2,)), np.broadcast_to(alt, shape)[..., None]],
                       axis=-1).reshape(-1, 3)
    t = np.broadcast_to(target, shape + (3,)).reshape(-1, 3)
    out = np.ones(len(u), dtype=bool)
    for s in range(0, len(u), _CHUNK):
        out[s:s + _CHUNK] = _los_general(arr, u[s:s + _CHUNK], t[s:s + _CHUNK], tol)
    return out.reshape(shape)


def line_of_sight_rows(terrain: Terrain, uav_xy, altitude: float, target_xyz, *,
                       tol: float = LOS_TOLERANCE) -> np.ndarray:
    """:func:`line_of_sight` for S rows of C points, row s against its own target ``target_xyz[s]``.

    The environments' observation maps (C cells at each of S slots) use it: a per-row broad phase keeps
    only the polytopes whose plan-view circle comes within reach of the row's points (a segment from a
    point to the target stays within ``max |p - q|`` of the target), then every kept (point, polytope)
    pair is clipped exactly, as in :func:`line_of_sight`. Along a road a slot's points are near a few of
    the scene's polytopes, which makes this several times cheaper than the general per-pair broad phase.

    Args:
        uav_xy: (S, C, 2) points; altitude: the UAV height (scalar); target_xyz: (S, 3).

    Returns:
        (S, C) bool, True = clear.
    """
    xy = np.asarray(uav_xy, dtype=float)
    q = np.asarray(target_xyz, dtype=float)
    altitude = float(altitude)
    if xy.ndim != 3 or xy.shape[-1] != 2 or q.shape != (len(xy), 3):
        raise ValueError(f"line_of_sight_rows: uav_xy must be (S, C, 2) and target_xyz (S, 3); "
                         f"got {xy.shape}, {q.shape}")
    n_rows, n_pts = xy.shape[:2]
    out = np.ones((n_rows, n_pts), dtype=bool)
    if len(terrain) == 0 or out.size == 0:
        return out
    arr = terrain_arrays(terrain)
    grow = _growth(arr, tol)
    rel = xy - q[:, None, :2]
    reach = np.sqrt((rel ** 2).sum(axis=-1).max(axis=1))                         # (S,)
    gap = np.hypot(arr.centre[:, 0] - q[:, 0, None], arr.centre[:, 1] - q[:, 1, None])   # (S, M)
    rows, m_idx = np.nonzero(gap <= reach[:, None] + arr.radius + grow + 1e-9)
    if len(rows) == 0:
        return out
    k = (rows[:, None] * n_pts + np.arange(n_pts)).reshape(-1)                  # every point of the row
    m = np.repeat(m_idx, n_pts)
    # Then _los_general's test on the kept pairs: the part of the segment lower than the polytope's top
    # must pass within its plan-view circle (here the target is below the UAV: the low part ends at q).
    p = xy.reshape(-1, 2)[k]
    qk = q[rows].repeat(n_pts, axis=0)
    if altitude > q[:, 2].max():
        grow_m = grow if np.ndim(grow) == 0 else grow[m]
        s0 = np.clip((arr.z_max[m] + grow_m - altitude) / (qk[:, 2] - altitude), 0.0, 1.0)   # UAV -> q, going down
        near = passes_near(p[:, 0], p[:, 1], qk[:, 0] - p[:, 0], qk[:, 1] - p[:, 1], s0, 1.0,
                           arr.centre[m, 0], arr.centre[m, 1], arr.radius[m] + grow_m)
        k, m, p, qk = k[near], m[near], p[near], qk[near]
    nx, ny, nz, d = arr.faces[..., m]                                           # (F, K) each
    start = face_values(nx, ny, face_offsets(nz, d, altitude, tol), p[:, 0], p[:, 1])
    end = face_values(nx, ny, face_offsets(nz, d, qk[:, 2], tol), qk[:, 0], qk[:, 1])
    blocked = clip_segments(start, end)
    flat = out.reshape(-1)
    flat[k[blocked]] = False
    return out


def visible_nodes(terrain: Terrain, offsets, q, phi, altitude: float, *,
                  tol: float = SAFE_LOS_TOLERANCE) -> np.ndarray:
    """The visible feasible zone (eq. 10) on the waypoint lattice: which nodes see the target.

    The one rule behind the planner's states, the waypoint action mask, the observation maps and the start
    sampler. ``offsets`` are target-frame offsets inside the eroded zone (the lattice's nodes,
    :func:`~covert_env.zone.zone_lattice`, or the maps' cells): zone membership is decided once in the target's
    frame, so it does not depend on the rounding of the rotation to the world; visibility is the line of sight
    (eq. 6) at :data:`SAFE_LOS_TOLERANCE`, which equals "outside every shadow" by the tested invariant.

    Args:
        terrain: the polytopes.
        offsets: (L, 2) target-frame offsets of the nodes.
        q: (3,) the target, or (S, 3) one per slot; phi: its heading(s), () or (S,).
        altitude: the UAVs' height h.
        tol: the LoS tolerance (m), see :data:`SAFE_LOS_TOLERANCE`.

    Returns:
        (L,) bool, or (S, L) for S targets; True = clear line of sight.
    """
    q = np.asarray(q, dtype=float)
    xy = to_world(offsets, q[..., :2], phi)
    if q.ndim == 1:
        return line_of_sight(terrain, xy, altitude, q, tol=tol)
    return line_of_sight_rows(terrain, xy, altitude, q, tol=tol)


def _los_brute(arr: TerrainArrays, xy: np.ndarray, alt, t: np.ndarray, tol: float) -> np.ndarray:
    """Every (point, polytope) pair clipped exactly, no broad phase. ``xy`` (K, 2) at heights ``alt`` (a
    scalar or (K, 1)), ``t`` (K, 3) or one target (1, 3) -> (K,) clear."""
    nx, ny, nz, d = arr.faces[:, :, None]                               # (F, 1, M) each
    # Points (K, 1) against every face (F, 1, M): (F, K, M) face values at both ends.
    off = arr.offsets_at(alt, tol)[:, None] if np.ndim(alt) == 0 else face_offsets(nz, d, alt, tol)
    start = face_values(nx, ny, off, xy[:, :1], xy[:, 1:])
    end = face_values(nx, ny, face_offsets(nz, d, t[:, 2:], tol), t[:, :1], t[:, 1:2])
    return ~clip_segments(start, end).any(axis=1)


def _los_single(arr: TerrainArrays, xy: np.ndarray, h: float, q: np.ndarray, tol: float) -> np.ndarray:
    """Fast path: one target, one altitude above it. ``xy`` (K, 2) -> (K,) clear."""
    grow = _growth(arr, tol)
    rho_min, inside = _plan_distance(arr.plan, q[:2])
    # The wedge of directions from q that meet each footprint, bounded by the directions e_lo, e_hi to
    # its extreme vertices. From outside a convex footprint the wedge is narrower than pi, so offsets
    # wrapped about the centre's bearing are unambiguous and "d between e_lo and e_hi" is two cross
    # products (no per-point angles: a float modulo on (K, M) arrays costs more than the exact clip).
    b = np.arctan2(arr.centre[:, 1] - q[1], arr.centre[:, 0] - q[0])
    rel = arr.plan - q[:2]
    vb = np.arctan2(rel[..., 1], rel[..., 0]) - b[:, None]
    vb = wrap_angle(vb)
    rows = np.arange(len(rel))
    e_lo, e_hi = rel[rows, vb.argmin(axis=1)], rel[rows, vb.argmax(axis=1)]
    e_lo = e_lo / np.maximum(np.linalg.norm(e_lo, axis=1, keepdims=True), 1e-300)   # q on a vertex: 0
    e_hi = e_hi / np.maximum(np.linalg.norm(e_hi, axis=1, keepdims=True), 1e-300)
    every = inside | (rho_min < grow + 1e-9)           # q in (or on) the footprint: every direction
    slack = np.where(every, np.inf, 1e-9)              # 1 nm: rounding at the wedge's edges
    # The segment is lower than z_max only within horizontal distance |p - q| * s of the target.
    s = (arr.z_max + grow - q[2]) / (h - q[2])
    dx, dy = xy[:, 0, None] - q[0], xy[:, 1, None] - q[1]
    dist = np.hypot(dx, dy)
    if tol < 0:
        # A point within `grow` of the footprint is seen from q at most asin(grow / rho_min) outside its wedge,
        # so a cross product with the unit edge, |p - q| sin(angle), exceeds the edge by at most this.
        slack = np.where(every, np.inf, slack + dist * (grow / np.maximum(rho_min, 1e-300)))
    cand = ((e_lo[:, 0] * dy - e_lo[:, 1] * dx >= -slack) & (dx * e_hi[:, 1] - dy * e_hi[:, 0] >= -slack)
            & (dist * s > rho_min - grow - 1e-9))
    k, m = np.nonzero(cand)
    if len(k) == 0:
        return np.ones(len(xy), dtype=bool)
    nx, ny, nz, d = arr.faces                                           # (F, M) each
    # The parts of the face values that are the same for every point: the UAV plane's and the target's.
    at_h = arr.offsets_at(h, tol)
    end = face_values(nx, ny, face_offsets(nz, d, q[2], tol), q[0], q[1])
    start = face_values(nx[:, m], ny[:, m], at_h[:, m], xy[k, 0], xy[k, 1])
    blocked = clip_segments(start, end[:, m])
    out = np.ones(len(xy), dtype=bool)
    out[k[blocked]] = False
    return out


def _los_general(arr: TerrainArrays, u: np.ndarray, t: np.ndarray, tol: float) -> np.ndarray:
    """General path: per-point targets and altitudes. ``u``, ``t`` (K, 3) -> (K,) clear."""
    grow = _growth(arr, tol)
    s0, s1 = _low_part(arr.z_max + grow, u[:, 2, None], t[:, 2, None] - u[:, 2, None])
    # Distance from each footprint circle's centre to the 2-D sub-segment [a, b] (components written
    # out: einsum over a length-2 axis is several times slower on (K, M) arrays).
    ex, ey = t[:, 0, None] - u[:, 0, None], t[:, 1, None] - u[:, 1, None]
    cand = (s1 > s0 - 1e-12) & passes_near(u[:, 0, None], u[:, 1, None], ex, ey, s0, s1,
                                           arr.centre[:, 0], arr.centre[:, 1], arr.radius + grow)
    k, m = np.nonzero(cand)
    if len(k) == 0:
        return np.ones(len(u), dtype=bool)
    nx, ny, nz, d = arr.faces[..., m]                                   # (F, K) each
    uk, tk = u[k], t[k]
    start = face_values(nx, ny, face_offsets(nz, d, uk[:, 2], tol), uk[:, 0], uk[:, 1])
    end = face_values(nx, ny, face_offsets(nz, d, tk[:, 2], tol), tk[:, 0], tk[:, 1])
    blocked = clip_segments(start, end)
    out = np.ones(len(u), dtype=bool)
    out[k[blocked]] = False
    return out


class TerrainRows:
    """Terrains as rows of padded arrays (one terrain per row), for line of sight of a batch of copies, copy b
    against the terrain in row ``rows[b]`` (the vector env's scene pool keeps one row per scene).

    Rows are written by :meth:`set_rows` (many at once) or :meth:`set_row`; the arrays grow (geometrically, up to
    ``capacity`` rows) to the largest polytope and face counts seen. Extra faces are the always-true row
    ``0.x - 1 <= 0`` and extra polytopes are empty (a row ``0.x + 1 <= 0``) and marked invalid, so padding never
    blocks.

    Attributes (rows R, polytopes M, faces F):
        faces (4, F, R, M): the columns n_x, n_y, n_z, d of each polytope's half-spaces, faces first.
        cx, cy, radius, z_max (R, M): plan-view enclosing circles and heights; valid (R, M): real polytopes.
        growth (R, M): :func:`growth_factors` (how far a negative tolerance grows each polytope, per metre).
        top (R, M, 3): polytope top points (eq. 3), padded with inf.
    """

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.faces = np.zeros((4, 1, 0, 0))
        self.cx, self.cy, self.radius, self.z_max = (np.zeros((0, 0)) for _ in range(4))
        self.growth = np.zeros((0, 0))
        self.valid = np.zeros((0, 0), bool)
        self.top = np.zeros((0, 0, 3))
        # The line of sight's inputs, packed so that a step gathers each in one call: (4, R, 1, M) the circle's
        # centre x, y, the top z_max (-inf: no polytope) and the radius with slack r' (the broad phase's); and per
        # tol, (4, F, R M) the faces' n_x, n_y, n_z, d + tol (the clip's).
        self._circles = np.zeros((4, 0, 1, 0))
        self._tables: dict = {}

    def __len__(self) -> int:
        return len(self.valid)

    def _clip_table(self, tol: float) -> np.ndarray:
        """(4, F, R M) the columns n_x, n_y, n_z, d + tol (what :func:`face_offsets` adds), kept per tol; a row
        written later is updated in place."""
        table = self._tables.get(tol)
        if table is None:
            if len(self._tables) >= 4:
                self._tables.clear()
            table = self._tables[tol] = self.faces.reshape(4, self.faces.shape[1], -1).copy()
            table[3] += tol
        return table

    def set_row(self, r: int, terrain: Terrain) -> None:
        """Write ``terrain`` into row r (growing the arrays as needed)."""
        arr = terrain_arrays(terrain)
        self.set_rows(np.array([r]), arr.hs[None], arr.centre[None], arr.radius[None], arr.z_max[None],
                      np.asarray(terrain.highest_points, float).reshape(1, -1, 3), arr.growth_factor[None])

    def set_rows(self, rows: np.ndarray, hs: np.ndarray, centre: np.ndarray, radius: np.ndarray, z_max: np.ndarray,
                 top: np.ndarray, growth: np.ndarray) -> None:
        """Write N terrains of M polytopes each into ``rows`` (N,) (growing the arrays as needed): half-spaces ``hs``
        (N, M, F, 4), footprint circles ``centre`` (N, M, 2) and ``radius`` (N, M), heights ``z_max`` (N, M), tops
        ``top`` (N, M, 3) (eq. 3) and :func:`growth_factors` ``growth`` (N, M), as in :class:`TerrainArrays`."""
        rows = np.asarray(rows, dtype=np.intp)
        m, f = hs.shape[1:3]
        n = len(self)
        if rows.max(initial=-1) >= n:                       # grow geometrically: amortised O(1) per row
            n = max(int(rows.max()) + 1, min(2 * n, self.capacity))
        mm, ff = max(m, self.valid.shape[1]), max(f, self.faces.shape[1])
        pad = np.zeros((4, 1, 1))
        pad[3] = -1.0                                       # 0.x - 1 <= 0: always true
        if self.faces.shape != (4, ff, n, mm):
            faces = np.empty((4, ff, n, mm))
            faces[...] = pad[..., None]
            faces[3, 0] = 1.0                               # 0.x + 1 <= 0: no polytope until one is written
            old = self.faces
            faces[:, :old.shape[1], :old.shape[2], :old.shape[3]] = old
            self.faces = faces
            self._tables.clear()                            # the kept tables have the old shape
            circles = np.zeros((4, n, 1, mm))
            circles[2] = -np.inf
            circles[:, :self._circles.shape[1], :, :self._circles.shape[3]] = self._circles
            self._circles = circles
        self.cx, self.cy = grown(self.cx, (n, mm), 0.0), grown(self.cy, (n, mm), 0.0)
        self.radius, self.z_max = grown(self.radius, (n, mm), 0.0), grown(self.z_max, (n, mm), 0.0)
        self.growth = grown(self.growth, (n, mm), 0.0)
        self.valid = grown(self.valid, (n, mm), False)
        self.top = grown(self.top, (n, mm, 3), np.inf)
        block = np.empty((4, ff, len(rows), mm))
        block[...] = pad[..., None]
        block[3, 0, :, m:] = 1.0
        block[:, :f, :, :m] = hs.transpose(3, 2, 0, 1)
        self.faces[:, :, rows] = block
        for a in (self.cx, self.cy, self.radius, self.z_max, self.growth):
            a[rows] = 0.0
        self.valid[rows], self.top[rows] = False, np.inf
        self.cx[rows, :m], self.cy[rows, :m] = centre[..., 0], centre[..., 1]
        self.radius[rows, :m], self.z_max[rows, :m], self.valid[rows, :m] = radius, z_max, True
        self.growth[rows, :m], self.top[rows, :m] = growth, top
        # r' = (r + 1 nm)(1 + 1e-9): the circle grown by rounding slack (the broad phase must never drop a triple
        # the exact clip would block). No polytope: z_max = -inf, beyond every reach (and empty if kept anyway).
        circles = np.zeros((4, len(rows), 1, mm))
        circles[2] = -np.inf
        circles[:, :, 0, :m] = centre[..., 0], centre[..., 1], z_max, (radius + 1e-9) * (1.0 + 1e-9)
        self._circles[:, rows] = circles
        for tol, table in self._tables.items():             # the kept tables: these rows only
            view = table.reshape(4, ff, n, mm)
            view[:, :, rows] = block
            view[3, :, rows] += tol

    def line_of_sight(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                      *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) from UAVs ``uav_xy`` (B, U, 2) at ``altitude`` to targets ``target_xyz`` (B, 3), copy
        b against the terrain of row ``rows[b]``; (B, U) bool, the same as :func:`line_of_sight` per copy.

        One broad phase, then the exact clip (:func:`clip_segments` on :func:`face_values`), each a few array
        operations over the whole batch (their count, not the batch size, is the cost of a small batch). A (copy,
        UAV, polytope) triple is kept when the polytope's footprint circle (radius r, centre c at distance g from the
        target q) lies in the UAV's direction from the target -- the UAV's unit bearing e satisfies
        ``e . (c - q) >= sqrt(g^2 - r^2)`` (the cone the circle subtends at q), or q is inside the circle -- and
        within reach of the part of the segment lower than the polytope's top, which lies within
        ``|p - q| (z_max - z_q) / (h - z_q)`` of the target (so ``|p - q| >= (g - r) / low``). Both tests are
        conservative (r grown by 1 nm and 1e-9 relative, the bearing by 1e-9 relative): they only drop triples
        the clip finds clear, so the result is the exact clip's. ``tol`` >= 0 only: the circles are not grown."""
        if tol < 0:
            raise ValueError(f"TerrainRows.line_of_sight: tol must be >= 0 (its broad phase does not grow the "
                             f"polytopes), got {tol!r}; use line_of_sight or line_of_sight_rows")
        q = target_xyz
        b_n, u_n = uav_xy.shape[:2]
        n_m = self._circles.shape[3]
        out = np.empty((b_n, u_n), dtype=bool)
        out.fill(True)
        # Per (copy, UAV): both ends of each segment, (x, y, z) x (UAV, target) x (B, U), gathered once per
        # candidate below; the distance to the target and the bearing (with the cone's slack; 0 right above q).
        ends = np.empty((3, 2, b_n, u_n))
        ends[:2, 0] = uav_xy.transpose(2, 0, 1)
        ends[2, 0] = altitude
        ends[:, 1] = q.T[:, :, None]
        rel = (ends[:2, 0] - ends[:2, 1])[..., None]
        ex, ey = rel                                                                    # (B, U, 1) each
        dist = ex * ex
        dist += ey * ey
        np.sqrt(dist, out=dist)                                                         # not hypot: slower
        rel *= (1.0 + 1e-9) / np.maximum(dist, 1e-300)
        # Per (copy, polytope): e = g - r' (<= 0: q inside the circle), the cone's threshold sqrt(g^2 - r'^2) (-inf
        # inside) and the reach d_min = e / low.
        circles = self._circles.take(rows, axis=1)                                      # (4, B, 1, M), a copy
        circles[:3] -= q.T[:, :, None, None]                                            # relative to the target
        cx, cy, z_rel, r = circles
        e = cx * cx
        e += cy * cy
        np.sqrt(e, out=e)
        thr = e + r
        e -= r
        thr *= e
        outside = e > 0.0
        r.fill(-np.inf)
        thr = np.sqrt(thr, out=r, where=outside)
        hq = altitude - q[:, 2, None, None]
        if hq.min(initial=np.inf) > 0.0:
            # low = (z_max - z_q) / (h - z_q), floored at 1e-200: a top not above the target (or no polytope) puts
            # d_min beyond any UAV, as such a polytope lies below the whole segment.
            z_rel /= hq
            np.maximum(z_rel, 1e-200, out=z_rel)
            e /= z_rel
        # Per (copy, UAV, polytope) triple: a few passes over (B, U, M), (B, U, 1) against (B, 1, M).
        dot = ex * cx
        dot += ey * cy
        cand = dot >= thr
        cand &= dist >= e
        flat = np.flatnonzero(cand)                    # not np.nonzero on (B U, M): many times slower on large B
        if len(flat) == 0:
            return out
        bu = flat // n_m
        idx = rows.take(bu // u_n) - bu                # the polytope's column in the rows' tables: rows[b] M + m
        idx *= n_m
        idx += flat
        x, y, z = ends.reshape(3, 2, -1).take(bu, axis=2)                              # (2, K) each
        nx, ny, nz, dt = self._clip_table(tol).take(idx, axis=2)[:, :, None]          # (F, 1, K) each
        # Face values at both ends, (F, 2, K): n_x x + n_y y + (n_z z + d + tol), as face_offsets/face_values.
        off = nz * z
        off += dt
        val = face_values(nx, ny, off, x, y)
        blocked = clip_segments(val[:, 0], val[:, 1])
        out.reshape(-1)[bu[blocked]] = False
        return out

    def line_of_sight_paths(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                            *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) along paths: UAV samples ``uav_xy`` (B, U, S, 2) at ``altitude`` against the target at
        the same instants, ``target_xyz`` (B, S, 3), copy b against the terrain of row ``rows[b]``; (B, U, S) bool,
        :meth:`line_of_sight` of every sample (the same clip on the same face values, tested).

        The broad phase runs once per slot before the per-sample one: a (copy, UAV, polytope) triple is kept when
        the farthest sample's distance to its target, times the polytope's ``low`` ratio, reaches the circle from
        the nearest the target comes to it (``g0 - travel - r'``, g0 from the first target sample, travel the
        target's farthest sample from it): every (sample, polytope) pair :meth:`line_of_sight` keeps is in a kept
        triple, so this only saves work. The kept triples' samples then pass :meth:`line_of_sight`'s cone and
        reach tests and the exact clip."""
        if tol < 0:
            raise ValueError(f"TerrainRows.line_of_sight_paths: tol must be >= 0, got {tol!r}")
        b_n, u_n, s_n = uav_xy.shape[:3]
        n_m = self._circles.shape[3]
        out = np.ones((b_n, u_n, s_n), dtype=bool)
        if out.size == 0:
            return out
        q = target_xyz
        # Per (copy, UAV, sample): the UAV minus its target, and their distance.
        rx = uav_xy[..., 0] - q[:, None, :, 0]
        ry = uav_xy[..., 1] - q[:, None, :, 1]
        dist = np.sqrt(rx * rx + ry * ry)                                               # (B, U, S)
        # Per (copy, polytope): the circle relative to the first target sample, the target's travel, the ratio
        # low = (z_max - z_q) / (h - z_q) at its largest over the samples' heights (it is monotone in z_q).
        circles = self._circles.take(rows, axis=1)[:, :, 0]                             # (4, B, M)
        cx, cy, z_top, r = circles
        gx, gy = cx - q[:, :1, 0], cy - q[:, :1, 1]
        g0 = np.sqrt(gx * gx + gy * gy)
        dq = q[:, :, :2] - q[:, :1, :2]
        travel = np.sqrt((dq * dq).sum(-1)).max(axis=1)                                # (B,)
        z_lo, z_hi = q[:, :, 2].min(axis=1)[:, None], q[:, :, 2].max(axis=1)[:, None]
        if min(altitude - z_hi.max(initial=-np.inf), 1.0) <= 0.0:
            return np.stack([self.line_of_sight(rows, uav_xy[:, :, j], altitude, q[:, j], tol=tol)
                             for j in range(s_n)], axis=-1)                            # not in flight: no shortcut
        with np.errstate(invalid="ignore"):                                            # -inf - -inf: no polytope
            low = np.maximum((z_top - z_lo) / (altitude - z_lo), (z_top - z_hi) / (altitude - z_hi))
        gap = g0 - travel[:, None] - r                                                  # (B, M)
        gap -= 1e-9 * (g0 + travel[:, None] + r + 1.0)                                  # rounding slack
        reach = dist.max(axis=2)[:, :, None] * np.maximum(low, 0.0)[:, None, :]        # (B, U, M)
        keep = (reach >= gap[:, None, :]) & (z_top > -np.inf)[:, None, :]
        keep &= _in_slot_cone(rx, ry, gx, gy, g0, r + travel[:, None])
        flat = np.flatnonzero(keep)
        if len(flat) == 0:
            return out
        bu, m = flat // n_m, flat % n_m
        b = bu // u_n
        # The kept triples' samples: line_of_sight's per-sample tests, then its clip.
        pb = np.repeat(b, s_n)
        pbu = np.repeat(bu, s_n)
        pm = np.repeat(m, s_n)
        ps = np.tile(np.arange(s_n), len(flat))
        samples = pbu * s_n + ps
        px, py = uav_xy.reshape(-1, 2)[samples].T
        qx, qy, qz = q.reshape(-1, 3)[pb * s_n + ps].T
        keep_s = _kept_by_cone_and_reach(px, py, qx, qy, qz, cx[pb, pm], cy[pb, pm], z_top[pb, pm], r[pb, pm],
                                         altitude)
        samples, pb, pm = samples[keep_s], pb[keep_s], pm[keep_s]
        if len(samples) == 0:
            return out
        x = np.stack([px[keep_s], qx[keep_s]])
        y = np.stack([py[keep_s], qy[keep_s]])
        z = np.stack([np.full(len(samples), float(altitude)), qz[keep_s]])
        idx = rows.take(pb) * n_m + pm
        nx, ny, nz, dt = self._clip_table(tol).take(idx, axis=2)[:, :, None]
        off = nz * z
        off += dt
        blocked = clip_segments(*face_values(nx, ny, off, x, y).transpose(1, 0, 2))
        out.reshape(-1)[samples[blocked]] = False
        return out


def _in_slot_cone(rx, ry, gx, gy, g0, radius) -> np.ndarray:
    """(B, U, M): some sample's sight direction (rx, ry) (B, U, S) (UAV minus its target) points from the first
    target sample into the cone of the circle (centre offset (gx, gy), distance g0, ``radius``) (B, M). With the
    circle grown by the target's travel, every sample whose ray from its own target meets the ungrown circle is in
    it (the ray translated to the first sample meets the grown circle): a conservative cone test for a slot.
    Bearings are compared on an interval relative to the first sample's, with 1e-6 rad of slack."""
    theta = np.arctan2(ry, rx)
    rel = np.remainder(theta - theta[..., :1] + np.pi, 2 * np.pi) - np.pi               # (B, U, S) in [-pi, pi)
    lo, hi = rel.min(axis=2)[..., None] - 1e-6, rel.max(axis=2)[..., None] + 1e-6       # (B, U, 1)
    inside = g0 <= radius                                                               # (B, M)
    half = np.arcsin(np.minimum(radius / np.maximum(g0, 1e-300), 1.0)) + 1e-6
    centre = np.arctan2(gy, gx)[:, None, :] - theta[:, :, :1]                           # (B, U, M)
    centre = np.remainder(centre + np.pi, 2 * np.pi) - np.pi
    keep = inside[:, None, :] | ((centre + half[:, None, :] >= lo) & (centre - half[:, None, :] <= hi))
    # The cone's interval may wrap around +-pi: its shifted copies.
    keep |= (centre + 2 * np.pi - half[:, None, :] <= hi) | (centre - 2 * np.pi + half[:, None, :] >= lo)
    return keep

def _kept_by_cone_and_reach(px, py, qx, qy, qz, cx, cy, z_top, r, altitude: float) -> np.ndarray:
    """:meth:`TerrainRows.line_of_sight`'s broad phase for K (UAV, target, polytope) triples given flat (K,): the
    circle (centre c, radius r' with slack) in the UAV's bearing cone from the target, and within reach of the part
    of the sight line lower than the polytope's top; False only where the exact clip finds the line clear."""
    ex, ey = px - qx, py - qy
    dist = np.sqrt(ex * ex + ey * ey)
    scale = (1.0 + 1e-9) / np.maximum(dist, 1e-300)
    gx, gy = cx - qx, cy - qy
    g = np.sqrt(gx * gx + gy * gy)
    e = g - r
    thr = np.full(len(e), -np.inf)
    outside = e > 0.0
    thr[outside] = np.sqrt((g[outside] + r[outside]) * e[outside])
    low = np.maximum((z_top - qz) / (altitude - qz), 1e-200)
    return ((ex * gx + ey * gy) * scale >= thr) & (dist >= e / low)

def visible_nodes_rows(terrains: TerrainRows, rows, offsets, q, phi, altitude: float, *,
                       tol: float = SAFE_LOS_TOLERANCE) -> np.ndarray:
    """:func:`visible_nodes` of N scenes at T target poses each, scene n the terrain in row ``rows[n]`` of
    ``terrains``: the vector env's scene pool computes the maps, start candidates and lattice visibility of every
    scene a reset builds in one call.

    The same decisions as :func:`visible_nodes` scene by scene: the same points (:func:`~covert_env.zone.to_world`)
    and the same clip on the same face values (:func:`face_values`, :func:`clip_segments`); the broad phases only
    drop pairs the clip finds clear. A (scene, slot, polytope) triple is kept when the polytope's footprint circle
    (grown with a negative ``tol``) comes within reach of the part of a segment lower than its top (within
    ``|p - q| (z_max - z_q) / (h - z_q)`` of the target q, |p - q| at most the slot's farthest node); then every
    node of a kept triple whose segment's low part passes near the circle (:func:`passes_near`) is clipped.

    Args:
        terrains: the scenes' terrains; rows: (N,) their rows.
        offsets: (L, 2) target-frame offsets of the nodes (inside the eroded zone).
        q: (N, T, 3) target positions; phi: (N, T) headings; altitude: the UAVs' height h (above every q).
        tol: the LoS tolerance (m), see :data:`SAFE_LOS_TOLERANCE`.

    Returns:
        (N, T, L) bool, True = clear line of sight.
    """
    rows = np.asarray(rows, dtype=np.intp)
    q, phi, off = np.asarray(q, float), np.asarray(phi, float), np.asarray(offsets, float)
    n_s, n_t = q.shape[:2]
    out = np.ones((n_s, n_t, len(off)), dtype=bool)
    if out.size == 0 or terrains.valid.shape[1] == 0:
        return out
    if not float(altitude) > q[..., 2].max():
        raise ValueError(f"visible_nodes_rows: the altitude ({float(altitude):g} m) must be above every target")
    # Scenes per block: at most 2^21 (node, polytope) pairs, so the broad phase's (kept triple x node) arrays stay
    # within ~16 MB each whatever the terrain's polytope count.
    chunk = max(1, (1 << 21) // (n_t * len(off) * max(terrains.valid.shape[1], 1)))
    for a in range(0, n_s, chunk):
        _visible_block(terrains, rows[a:a + chunk], off, q[a:a + chunk], phi[a:a + chunk], float(altitude), tol,
                       out[a:a + chunk])
    return out


def _visible_block(terrains: TerrainRows, rows, off, q, phi, h: float, tol: float, out: np.ndarray) -> None:
    """:func:`visible_nodes_rows` on a block of scenes, writing ``out`` (n, T, L). The broad phase is
    :meth:`TerrainRows.line_of_sight`'s (a footprint circle's cone seen from the target, and the reach of the
    segment's part lower than the top), with the circles grown by a negative ``tol``."""
    xy = to_world(off, q[..., :2], phi)                                         # (n, T, L, 2)
    ex, ey = xy[..., 0] - q[..., 0, None], xy[..., 1] - q[..., 1, None]         # (n, T, L) each
    dist = np.sqrt(ex * ex + ey * ey)
    scale = (1.0 + 1e-9) / np.maximum(dist, 1e-300)
    ex, ey = ex * scale, ey * scale                                             # unit bearings, 1e-9 slack
    grow = terrains.growth[rows] * -tol if tol < 0 else np.zeros(terrains.growth[rows].shape)
    cx, cy, rad, z_max = (a[rows][:, None] for a in (terrains.cx, terrains.cy, terrains.radius, terrains.z_max))
    grow = grow[:, None]                                                        # (n, 1, M) each
    # Per (scene, slot, polytope): the circle relative to q, grown by rounding slack; e = g - r' (<= 0: q inside),
    # the cone's threshold sqrt(g^2 - r'^2) and the reach d_min = e / low.
    rx, ry = cx - q[..., 0, None], cy - q[..., 1, None]                         # (n, T, M)
    r = (rad + grow + 1e-9) * (1.0 + 1e-9)
    g = np.sqrt(rx * rx + ry * ry)
    e = g - r
    thr = np.where(e > 0.0, np.sqrt(np.maximum((g + r) * e, 0.0)), -np.inf)
    low = np.maximum((z_max + grow - q[..., 2, None]) / (h - q[..., 2, None]), 1e-200)
    d_min = e / low
    near = d_min <= dist.max(axis=-1)[..., None]
    near &= terrains.valid[rows][:, None]
    i_s, i_t, i_m = np.nonzero(near)
    if len(i_s) == 0:
        return
    # Per (triple, node): the node's bearing inside the cone and its segment long enough to reach the footprint.
    hit = ex[i_s, i_t] * rx[i_s, i_t, i_m, None]
    hit += ey[i_s, i_t] * ry[i_s, i_t, i_m, None]
    hit = hit >= thr[i_s, i_t, i_m, None]
    hit &= dist[i_s, i_t] >= d_min[i_s, i_t, i_m, None]
    k, node = np.nonzero(hit)
    if len(k) == 0:
        return
    n_m = terrains.valid.shape[1]
    nx, ny, nz, dt = terrains._clip_table(tol).take(rows[i_s[k]] * n_m + i_m[k], axis=2)     # (F, K) each
    pk, qq = xy[i_s[k], i_t[k], node], q[i_s[k], i_t[k]]
    start = face_values(nx, ny, nz * h + dt, pk[:, 0], pk[:, 1])
    off_q = nz * qq[:, 2]
    off_q += dt
    end = face_values(nx, ny, off_q, qq[:, 0], qq[:, 1])
    blocked = clip_segments(start, end)
    out[i_s[k[blocked]], i_t[k[blocked]], node[blocked]] = False


def grown(arr: np.ndarray, shape: tuple, fill) -> np.ndarray:
    """``arr`` copied into a larger array of ``shape`` (each axis at least as long), the rest ``fill``."""
    if arr.shape == shape:
        return arr
    out = np.full(shape, fill, dtype=arr.dtype)
    out[tuple(slice(0, n) for n in arr.shape)] = arr
    return out


# ----------------------------------------------------------------------------- shadows
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
