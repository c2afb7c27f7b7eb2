"""The line-of-sight kernel (eq. 6): which segments from UAVs to their targets meet a terrain polytope.

Every line-of-sight question of the library -- the env at slot ends and along the flown paths, the observation
maps, the waypoint lattice and the action masks, the planner's states and path checks, the metrics -- is a batch of
segments, each from a UAV position ``p`` to a target position ``q``, each against the terrain of its scene. This
module answers it once, for any batch, with one broad phase (per target, then per point) and one exact clip:

* **Layout.** Segments are grouped by target: target j (``targets[j]``, the terrain in row ``rows[j]`` of a
  :class:`~covert_env.world.visibility.TerrainRows`) owns the points ``points[start[j]:start[j + 1]]``. A batch of
  copies, slots, path instants or lattice nodes is one such flat layout; the callers build it with array operations.
  :func:`blocked_offsets` is the layout of one set of target-frame offsets about every target (the maps, lattices
  and start candidates of every slot of every scene): the kernel computes each target's points itself, term by
  term as :func:`~covert_env.geometry.zone.to_world`, instead of reading (T, L, 2) of them from memory.
* **Broad phase, per (target, polytope).** The part of a segment lower than a polytope's top lies within
  ``|p - q| (z_top - z_q) / (h - z_q)`` of the target (h the UAV's height, above the target); a polytope whose
  footprint circle is farther than that from every point's segment of the target is dropped for all of them.
* **Broad phase, per (point, polytope).** The 2-D part of the segment lower than the top (``s`` in ``[s0, s1]``
  along ``p -> q``) must pass within the footprint circle.
* **Exact clip** (Cyrus-Beck, the one formula of eq. 6). Each face value ``n . x + d + tol`` is linear along the
  segment; the segment meets the polytope shrunk by ``tol`` iff the entering bounds' maximum is at most the leaving
  bounds' minimum on ``[0, 1]``. Face values are summed in one fixed order, ``(n_x x + n_y y) + (n_z z + (d + tol))``,
  so a decision never depends on how the batch is laid out.

The broad phase is conservative (circles grown by 1 nm, and 1e-9 relative per target; tops raised by 1 nm; both
grown by how far a negative ``tol`` grows each polytope, ``growth`` times ``-tol``, with ``growth`` from
:func:`~covert_env.world.visibility.growth_factors`): it only drops pairs the clip finds clear, so the result is the
clip's alone. (A caller that passes smaller growth factors makes the circle-and-top test part of the result: the
planner's possible targets, :func:`baselines.dp.possible_targets.clear_to_all`, block a pair only where the segment
meets both the pushed-out faces and the widened cylinder.)

The kernel is compiled with numba, a loop per target. A target's many points at one height (the planner's path
samples, the lattices and maps) go polytope by polytope, each kept polytope's footprint test over all the points in
one branch-free pass, then the clips of the points near it. A target's few points at one height (the env's team at
a slot end or a path instant) skip the broad phase per target: each point is tested against the footprint of every
polytope of its row in one branch-free pass over the polytopes, then clipped against those it passes near, stopping
at the first that blocks. Points at their own heights go point by point through both broad phases. All three make
the same decision for every (point, polytope) pair: the clip's. It runs single-threaded and holds no state between
calls. numba checks no bounds, so :func:`blocked_segments` checks every shape and index first.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

__all__ = ["TerrainTable", "blocked_offsets", "blocked_segments", "offsets_blocked", "segments_blocked",
           "terrain_table"]

# From this many points of one target at one height, the kernel goes polytope by polytope (the planner's path
# checks: hundreds to tens of thousands of samples per instant); below it, point by point (the env: a target's
# team), where the polytope-first passes cost more than they save. The decisions are the same either way.
_MANY_POINTS = 16


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _kernel(hs, cx, cy, radius, z_top, growth, targets, rows, start, points, heights, tol, out):  # pragma: no cover
    """``out[i]`` = segment i is blocked; arguments as :func:`blocked_segments`. A target's ``_MANY_POINTS`` or
    more points at one height go polytope by polytope (:func:`_polytopes_first`), fewer at one height point by point
    over every polytope (:func:`_team_points`), points at their own heights point by point over the kept polytopes
    (:func:`_point_blocked`): the same decisions."""
    one_height = len(heights) == 1
    keep = np.empty(hs.shape[1], dtype=np.int64)
    width = 0
    for j in range(len(targets) if one_height else 0):
        if start[j + 1] - start[j] >= _MANY_POINTS:
            width = max(width, start[j + 1] - start[j])
    xs, ys, near = np.empty(width), np.empty(width), np.empty(width, dtype=np.bool_)
    if one_height:
        _team_points(hs, cx, cy, radius, z_top, growth, targets, rows, start, points, heights[0], tol, out)
    for j in range(len(targets)):
        a, b = start[j], start[j + 1]
        if a == b:
            continue
        if one_height and b - a < _MANY_POINTS:         # _team_points' (below)
            continue
        # The target's points: their farthest horizontal distance and lowest height.
        d2_max = 0.0
        h_min = heights[0] if one_height else heights[a]
        for i in range(a, b):
            dx = points[i, 0] - targets[j, 0]
            dy = points[i, 1] - targets[j, 1]
            d2 = dx * dx + dy * dy
            if d2 > d2_max:
                d2_max = d2
            if not one_height and heights[i] < h_min:
                h_min = heights[i]
        qx, qy, qz, r = targets[j, 0], targets[j, 1], targets[j, 2], rows[j]
        n_keep = _near_polytopes(z_top, cx, cy, radius, growth, r, qx, qy, qz, np.sqrt(d2_max), h_min, tol, keep)
        if n_keep == 0:
            continue
        if one_height and b - a >= _MANY_POINTS:
            n = b - a
            for i in range(n):
                xs[i] = points[a + i, 0]
                ys[i] = points[a + i, 1]
            _polytopes_first(hs, cx, cy, radius, z_top, growth, r, keep, n_keep, qx, qy, qz, xs[:n], ys[:n],
                             heights[0], tol, near[:n], out[a:b])
            continue
        for i in range(a, b):
            uz = heights[0] if one_height else heights[i]
            if _point_blocked(hs, cx, cy, radius, z_top, growth, r, keep, n_keep, qx, qy, qz, points[i, 0],
                              points[i, 1], uz, tol):
                out[i] = True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _team_points(hs, cx, cy, radius, z_top, growth, targets, rows, start, points, uz, tol, out):  # pragma: no cover
    """Sets ``out[i]`` for the points of every target with fewer than ``_MANY_POINTS`` points (all at height
    ``uz``) whose segment to the target meets a polytope of the target's row.

    A polytope's low part of the segments (``s0``, ``s1``) depends on the target and the height only, so it is
    worked out once per target. Each point is then tested against every polytope's footprint circle in one
    branch-free pass over the polytopes (contiguous: the compiler vectorises it), which costs less than
    :func:`_near_polytopes`' pruning saves for a handful of points; the clips follow in polytope order. The
    decisions are :func:`_point_blocked`'s: the same low part, footprint test and clip, over a superset of the
    polytopes it keeps, and the broad phase only drops pairs the clip finds clear."""
    n_m = z_top.shape[1]
    s0s, s1s, rad2 = np.empty(n_m), np.empty(n_m), np.empty(n_m)
    kept, near = np.empty(n_m, dtype=np.bool_), np.empty(n_m, dtype=np.bool_)
    for j in range(len(targets)):
        a, b = start[j], start[j + 1]
        if a == b or b - a >= _MANY_POINTS:
            continue
        r = rows[j]
        qx, qy, qz = targets[j, 0], targets[j, 1], targets[j, 2]
        dz = qz - uz
        inv_dz = 1.0 / (dz if dz != 0.0 else -1e-300)
        n_r = n_m                                        # the row's columns up to its last polytope
        while n_r > 0 and z_top[r, n_r - 1] == -np.inf:
            n_r -= 1
        for m in range(n_r):
            # _low_part written out: its tuple return keeps this loop from compiling well (7x slower).
            grow = growth[r, m] * -tol if tol < 0.0 else 0.0
            rad = radius[r, m] + grow + 1e-9
            sc = (z_top[r, m] + grow + 1e-9 - uz) * inv_dz
            sc = min(max(sc, 0.0), 1.0)
            s0 = sc if dz <= 0.0 else 0.0
            s1 = 1.0 if dz <= 0.0 else sc
            s0s[m], s1s[m], rad2[m] = s0, s1, rad * rad
            kept[m] = z_top[r, m] != -np.inf and s1 > s0 - 1e-12
        cxr, cyr = cx[r], cy[r]
        for i in range(a, b):
            ux, uy = points[i, 0], points[i, 1]
            ex, ey = qx - ux, qy - uy
            any_near = False
            for m in range(n_r):
                # _near_footprint's test, written out over contiguous arrays so that the loop vectorises.
                s0, s1 = s0s[m], s1s[m]
                acx = cxr[m] - (ux + s0 * ex)
                acy = cyr[m] - (uy + s0 * ey)
                abx, aby = (s1 - s0) * ex, (s1 - s0) * ey
                ab2 = abx * abx + aby * aby
                w = (acx * abx + acy * aby) / (ab2 if ab2 > 0 else 1.0)
                w = min(max(w, 0.0), 1.0)
                px, py = acx - w * abx, acy - w * aby
                hit = kept[m] and not px * px + py * py > rad2[m]
                near[m] = hit
                any_near |= hit
            if any_near:
                for m in range(n_r):
                    if near[m] and _clip_meets(hs, r, m, ux, uy, uz, qx, qy, qz, tol):
                        out[i] = True
                        break


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _kernel_offsets(hs, cx, cy, radius, z_top, growth, targets, rows, cos, sin, offsets, height, tol,
                    out):  # pragma: no cover
    """``out[j, l]`` = the segment from target j's offset l (in its frame, at ``height``) is blocked; arguments as
    :func:`blocked_offsets`. The points are :func:`~covert_env.geometry.zone.to_world`'s, term by term."""
    keep = np.empty(hs.shape[1], dtype=np.int64)
    n = len(offsets)
    xs, ys = np.empty(n), np.empty(n)
    near = np.empty(n, dtype=np.bool_)
    for j in range(len(targets)):
        qx, qy, qz, r = targets[j, 0], targets[j, 1], targets[j, 2], rows[j]
        c, s = cos[j], sin[j]
        d2_max = 0.0
        for i in range(n):
            x = qx + c * offsets[i, 0] - s * offsets[i, 1]
            y = qy + s * offsets[i, 0] + c * offsets[i, 1]
            xs[i], ys[i] = x, y
            dx, dy = x - qx, y - qy
            d2 = dx * dx + dy * dy
            if d2 > d2_max:
                d2_max = d2
        n_keep = _near_polytopes(z_top, cx, cy, radius, growth, r, qx, qy, qz, np.sqrt(d2_max), height, tol, keep)
        _polytopes_first(hs, cx, cy, radius, z_top, growth, r, keep, n_keep, qx, qy, qz, xs, ys, height, tol, near,
                         out[j])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _polytopes_first(hs, cx, cy, radius, z_top, growth, r, keep, n_keep, qx, qy, qz, xs, ys, uz, tol, near,
                     blocked):  # pragma: no cover
    """Sets ``blocked[i]`` where the segment from (xs[i], ys[i], uz) to the target meets one of the polytopes
    ``keep[:n_keep]`` of row ``r``; ``near`` is scratch of the points' length.

    Every point is at the same height, so a polytope's low part of the segments (``s0``, ``s1``) is the same for
    all: one kept polytope at a time, every point is tested against its footprint circle in one branch-free pass
    (which the compiler vectorises), then the points that pass and are not yet blocked are clipped. A point is
    blocked iff some polytope blocks it: the decisions of :func:`_point_blocked`, polytope by polytope."""
    n = len(xs)
    dz = qz - uz
    inv_dz = 1.0 / (dz if dz != 0.0 else -1e-300)
    for k in range(n_keep):
        m = keep[k]
        s0, s1, rad = _low_part(radius, z_top, growth, r, m, uz, dz, inv_dz, tol)
        if not s1 > s0 - 1e-12:
            continue
        for i in range(n):
            near[i] = _near_footprint(cx[r, m], cy[r, m], rad, xs[i], ys[i], qx - xs[i], qy - ys[i], s0, s1)
        for i in range(n):
            if near[i] and not blocked[i] and _clip_meets(hs, r, m, xs[i], ys[i], uz, qx, qy, qz, tol):
                blocked[i] = True


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _near_polytopes(z_top, cx, cy, radius, growth, r, qx, qy, qz, d_max, h_min, tol, keep):  # pragma: no cover
    """The broad phase per (target, polytope): writes into ``keep`` the polytopes of row ``r`` within reach of the
    low parts of segments from points at most ``d_max`` (horizontally) from ``target`` and at least ``h_min`` high;
    returns how many."""
    above = h_min > qz
    inv_hq = 1.0 / (h_min - qz) if above else 0.0
    n_keep = 0
    for m in range(z_top.shape[1]):
        top = z_top[r, m]
        if top == -np.inf:                     # no polytope in this column of the row
            continue
        grow = growth[r, m] * -tol if tol < 0.0 else 0.0
        rad = (radius[r, m] + grow + 1e-9) * (1.0 + 1e-9)
        if above:
            # Kept iff |c - q| - r <= reach, the reach of the segments' low parts (squared: no root).
            low = (top + grow + 1e-9 - qz) * inv_hq
            if low < 0.0:
                low = 0.0
            reach = d_max * low * (1.0 + 1e-9) + 1e-9 + rad
            gx = cx[r, m] - qx
            gy = cy[r, m] - qy
            if gx * gx + gy * gy > reach * reach * (1.0 + 1e-12):
                continue
        keep[n_keep] = m
        n_keep += 1
    return n_keep


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _point_blocked(hs, cx, cy, radius, z_top, growth, r, keep, n_keep, qx, qy, qz, ux, uy, uz,
                   tol):  # pragma: no cover
    """Whether the segment from (ux, uy, uz) to ``target`` meets one of the polytopes ``keep[:n_keep]`` of row
    ``r``: the broad phase per (point, polytope), then the exact clip."""
    ex, ey, dz = qx - ux, qy - uy, qz - uz
    inv_dz = 1.0 / (dz if dz != 0.0 else -1e-300)
    for k in range(n_keep):
        m = keep[k]
        # _low_part written out: called per (point, polytope), its tuple return keeps this loop from compiling well.
        grow = growth[r, m] * -tol if tol < 0.0 else 0.0
        rad = radius[r, m] + grow + 1e-9
        top = z_top[r, m] + grow + 1e-9
        sc = (top - uz) * inv_dz
        if dz <= 0.0:
            s0, s1 = min(max(sc, 0.0), 1.0), 1.0
        else:
            s0, s1 = 0.0, min(max(sc, 0.0), 1.0)
        if not s1 > s0 - 1e-12:
            continue
        if not _near_footprint(cx[r, m], cy[r, m], rad, ux, uy, ex, ey, s0, s1):
            continue
        if _clip_meets(hs, r, m, ux, uy, uz, qx, qy, qz, tol):
            return True
    return False


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _low_part(radius, z_top, growth, r, m, uz, dz, inv_dz, tol):  # pragma: no cover
    """Polytope m of row r against a segment from height ``uz`` rising ``dz``: the parameter range [s0, s1] (s = 0
    at the UAV) where the segment is lower than the grown top, and the grown footprint circle's radius."""
    grow = growth[r, m] * -tol if tol < 0.0 else 0.0
    rad = radius[r, m] + grow + 1e-9
    top = z_top[r, m] + grow + 1e-9
    sc = (top - uz) * inv_dz
    if dz <= 0.0:
        return min(max(sc, 0.0), 1.0), 1.0, rad
    return 0.0, min(max(sc, 0.0), 1.0), rad


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _near_footprint(cxm, cym, rad, ux, uy, ex, ey, s0, s1):  # pragma: no cover
    """Whether the 2-D part [s0, s1] of the segment from (ux, uy) along (ex, ey) passes within ``rad`` of the
    footprint circle's centre (cxm, cym): the broad phase per (point, polytope)."""
    acx = cxm - (ux + s0 * ex)
    acy = cym - (uy + s0 * ey)
    abx, aby = (s1 - s0) * ex, (s1 - s0) * ey
    ab2 = abx * abx + aby * aby
    w = (acx * abx + acy * aby) / (ab2 if ab2 > 0 else 1.0)
    w = min(max(w, 0.0), 1.0)
    px, py = acx - w * abx, acy - w * aby
    return not px * px + py * py > rad * rad


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _clip_meets(hs, r, m, ux, uy, uz, qx, qy, qz, tol):  # pragma: no cover
    """The exact clip (Cyrus-Beck): whether the segment from (ux, uy, uz) to (qx, qy, qz) meets polytope m of row r
    shrunk by ``tol``."""
    s_in, s_out = 0.0, 1.0
    for f in range(hs.shape[2]):
        nx, ny, nz = hs[r, m, f, 0], hs[r, m, f, 1], hs[r, m, f, 2]
        dt = hs[r, m, f, 3] + tol
        v0 = nx * ux + ny * uy
        v0 = v0 + (nz * uz + dt)
        v1 = nx * qx + ny * qy
        v1 = v1 + (nz * qz + dt)
        den = v1 - v0
        s = -v0 / den
        if den < 0.0:
            if s > s_in:
                s_in = s
        elif s < s_out:                 # den == 0: -inf (outside), +inf or NaN (no bound)
            s_out = s
        if s_in > s_out:
            return False
    return s_in <= s_out


