"""covert_env.world.road: the road centreline (arc-length parametrisation) and the target's track on it.

References are independent of the module: vertices and segment directions of hand-made polylines,
shapely's distance, and the arc-length definition of the speed profile.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from covert_env.world.road import Road, TargetTrack

# A polyline with segments of length 10, 5 and 5 (a 3-4-5 diagonal last), headings 0, pi/2, atan2(4, 3).
POLY = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0], [13.0, 9.0]])
POLY_CUM = np.array([0.0, 10.0, 15.0, 20.0])
POLY_HEADINGS = np.array([0.0, math.pi / 2, math.atan2(4.0, 3.0)])


def wrapped(a):
    return np.abs(np.angle(np.exp(1j * np.asarray(a, float))))


@pytest.fixture
def poly():
    return Road.from_points(POLY.tolist())


# ----------------------------------------------------------------------------- arc length
def test_cumulative_length_and_length(poly):
    np.testing.assert_allclose(poly.cumulative_length, POLY_CUM, atol=1e-12)
    assert poly.length == pytest.approx(20.0, abs=1e-12)


def test_point_at_cumulative_lengths_are_the_vertices(poly):
    np.testing.assert_allclose(poly.point_at(POLY_CUM), POLY, atol=1e-12)
    for s, p in zip(POLY_CUM, POLY, strict=True):
        np.testing.assert_allclose(poly.point_at(s), p, atol=1e-12)


def test_point_at_interpolates_linearly_within_segments(poly):
    np.testing.assert_allclose(poly.point_at(2.5), [2.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(poly.point_at(12.0), [10.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(poly.point_at(17.5), [10.0 + 1.5, 5.0 + 2.0], atol=1e-12)   # half the 3-4-5 leg


def test_point_at_is_clamped_to_the_road(poly):
    np.testing.assert_allclose(poly.point_at(-7.0), POLY[0], atol=1e-12)
    np.testing.assert_allclose(poly.point_at(1e6), POLY[-1], atol=1e-12)


def test_point_at_broadcasts_over_shapes(poly):
    s = np.array([[0.0, 2.5], [12.0, 20.0], [15.0, 17.5]])
    out = poly.point_at(s)
    assert out.shape == (3, 2, 2)
    np.testing.assert_allclose(out[1, 0], [10.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(out[2, 0], POLY[2], atol=1e-12)


def test_heading_is_the_segment_direction(poly):
    mids = 0.5 * (POLY_CUM[:-1] + POLY_CUM[1:])
    np.testing.assert_allclose(poly.heading_at(mids), POLY_HEADINGS, atol=1e-12)
    # Anywhere strictly inside segment i the heading is segment i's direction.
    for i in range(3):
        for f in (0.01, 0.5, 0.99):
            s = POLY_CUM[i] + f * (POLY_CUM[i + 1] - POLY_CUM[i])
            assert wrapped(poly.heading_at(s) - POLY_HEADINGS[i]) < 1e-12


@settings(max_examples=60, deadline=None)
@given(s=st.floats(0.0, 20.0), t=st.floats(0.0, 20.0))
def test_point_at_is_one_lipschitz_and_exact_within_a_segment(s, t):
    road = Road(POLY)
    d = np.linalg.norm(road.point_at(s) - road.point_at(t))
    assert d <= abs(s - t) + 1e-9
    same_segment = np.searchsorted(POLY_CUM, s, "right") == np.searchsorted(POLY_CUM, t, "right")
    if same_segment:
        assert d == pytest.approx(abs(s - t), abs=1e-9)
    assert road.distance_to(road.point_at(s)) < 1e-9           # every point_at lies on the centreline


# ----------------------------------------------------------------------------- distance_to
@settings(max_examples=80, deadline=None)
@given(x=st.floats(-30.0, 40.0), y=st.floats(-30.0, 40.0))
def test_distance_to_matches_shapely(x, y):
    road = Road(POLY)
    assert road.distance_to([x, y]) == pytest.approx(road.linestring.distance(Point(x, y)), abs=1e-9)


def test_distance_to_random_road_matches_shapely_and_is_vectorised():
    road = Road.random(11, length=400.0)
    rng = np.random.default_rng(0)
    lo, hi = road.points.min(0) - 50, road.points.max(0) + 50
    pts = rng.uniform(lo, hi, size=(3, 40, 2))
    d = road.distance_to(pts)
    assert d.shape == (3, 40)
    ref = np.array([[road.linestring.distance(Point(*p)) for p in row] for row in pts])
    np.testing.assert_allclose(d, ref, atol=1e-8)
    assert road.distance_to(road.points).max() < 1e-9


def test_distance_to_known_values(poly):
    assert poly.distance_to([5.0, -3.0]) == pytest.approx(3.0)       # below the first leg
    assert poly.distance_to([-4.0, 3.0]) == pytest.approx(5.0)       # beyond the start vertex
    assert poly.distance_to([12.0, 2.0]) == pytest.approx(2.0)       # right of the vertical leg


# ----------------------------------------------------------------------------- random roads
def test_random_road_is_deterministic_per_seed():
    a, b = Road.random(7), Road.random(7)
    np.testing.assert_array_equal(a.points, b.points)
    c = Road.random(8)
    assert a.points.shape != c.points.shape or not np.allclose(a.points, c.points)
    g1, g2 = Road.random(np.random.default_rng(3)), Road.random(np.random.default_rng(3))
    np.testing.assert_array_equal(g1.points, g2.points)


def segment_headings(road):
    d = np.diff(road.points, axis=0)
    return np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), kmax=st.sampled_from([1 / 30, 1 / 120, 1 / 500]),
       step=st.sampled_from([1.0, 2.0, 5.0]))
def test_random_road_curvature_is_bounded(seed, kmax, step):
    road = Road.random(seed, length=600.0, step=step, max_curvature=kmax)
    th, seg = segment_headings(road)
    np.testing.assert_allclose(seg, step, rtol=1e-9)
    dth = wrapped(np.diff(th))
    # Turning between consecutive segments, per metre driven.
    assert np.all(dth / step <= kmax + 1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_road_start_pose_length_and_straight_start(seed):
    start, heading, ss = (5.0, -7.0), 0.7, 60.0
    road = Road.random(seed, length=500.0, start=start, heading=heading, step=2.0, straight_start=ss)
    np.testing.assert_allclose(road.points[0], start, atol=1e-12)
    assert road.length >= 500.0 - 1e-9
    th, _ = segment_headings(road)
    s_start = road.cumulative_length[:-1]
    straight = s_start + 2.0 <= ss
    assert straight.sum() >= 29
    assert np.all(wrapped(th[straight] - heading) < 1e-12)
    assert np.max(wrapped(th - heading)) > 1e-3          # the road does curve later on


# ----------------------------------------------------------------------------- validation
@pytest.mark.parametrize("pts", [
    [[0.0, 0.0]],                                   # one point
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],             # 3 columns
    [0.0, 1.0, 2.0],                                # 1-D
    np.zeros((2, 2, 2)),                            # 3-D
])
def test_road_rejects_bad_shape_naming_the_field(pts):
    with pytest.raises(ValueError, match=r"Road\.points"):
        Road(pts)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_road_rejects_non_finite_points(bad):
    with pytest.raises(ValueError, match=r"Road\.points.*finite"):
        Road([[0.0, 0.0], [1.0, bad], [2.0, 0.0]])


def test_road_rejects_repeated_consecutive_points():
    with pytest.raises(ValueError, match=r"Road\.points.*distinct"):
        Road([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [2.0, 0.0]])
    # A point visited again later (not consecutively) is a legal route.
    Road([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])


def test_road_points_are_read_only(poly):
    with pytest.raises(ValueError):
        poly.points[0, 0] = 99.0


def test_road_does_not_freeze_or_alias_the_callers_array():
    pts = POLY.copy()
    road = Road(pts)
    assert road.points is not pts
    pts[0, 0] = -1.0                           # the caller's own array must stay writable
    assert road.points[0, 0] == 0.0


def test_to_json_round_trip(poly):
    again = Road(**poly.to_json())
    np.testing.assert_array_equal(again.points, poly.points)


# ----------------------------------------------------------------------------- target track
@pytest.fixture
def track(poly):
    # Speeds 2, 3, 0, 5 m/s over slots of 0.5 s starting 1 m along the road.
    return TargetTrack(poly, [2.0, 3.0, 0.0, 5.0, 4.0, 4.0], delta=0.5, z=1.5, s0=1.0)


def test_track_arc_and_positions_follow_the_speed_profile(track, poly):
    arc = 1.0 + np.concatenate([[0.0], np.cumsum(np.array([2.0, 3.0, 0.0, 5.0, 4.0, 4.0]) * 0.5)])
    np.testing.assert_allclose(track.arc, arc, atol=1e-12)
    assert track.n_slots == 6
    for k in range(7):
        q = track.position(k)
        assert q.shape == (3,)
        np.testing.assert_allclose(q[:2], poly.point_at(arc[k]), atol=1e-12)
        assert q[2] == 1.5
        assert track.heading(k) == pytest.approx(float(poly.heading_at(arc[k])), abs=1e-12)
    np.testing.assert_allclose(track.position(2), track.position(3))   # speed 0 in slot 2
    qs = track.position(np.arange(7))
    assert qs.shape == (7, 3)
    np.testing.assert_allclose(qs[:, :2], poly.point_at(arc), atol=1e-12)
    assert isinstance(track.heading(1), float)
    assert np.shape(track.heading(np.arange(3))) == (3,)


def test_track_position_is_clamped(track):
    np.testing.assert_allclose(track.position(-3), track.position(0))
    np.testing.assert_allclose(track.position(100), track.position(track.n_slots))
    np.testing.assert_allclose(track.position(np.array([-1, 50]))[1], track.position(6))


def test_track_results_are_not_shared_state(track):
    q = track.position(2)
    q[:] = 1e9
    assert track.position(2)[0] < 1e3


def test_constant_track(poly):
    t = TargetTrack.constant(poly, 4.0, 5, delta=1.0, z=2.0, s0=0.0)
    assert t.n_slots == 5
    np.testing.assert_allclose(t.speeds, 4.0)
    np.testing.assert_allclose(t.position(3), [10.0, 2.0, 2.0], atol=1e-12)
    assert t.heading(3) == pytest.approx(math.pi / 2)


@pytest.mark.parametrize("k,n", [(0, 1), (0, 5), (2, 3), (1, 4)])
def test_predict_is_the_next_n_positions(track, k, n):
    q, phi = track.predict(k, n)
    assert q.shape == (n, 3) and np.shape(phi) == (n,)
    for j in range(n):
        np.testing.assert_allclose(q[j], track.position(k + 1 + j), atol=1e-12)
        assert phi[j] == pytest.approx(track.heading(k + 1 + j), abs=1e-12)


@pytest.mark.parametrize("k", range(6))
def test_position_between_endpoints_and_interpolation(track, k):
    f = np.linspace(0.0, 1.0, 7)
    pb = track.position_between(k, f)
    assert pb.shape == (7, 3)
    np.testing.assert_allclose(pb[0], track.position(k), atol=1e-12)
    np.testing.assert_allclose(pb[-1], track.position(k + 1), atol=1e-12)
    s = track.arc[k] + f * (track.arc[k + 1] - track.arc[k])
    np.testing.assert_allclose(pb[:, :2], track.road.point_at(s), atol=1e-12)
    np.testing.assert_allclose(pb[:, 2], 1.5)
    # A different set of fractions on the same slot.
    np.testing.assert_allclose(track.position_between(k, [0.5])[0, :2], track.road.point_at(s[3]), atol=1e-12)


@pytest.mark.parametrize("speeds", [[1.0, -0.5], [1.0, np.nan], [np.inf], [[1.0, 2.0], [3.0, 4.0]]])
def test_track_rejects_bad_speeds_naming_the_field(poly, speeds):
    with pytest.raises(ValueError, match=r"TargetTrack\.speeds"):
        TargetTrack(poly, speeds)


def test_track_speeds_are_read_only(track):
    with pytest.raises(ValueError):
        track.speeds[0] = 10.0


def test_track_does_not_freeze_or_alias_the_callers_speeds(poly):
    speeds = np.array([1.0, 2.0, 3.0])
    t = TargetTrack(poly, speeds)
    speeds[0] = 9.0                            # the caller's own array must stay writable
    assert t.speeds[0] == 1.0


def test_pose_at_matches_point_and_heading():
    """The generator's scalar lookup gives exactly point_at/heading_at (so scenes do not depend on it)."""
    road = Road.random(3)
    rng = np.random.default_rng(0)
    for s in [*rng.uniform(-10.0, road.length + 10.0, 500), 0.0, road.length, float(road.cumulative_length[5])]:
        p, h = road.pose_at(s)
        np.testing.assert_array_equal(p, road.point_at(s))
        assert h == float(road.heading_at(s))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_roads=st.integers(1, 4), n_points=st.integers(2, 40),
       uneven=st.booleans())
