"""Timing of the geometry kernels: shadows + visible zone per slot, line of sight per point.

Run ``python benchmarks/geometry.py`` (``--help`` for options). Prints a small table:

* per-slot time (ms, median over ``--slots`` slots of a target driving along the road) of the eq. 5 zone,
  the eq. 8-9 shadows and the eq. 10 visible zone, on the paper-like terrain (``Terrain.random``);
* ``line_of_sight`` microseconds per point for 10^3 and 10^5 UAV points within R2 of the target, on
  the paper-like terrain (16 polytopes along the road) and on a dense scene (16 polytopes all within
  120 m of the target: the worst case for the broad phase), single-threaded numpy;
* ``Terrain.load`` of a GeoJSON city of ``--city`` flat-topped buildings on a grid (the overlap check is
  an R-tree query; 0 skips it).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from covert_env import Config, Road, TargetTrack, Terrain  # noqa: E402
from covert_env.geometry.zone import feasible_zone, visible_zone  # noqa: E402
from covert_env.world.shadows import shadow_polygons  # noqa: E402
from covert_env.world.terrain import Polytope  # noqa: E402
from covert_env.world.visibility import line_of_sight  # noqa: E402


def _fallback_polytope(rng: np.random.Generator, centre: np.ndarray, radius: float) -> Polytope:
    n = int(rng.integers(4, 9))
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    while np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi])).min() < 0.3:
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    base = centre + radius * np.column_stack([np.cos(ang), np.sin(ang)])
    c = base.mean(axis=0)
    top_xy = c + rng.uniform(0.5, 0.9) * (base - c)
    z0 = rng.uniform(25, 60)
    g = rng.uniform(-0.3, 0.3, 2)
    return Polytope(base, np.column_stack([top_xy, np.clip(z0 + (top_xy - c) @ g, 20, 70)]))


def paper_like_terrain(seed: int, road: Road, cfg: Config) -> tuple[Terrain, str]:
    """``Terrain.random`` when available, else 16 random polytopes beside the road."""
    try:
        return Terrain.random(seed=seed, road=road, config=cfg), "Terrain.random"
    except (AttributeError, TypeError):
        pass
    rng = np.random.default_rng(seed)
    polys: list[tuple[np.ndarray, float]] = []
    while len(polys) < cfg.n_polytopes:
        s = rng.uniform(0, road.length)
        p, phi = road.point_at(s), road.heading_at(s)
        r = rng.uniform(cfg.min_radius, cfg.max_radius)
        side = rng.choice([-1.0, 1.0])
        c = p + side * (r + cfg.road_clearance + rng.uniform(0, 40)) * np.array([-np.sin(phi), np.cos(phi)])
        overlap = any(np.hypot(*(c - c2)) < r + r2 + 2 for c2, r2 in polys)
        if overlap or road.distance_to(c) < r + cfg.road_clearance:
            continue
        polys.append((c, r))
    return Terrain([_fallback_polytope(rng, c, r) for c, r in polys]), "fallback generator"


def dense_terrain(seed: int) -> Terrain:
    """16 non-overlapping polytopes 20-120 m around the origin."""
    rng = np.random.default_rng(seed)
    polys: list[tuple[np.ndarray, float]] = []
    while len(polys) < 16:
        r, d, a = rng.uniform(5, 15), rng.uniform(20, 120), rng.uniform(0, 2 * np.pi)
        c = d * np.array([np.cos(a), np.sin(a)])
        if d - r < 4 or any(np.hypot(*(c - c2)) < r + r2 + 1 for c2, r2 in polys):
            continue
        polys.append((c, r))
    return Terrain([_fallback_polytope(rng, c, r) for c, r in polys])


def city_load_seconds(n: int) -> tuple[int, float]:
    """(buildings, seconds) for ``Terrain.load`` of a file of about ``n`` 8 m squares on a 12 m grid."""
    import json
    import tempfile

    side = max(1, round(math.sqrt(n)))
    feats = []
    for k in range(side * side):
        x, y = 12.0 * (k // side), 12.0 * (k % side)
        ring = [[x, y], [x + 8, y], [x + 8, y + 8], [x, y + 8], [x, y]]
        feats.append({"type": "Feature", "id": k, "properties": {"height": 10.0 + k % 7},
                      "geometry": {"type": "Polygon", "coordinates": [ring]}})
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "city.geojson")
        with open(path, "w") as f:
            json.dump({"type": "FeatureCollection", "features": feats}, f)
        t0 = time.perf_counter()
        terrain = Terrain.load(path, altitude=80.0)
        return len(terrain), time.perf_counter() - t0


def _median_time(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=None,
                    help="a random scene's seed (default: the paper scenario, Scenario.paper)")
    ap.add_argument("--slots", type=int, default=50, help="slots for the per-slot timing (default 50)")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of each LoS timing (median)")
    ap.add_argument("--city", type=int, default=20_000, help="buildings in the Terrain.load timing (0: skip)")
    args = ap.parse_args(argv)

    cfg = Config()
    if args.seed is None:
        from covert_env.world.scenario import Scenario

        scenario = Scenario.paper(cfg)
        terrain, track, source = scenario.terrain, scenario.track, "Scenario.paper"
        args.seed = 0
    else:
        road = Road.random(args.seed)
        terrain, source = paper_like_terrain(args.seed, road, cfg)
        track = TargetTrack.constant(road, cfg.target_speed, args.slots + 1, z=cfg.target_height)
    radius = cfg.r2 + cfg.shadow_margin

    # --- per slot: zone (eq. 5), shadows (eqs. 8-9), visible zone (eq. 10)
    slot_ms, n_shadows, vis_area = [], [], []
    for k in range(args.slots):
        q, phi = track.position(k), float(track.heading(k))

        def one_slot(q=q, phi=phi):
            zone = feasible_zone(q[:2], phi, cfg.r1, cfg.r2, cfg.mu, cfg.r_u)
            shadows = shadow_polygons(terrain, q, cfg.altitude, radius, h_min=cfg.h_min)
            return zone, shadows, visible_zone(zone, shadows)

        one_slot()                                      # warm the per-terrain cache
        slot_ms.append(1e3 * _median_time(one_slot, 3))
        zone, shadows, vis = one_slot()
        n_shadows.append(sum(not s.is_empty for s in shadows))
        vis_area.append(vis.area / zone.area)

    # --- line of sight per point
    rng = np.random.default_rng(args.seed)
    k_busy = int(np.argmax(n_shadows))
    scenes = [("paper" if source == "Scenario.paper" else "paper-like", terrain, track.position(k_busy)),
              ("dense", dense_terrain(args.seed), np.array([0.0, 0.0, cfg.target_height]))]
    los_rows = []
    for name, ter, q in scenes:
        for n in (10**3, 10**5):
            r, a = cfg.r2 * np.sqrt(rng.uniform(size=n)), rng.uniform(0, 2 * math.pi, n)
            xy = q[:2] + np.column_stack([r * np.cos(a), r * np.sin(a)])
            line_of_sight(ter, xy, cfg.altitude, q)
            qs = np.broadcast_to(q, (n, 3))              # one target per point: the general path
            t, tg = (_median_time(lambda ter=ter, xy=xy, tq=tq: line_of_sight(ter, xy, cfg.altitude, tq),
                                  args.repeat) for tq in (q, qs))
            blocked = 1 - line_of_sight(ter, xy, cfg.altitude, q).mean()
            los_rows.append((name, len(ter), n, 1e6 * t / n, 1e6 * tg / n, blocked))

    print(f"terrain: {source}, seed {args.seed}, {len(terrain)} polytopes; python {sys.version.split()[0]}, "
          f"numpy {np.__version__}")
    print()
    print(f"per slot over {args.slots} slots (target at {cfg.target_speed:g} m/s along the road)")
    print(f"  {'zone + shadows + visible zone':32s} median {np.median(slot_ms):7.3f} ms   "
          f"max {np.max(slot_ms):7.3f} ms")
    print(f"  {'shadows in range per slot':32s} median {np.median(n_shadows):7.1f}      "
          f"max {np.max(n_shadows):5d}")
    print(f"  {'visible / zone area':32s} min    {np.min(vis_area):7.3f}")
    print()
    print("line_of_sight (points uniform within R2 of the target)")
    print(f"  {'scene':12s} {'M':>3s} {'points':>8s} {'us/pt':>8s} {'us/pt per-pt target':>20s} "
          f"{'blocked':>8s}")
    for name, m, n, us, usg, b in los_rows:
        print(f"  {name:12s} {m:3d} {n:8d} {us:8.3f} {usg:20.3f} {b:8.3f}")
    if args.city > 0:
        m, sec = city_load_seconds(args.city)
        print()
        print(f"Terrain.load of a GeoJSON city of {m} buildings: {sec:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