def blocked_segments(hs: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, z_top: np.ndarray,
                     growth: np.ndarray, targets: np.ndarray, rows: np.ndarray, start: np.ndarray,
                     points: np.ndarray, heights, tol: float) -> np.ndarray:
    """Whether each segment from ``points[i]`` to its target meets a polytope of the target's terrain (eq. 6).

    Args:
        hs: (R, M, F, 4) the polytopes' half-spaces ``n . x + d <= 0`` per terrain row, padded with always-true
            faces (``0 . x - 1``).
        cx, cy, radius: (R, M) their plan-view enclosing circles; z_top: (R, M) their heights (-inf: no polytope).
        growth: (R, M) :func:`~covert_env.world.visibility.growth_factors` (used when ``tol < 0``).
        targets: (T, 3) target positions; rows: (T,) the terrain row of each target.
        start: (T + 1,) target j owns the points ``start[j]:start[j + 1]``.
        points: (N, 2) UAV horizontal positions; heights: their heights, one number or (N,).
        tol: shrink distance (m) of the polytopes (negative: grown), see
            :data:`~covert_env.world.visibility.LOS_TOLERANCE`.

    Returns:
        (N,) bool, True = blocked.
    """
    return segments_blocked(terrain_table(hs, cx, cy, radius, z_top, growth), targets, rows, start, points, heights,
                            tol)