def test_many_roads_at_once_equal_each_road(seed, n_roads, n_points, uneven):
    """points_along / headings_along on N roads at once (the scene pool's tracks) give each road's Road.point_at and
    heading_at bit for bit, on roads of uneven spacing (the batched segment search starts from a guess and must
    still find searchsorted's segment), at vertices, at both ends and beyond them (clamped)."""
    from covert_env.world.road import cumulative_lengths, headings_along, points_along

    rng = np.random.default_rng(seed)
    steps = rng.exponential(3.0, (n_roads, n_points - 1, 2)) + 1e-3
    if uneven:
        steps[:, : (n_points - 1) // 2] *= 50.0
    pts = np.concatenate([np.zeros((n_roads, 1, 2)), np.cumsum(steps, axis=1)], axis=1)
    cl = cumulative_lengths(pts)
    s = rng.uniform(-5.0, cl[:, -1].max() + 5.0, (n_roads, 3, 4))
    s[:, 0, :3] = cl[:, [0, min(2, n_points - 1), -1]]
    got_xy, got_phi = points_along(pts, cl, s), headings_along(pts, cl, s)
    for n in range(n_roads):
        road = Road(pts[n])
        np.testing.assert_array_equal(cl[n], road.cumulative_length)
        np.testing.assert_array_equal(got_xy[n], road.point_at(s[n]))
        np.testing.assert_array_equal(got_phi[n], road.heading_at(s[n]))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_roads=st.integers(1, 4), n_points=st.integers(2, 40),
       uneven=st.booleans(), guess_off=st.integers(-50, 50))
