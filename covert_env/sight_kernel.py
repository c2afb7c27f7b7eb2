"""The line-of-sight kernel (eq. 6): which segments from UAVs to their targets meet a terrain polytope.

Every line-of-sight question of the library -- the env at slot ends and along the flown paths, the observation
maps, the waypoint lattice and the action masks, the planner's states and path checks, the metrics -- is a batch of
segments, each from a UAV position ``p`` to a target position ``q``, each against the terrain of its scene. This
module answers it once, for any batch, with one broad phase and one exact clip:

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

Both broad phases are conservative (circles grown by 1 nm and 1e-9 relative, and by how far a negative ``tol``
grows each polytope: :func:`~covert_env.visibility.growth_factors`): they only drop pairs the clip finds clear, so
the result is the clip's alone. The kernel is compiled with numba (a loop per target, per polytope, per point, that
stops at the first blocking polytope); it runs single-threaded and holds no state between calls.
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
        h_min = heights[0]
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
                low = (top + grow - qz) * inv_hq
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
                top = z_top[r, m] + grow
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
    out = np.zeros(len(points), dtype=bool)
    heights = np.ascontiguousarray(np.atleast_1d(np.asarray(heights, dtype=np.float64)).reshape(-1))
    if len(heights) not in (1, len(points)):
        raise ValueError(f"blocked_segments: heights must be one number or one per point ({len(points)}), "
                         f"got {len(heights)}")
    if len(points) and hs.shape[1]:
        _kernel(np.ascontiguousarray(hs, dtype=np.float64), np.ascontiguousarray(cx, dtype=np.float64),
                np.ascontiguousarray(cy, dtype=np.float64), np.ascontiguousarray(radius, dtype=np.float64),
                np.ascontiguousarray(z_top, dtype=np.float64), np.ascontiguousarray(growth, dtype=np.float64),
                np.ascontiguousarray(targets, dtype=np.float64), np.ascontiguousarray(rows, dtype=np.int64),
                np.ascontiguousarray(start, dtype=np.int64), np.ascontiguousarray(points, dtype=np.float64),
                heights, float(tol), out)
    return out