def segments_blocked(table: TerrainTable, targets: np.ndarray, rows: np.ndarray, start: np.ndarray,
                     points: np.ndarray, heights, tol: float) -> np.ndarray:
    """:func:`blocked_segments` on a :class:`TerrainTable` (the terrain arrays checked once, read by many calls)."""
    if not isinstance(table, TerrainTable):
        raise TypeError(f"segments_blocked: table must be a TerrainTable (terrain_table(...)), got "
                        f"{type(table).__name__}")
    targets, rows = _checked_targets("blocked_segments", table, targets, rows)
    points, start = _c(points, np.float64), _c(start, np.int64)
    heights = _c(np.atleast_1d(np.asarray(heights, dtype=np.float64)).reshape(-1), np.float64)
    if start.shape != (len(targets) + 1,) or points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"blocked_segments: start must be (T + 1,) and points (N, 2) with targets (T, 3); got "
                         f"{start.shape}, {points.shape}, {targets.shape}")
    if _layout_error(rows, start, len(table.hs), len(points)) == 1:
        raise ValueError(f"blocked_segments: start must rise from 0 to the number of points ({len(points)})")
    if len(heights) not in (1, len(points)):
        raise ValueError(f"blocked_segments: heights must be one number or one per point ({len(points)}), "
                         f"got {len(heights)}")
    out = np.zeros(len(points), dtype=bool)
    if len(points) and table.hs.shape[1]:
        _kernel(*table, targets, rows, start, points, heights, float(tol), out)
    return out