def test_points_along_padded_rows_equal_each_road(seed, n_roads, n_points, uneven, guess_off):
    """points_along_rows (the vector env's target between slot times: roads as padded rows of different lengths,
    copies gathering their row) gives each road's Road.point_at bit for bit, from any starting guess, at vertices,
    at both ends and beyond them (clamped to the row's own road, not the padding)."""
    from covert_env.world.road import cumulative_lengths, points_along_rows, segments_at

    rng = np.random.default_rng(seed)
    lengths = rng.integers(2, n_points + 1, n_roads)
    lengths[0] = n_points
    pts = np.full((n_roads, n_points, 2), 7.0)                      # padding: any value
    cl = np.full((n_roads, n_points), 1e9)
    for n, k in enumerate(lengths):
        steps = rng.exponential(3.0, (k - 1, 2)) + 1e-3
        if uneven:
            steps[: (k - 1) // 2] *= 50.0
        pts[n, :k] = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
        cl[n, :k] = cumulative_lengths(pts[n, :k])
    rows = rng.integers(0, n_roads, 6)
    ends = cl[rows, lengths[rows] - 1]
    s = rng.uniform(-5.0, 1.0, (6, 5)) * (ends[:, None] + 5.0)
    s[:, 0], s[:, 1] = ends, cl[rows, np.minimum(1, lengths[rows] - 1)]
    # From the true segment of the first sample, moved by guess_off (clamped to the row's road by the function).
    true = np.array([segments_at(cl[r, :lengths[r]], s[b, :1]) for b, r in enumerate(rows)])
    got = points_along_rows(pts, cl, lengths - 1, rows, s, true + guess_off)
    for b, r in enumerate(rows):
        np.testing.assert_array_equal(got[b], Road(pts[r, :lengths[r]]).point_at(s[b]))


def test_points_along_rows_checks_its_indices_before_the_kernel_reads():
    """The compiled walk checks no bounds: a row, a last vertex or a guess of the wrong shape is refused first."""
    from covert_env.world.road import points_along_rows

    pts = np.cumsum(np.ones((2, 5, 2)), axis=1)
    cl = np.cumsum(np.full((2, 5), 2 ** 0.5), axis=1) - 2 ** 0.5
    s = np.array([[0.5, 1.0]])
    good = points_along_rows(pts, cl, np.array([4, 4]), np.array([1]), s, np.array([[0]]))
    np.testing.assert_array_equal(good[0], Road(pts[1]).point_at(s[0]))
    with pytest.raises(ValueError, match="rows must lie in"):
        points_along_rows(pts, cl, np.array([4, 4]), np.array([2]), s, np.array([[0]]))
    with pytest.raises(ValueError, match="last vertices must lie in"):
        points_along_rows(pts, cl, np.array([4, 5]), np.array([1]), s, np.array([[0]]))
    with pytest.raises(ValueError, match="guess"):
        points_along_rows(pts, cl, np.array([4, 4]), np.array([1]), s, np.zeros((1, 3), int))
