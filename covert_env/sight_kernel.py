"""The line-of-sight kernel (eq. 6): which segments from UAVs to their targets meet a terrain polytope.

Every line-of-sight question of the library -- the env at slot ends and along the flown paths, the observation
maps, the waypoint lattice and the action masks, the planner's states and path checks, the metrics -- is a batch of
segments, each from a UAV position ``p`` to a target position ``q``, each against the terrain of its scene. This
module answers it once, for any batch, with one broad phase (per target, then per point) and one exact clip:

* **Layout.** Segments are grouped by target: target j (``targets[j]``, the terrain in row ``rows[j]`` of a
  :class:`~covert_env.visibility.TerrainRows`) owns the points ``points[start[j]:start[j + 1]]``. A batch of copies,
  slots, path instants or lattice nodes is one such flat layout; the callers build it with array operations.
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
:func:`~covert_env.visibility.growth_factors`): it only drops pairs the clip finds clear, so the result is the
clip's alone. (A caller that passes smaller growth factors makes the circle-and-top test part of the result: the
planner's possible targets, :func:`baselines.dp.possible_targets.clear_to_all`, block a pair only where the segment
meets both the pushed-out faces and the widened cylinder.)

The kernel is compiled with numba (a loop per target, per polytope, per point, that stops at the first blocking
polytope); it runs single-threaded and holds no state between calls. numba checks no bounds, so
:func:`blocked_segments` checks every shape and index first.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["blocked_segments"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _kernel(hs, cx, cy, radius, z_top, growth, targets, rows, start, points, heights, tol, out):  # pragma: no cover
    """``out[i]`` = segment i is blocked; arguments as :func:`blocked_segments`."""
    n_faces = hs.shape[2]
    n_m = hs.shape[1]
    one_height = len(heights) == 1
    keep = np.empty(n_m, dtype=np.int64)
    for j in range(len(targets)):
        a, b = start[j], start[j + 1]
        if a == b:
            continue
        r = rows[j]
        qx, qy, qz = targets[j, 0], targets[j, 1], targets[j, 2]
        # The target's points: their farthest horizontal distance and lowest height.
        d2_max = 0.0
        h_min = heights[0] if one_height else heights[a]
        for i in range(a, b):
            dx = points[i, 0] - qx
            dy = points[i, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 > d2_max:
                d2_max = d2
            if not one_height and heights[i] < h_min:
                h_min = heights[i]
        d_max = np.sqrt(d2_max)
        above = h_min > qz
        inv_hq = 1.0 / (h_min - qz) if above else 0.0
        # Per (target, polytope): within reach of the part of some segment lower than the top?
        n_keep = 0
        for m in range(n_m):
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
        if n_keep == 0:
            continue
        for i in range(a, b):
            ux, uy = points[i, 0], points[i, 1]
            uz = heights[0] if one_height else heights[i]
            ex, ey, dz = qx - ux, qy - uy, qz - uz
            inv_dz = 1.0 / (dz if dz != 0.0 else -1e-300)
            for k in range(n_keep):
                m = keep[k]
                grow = growth[r, m] * -tol if tol < 0.0 else 0.0
                rad = radius[r, m] + grow + 1e-9
                # The parameter range [s0, s1] (s = 0 at the UAV) where the segment is lower than the grown top.
                top = z_top[r, m] + grow + 1e-9
                sc = (top - uz) * inv_dz
                if dz <= 0.0:
                    s0, s1 = min(max(sc, 0.0), 1.0), 1.0
                else:
                    s0, s1 = 0.0, min(max(sc, 0.0), 1.0)
                if not s1 > s0 - 1e-12:
                    continue
                # Its 2-D part must pass within the footprint circle.
                acx = cx[r, m] - (ux + s0 * ex)
                acy = cy[r, m] - (uy + s0 * ey)
                abx, aby = (s1 - s0) * ex, (s1 - s0) * ey
                ab2 = abx * abx + aby * aby
                w = (acx * abx + acy * aby) / (ab2 if ab2 > 0 else 1.0)
                w = min(max(w, 0.0), 1.0)
                px, py = acx - w * abx, acy - w * aby
                if px * px + py * py > rad * rad:
                    continue
                # The exact clip (Cyrus-Beck) against the polytope shrunk by tol.
                s_in, s_out = 0.0, 1.0
                for f in range(n_faces):
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
                        break
                if s_in <= s_out:
                    out[i] = True
                    break


def blocked_segments(hs: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, z_top: np.ndarray,
                     growth: np.ndarray, targets: np.ndarray, rows: np.ndarray, start: np.ndarray,
                     points: np.ndarray, heights, tol: float) -> np.ndarray:
    """Whether each segment from ``points[i]`` to its target meets a polytope of the target's terrain (eq. 6).

    Args:
        hs: (R, M, F, 4) the polytopes' half-spaces ``n . x + d <= 0`` per terrain row, padded with always-true
            faces (``0 . x - 1``).
        cx, cy, radius: (R, M) their plan-view enclosing circles; z_top: (R, M) their heights (-inf: no polytope).
        growth: (R, M) :func:`~covert_env.visibility.growth_factors` (used when ``tol < 0``).
        targets: (T, 3) target positions; rows: (T,) the terrain row of each target.
        start: (T + 1,) target j owns the points ``start[j]:start[j + 1]``.
        points: (N, 2) UAV horizontal positions; heights: their heights, one number or (N,).
        tol: shrink distance (m) of the polytopes (negative: grown), see
            :data:`~covert_env.visibility.LOS_TOLERANCE`.

    Returns:
        (N,) bool, True = blocked.
    """
    hs, cx, cy, radius, z_top, growth, targets, points = (
        _c(a, np.float64) for a in (hs, cx, cy, radius, z_top, growth, targets, points))
    rows, start = _c(rows, np.int64), _c(start, np.int64)
    heights = _c(np.atleast_1d(np.asarray(heights, dtype=np.float64)).reshape(-1), np.float64)
    # numba checks no bounds: every index the kernel reads is checked here.
    n_rows, n_m = hs.shape[:2] if hs.ndim == 4 else (-1, -1)
    t = len(targets)
    if hs.ndim != 4 or hs.shape[3] != 4 or any(a.shape != (n_rows, n_m) for a in (cx, cy, radius, z_top, growth)):
        raise ValueError(f"blocked_segments: hs must be (R, M, F, 4) and the circles, tops and growth (R, M); got "
                         f"{hs.shape}, {[a.shape for a in (cx, cy, radius, z_top, growth)]}")
    if targets.shape != (t, 3) or rows.shape != (t,) or start.shape != (t + 1,) or points.ndim != 2 \
            or points.shape[1] != 2:
        raise ValueError(f"blocked_segments: targets must be (T, 3), rows (T,), start (T + 1,) and points (N, 2); "
                         f"got {targets.shape}, {rows.shape}, {start.shape}, {points.shape}")
    bad = _layout_error(rows, start, n_rows, len(points))
    if bad == 1:
        raise ValueError(f"blocked_segments: start must rise from 0 to the number of points ({len(points)})")
    if bad == 2:
        raise ValueError(f"blocked_segments: rows must lie in [0, {n_rows}), got {rows.min()} to {rows.max()}")
    if len(heights) not in (1, len(points)):
        raise ValueError(f"blocked_segments: heights must be one number or one per point ({len(points)}), "
                         f"got {len(heights)}")
    out = np.zeros(len(points), dtype=bool)
    if len(points) and n_m:
        _kernel(hs, cx, cy, radius, z_top, growth, targets, rows, start, points, heights, float(tol), out)
    return out


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