def blocked_offsets(hs: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, z_top: np.ndarray,
                    growth: np.ndarray, targets: np.ndarray, rows: np.ndarray, phi: np.ndarray, offsets: np.ndarray,
                    height: float, tol: float) -> np.ndarray:
    """:func:`blocked_segments` of the same offsets about every target: the segment from each target j to the
    point ``to_world(offsets, targets[j, :2], phi[j])`` at ``height``, without building the (T, L, 2) points (the
    maps, lattices and start candidates of every slot of every scene).

    Args:
        hs, cx, cy, radius, z_top, growth: the terrain rows, as :func:`blocked_segments`.
        targets: (T, 3) target positions; rows: (T,) the terrain row of each; phi: (T,) their headings.
        offsets: (L, 2) target-frame offsets (x forward, y to the left).
        height: the points' height; tol: as :func:`blocked_segments`.

    Returns:
        (T, L) bool, True = blocked; the same decisions as :func:`blocked_segments` on
        :func:`~covert_env.geometry.zone.to_world`'s points, which the kernel computes term by term.
    """
    return offsets_blocked(terrain_table(hs, cx, cy, radius, z_top, growth), targets, rows, phi, offsets, height,
                           tol)


def offsets_blocked(table: TerrainTable, targets: np.ndarray, rows: np.ndarray, phi: np.ndarray,
                    offsets: np.ndarray, height: float, tol: float) -> np.ndarray:
    """:func:`blocked_offsets` on a :class:`TerrainTable` (the terrain arrays checked once, read by many calls)."""
    if not isinstance(table, TerrainTable):
        raise TypeError(f"offsets_blocked: table must be a TerrainTable (terrain_table(...)), got "
                        f"{type(table).__name__}")
    phi = _c(np.asarray(phi, dtype=np.float64).reshape(-1), np.float64)
    offsets = _c(offsets, np.float64)
    if offsets.ndim != 2 or offsets.shape[1] != 2 or phi.shape != (len(targets),):
        raise ValueError(f"blocked_offsets: offsets must be (L, 2) and phi (T,) with targets (T, 3); got "
                         f"{offsets.shape}, {phi.shape}, {np.shape(targets)}")
    targets, rows = _checked_targets("blocked_offsets", table, targets, rows)
    height = np.asarray(height, dtype=np.float64)
    if height.shape != ():
        raise ValueError(f"blocked_offsets: height must be one number, got shape {height.shape}")
    out = np.zeros((len(targets), len(offsets)), dtype=bool)
    if out.size and table.hs.shape[1]:
        _kernel_offsets(*table, targets, rows, np.cos(phi), np.sin(phi), offsets, float(height), float(tol), out)
    return out


