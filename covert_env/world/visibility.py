"""Line of sight (paper §2.2, eq. 6): which UAV positions see the target, for one scene or a batch of scenes.

A UAV at ``p = (x, y, h)`` sees the target at ``q = (x_q, y_q, z_q)`` unless the segment between them meets the
interior of some terrain polytope C_m (eq. 6). Every question of that kind goes to one kernel,
:func:`covert_env.geometry.sight_kernel.blocked_segments` (one broad phase, per target then per point, and one exact
clip);
this module lays the questions out for it:

* one terrain (:func:`line_of_sight`, :func:`line_of_sight_rows`, :func:`visible_nodes`): the planner, the metrics,
  the start sampler and the pictures, with the terrain's padded arrays (:class:`TerrainArrays`, built once per
  terrain);
* terrains as rows of a table (:class:`TerrainRows`, :func:`visible_nodes_rows`): the vector env's scene pool, copy
  b against the terrain of row ``rows[b]``, at slot ends, along the flown paths and on the lattice.

Touching a face, an edge or a vertex is clear: the polytopes are shrunk by :data:`LOS_TOLERANCE`. Where a line of
sight is promised ahead (the lattice, the masks, the planner), they are grown by 1 µm instead
(:data:`SAFE_LOS_TOLERANCE`). The shadows these polytopes cast on the UAV plane (eqs. 8-9) are in
:mod:`covert_env.world.shadows`.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from covert_env.geometry.sight_kernel import TerrainTable, offsets_blocked, segments_blocked, terrain_table
from covert_env.world.terrain import Terrain

__all__ = [
    "LOS_TOLERANCE",
    "SAFE_LOS_TOLERANCE",
    "TerrainArrays",
    "TerrainRows",
    "grown",
    "growth_factors",
    "line_of_sight",
    "line_of_sight_rows",
    "register_terrain_arrays",
    "terrain_arrays",
    "visible_nodes",
    "visible_nodes_rows",
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


# ----------------------------------------------------------------------------- one terrain
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
    def growth_factor(self) -> np.ndarray:
        """(M,) ``R / r``: moving every face plane of a polytope out by g keeps it within ``g R / r`` of the polytope
        (the faces of ``{n.x + d <= g}`` meet beyond g at sharp edges, not on a sphere). With c the mean of the
        (padded) vertex list, a point inside the hull, r the radius of the ball about c inside the polytope
        (``min_f -(n_f.c + d_f)`` over the real faces, unit normals) and R the farthest vertex from c, the grown
        polytope lies inside the polytope scaled by ``1 + g / r`` about c."""
        return growth_factors(self.hs, self.verts)

    @cached_property
    def table(self) -> TerrainTable:
        """The terrain as the one row of a checked :class:`~covert_env.geometry.sight_kernel.TerrainTable`: half-spaces
        (1, M, F, 4), circle centres x and y, radii, tops and growth factors (1, M)."""
        return terrain_table(*(a[None] for a in (self.hs, self.centre[:, 0], self.centre[:, 1], self.radius,
                                                 self.z_max, self.growth_factor)))


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



def line_of_sight(terrain: Terrain, uav_xy, altitude, target_xyz, *,
                  tol: float = LOS_TOLERANCE) -> np.ndarray:
    """Whether each UAV position sees the target (True = clear line of sight), eq. 6, exactly.

    The segment from the UAV ``(x, y, altitude)`` to the target ``(x_q, y_q, z_q)`` is blocked iff it meets the
    interior of some polytope C_m, shrunk by ``tol`` metres (:data:`LOS_TOLERANCE`: touching a face, an edge or a
    vertex is clear). The kernel (:func:`~covert_env.geometry.sight_kernel.blocked_segments`) keeps only the (point,
    polytope) pairs whose segment's part lower than the polytope's top passes near its footprint, and clips those
    exactly (Cyrus-Beck in 3D).

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
    one_target = target.size == 3 and target.ndim <= uav_xy.ndim
    if one_target:
        shape = np.broadcast_shapes(uav_xy.shape[:-1], alt.shape)
    else:
        shape = np.broadcast_shapes(uav_xy.shape[:-1], target.shape[:-1], alt.shape)
    n = int(np.prod(shape))
    if len(terrain) == 0 or n == 0:
        return np.ones(shape, dtype=bool)
    points = np.broadcast_to(uav_xy, shape + (2,)).reshape(-1, 2)
    heights = alt if alt.ndim == 0 else np.broadcast_to(alt, shape).reshape(-1)
    if one_target:                      # one target owns every point
        targets, start = target.reshape(1, 3), np.array([0, n])
    else:                               # each point its own target
        targets, start = np.broadcast_to(target, shape + (3,)).reshape(-1, 3), np.arange(n + 1)
    blocked = segments_blocked(terrain_arrays(terrain).table, targets, np.zeros(len(targets), np.int64), start,
                               points, heights, tol)
    return ~blocked.reshape(shape)


