"""Batched scene generation: the roads and terrains of B random scenes, each step one array operation.

``random_roads`` and ``random_terrains`` draw B scenes at once (through ``scenario.random_scene_arrays`` and
``scenario.random_worlds``): roads as (B, P, 2) arrays, polytopes as padded
(B, M, V, ...) arrays placed by rejection in rounds (every unplaced polytope of every scene proposes a placement
per round; a proposal is kept when it is clear of the road and of every placed polytope and of the proposals that
come before it), tops and faces in closed form. No Python loop runs over scenes, polytopes or vertices; the rounds
are few (most polytopes are placed in the first).

Every random number of a scene is a function of its seed, a stream and a counter (SplitMix64, :func:`uniforms`),
so a scene does not depend on the batch it is drawn in or on the process: ``random_worlds([s])`` is row ``i`` of
``random_worlds(seeds)`` wherever ``seeds[i] == s``. The generator's rules are those of
docs/decisions/world.md#terrain-generator; its invariants (tested for every family): footprints convex and
counter-clockwise, at least ``MIN_GAP`` apart; every footprint's circumcircle at least ``road_clearance`` from the
road's centreline; tops in ``[min_height, max_polytope_height]`` and inside the footprint's plan view.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from covert_env.world.config import SCENE_ROAD_LEAD_IN, SCENE_ROAD_TAIL, Config

__all__ = ["MIN_GAP", "ROAD_STEP", "TerrainBatch", "frustum_faces", "polygon_gap", "random_roads", "random_terrains",
           "uniforms"]

#: (decided) Smallest gap (m) between two footprints (streets between buildings); these rules are shared by the
#: sequential generator (``Terrain.random``).
MIN_GAP = 2.0
#: Spacing (m) of a random road's points.
ROAD_STEP = 2.0
#: Share of slanted hills among the polytopes; the others are flat-topped buildings.
HILL_FRACTION = 0.4
#: Top of a building: the base shrunk about its centroid by a factor in this range; of a hill, the pyramid's cut.
BUILDING_SHRINK = (0.8, 0.95)
HILL_SHRINK = (0.35, 0.75)
#: Slope of a hill's cutting plane, as a share of the height the cut leaves.
HILL_TILT = (0.3, 0.8)
#: Rounds of proposals in one attempt at placing a scene's polytopes; the second half of an attempt may place a
#: polytope anywhere along the road, not only in its own stretch.
MAX_ROUNDS = 200
#: Attempts of MAX_ROUNDS rounds each at placing a scene's polytopes: a scene left incomplete starts again.
MAX_ATTEMPTS = 5

# Stream numbers: one per kind of draw, so that adding a draw of one kind leaves the others' numbers alone.
_ROAD, _TERRAIN = 1, 2
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _splitmix(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser on uint64 arrays (wrapping arithmetic)."""
    with np.errstate(over="ignore"):
        z = x + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def uniforms(seeds, stream, n: int) -> np.ndarray:
    """(..., n) floats in [0, 1), the ``n`` numbers of ``stream`` for each seed: ``seeds`` and ``stream`` are
    integer arrays (>= 0) broadcast together. The same (seed, stream, index) always gives the same number."""
    key = _splitmix(_splitmix(np.asarray(seeds, dtype=np.uint64)) ^ np.asarray(stream, dtype=np.uint64))
    with np.errstate(over="ignore"):
        x = _splitmix(key[..., None] + np.arange(n, dtype=np.uint64) * _GOLDEN)
    return (x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def _normal(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Standard normals from pairs of uniforms (Box-Muller)."""
    return np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2.0 * math.pi * u2)


# ----------------------------------------------------------------------------- roads
def random_roads(seeds, config: Config, start=(-20.0, 0.0), heading: float = 0.0,
                 straight_start: float = SCENE_ROAD_LEAD_IN + 30.0) -> np.ndarray:
    """(B, P, 2) the scenes' road points, every ``ROAD_STEP`` metres from ``start`` along ``heading``.

    The heading integrates a smooth random curvature: four sinusoids of wavelengths 150-600 m, scaled so that the
    largest |curvature| is ``config.road_max_curvature`` times U(0.4, 1); straight for the first
    ``straight_start`` metres, then eased in over 40 m. The road is the scenario's length
    (:func:`~covert_env.world.config.scene_road_length`)."""
    c = config
    travel = c.target_speed * c.delta * (c.n_slots + c.horizon + 1)
    length = SCENE_ROAD_LEAD_IN + travel + SCENE_ROAD_TAIL
    n = max(2, int(np.ceil(length / ROAD_STEP)) + 1)
    s = np.arange(n) * ROAD_STEP
    u = uniforms(np.asarray(seeds), _ROAD, 17)                                       # (B, 17)
    wavelength = 150.0 + 450.0 * u[:, 0:4]
    amplitude = _normal(u[:, 4:8], u[:, 8:12])
    phase = 2.0 * math.pi * u[:, 12:16]
    kappa = (amplitude[:, :, None] * np.sin(2.0 * math.pi * s / wavelength[:, :, None] + phase[:, :, None])).sum(1)
    peak = np.maximum(np.abs(kappa).max(axis=1, keepdims=True), 1e-12)
    kappa *= c.road_max_curvature / peak * (0.4 + 0.6 * u[:, 16:17])
    kappa *= np.clip((s - straight_start) / 40.0, 0.0, 1.0)
    th = heading + np.concatenate([np.zeros((len(u), 1)), np.cumsum(kappa[:, :-1] * ROAD_STEP, axis=1)], axis=1)
    steps = ROAD_STEP * np.stack([np.cos(th[:, :-1]), np.sin(th[:, :-1])], axis=-1)
    return np.asarray(start, float) + np.concatenate([np.zeros((len(u), 1, 2)), np.cumsum(steps, axis=1)], axis=1)


# ----------------------------------------------------------------------------- geometry helpers
def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b`` (all (..., 2), broadcast)."""
    ab = b - a
    ap = p - a
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    d = ap - t[..., None] * ab
    return np.sqrt((d * d).sum(-1))


#: Every COARSE-th road point is a coarse point: a road point lies within COARSE * ROAD_STEP / 2 of one.
COARSE = 5
#: Road segments on each side of a proposal's own whose distance is computed exactly.
WINDOW = 30


def _road_clear(centres: np.ndarray, scene: np.ndarray, idx: np.ndarray, roads: np.ndarray,
                need: np.ndarray) -> np.ndarray:
    """(N,) whether each centre (N, 2), proposed beside segment ``idx`` (N,) of its scene's road (``roads[scene]``),
    is at least ``need`` (N,) from that whole road.

    Exact against the WINDOW segments on each side of its own; the rest of the road (where it comes back) through
    its coarse points: none closer than ``need + COARSE * ROAD_STEP / 2`` leaves every road point far enough, and
    the few centres with a closer one are checked against every segment. One compiled loop per centre, which
    stops at the first segment closer than ``need``; the distances are :func:`_segment_distance`'s, bit for bit."""
    centres, roads, need = (np.ascontiguousarray(a, dtype=np.float64) for a in (centres, roads, need))
    scene, idx = np.ascontiguousarray(scene, dtype=np.int64), np.ascontiguousarray(idx, dtype=np.int64)
    n = len(centres)
    if centres.shape != (n, 2) or scene.shape != (n,) or idx.shape != (n,) or need.shape != (n,) \
            or roads.ndim != 3 or roads.shape[1] < 2 or roads.shape[2] != 2:
        raise ValueError(f"_road_clear: centres (N, 2), scene, idx and need (N,), roads (B, P >= 2, 2); got "
                         f"{centres.shape}, {scene.shape}, {idx.shape}, {need.shape}, {roads.shape}")
    # The kernel checks no bounds: every index it reads is checked here.
    if n and (scene.min() < 0 or scene.max() >= len(roads) or idx.min() < 0 or idx.max() > roads.shape[1] - 2):
        raise ValueError(f"_road_clear: scene must lie in [0, {len(roads)}) and idx in [0, {roads.shape[1] - 2}]")
    ok = np.empty(n, dtype=bool)
    _road_clear_kernel(centres, scene, idx, roads, need, WINDOW, COARSE, COARSE * ROAD_STEP / 2, ok)
    return ok


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _distance_below(px, py, ax, ay, bx, by, need):  # pragma: no cover
    """Whether the distance from (px, py) to segment a-b is below ``need``: :func:`_segment_distance`'s
    arithmetic, term by term (no fused multiply-add)."""
    abx, aby = bx - ax, by - ay
    apx, apy = px - ax, py - ay
    den = abx * abx + aby * aby
    t = (apx * abx + apy * aby) / (den if den >= 1e-300 else 1e-300)
    t = t if t >= 0.0 else 0.0                           # np.clip(., 0, 1): maximum, then minimum
    t = t if t <= 1.0 else 1.0
    dx, dy = apx - t * abx, apy - t * aby
    return np.sqrt(dx * dx + dy * dy) < need


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _road_clear_kernel(centres, scene, idx, roads, need, window, coarse, slack, ok):  # pragma: no cover
    """:func:`_road_clear` into ``ok``."""
    n_seg = roads.shape[1] - 1
    for n in range(len(centres)):
        px, py = centres[n, 0], centres[n, 1]
        road = roads[scene[n]]
        lo = min(max(idx[n] - window, 0), max(n_seg - 2 * window - 1, 0))
        clear = True
        for w in range(2 * window + 1):                   # the window: exact
            j = min(lo + w, n_seg - 1)
            if _distance_below(px, py, road[j, 0], road[j, 1], road[j + 1, 0], road[j + 1, 1], need[n]):
                clear = False
                break
        if clear:
            # Outside the window, through the coarse points; a close one sends the centre to every segment.
            reach = need[n] + slack
            reach = reach * reach                        # numpy's ** 2
            close = False
            for ci in range(0, n_seg + 1, coarse):
                if lo + coarse <= ci <= lo + 2 * window + 1 - coarse:
                    continue
                dx, dy = road[ci, 0] - px, road[ci, 1] - py
                if dx * dx + dy * dy < reach:
                    close = True
                    break
            if close:
                for j in range(n_seg):
                    if _distance_below(px, py, road[j, 0], road[j, 1], road[j + 1, 0], road[j + 1, 1], need[n]):
                        clear = False
                        break
        ok[n] = clear


def polygon_gap(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(N,) the distance between convex polygons ``p`` and ``q`` (N, V, 2), 0 where they overlap; vertices may
    repeat (padding). Separating-axis test on both polygons' edge normals, then vertex-to-edge distances."""
    def edges(poly):
        return poly, np.roll(poly, -1, axis=1)

    def separated(a, b):
        e0, e1 = edges(a)
        normal = np.stack([e1[..., 1] - e0[..., 1], e0[..., 0] - e1[..., 0]], axis=-1)     # (N, V, 2)
        pa = np.einsum("nvk,nwk->nvw", normal, a)
        pb = np.einsum("nvk,nwk->nvw", normal, b)
        return ((pa.max(-1) < pb.min(-1)) | (pb.max(-1) < pa.min(-1))).any(axis=1)

    apart = separated(p, q) | separated(q, p)
    p0, p1 = edges(p)
    q0, q1 = edges(q)
    d_pq = _segment_distance(p[:, :, None], q0[:, None], q1[:, None]).min(axis=(1, 2))
    d_qp = _segment_distance(q[:, :, None], p0[:, None], p1[:, None]).min(axis=(1, 2))
    return np.where(apart, np.minimum(d_pq, d_qp), 0.0)


class TerrainBatch:
    """The polytopes of B scenes, M each, padded to V vertices (the last real vertex repeated).

    Attributes:
        base (B, M, V, 2): footprints, counter-clockwise; top (B, M, V, 3): the tops above them (``top[..., j]``
        above ``base[..., j]``, a planar top cut from the pyramid over the base, so every side face is planar);
        n_vertices (B, M); centre (B, M, 2) and radius (B, M): circles enclosing the footprints.
    """

    def __init__(self, base, top, n_vertices, centre, radius):
        self.base, self.top, self.n_vertices = base, top, n_vertices
        self.centre, self.radius = centre, radius


def _footprints(u: np.ndarray, k: np.ndarray, r: np.ndarray, v: int) -> np.ndarray:
    """(N, V, 2) footprints about the origin: k vertices on an ellipse of semi-axes r and r U(0.6, 1) at jittered,
    increasing angles, randomly rotated (convex and counter-clockwise: in order along a convex curve), padded."""
    j = np.minimum(np.arange(v), k[:, None] - 1)
    ang = 2.0 * math.pi * (j + 0.6 * u[:, 5:5 + v][np.arange(len(k))[:, None], j] - 0.3) / k[:, None]
    minor = 0.6 + 0.4 * u[:, 5 + v]
    pts = np.stack([r[:, None] * np.cos(ang), (r * minor)[:, None] * np.sin(ang)], axis=-1)
    rot = 2.0 * math.pi * u[:, 6 + v]
    cs, sn = np.cos(rot)[:, None], np.sin(rot)[:, None]
    return np.stack([cs * pts[..., 0] - sn * pts[..., 1], sn * pts[..., 0] + cs * pts[..., 1]], axis=-1)


def _tops(base: np.ndarray, u: np.ndarray, zmin: float, zmax: float) -> np.ndarray:
    """(N, V, 3) tops cut from the pyramid over each base (apex above its centroid) by a plane: flat for buildings,
    slanted for hills, so every side face stays planar; scaled so that every top z lies in [zmin, zmax]."""
    nxt = np.roll(base, -1, axis=1)
    cross = base[..., 0] * nxt[..., 1] - nxt[..., 0] * base[..., 1]     # padding repeats a vertex: adds 0
    area = 0.5 * cross.sum(1)
    c = np.stack([((base[..., 0] + nxt[..., 0]) * cross).sum(1), ((base[..., 1] + nxt[..., 1]) * cross).sum(1)],
                 axis=-1) / (6.0 * area[:, None])
    hill = u[:, 0] < HILL_FRACTION
    lo = np.where(hill, HILL_SHRINK[0], BUILDING_SHRINK[0])
    hi = np.where(hill, HILL_SHRINK[1], BUILDING_SHRINK[1])
    z0 = 1.0 - (lo + u[:, 1] * (hi - lo))                     # the plane's height above the centroid; apex at 1
    slope = 2.0 * math.pi * u[:, 2]
    q = ((base - c[:, None]) * np.stack([np.cos(slope), np.sin(slope)], -1)[:, None]).sum(-1)       # (N, V)
    tilt = np.where(hill, HILL_TILT[0] + u[:, 3] * (HILL_TILT[1] - HILL_TILT[0]), 0.0)
    # Halve the tilt until the tops fit in [zmin, zmax] (at most 8 times, then flat): all 8 at once.
    tilts = tilt[:, None] * 0.5 ** np.arange(8)                                      # (N, 8)
    p = (tilts * z0[:, None] / np.maximum(np.abs(q).max(1), 1e-12)[:, None])[..., None] * q[:, None]
    lam = (z0[:, None, None] + p) / (1.0 + p)                                         # (N, 8, V)
    ratio = lam.max(-1) / lam.min(-1)
    fits = zmin * ratio <= zmax
    first = np.argmax(fits, axis=1)
    rows = np.arange(len(base))
    lam = np.where(fits.any(1)[:, None], lam[rows, first], z0[:, None])
    ratio = np.where(fits.any(1), ratio[rows, first], 1.0)
    low = zmin * ratio
    top_z = np.where(low < zmax, low + u[:, 4] * (zmax - low), zmax)
    z = np.clip(lam * (top_z / lam.max(1))[:, None], zmin, zmax)
    xy = base + lam[..., None] * (c[:, None] - base)
    return np.concatenate([xy, z[..., None]], axis=-1)


def frustum_faces(base: np.ndarray, top: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N, V + 2, 4) the faces ``[nx, ny, nz, d]`` (unit outward normals, ``n.x + d <= 0`` inside) of frustums with
    padded bases (N, V, 2) and tops (N, V, 3), ``k`` (N,) real vertices: the base (z = 0), the planar top and one
    planar side per base edge, in the order of ``Polytope.halfspaces`` for a frustum; the rest padded with the
    always-true row ``[0, 0, 0, -1]``."""
    n, v = base.shape[:2]
    j = np.arange(v)
    real = j[None] < k[:, None]
    nj = np.where(j[None] + 1 < k[:, None], j[None] + 1, 0)                         # edge j ends at vertex j + 1
    rows = np.arange(n)[:, None]
    b1, t1 = base[rows, nj], top[rows, nj]
    out = np.zeros((n, v + 2, 4))
    out[:, 0, 2] = -1.0                                                              # the base, z = 0
    top_n = np.stack([((top[..., 1] * t1[..., 2] - top[..., 2] * t1[..., 1]) * real).sum(1),      # Newell's
                      ((top[..., 2] * t1[..., 0] - top[..., 0] * t1[..., 2]) * real).sum(1),      # normal
                      ((top[..., 0] * t1[..., 1] - top[..., 1] * t1[..., 0]) * real).sum(1)], axis=-1)
    out[:, 1, :3] = top_n / np.sqrt((top_n ** 2).sum(axis=1))[:, None]
    out[:, 1, 3] = -(out[:, 1, :3] * ((top * real[..., None]).sum(1) / k[:, None])).sum(1)
    e = b1 - base                                                                    # base edge j (z = 0)
    w = top - np.concatenate([base, np.zeros((n, v, 1))], axis=-1)                   # base vertex j -> top vertex j
    side = np.stack([e[..., 1] * w[..., 2], -e[..., 0] * w[..., 2], e[..., 0] * w[..., 1] - e[..., 1] * w[..., 0]],
                    axis=-1)                                                         # e x w: outward (CCW base)
    side /= np.maximum(np.sqrt((side ** 2).sum(axis=-1)), 1e-300)[..., None]
    out[:, 2:, :3] = np.where(real[..., None], side, 0.0)
    out[:, 2:, 3] = np.where(real, -(side[..., 0] * base[..., 0] + side[..., 1] * base[..., 1]), -1.0)
    return out


# ----------------------------------------------------------------------------- terrains
def random_terrains(seeds, roads: np.ndarray, config: Config) -> TerrainBatch:
    """The polytopes of B scenes along their roads (B, P, 2): ``config.n_polytopes`` each.

    Polytope i is proposed at a random arc length in the i-th of M equal stretches of the road (anywhere in the
    second half of an attempt's :data:`MAX_ROUNDS`), on a random side, its circumcircle at least
    ``road_clearance`` from the centreline and, radius permitting, its centre within ``road_max_offset`` of it; a
    proposal is kept if that circle clears the whole road, and the footprint is at least :data:`MIN_GAP` from every
    kept footprint and from the proposals of lower index in its round. A scene not complete after an attempt starts
    again with the next rounds' numbers; raises ValueError naming the seeds whose polytopes could not all be placed
    in :data:`MAX_ATTEMPTS` attempts."""
    c = config
    seeds = np.asarray(seeds, dtype=np.int64)
    b, m, v = len(seeds), c.n_polytopes, c.max_vertices
    placed = np.zeros((b, m), bool)
    base = np.zeros((b, m, v, 2))
    centre = np.zeros((b, m, 2))
    radius = np.zeros((b, m))
    k = np.full((b, m), 3)
    draws = np.zeros((b, m, 12 + v))
    seg = np.diff(roads, axis=1)
    seg_len = np.sqrt((seg * seg).sum(-1))
    arc = np.concatenate([np.zeros((b, 1)), np.cumsum(seg_len, axis=1)], axis=1)
    length = arc[:, -1]
    for rnd in range(MAX_ROUNDS * MAX_ATTEMPTS):
        if rnd and rnd % MAX_ROUNDS == 0:
            # A scene left incomplete after an attempt starts again, with the next rounds' numbers: rare (2 dense
            # scenes in 10,000), and the scenes complete in the first attempt are the same as with one attempt.
            placed[~placed.all(axis=1)] = False
        sb, si = np.nonzero(~placed)
        if len(sb) == 0:
            break
        u = uniforms(seeds[sb], _TERRAIN + 16 * (rnd * (m + 1) + si + 1), 12 + v)
        stretch = rnd % MAX_ROUNDS < MAX_ROUNDS // 2
        s = (np.where(stretch, (si + u[:, 0]) / m, u[:, 0])) * length[sb]
        kk = c.min_vertices + np.minimum((u[:, 1] * (c.max_vertices - c.min_vertices + 1)).astype(int),
                                         c.max_vertices - c.min_vertices)
        r = c.min_radius + u[:, 2] * (c.max_radius - c.min_radius)
        near = c.road_clearance + r
        off = (near + u[:, 3] * np.maximum(c.road_max_offset - r - near, 0.0)) * np.where(u[:, 4] < 0.5, -1.0, 1.0)
        idx = np.clip((s / ROAD_STEP).astype(int), 0, roads.shape[1] - 2)              # points ROAD_STEP apart
        frac = (s - arc[sb, idx]) / seg_len[sb, idx]
        d = seg[sb, idx] / seg_len[sb, idx, None]
        point = roads[sb, idx] + frac[:, None] * seg[sb, idx]
        cen = point + off[:, None] * np.stack([-d[:, 1], d[:, 0]], axis=-1)
        poly = _footprints(u, kk, r, v) + cen[:, None]
        ok = _road_clear(cen, sb, idx, roads, near)
        # Against the kept footprints, then, among the proposals left, the earlier ones (lower index) of the same
        # scene: circles first, then the footprints' exact gap. Per proposal, against the M slots of its scene.
        cand_c, cand_r = centre[sb], radius[sb]                                      # (N, M, ...) copies
        prop = np.zeros((b, m), bool)
        prop[sb, si] = ok
        slot = np.full((b, m), -1)
        slot[sb, si] = np.arange(len(sb))
        own = slot[sb]                                                                # (N, M): proposal index or -1
        has = own >= 0
        cand_c[has] = cen[own[has]]
        cand_r[has] = r[own[has]]
        dist = np.sqrt(((cand_c - cen[:, None]) ** 2).sum(-1))                       # (N, M)
        near_pair = dist < cand_r + r[:, None] + MIN_GAP
        earlier = np.arange(m)[None, :] < si[:, None]
        for rival in (placed[sb], earlier):
            pn, pj = np.nonzero(near_pair & rival & (placed[sb] | prop[sb]) & prop[sb, si][:, None])
            if len(pn):
                other = np.where((own[pn, pj] >= 0)[:, None, None], poly[own[pn, pj]], base[sb[pn], pj])
                close = polygon_gap(poly[pn], other) < MIN_GAP
                prop[sb[pn[close]], si[pn[close]]] = False
        keep = prop[sb, si]
        kb, ki = sb[keep], si[keep]
        placed[kb, ki] = True
        base[kb, ki], centre[kb, ki], radius[kb, ki], k[kb, ki] = poly[keep], cen[keep], r[keep], kk[keep]
        draws[kb, ki] = u[keep]
    if not placed.all():
        bad = seeds[~placed.all(axis=1)].tolist()
        raise ValueError(f"random scenes {bad[:5]}{'...' if len(bad) > 5 else ''}: could not place all "
                         f"{m} polytopes (Config.n_polytopes) in {MAX_ATTEMPTS} attempts of {MAX_ROUNDS} rounds; "
                         f"use fewer polytopes, a "
                         f"smaller max_radius ({c.max_radius:g}) or road_clearance ({c.road_clearance:g})")
    flat_base = base.reshape(b * m, v, 2)
    top = _tops(flat_base, draws.reshape(b * m, 12 + v)[:, 7 + v:], c.min_height, c.max_polytope_height)
    return TerrainBatch(base, top.reshape(b, m, v, 3), k, centre, radius)