class TerrainTable(NamedTuple):
    """The terrain rows as the kernels read them (float64, C-contiguous), their shapes checked:
    :func:`terrain_table` builds it; a holder of terrain rows keeps one while its arrays stay the same
    (:class:`~covert_env.world.visibility.TerrainRows`), so a call checks only its own targets and points."""

    hs: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    radius: np.ndarray
    z_top: np.ndarray
    growth: np.ndarray


def terrain_table(hs, cx, cy, radius, z_top, growth) -> TerrainTable:
    """The :class:`TerrainTable` of these arrays (copies only where a dtype or layout differs), after the shape
    checks numba does not make: ``hs`` (R, M, F, 4), the others (R, M)."""
    hs, cx, cy, radius, z_top, growth = (_c(a, np.float64) for a in (hs, cx, cy, radius, z_top, growth))
    n_rows, n_m = hs.shape[:2] if hs.ndim == 4 else (-1, -1)
    if hs.ndim != 4 or hs.shape[3] != 4 or any(a.shape != (n_rows, n_m) for a in (cx, cy, radius, z_top, growth)):
        raise ValueError(f"terrain_table: hs must be (R, M, F, 4) and the circles, tops and growth (R, M); got "
                         f"{hs.shape}, {[a.shape for a in (cx, cy, radius, z_top, growth)]}")
    return TerrainTable(hs, cx, cy, radius, z_top, growth)