def line_of_sight_rows(terrain: Terrain, uav_xy, altitude: float, target_xyz, *,
                       tol: float = LOS_TOLERANCE) -> np.ndarray:
    """:func:`line_of_sight` for S rows of C points, row s against its own target ``target_xyz[s]`` (the
    observation maps: C cells at each of S slots).

    Args:
        uav_xy: (S, C, 2) points; altitude: the UAV height (scalar); target_xyz: (S, 3).

    Returns:
        (S, C) bool, True = clear.
    """
    xy = np.asarray(uav_xy, dtype=float)
    q = np.asarray(target_xyz, dtype=float)
    if xy.ndim != 3 or xy.shape[-1] != 2 or q.shape != (len(xy), 3):
        raise ValueError(f"line_of_sight_rows: uav_xy must be (S, C, 2) and target_xyz (S, 3); "
                         f"got {xy.shape}, {q.shape}")
    n_rows, n_pts = xy.shape[:2]
    if len(terrain) == 0 or xy.size == 0:
        return np.ones((n_rows, n_pts), dtype=bool)
    blocked = segments_blocked(terrain_arrays(terrain).table, q, np.zeros(n_rows, np.int64),
                               np.arange(n_rows + 1) * n_pts, xy.reshape(-1, 2), altitude, tol)
    return ~blocked.reshape(n_rows, n_pts)


