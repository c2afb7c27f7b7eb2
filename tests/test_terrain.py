"""Tests for covert_env.world.terrain: validation, the random generator, GeoJSON I/O and queries."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from covert_env.world.config import Config
from covert_env.world.road import Road
from covert_env.world.terrain import Polytope, Terrain, _check_polytope

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])


def square(x0=0.0, y0=0.0, s=10.0):
    return SQUARE * (s / 10.0) + [x0, y0]


def flat_top(base, h):
    base = np.asarray(base, float)
    return np.column_stack([base, np.full(len(base), h)])


def signed_area(b):
    x, y = b[:, 0], b[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def feature(ring, fid=None, close=True, **props):
    ring = [list(map(float, p)) for p in ring]
    if close:
        ring = ring + [ring[0]]
    f = {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [ring]}}
    if fid is not None:
        f["id"] = fid
    return f


def fc(*features):
    return {"type": "FeatureCollection", "features": list(features)}


def assert_same(t1: Terrain, t2: Terrain):
    assert len(t1) == len(t2)
    for p, q in zip(t1, t2, strict=True):
        np.testing.assert_allclose(p.base, q.base, atol=1e-12)
        np.testing.assert_allclose(p.top, q.top, atol=1e-12)


# ============================================================================ Polytope validation
def test_valid_polytope_and_existing_attributes():
    p = Polytope(SQUARE, flat_top(SQUARE, 30.0))
    assert p.n_vertices == 4
    assert p.z_max == 30.0
    np.testing.assert_allclose(p.centroid_xy, [5, 5])
    assert p.radius_xy == pytest.approx(math.sqrt(50))
    assert p.vertices.shape == (8, 3)
    assert len(p.halfspaces) == 6                      # a box: 6 planar faces
    assert p.footprint.area == pytest.approx(100.0)
    np.testing.assert_array_equal(p.highest_point, [0, 0, 30])
    with pytest.raises(ValueError):
        p.base[0, 0] = 1.0                             # read-only


def test_too_few_vertices():
    with pytest.raises(ValueError, match=r"Polytope: base must have at least 3 vertices, got 2"):
        Polytope([[0, 0], [1, 0]], [[0, 0, 1], [1, 0, 1]])


def test_wrong_shape():
    with pytest.raises(ValueError, match=r"base must be an \(n, 2\) array"):
        Polytope(np.zeros((4, 3)), np.ones((4, 3)))
    with pytest.raises(ValueError, match=r"top must be an \(n, 3\) array"):
        Polytope(SQUARE, SQUARE)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_base_and_top(bad):
    b = SQUARE.copy()
    b[2, 1] = bad
    with pytest.raises(ValueError, match=r"Polytope: base vertex 2 is not finite"):
        Polytope(b, flat_top(SQUARE, 5))
    t = flat_top(SQUARE, 5)
    t[1, 2] = bad
    with pytest.raises(ValueError, match=r"Polytope: top vertex 1 is not finite"):
        Polytope(SQUARE, t)


def test_non_convex_base():
    arrow = np.array([[0, 0], [10, 0], [10, 10], [5, 3], [0, 10]], float)
    with pytest.raises(ValueError, match=r"Polytope: base is not convex \(reflex angle at vertex 3\)"):
        Polytope(arrow, flat_top(arrow, 5))


def test_self_intersecting_base():
    bowtie = np.array([[0, 0], [2, 2], [2, 0], [0, 1]], float)
    with pytest.raises(ValueError, match=r"Polytope: base is self-intersecting"):
        Polytope(bowtie, flat_top(bowtie, 5))
    star = np.array([[math.cos(a), math.sin(a)] for a in 4 * np.pi * np.arange(5) / 5])  # pentagram
    with pytest.raises(ValueError, match=r"base is self-intersecting"):
        Polytope(star, flat_top(star, 5))


def test_zero_area_base():
    line = np.array([[0, 0], [1, 0], [2, 0]], float)
    with pytest.raises(ValueError, match=r"Polytope: base has zero area"):
        Polytope(line, flat_top(line, 5))


def test_repeated_vertex():
    closed = np.vstack([SQUARE, SQUARE[:1]])
    with pytest.raises(ValueError, match=r"base vertices 4 and 0 coincide"):
        Polytope(closed, flat_top(closed, 5))


def test_clockwise_base_is_reoriented_with_top():
    cw = SQUARE[::-1].copy()                           # (0,10), (10,10), (10,0), (0,0): clockwise
    top = np.column_stack([cw * 0.5 + 2.5, [10.0, 20.0, 30.0, 40.0]])   # z tags each vertex
    p = Polytope(cw, top)
    assert signed_area(p.base) > 0
    np.testing.assert_array_equal(p.base[0], cw[0])    # vertex 0 stays first
    assert sorted(map(tuple, p.base)) == sorted(map(tuple, cw))
    # each top vertex still sits above its own base vertex
    for b, t in zip(p.base, p.top, strict=True):
        j = int(np.flatnonzero((cw == b).all(axis=1))[0])
        np.testing.assert_array_equal(t, top[j])
    np.testing.assert_array_equal(p.top[:, 2], [10.0, 40.0, 30.0, 20.0])


def test_top_count_mismatch():
    with pytest.raises(ValueError, match=r"Polytope: top has 3 vertices but base has 4"):
        Polytope(SQUARE, flat_top(SQUARE[:3], 5))


@pytest.mark.parametrize("z", [0.0, -3.0])
def test_top_height_not_positive(z):
    t = flat_top(SQUARE, 5)
    t[2, 2] = z
    with pytest.raises(ValueError, match=r"Polytope: top vertex 2 has z = -?\d+; top heights must be > 0"):
        Polytope(SQUARE, t)


def test_top_outside_footprint():
    t = flat_top(SQUARE, 5)
    t[1, :2] = [10.5, 0.0]
    with pytest.raises(ValueError, match=r"Polytope: top vertex 1 .* lies outside the footprint by 0\.5 m"):
        Polytope(SQUARE, t)
    t[1, :2] = [10.0 + 1e-9, 0.0]                      # within tolerance: accepted
    assert Polytope(SQUARE, t).n_vertices == 4


def test_polytope_altitude():
    p = Polytope(SQUARE, flat_top(SQUARE, 80.0))
    with pytest.raises(ValueError, match=r"Polytope: top vertex 0 has z = 80 >= altitude h = 80"):
        p.validate(altitude=80.0)
    assert p.validate(altitude=80.5) is p
    assert p.validate() is p


def test_prism():
    p = Polytope.prism(SQUARE, 12.0)
    np.testing.assert_array_equal(p.top, flat_top(SQUARE, 12.0))
    with pytest.raises(ValueError, match=r"base must be an \(n, 2\) array"):
        Polytope.prism(np.zeros(4), 12.0)


# ============================================================================ Terrain validation
def test_terrain_overlap_names_both_indices():
    a = Polytope.prism(square(0, 0), 10)
    b = Polytope.prism(square(30, 0), 10)
    c = Polytope.prism(square(5, 5), 10)
    with pytest.raises(ValueError, match=r"Terrain: polytopes 0 and 2: footprints overlap .*area 25 m\^2"):
        Terrain([a, b, c])


def test_terrain_touching_footprints_allowed():
    t = Terrain([Polytope.prism(square(0, 0), 10), Polytope.prism(square(10, 0), 10),
                 Polytope.prism(square(10, 10), 20)])
    assert len(t) == 3
    assert [p.z_max for p in t] == [10, 10, 20]
    assert t[2].z_max == 20
    assert t.bounds == (0.0, 0.0, 20.0, 20.0)


def test_terrain_rejects_non_polytope():
    with pytest.raises(TypeError, match="polytope 1 must be a Polytope"):
        Terrain([Polytope.prism(SQUARE, 3), "house"])


def test_terrain_validate_altitude_names_polytope():
    t = Terrain([Polytope.prism(square(0, 0), 10), Polytope.prism(square(20, 0), 85)])
    with pytest.raises(ValueError, match=r"Terrain: polytope 1: top vertex 0 has z = 85 >= altitude h = 80"):
        t.validate(altitude=80)
    assert t.validate(altitude=90) is t


def test_padded_arrays():
    box = Polytope.prism(square(0, 0), 10)
    tri = Polytope.prism(np.array([[20, 0], [30, 0], [25, 8]], float), 9.0)
    t = Terrain([box, tri])
    assert t.halfspace_array.shape == (2, 6, 4)        # box: 6 faces; triangular prism: 5 + 1 padding row
    np.testing.assert_array_equal(t.halfspace_array[1, 5], [0, 0, 0, -1])
    np.testing.assert_allclose(t.z_max, [10, 9])
    np.testing.assert_allclose(t.highest_points, [[0, 0, 10], [20, 0, 9]])
    assert t.centroids_xy.shape == (2, 2) and t.radii_xy.shape == (2,)
    # a point strictly inside the box satisfies all of its faces (padding rows are always true)
    hs = t.halfspace_array[0]
    assert np.all(hs[:, :3] @ [5, 5, 5] + hs[:, 3] < 0)
    empty = Terrain()
    assert len(empty) == 0 and all(math.isnan(v) for v in empty.bounds)
    assert empty.polytopes_near([0, 0], 100).size == 0


def test_polytopes_near_is_exact():
    polys = [Polytope.prism(square(x, 0), 10) for x in (0, 30, 60)]
    t = Terrain(polys)
    # (25, 5) is 5 m from square 1 (x in [30, 40]) and 15 m from square 0
    np.testing.assert_array_equal(t.polytopes_near([25, 5], 5.0), [1])
    np.testing.assert_array_equal(t.polytopes_near([25, 5], 15.0), [0, 1])
    np.testing.assert_array_equal(t.polytopes_near([25, 5], 4.99), [])
    # corner: the bounding circle of square 2 reaches (52, -2) but the square does not (distance sqrt(68))
    np.testing.assert_array_equal(t.polytopes_near([52, -2], 8.0), [])
    np.testing.assert_array_equal(t.polytopes_near([52, -2], 8.3), [2])
    rng = np.random.default_rng(0)
    for xy in rng.uniform(-20, 90, (30, 2)):
        brute = [i for i, p in enumerate(t) if p.footprint.distance(Point(xy)) <= 7.0]
        np.testing.assert_array_equal(t.polytopes_near(xy, 7.0), brute)


# ============================================================================ random generator
SEEDS = range(50)


def _plane_residual(pts):
    """Largest distance of 4 points from the plane through the first three (or best fit)."""
    c = pts.mean(axis=0)
    _, s, _ = np.linalg.svd(pts - c)
    return s[-1]


@pytest.fixture(scope="module")
def random_terrains():
    cfg = Config()
    return cfg, [(seed, Road.random(seed), Terrain.random(seed)) for seed in SEEDS]


def test_random_deterministic_per_seed():
    a, b = Terrain.random(7), Terrain.random(7)
    assert_same(a, b)
    c = Terrain.random(8)
    assert not np.allclose(a[0].base.mean(axis=0), c[0].base.mean(axis=0))
    # road=None means Road.random(seed)
    assert_same(a, Terrain.random(7, road=Road.random(7)))
    # a Generator seed is deterministic too
    assert_same(Terrain.random(np.random.default_rng(3), road=Road.random(1)),
                Terrain.random(np.random.default_rng(3), road=Road.random(1)))


def test_random_counts_and_overrides():
    assert len(Terrain.random(1)) == Config().n_polytopes == 16
    assert len(Terrain.random(1, n=5)) == 5
    assert len(Terrain.random(1, n=0)) == 0
    t = Terrain.random(2, n_polytopes=9, min_vertices=3, max_vertices=3, min_height=30.0, max_height=31.0)
    assert len(t) == 9
    assert all(p.n_vertices == 3 for p in t)
    assert all(30.0 <= z <= 31.0 for p in t for z in p.top[:, 2])
    t = Terrain.random(2, n=4, config=Config(altitude=60.0, d_safe2=5.0))
    assert max(t.z_max) <= 55.0
    with pytest.raises(ValueError, match="Config.min_radius"):
        Terrain.random(0, min_radius=30.0)
    with pytest.raises(ValueError, match="n must be an integer >= 0"):
        Terrain.random(0, n=-1)


def test_random_cannot_place_raises():
    road = Road(np.array([[0.0, 0.0], [60.0, 0.0]]))
    with pytest.raises(ValueError, match=r"Terrain.random: could not place polytope \d+ of 40"):
        Terrain.random(0, road=road, n=40)


def test_random_properties_over_many_seeds(random_terrains):
    cfg, items = random_terrains
    zmax = cfg.altitude - cfg.d_safe2
    n_flat = n_slanted = 0
    sides = set()
    for seed, road, t in items:
        assert len(t) == cfg.n_polytopes, seed
        # the generator skips Terrain's checks too (valid by construction): they agree
        Terrain(t.polytopes).validate(cfg.altitude)
        for m, p in enumerate(t):
            b, top = p.base, p.top
            k = len(b)
            assert cfg.min_vertices <= k <= cfg.max_vertices
            # the generator skips Polytope validation (valid by construction): the full validator agrees
            b2, t2 = _check_polytope(b, top)
            np.testing.assert_array_equal(b2, b)
            np.testing.assert_array_equal(t2, top)
            assert not b.flags.writeable and not top.flags.writeable
            # the generator writes the frustum's faces down directly: they are the convex hull's faces
            hull = Polytope(b, top)   # validated, faces from the hull
            assert len(p.halfspaces) == len(hull.halfspaces), (seed, m)
            diff = np.abs(p.halfspaces[:, None, :] - hull.halfspaces[None, :, :]).max(axis=-1)
            assert diff.min(axis=1).max() < 1e-8 and diff.min(axis=0).max() < 1e-8, (seed, m)
            # convex, counter-clockwise footprint
            e = np.roll(b, -1, axis=0) - b
            turn = e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1)
            assert np.all(turn > 0), (seed, m)
            assert cfg.min_radius * 0.55 <= p.radius_xy <= 2 * cfg.max_radius
            # clearance from the road, both on vertices and for the whole polygon
            assert road.distance_to(b).min() >= cfg.road_clearance - 1e-9, (seed, m)
            assert road.linestring.distance(p.footprint) >= cfg.road_clearance - 1e-9, (seed, m)
            assert road.linestring.distance(p.footprint) <= 70.0
            # heights
            assert np.all(top[:, 2] >= cfg.min_height - 1e-9), (seed, m)
            assert np.all(top[:, 2] <= zmax + 1e-9), (seed, m)
            assert np.all(top[:, 2] < cfg.altitude - cfg.d_safe2 + 1e-9)
            # top strictly inside the footprint (plan view)
            assert all(p.footprint.contains(Point(xy)) for xy in top[:, :2]), (seed, m)
            # every side face b_j, b_j+1, t_j+1, t_j is planar
            for j in range(k):
                quad = np.array([[*b[j], 0.0], [*b[(j + 1) % k], 0.0], top[(j + 1) % k], top[j]])
                assert _plane_residual(quad) < 1e-6, (seed, m, j)
            # the top is planar too
            if k > 3:
                assert _plane_residual(top) < 1e-6, (seed, m)
            flat = np.ptp(top[:, 2]) == 0
            n_flat += flat
            n_slanted += not flat
            # side of the road, from the centreline tangent at the closest point
            s = road.linestring.project(p.footprint.centroid)
            th = float(road.heading_at(s))
            d = p.centroid_xy - road.point_at(s)
            sides.add(np.sign(math.cos(th) * d[1] - math.sin(th) * d[0]))
        # footprints pairwise disjoint (the generator keeps a 2 m gap)
        for i in range(len(t)):
            for j in range(i + 1, len(t)):
                assert t[i].footprint.distance(t[j].footprint) >= 2.0 - 1e-9, (seed, i, j)
        # spread along the road: polytope i sits near the i-th stretch
        s = np.array([road.linestring.project(Point(c)) for c in t.centroids_xy])
        assert np.ptp(s) > 0.6 * road.length
    assert n_flat > 0.4 * 50 * 16 and n_slanted > 0.25 * 50 * 16
    assert sides == {-1.0, 1.0}


def test_random_slanted_tops_are_slanted_planes():
    t = Terrain.random(11)
    slanted = [p for p in t if np.ptp(p.top[:, 2]) > 1.0]
    assert slanted
    for p in slanted:
        # top z is an affine function of the top's (x, y): fit a plane and check the residual
        A = np.column_stack([p.top[:, :2], np.ones(len(p.top))])
        coef, *_ = np.linalg.lstsq(A, p.top[:, 2], rcond=None)
        np.testing.assert_allclose(A @ coef, p.top[:, 2], atol=1e-9)
        assert np.hypot(*coef[:2]) > 0.01


@pytest.mark.slow
def test_random_is_fast():
    road = Road.random(0)
    Terrain.random(0, road=road)
    best = min(_timed(lambda s=s: Terrain.random(s, road=road)) for s in range(5))
    assert best < 0.05


def _timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


# ============================================================================ GeoJSON
def test_geojson_round_trip_random(tmp_path):
    t = Terrain.random(3)
    obj = t.to_geojson()
    json.dumps(obj)                                    # plain JSON
    assert obj["type"] == "FeatureCollection" and len(obj["features"]) == 16
    assert_same(t, Terrain.from_geojson(obj, altitude=80.0))
    path = tmp_path / "terrain.geojson"
    t.save(path)
    loaded = Terrain.load(path, altitude=80.0)
    assert_same(t, loaded)
    for p, q in zip(t, loaded, strict=True):
        np.testing.assert_array_equal(p.top, q.top)     # exact, not just close


def test_geojson_height_vs_top_on_save(tmp_path):
    prism = Polytope.prism(square(0, 0), 25.0)
    frustum = Polytope(square(20, 0), flat_top(square(21, 1, 8.0), 25.0))   # flat but shrunk
    slanted = Polytope(square(40, 0), np.column_stack([square(41, 1, 8), [10.0, 12.0, 14.0, 12.0]]))
    t = Terrain([prism, frustum, slanted])
    feats = t.to_geojson()["features"]
    assert feats[0]["properties"] == {"height": 25.0}
    assert feats[1]["properties"]["top"][0] == [21.0, 1.0, 25.0]
    assert feats[2]["properties"]["top"][2] == [49.0, 9.0, 14.0]
    ring = feats[0]["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and len(ring) == 5
    path = tmp_path / "t.json"
    t.save(path)
    assert_same(t, Terrain.load(path))


def test_hand_written_geojson_with_slanted_top():
    text = """{
      "type": "FeatureCollection",
      "features": [
        {"type": "Feature", "id": "hill",
         "properties": {"name": "ridge", "top": [[2, 2, 20], [18, 2, 35], [18, 8, 35], [2, 8, 20]]},
         "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]]]}},
        {"type": "Feature", "properties": {"height": 42.5},
         "geometry": {"type": "Polygon", "coordinates": [[[30, 0], [30, 10], [40, 10], [40, 0], [30, 0]]]}}
      ]
    }"""
    t = Terrain.from_geojson(json.loads(text), altitude=80)
    assert len(t) == 2
    np.testing.assert_array_equal(t[0].top[:, 2], [20, 35, 35, 20])
    assert t[0].z_max == 35 and t[1].z_max == 42.5
    # the second ring was clockwise: reoriented
    assert signed_area(t[1].base) > 0
    assert t[1].footprint.area == pytest.approx(100.0)
    # the polytope is the hull: all 8 vertices on or inside every face; the two sloping sides are not
    # planar quadrilaterals in this hand-written data, so the hull splits each in two (4 + 2 * 2 faces)
    hs = t[0].halfspaces
    assert np.all(t[0].vertices @ hs[:, :3].T + hs[:, 3] <= 1e-9)
    assert len(hs) == 8


def _good(fid="tower", **kw):
    props = kw or {"height": 30.0}
    return feature(SQUARE, fid=fid, **props)


def test_geojson_good_helper_loads():
    assert len(Terrain.from_geojson(fc(_good()))) == 1


@pytest.mark.parametrize("obj, msg", [
    ([], r"must be an object with type 'FeatureCollection', got 'list'"),
    ({"type": "Feature"}, r"must be an object with type 'FeatureCollection', got 'Feature'"),
    ({"type": "FeatureCollection"}, r"features must be a list"),
])
def test_geojson_not_a_feature_collection(obj, msg):
    with pytest.raises(ValueError, match=msg):
        Terrain.from_geojson(obj)


def test_geojson_non_polygon_geometry():
    f = _good()
    f["geometry"] = {"type": "MultiPolygon", "coordinates": []}
    with pytest.raises(ValueError, match=r"feature 1 \(id 'tower'\): geometry.type must be 'Polygon', "
                                         r"got 'MultiPolygon'"):
        Terrain.from_geojson(fc(feature(square(50, 50), height=5.0), f))
    f["geometry"] = None
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): geometry.type must be 'Polygon'"):
        Terrain.from_geojson(fc(f))


def test_geojson_not_a_feature():
    with pytest.raises(ValueError, match=r"feature 0: must be a GeoJSON object with type 'Feature'"):
        Terrain.from_geojson(fc({"type": "Point"}))


def test_geojson_hole_rejected():
    f = _good()
    f["geometry"]["coordinates"].append([[2, 2], [3, 2], [3, 3], [2, 2]])
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): geometry has 1 hole\(s\)"):
        Terrain.from_geojson(fc(f))


def test_geojson_ring_not_closed():
    f = feature(SQUARE, fid="tower", close=False, height=30.0)
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): geometry ring is not closed"):
        Terrain.from_geojson(fc(f))


def test_geojson_bad_positions():
    f = _good()
    f["geometry"]["coordinates"][0][1] = ["10", 0]
    with pytest.raises(ValueError, match=r"geometry.coordinates\[0\]\[1\] must be \[x, y\]"):
        Terrain.from_geojson(fc(f))
    f["geometry"]["coordinates"][0][1] = [10, 0, 5]
    with pytest.raises(ValueError, match=r"geometry.coordinates\[0\]\[1\] has z = 5"):
        Terrain.from_geojson(fc(f))
    f["geometry"]["coordinates"][0][1] = [10, 0, 0]   # explicit ground z is fine
    assert len(Terrain.from_geojson(fc(f))) == 1


@pytest.mark.parametrize("props, msg", [
    ({"height": 30.0, "top": flat_top(SQUARE, 30).tolist()}, r"exactly one of 'height'.*got both"),
    ({}, r"exactly one of 'height'.*got neither"),
    ({"name": "x"}, r"exactly one.*got neither"),
])
def test_geojson_height_xor_top(props, msg):
    f = feature(SQUARE, fid="tower", **props)
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): properties must give " + msg):
        Terrain.from_geojson(fc(f))


def test_geojson_name_used_when_no_id():
    f = feature(SQUARE, name="church")
    with pytest.raises(ValueError, match=r"feature 0 \(name 'church'\): properties must give exactly one"):
        Terrain.from_geojson(fc(f))


def test_geojson_top_wrong_count():
    f = feature(SQUARE, fid="tower", top=flat_top(SQUARE[:3], 30).tolist())
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): properties.top has 3 vertices but the "
                                         r"footprint has 4 distinct vertices"):
        Terrain.from_geojson(fc(f))
    f = feature(SQUARE, fid="tower", top=[[0, 0], [10, 0], [10, 10], [0, 10]])
    with pytest.raises(ValueError, match=r"properties.top must be a list of \[x, y, z\] numbers"):
        Terrain.from_geojson(fc(f))


def test_geojson_nan():
    f = _good()
    f["geometry"]["coordinates"][0][2] = [math.nan, 10.0]
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): geometry vertex 2 is not finite"):
        Terrain.from_geojson(fc(f))
    top = flat_top(SQUARE, 30).tolist()
    top[3][2] = math.nan
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): properties.top vertex 3 is not finite"):
        Terrain.from_geojson(fc(_good(top=top)))
    with pytest.raises(ValueError, match=r"properties.height must be in \(0, inf\), got nan"):
        Terrain.from_geojson(fc(_good(height=math.nan)))


def test_geojson_nan_in_file(tmp_path):
    path = tmp_path / "nan.geojson"
    path.write_text(json.dumps(fc(_good())).replace("30.0", "NaN"))
    with pytest.raises(ValueError, match=r"nan.geojson: feature 0 \(id 'tower'\): properties.height must be"):
        Terrain.load(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"invalid JSON"):
        Terrain.load(path)


@pytest.mark.parametrize("h", [0, -5.0, "30", True])
def test_geojson_height_not_positive_or_not_number(h):
    with pytest.raises(ValueError,
                       match=r"feature 0 \(id 'tower'\): properties.height must be in \(0, h=80\)"):
        Terrain.from_geojson(fc(_good(height=h)), altitude=80)


def test_geojson_height_at_or_above_altitude():
    features = [feature(square(0, 0), fid="a", height=10.0), feature(square(20, 0), fid="b", height=10.0),
                feature(square(40, 0), fid="tower", height=95.0)]
    with pytest.raises(ValueError, match=r"^feature 2 \(id 'tower'\): properties.height must be in "
                                         r"\(0, h=80\), got 95.0$"):
        Terrain.from_geojson(fc(*features), altitude=80)
    features[2] = feature(square(40, 0), fid="tower", height=80)
    with pytest.raises(ValueError, match=r"feature 2 \(id 'tower'\): properties.height .* got 80"):
        Terrain.from_geojson(fc(*features), altitude=80)
    assert len(Terrain.from_geojson(fc(*features))) == 3      # no altitude given: accepted


def test_geojson_top_at_or_above_altitude():
    top = flat_top(SQUARE, 30).tolist()
    top[1][2] = 81.0
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): properties.top vertex 1 has z = 81 "
                                         r">= altitude h = 80"):
        Terrain.from_geojson(fc(_good(top=top)), altitude=80)
    top[1][2] = -1.0
    with pytest.raises(ValueError, match=r"properties.top vertex 1 has z = -1; top heights must be > 0"):
        Terrain.from_geojson(fc(_good(top=top)))


def test_geojson_non_convex():
    arrow = [[0, 0], [10, 0], [10, 10], [5, 3], [0, 10]]
    with pytest.raises(ValueError, match=r"feature 0 \(id 'arrow'\): geometry is not convex"):
        Terrain.from_geojson(fc(feature(arrow, fid="arrow", height=5.0)))


def test_geojson_self_intersecting():
    bowtie = [[0, 0], [2, 2], [2, 0], [0, 1]]
    with pytest.raises(ValueError, match=r"feature 0 \(id 'bow'\): geometry is self-intersecting"):
        Terrain.from_geojson(fc(feature(bowtie, fid="bow", height=5.0)))


def test_geojson_too_few_positions():
    with pytest.raises(ValueError, match=r"feature 0: geometry.coordinates\[0\] must be a closed ring"):
        Terrain.from_geojson(fc(feature([[0, 0], [1, 0]], height=5.0)))


def test_geojson_overlap_names_both_features():
    features = [feature(square(0, 0), fid="a", height=10.0), feature(square(40, 0), fid="b", height=10.0),
                feature(square(45, 5), fid="c", height=10.0)]
    with pytest.raises(ValueError,
                       match=r"feature 1 \(id 'b'\) and feature 2 \(id 'c'\): footprints overlap"):
        Terrain.from_geojson(fc(*features))


def test_geojson_top_outside_footprint():
    top = flat_top(SQUARE, 30).tolist()
    top[2] = [12.0, 10.0, 30.0]
    with pytest.raises(ValueError, match=r"feature 0 \(id 'tower'\): properties.top vertex 2 .* lies outside "
                                         r"the footprint by 2 m"):
        Terrain.from_geojson(fc(_good(top=top)))


def test_geojson_clockwise_top_order_follows_footprint():
    cw = SQUARE[::-1]
    top = np.column_stack([cw * 0.8 + 1, [10.0, 20.0, 30.0, 20.0]])
    t = Terrain.from_geojson(fc(feature(cw, top=top.tolist())))
    p = t[0]
    assert signed_area(p.base) > 0
    # top vertex i still above base vertex i (both shrunk toward (5, 5) by 0.8)
    np.testing.assert_allclose(p.top[:, :2], p.base * 0.8 + 1)
    assert p.z_max == 30.0


def test_plan_view_is_the_base_unless_the_top_overhangs():
    sq = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    inside = Polytope(sq, np.column_stack([sq * 0.5 + 2.5, np.full(4, 5.0)]))
    np.testing.assert_array_equal(inside.plan_view, inside.base)
    # validation tolerates a tiny overhang; the plan view (used by LoS's broad phase) must still cover it
    top = np.column_stack([sq + [[-5e-6, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]], np.full(4, 5.0)])
    over = Polytope(sq, top)
    assert Polygon(over.plan_view).exterior.is_ccw
    assert Polygon(over.plan_view).buffer(1e-12).contains(Polygon(over.top[:, :2]))
    assert Polygon(over.plan_view).area > Polygon(sq).area