def _checked_targets(name, table: TerrainTable, targets, rows):
    """The targets (T, 3) and their rows (T,) as the kernels read them, every row within the table."""
    targets, rows = _c(targets, np.float64), _c(rows, np.int64)
    t = len(targets)
    if targets.shape != (t, 3) or rows.shape != (t,):
        raise ValueError(f"{name}: targets must be (T, 3) and rows (T,); got {targets.shape}, {rows.shape}")
    if _layout_error(rows, np.zeros(t + 1, np.int64), len(table.hs), 0) == 2:
        raise ValueError(f"{name}: rows must lie in [0, {len(table.hs)}), got {rows.min()} to {rows.max()}")
    return targets, rows


@numba.njit(cache=True, nogil=True)
def _layout_error(rows, start, n_rows, n_points):  # pragma: no cover
    """0 if ``start`` rises from 0 to ``n_points`` and every row lies in ``[0, n_rows)``; 1 (start) or 2 (rows)
    otherwise: the index checks of :func:`blocked_segments`, compiled (a few ns per target, not µs per call)."""
    if start[0] != 0 or start[len(start) - 1] != n_points:
        return 1
    for j in range(len(rows)):
        if start[j + 1] < start[j]:
            return 1
        if rows[j] < 0 or rows[j] >= n_rows:
            return 2
    return 0


def _c(a, dtype) -> np.ndarray:
    """``a`` as a C-contiguous, writable array of ``dtype`` (a copy only if needed): one compiled signature."""
    a = np.asarray(a)
    if a.dtype != dtype or not a.flags.c_contiguous or not a.flags.writeable:
        a = np.array(a, dtype=dtype, order="C")
    return a
