"""Batched scene generation (covert_env.world.generation): counter-based draws, scenes independent of their batch and
process, the exact footprint gap, and the generator's invariants on every polytope (against shapely)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import shapely
from hypothesis import example, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Polygon

from covert_env import Config, Scenario
from covert_env.world.families import family_config
from covert_env.world.generation import MIN_GAP, polygon_gap, random_roads, random_terrains, uniforms
from covert_env.world.scenario import random_worlds
from covert_env.world.terrain import Polytope, Terrain


def test_uniforms_are_a_function_of_seed_stream_and_index():
    a = uniforms(np.array([5, 6, 5]), 3, 1000)
    assert a.shape == (3, 1000) and (a >= 0).all() and (a < 1).all()
    np.testing.assert_array_equal(a[0], a[2])                               # same seed, same numbers
    assert not np.array_equal(a[0], a[1]) and not np.array_equal(a[0], uniforms([5], 4, 1000)[0])
    np.testing.assert_array_equal(uniforms([5], 3, 10)[0], a[0, :10])       # a prefix of the same stream
    assert abs(a.mean() - 0.5) < 0.02 and abs(a.std() - 12 ** -0.5) < 0.02
    code = "from covert_env.world.generation import uniforms; print(uniforms([123456789], 7, 4).tolist())"
    runs = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={**os.environ, "PYTHONHASHSEED": str(h)}).stdout for h in (1, 2)}
    assert runs == {str(uniforms([123456789], 7, 4).tolist()) + "\n"}


def test_a_scene_does_not_depend_on_its_batch():
    c = family_config("dense")
    seeds = [7, 1_000_003, 42, 7]
    batch = random_worlds(seeds, c)
    for i in (1, 2):
        alone = random_worlds([seeds[i]], c)[0]
        assert all(np.array_equal(p.vertices, q.vertices) for p, q in zip(batch[i][0], alone[0], strict=True))
        np.testing.assert_array_equal(batch[i][1].road.points, alone[1].road.points)
    assert all(np.array_equal(p.vertices, q.vertices) for p, q in zip(batch[0][0], batch[3][0], strict=True))
    sc = Scenario.random(42, c)
    assert all(np.array_equal(p.vertices, q.vertices) for p, q in zip(sc.terrain, batch[2][0], strict=True))


def _convex(rng, n, centre, r):
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    return centre + r * np.column_stack([np.cos(ang), 0.5 * np.sin(ang)])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), v=st.integers(3, 9))
@example(seed=394, v=3)
def test_polygon_gap_is_shapelys_distance(seed, v):
    """Padded convex polygons (the last vertex repeated) at every relation: apart, touching-close, overlapping."""
    rng = np.random.default_rng(seed)
    n = 40
    p, q = np.empty((n, v, 2)), np.empty((n, v, 2))
    for i in range(n):
        k1, k2 = rng.integers(3, v + 1, 2)
        a = _convex(rng, k1, rng.uniform(-5, 5, 2), rng.uniform(1, 6))
        b = _convex(rng, k2, rng.uniform(-15, 15, 2) if i % 2 else rng.uniform(-3, 3, 2), rng.uniform(1, 6))
        p[i] = np.vstack([a, np.repeat(a[-1:], v - k1, axis=0)])
        q[i] = np.vstack([b, np.repeat(b[-1:], v - k2, axis=0)])
    # An overlapping pair, always: p[0] shrunk about its centre lies inside it (a shifted copy of a thin
    # triangle need not overlap it: seed 394, v 3).
    centre = p[0].mean(axis=0)
    q[0] = centre + 0.5 * (p[0] - centre)
    want = shapely.distance(shapely.polygons(p), shapely.polygons(q))
    np.testing.assert_allclose(polygon_gap(p, q), want, atol=1e-9)
    assert (want == 0).any() and (want > 0).any()


@pytest.mark.parametrize("name, seeds", [("paper", range(1_000_000, 1_000_012)),
                                         ("downtown", range(1_000_000, 1_000_012)),
                                         ("towers", range(1_000_000, 1_000_012)),
                                         ("dense", [2312, 2313, 8570])])     # 2313, 8570: a second attempt
def test_generated_polytopes_keep_the_invariants(name, seeds):
    """Every polytope valid for the full Polytope validator (convex CCW base, top inside it), footprints MIN_GAP
    apart, circumcircles road_clearance from the road, tops in [min_height, max_polytope_height]."""
    c = family_config(name)
    seeds = np.asarray(seeds)
    roads = random_roads(seeds, c)
    batch = random_terrains(seeds, roads, c)
    for i in range(len(seeds)):
        polys = [Polytope(batch.base[i, j, :kk], batch.top[i, j, :kk])                # the full validator
                 for j, kk in enumerate(batch.n_vertices[i])]
        Terrain(polys).validate(c.altitude)
        fps = [Polygon(p.base) for p in polys]
        gaps = shapely.distance(np.array(fps)[:, None], np.array(fps)[None])
        np.fill_diagonal(gaps, np.inf)
        assert gaps.min() >= MIN_GAP - 1e-9
        road = LineString(roads[i])
        d = shapely.distance(shapely.points(batch.centre[i]), road)
        assert (d >= batch.radius[i] + c.road_clearance - 1e-9).all()
        assert max(np.linalg.norm(p.base - ctr, axis=1).max() - r for p, ctr, r in
                   zip(polys, batch.centre[i], batch.radius[i], strict=True)) <= 1e-9
        z = np.concatenate([p.top[:, 2] for p in polys])
        assert z.min() >= c.min_height - 1e-9 and z.max() <= c.max_polytope_height + 1e-9


def test_a_scene_left_incomplete_starts_again_and_the_others_do_not_change():
    """Dense training scenes 2313 and 8570 lack a polytope after MAX_ROUNDS rounds (a training run drew 2313 and
    stopped): they start again with the next rounds' numbers and are built, each as alone in a batch. A scene
    complete in its first attempt is the same whether or not the batch holds one that starts again."""
    c = family_config("dense")
    seeds = np.array([2312, 2313, 2314, 8570])
    roads = random_roads(seeds, c)
    batch = random_terrains(seeds, roads, c)
    for i in range(len(seeds)):
        one = random_terrains(seeds[i:i + 1], roads[i:i + 1], c)
        np.testing.assert_array_equal(one.base[0], batch.base[i])
        np.testing.assert_array_equal(one.top[0], batch.top[i])
    with pytest.raises(ValueError, match=r"random scenes \[2313\]: could not place all 48 polytopes .* in 1 "
                                         r"attempts of 200 rounds"):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr("covert_env.world.generation.MAX_ATTEMPTS", 1)
            random_terrains(seeds[1:2], roads[1:2], c)


def test_a_scene_that_cannot_be_filled_is_named():
    c = Config(n_polytopes=150)
    with pytest.raises(ValueError, match=r"random scenes \[3\]: could not place all 150 polytopes"):
        Scenario.random(3, c)


def test_batched_faces_and_line_of_sight_arrays_describe_the_polytopes():
    """The faces the batch computes equal each polytope's convex hull's (1e-8), and the line-of-sight arrays it
    registers for a scene decide every sight line as arrays rebuilt from the polytopes do."""
    from covert_env.world.visibility import line_of_sight

    c = family_config("downtown")
    terrain, track, _ = random_worlds([1_000_004], c)[0]
    for p in list(terrain)[:12]:
        hull = Polytope(p.base, p.top).halfspaces                  # from a convex hull, not the closed form
        mine = p.halfspaces
        assert len(hull) == len(mine)
        assert all(np.abs(mine - h).max(axis=1).min() < 1e-8 for h in hull)
    rebuilt = Terrain(list(terrain))                                # a new object: arrays built polytope by polytope
    rng = np.random.default_rng(0)
    q = track.positions[rng.integers(0, 70, 400)]
    xy = q[:, :2] + rng.uniform(-110, 110, (400, 2))
    for tol in (1e-8, -1e-6):
        np.testing.assert_array_equal(line_of_sight(terrain, xy, c.altitude, q, tol=tol),
                                      line_of_sight(rebuilt, xy, c.altitude, q, tol=tol))
    assert not line_of_sight(terrain, xy, c.altitude, q).all()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10**6), curvature=st.sampled_from([0.0, 1 / 120, 1 / 30, 0.1]))
def test_road_clearance_test_equals_the_exact_distance(seed, curvature):
    """The windowed and coarse road test decides as the distance to every segment does, also where a sharply
    turning road comes back near a proposal (far along the road, outside its window)."""
    from covert_env.world.generation import ROAD_STEP, _road_clear, _segment_distance

    c = Config(road_max_curvature=curvature)
    roads = random_roads([seed, seed + 1], c)
    rng = np.random.default_rng(seed)
    n = 600
    scene = rng.integers(0, 2, n)
    idx = rng.integers(0, roads.shape[1] - 1, n)
    centres = roads[scene, idx] + rng.uniform(-60, 60, (n, 2))
    need = rng.uniform(5, 45, n)
    exact = _segment_distance(centres[:, None], roads[scene, :-1], roads[scene, 1:]).min(axis=1) >= need
    np.testing.assert_array_equal(_road_clear(centres, scene, idx, roads, need), exact)
    assert ROAD_STEP > 0 and exact.any() and not exact.all()