def visible_nodes(terrain: Terrain, offsets, q, phi, altitude: float, *,
                  tol: float = SAFE_LOS_TOLERANCE) -> np.ndarray:
    """The visible feasible zone (eq. 10) on the waypoint lattice: which nodes see the target.

    The one rule behind the planner's states, the waypoint action mask, the observation maps and the start
    sampler. ``offsets`` are target-frame offsets inside the eroded zone (the lattice's nodes,
    :func:`~covert_env.geometry.zone.zone_lattice`, or the maps' cells): zone membership is decided once in the target's
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
    phi = np.asarray(phi, dtype=float)
    if q.shape[-1:] != (3,) or q.ndim > 2 or phi.ndim > q.ndim - 1:
        raise ValueError(f"visible_nodes: q must be (3,) or (S, 3) and phi () or (S,); got {q.shape}, {phi.shape}")
    targets = q.reshape(-1, 3)
    blocked = offsets_blocked(terrain_arrays(terrain).table, targets, np.zeros(len(targets), np.int64),
                              np.broadcast_to(phi, q.shape[:-1]).reshape(-1), offsets, altitude, tol)
    return ~blocked.reshape(q.shape[:-1] + (-1,))

# ----------------------------------------------------------------------------- terrains as rows
class TerrainRows:
    """Terrains as rows of padded arrays (one terrain per row), for line of sight of a batch of copies, copy b
    against the terrain in row ``rows[b]`` (the vector env's scene pool keeps one row per scene).

    Rows are written by :meth:`set_rows` (many at once) or :meth:`set_row`; the arrays grow (geometrically, up to
    ``capacity`` rows) to the largest polytope and face counts seen. Extra faces are the always-true row
    ``0.x - 1 <= 0`` and extra polytopes have no top (``z_max = -inf``), so padding never blocks.

    Attributes (rows R, polytopes M, faces F):
        hs (R, M, F, 4): each polytope's half-spaces ``n . x + d <= 0``.
        cx, cy, radius (R, M): plan-view enclosing circles; z_max (R, M): heights (-inf: no polytope).
        growth (R, M): :func:`growth_factors` (how far a negative tolerance grows each polytope, per metre).
        top (R, M, 3): polytope top points (eq. 3), padded with inf.
    """

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.hs = np.zeros((0, 0, 1, 4))
        self.cx, self.cy, self.radius, self.growth = (np.zeros((0, 0)) for _ in range(4))
        self.z_max = np.zeros((0, 0))
        self.top = np.zeros((0, 0, 3))
        self._table: TerrainTable | None = None

    def __len__(self) -> int:
        return len(self.hs)

    @property
    def table(self) -> TerrainTable:
        """The rows as a checked :class:`~covert_env.geometry.sight_kernel.TerrainTable`, the same arrays (kept until an
        array is replaced: :meth:`set_rows` grows them by replacing, and writes rows in place)."""
        arrays = (self.hs, self.cx, self.cy, self.radius, self.z_max, self.growth)
        if self._table is None or any(a is not b for a, b in zip(arrays, self._table, strict=True)):
            self._table = terrain_table(*arrays)
        return self._table

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
        mm, ff = max(m, self.hs.shape[1]), max(f, self.hs.shape[2])
        always = np.array([0.0, 0.0, 0.0, -1.0])            # 0.x - 1 <= 0: a face that never blocks
        if self.hs.shape != (n, mm, ff, 4):
            old, self.hs = self.hs, np.empty((n, mm, ff, 4))
            self.hs[...] = always
            self.hs[:old.shape[0], :old.shape[1], :old.shape[2]] = old
        self.cx, self.cy = grown(self.cx, (n, mm), 0.0), grown(self.cy, (n, mm), 0.0)
        self.radius, self.z_max = grown(self.radius, (n, mm), 0.0), grown(self.z_max, (n, mm), -np.inf)
        self.growth = grown(self.growth, (n, mm), 0.0)
        self.top = grown(self.top, (n, mm, 3), np.inf)
        block = np.empty((len(rows), mm, ff, 4))
        block[...] = always
        block[:, :m, :f] = hs
        self.hs[rows] = block
        for a in (self.cx, self.cy, self.radius, self.growth):
            a[rows] = 0.0
        self.z_max[rows], self.top[rows] = -np.inf, np.inf
        self.cx[rows, :m], self.cy[rows, :m] = centre[..., 0], centre[..., 1]
        self.radius[rows, :m], self.z_max[rows, :m] = radius, z_max
        self.growth[rows, :m], self.top[rows, :m] = growth, top

    def blocked(self, targets: np.ndarray, rows: np.ndarray, start: np.ndarray, points: np.ndarray, heights,
                tol: float) -> np.ndarray:
        """:func:`~covert_env.geometry.sight_kernel.blocked_segments` on these terrains: target j (``targets``
        (T, 3)) in row ``rows[j]`` owns the points ``points[start[j]:start[j + 1]]`` ((N, 2), at ``heights``: one
        or (N,)); (N,) True = blocked."""
        return segments_blocked(self.table, targets, rows, start, points, heights, tol)

    def line_of_sight(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                      *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) from UAVs ``uav_xy`` (B, U, 2) at ``altitude`` to targets ``target_xyz`` (B, 3), copy
        b against the terrain of row ``rows[b]``; (B, U) bool, the same as :func:`line_of_sight` per copy."""
        b_n, u_n = uav_xy.shape[:2]
        blocked = self.blocked(target_xyz, rows, np.arange(b_n + 1) * u_n, uav_xy.reshape(-1, 2), altitude, tol)
        return ~blocked.reshape(b_n, u_n)

    def line_of_sight_paths(self, rows: np.ndarray, uav_xy: np.ndarray, altitude: float, target_xyz: np.ndarray,
                            *, tol: float = LOS_TOLERANCE) -> np.ndarray:
        """Clear LoS (eq. 6) along paths: UAV samples ``uav_xy`` (B, U, S, 2) at ``altitude`` against the target at
        the same instants, ``target_xyz`` (B, S, 3), copy b against the terrain of row ``rows[b]``; (B, U, S) bool,
        :meth:`line_of_sight` of every sample."""
        b_n, u_n, s_n = uav_xy.shape[:3]
        points = uav_xy.transpose(0, 2, 1, 3).reshape(-1, 2)                        # (B, S, U): by target
        blocked = self.blocked(target_xyz.reshape(-1, 3), np.repeat(rows, s_n), np.arange(b_n * s_n + 1) * u_n,
                               points, altitude, tol)
        return ~blocked.reshape(b_n, s_n, u_n).transpose(0, 2, 1)


def visible_nodes_rows(terrains: TerrainRows, rows, offsets, q, phi, altitude: float, *,
                       tol: float = SAFE_LOS_TOLERANCE) -> np.ndarray:
    """:func:`visible_nodes` of N scenes at T target poses each, scene n the terrain in row ``rows[n]`` of
    ``terrains``: the vector env's scene pool computes the maps, start candidates and lattice visibility of every
    scene a reset builds in one call. The same points (:func:`~covert_env.geometry.zone.to_world`) and the same kernel
    as :func:`visible_nodes`, hence the same decisions scene by scene.

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
    if out.size == 0 or terrains.hs.shape[1] == 0:
        return out
    if not float(altitude) > q[..., 2].max():
        raise ValueError(f"visible_nodes_rows: the altitude ({float(altitude):g} m) must be above every target")
    blocked = offsets_blocked(terrains.table, q.reshape(-1, 3), np.repeat(rows, n_t), phi.reshape(-1), off,
                              altitude, tol)
    return ~blocked.reshape(out.shape)


def grown(arr: np.ndarray, shape: tuple, fill) -> np.ndarray:
    """``arr`` copied into a larger array of ``shape`` (each axis at least as long), the rest ``fill``."""
    if arr.shape == shape:
        return arr
    out = np.full(shape, fill, dtype=arr.dtype)
    out[tuple(slice(0, n) for n in arr.shape)] = arr
    return out
