"""Feasible zone (eqs. 4-5), visible zone (eq. 10) and the target-frame lattice."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from shapely import affinity
from shapely.geometry import Point, Polygon

from covert_env.geometry.zone import (
    ARC_RESOLUTION,
    arc_error,
    feasible_zone,
    feasible_zone_cfg,
    grid_nodes,
    in_feasible_zone,
    lattice_offsets,
    lattice_offsets_cfg,
    to_world,
    visible_zone,
    zone_distance,
    zone_mask,
)
from covert_env.world.config import Config
from covert_env.world.shadows import shadow_polygons, shadow_union, visible_zone_cfg
from covert_env.world.terrain import Polytope, Terrain
from covert_env.world.visibility import line_of_sight

R1, R2, MU = 55.0, 100.0, math.pi / 4
PHIS = [0.3, -2.0, math.pi, -math.pi + 1e-3, math.pi - 1e-9]   # incl. zones straddling the +-pi cut
TOL = arc_error(R2) + 1e-9


def sample(rng, q, n, half=115.0):
    return np.asarray(q) + rng.uniform(-half, half, (n, 2))


def intersection_over_circle(zone, r_u, n):
    """The intersection of ``zone`` translated to n centres evenly spaced on the circle of radius r_u."""
    ang = np.arange(n) * 2 * np.pi / n
    return shapely.intersection_all([affinity.translate(zone, r_u * math.cos(a), r_u * math.sin(a))
                                     for a in ang])


# ----------------------------------------------------------------------------- eq. 5: erosion identity
@pytest.mark.parametrize("phi", PHIS)
@pytest.mark.parametrize("r_u", [2.0, 5.0])
def test_eroded_zone_is_intersection_over_uncertainty_disk(phi, r_u):
    """Phi_gamma(q) = intersection of Phi(q0) over q0 on the circle |q0 - q| = r_u (96 centres); for a
    simply connected zone this is the intersection over the whole disk (eq. 5)."""
    q = np.array([12.0, -7.0])
    eroded = feasible_zone(q, phi, R1, R2, MU, r_u)
    base = feasible_zone(q, phi, R1, R2, MU)
    inter = intersection_over_circle(base, r_u, 96)
    assert eroded.symmetric_difference(inter).area < 1e-3 * eroded.area
    # Not vacuous: erosion removes a band of about perimeter * r_u.
    assert base.area - eroded.area > 0.8 * r_u * base.length


@pytest.mark.parametrize("mu,r_u", [(0.15, 5.0), (0.3, 5.0), (3.5, 4.0), (5.5, 8.0)])
def test_erosion_identity_for_narrow_and_wide_sectors(mu, r_u):
    """Narrow sectors lose the inner arc (the eroded wedge's apex lies inside the annulus); wide (> pi)
    sectors are reflex. The intersection of translates still matches."""
    q = np.zeros(2)
    eroded = feasible_zone(q, 1.0, R1, R2, mu, r_u)
    base = feasible_zone(q, 1.0, R1, R2, mu)
    inter = intersection_over_circle(base, r_u, 128)
    assert not eroded.is_empty and eroded.is_valid
    assert eroded.symmetric_difference(inter).area < 1e-3 * eroded.area


def test_zone_area_and_emptiness():
    z = feasible_zone((0, 0), 0.0, R1, R2, MU)
    exact = MU / 2 * (R2**2 - R1**2)
    assert z.is_valid and z.area == pytest.approx(exact, rel=1e-5)
    assert z.area <= exact                                    # the polygon lies inside the exact sector
    assert feasible_zone((0, 0), 0.0, R1, R2, MU, r_u=22.5).is_empty    # 2 r_u = r2 - r1
    assert feasible_zone((0, 0), 0.0, R1, R2, 0.1, r_u=5.0).is_empty     # apex 100 m out > r2 - r_u
    assert feasible_zone((0, 0), 0.0, 0.0, R2, MU).area == pytest.approx(MU / 2 * R2**2, rel=1e-5)
    with pytest.raises(ValueError):
        feasible_zone((0, 0), 0.0, 60.0, 50.0, MU)


# ----------------------------------------------------------------------------- analytic membership
@pytest.mark.parametrize("phi", PHIS)
@pytest.mark.parametrize("r_u", [0.0, 2.0, 5.0])
def test_membership_agrees_with_polygon(phi, r_u):
    rng = np.random.default_rng(int(1000 * (phi + 4)) + int(10 * r_u))
    q = np.array([-30.0, 44.0])
    xy = sample(rng, q, 20000)
    poly = feasible_zone(q, phi, R1, R2, MU, r_u)
    inside = in_feasible_zone(xy, q, phi, R1, R2, MU, r_u)
    contains = shapely.contains_xy(poly, xy[:, 0], xy[:, 1])
    far = shapely.distance(poly.boundary, shapely.points(xy)) > TOL
    np.testing.assert_array_equal(inside[far], contains[far])
    assert 0.02 < inside.mean() < 0.1          # a few hundred points inside, not vacuous
    # The erosion definition: in the eroded zone iff at distance >= r_u inside the sector's boundary.
    zd = zone_distance(xy, q, phi, R1, R2, MU)
    clear = np.abs(zd + r_u) > 1e-9
    np.testing.assert_array_equal(inside[clear], (zd <= -r_u)[clear])


@pytest.mark.parametrize("phi", PHIS)
def test_zone_distance_is_the_signed_boundary_distance(phi):
    rng = np.random.default_rng(1)
    q = np.array([5.0, 5.0])
    xy = sample(rng, q, 5000, half=160.0)
    zd = zone_distance(xy, q, phi, R1, R2, MU)
    poly = feasible_zone(q, phi, R1, R2, MU)
    ref = shapely.distance(poly.boundary, shapely.points(xy))
    np.testing.assert_allclose(np.abs(zd), ref, atol=TOL)
    inside = shapely.contains_xy(poly, xy[:, 0], xy[:, 1])
    sure = ref > TOL
    np.testing.assert_array_equal((zd < 0)[sure], inside[sure])


def test_zone_lies_behind_the_target_across_the_pi_cut():
    q = np.zeros(2)
    # Heading +x: the zone is around bearing pi, i.e. on both sides of the +-pi cut.
    pts = np.array([[-70.0, 0.0],
                    [-70 * math.cos(0.35), 70 * math.sin(0.35)],       # bearing pi - 0.35 (mu / 2 = 0.39)
                    [-70 * math.cos(0.35), -70 * math.sin(0.35)],      # bearing -pi + 0.35
                    [-70 * math.cos(0.45), 70 * math.sin(0.45)],       # outside the angle
                    [70.0, 0.0],                                       # in front
                    [-50.0, 0.0], [-101.0, 0.0]])                      # too close, too far
    np.testing.assert_array_equal(in_feasible_zone(pts, q, 0.0, R1, R2, MU), [1, 1, 1, 0, 0, 0, 0])
    # Heading -x (phi = +-pi): the zone is in front along +x.
    for phi in (math.pi, -math.pi, math.pi - 1e-12):
        np.testing.assert_array_equal(in_feasible_zone(pts, q, phi, R1, R2, MU), [0, 0, 0, 0, 1, 0, 0])
    # zone_distance by hand: (-70, 0) is 15 m from the inner arc; (-120, 0) 20 m beyond the outer one;
    # the target itself 55 m from the inner arc's end points.
    zd = zone_distance(np.array([[-70.0, 0.0], [-120.0, 0.0], [0.0, 0.0]]), q, 0.0, R1, R2, MU)
    np.testing.assert_allclose(zd, [-15.0, 20.0, 55.0])
    # Broadcasting: one target per point.
    qs = np.array([[0.0, 0.0], [100.0, 0.0]])
    two = np.array([[-70.0, 0.0], [30.0, 0.0]])
    np.testing.assert_array_equal(in_feasible_zone(two, qs, 0.0, R1, R2, MU), [True, True])


# ----------------------------------------------------------------------------- lattice and nodes
def test_lattice_is_fixed_and_covers_the_sector():
    off = lattice_offsets(R1, R2, MU, 2.0)
    assert off is lattice_offsets(R1, R2, MU, 2.0) and not off.flags.writeable
    np.testing.assert_array_equal(off, lattice_offsets_cfg(Config()))
    # Multiples of the step, unique, ordered by x then y.
    np.testing.assert_allclose(off / 2.0, np.round(off / 2.0), atol=1e-12)
    assert len(np.unique(off, axis=0)) == len(off)
    assert np.all(np.lexsort((off[:, 1], off[:, 0])) == np.arange(len(off)))
    # The bounding box of the sector (x from -100 to -55 cos(pi/8), |y| <= 100 sin(pi/8)).
    assert off[:, 0].min() == -100.0 and off[:, 0].max() == -52.0
    assert off[:, 1].max() == 38.0 and off[:, 1].min() == -38.0
    # Every point of the sector is within half a diagonal of a lattice point.
    rng = np.random.default_rng(0)
    xy = sample(rng, (0, 0), 4000)
    xy = xy[in_feasible_zone(xy, (0, 0), 0.0, R1, R2, MU)]
    d = np.min(np.linalg.norm(xy[:, None] - off[None], axis=2), axis=1)
    assert d.max() <= math.sqrt(2) + 1e-9


@pytest.mark.parametrize("phi", PHIS)
@pytest.mark.parametrize("r_u", [0.0, 2.0])
def test_grid_nodes_inside_and_complete(phi, r_u):
    q = np.array([250.0, -80.0])
    off = lattice_offsets(R1, R2, MU, 2.0)
    nodes = grid_nodes(q, phi, 2.0, R1, R2, MU, r_u)
    assert nodes.shape == (int(zone_mask(off, R1, R2, MU, r_u).sum()), 2)
    assert np.all(zone_distance(nodes, q, phi, R1, R2, MU) <= -r_u + 1e-9)
    # The mask is decided in the target frame; in the world frame it agrees up to rounding.
    world = to_world(off, q, phi)
    mask = zone_mask(off, R1, R2, MU, r_u)
    zd = zone_distance(world, q, phi, R1, R2, MU)
    sure = np.abs(zd + r_u) > 1e-9
    np.testing.assert_array_equal(mask[sure], (zd <= -r_u)[sure])
    np.testing.assert_array_equal(nodes, world[mask])
    assert len(nodes) > 400


def test_to_world_rotation_and_batch():
    off = np.array([[-60.0, 0.0], [0.0, 10.0]])
    w = to_world(off, (5.0, 1.0), math.pi / 2)
    np.testing.assert_allclose(w, [[5.0, -59.0], [-5.0, 1.0]], atol=1e-12)
    qs = np.array([[0.0, 0.0], [5.0, 1.0], [1.0, 2.0]])
    phis = np.array([0.0, math.pi / 2, -3.0])
    batch = to_world(off, qs, phis)
    assert batch.shape == (3, 2, 2)
    for i in range(3):
        np.testing.assert_allclose(batch[i], to_world(off, qs[i], phis[i]))
    # Rotating back recovers the offsets.
    c, s = math.cos(-3.0), math.sin(-3.0)
    back = (batch[2] - qs[2]) @ np.array([[c, s], [-s, c]]).T
    np.testing.assert_allclose(back, off, atol=1e-12)


# ----------------------------------------------------------------------------- eq. 10: visible zone
def _box(x0, x1, y0, y1, z):
    base = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
    return Polytope(base, np.column_stack([base, np.full(4, float(z))]))


def test_visible_zone_excludes_shadows_and_keeps_the_rest():
    # Target at the origin heading +x; two buildings behind it throw shadows into the zone.
    terrain = Terrain([_box(-40, -30, -8, 2, 45), _box(-35, -25, 12, 22, 30)])
    q = np.array([0.0, 0.0, 1.5])
    zone = feasible_zone(q[:2], 0.0, R1, R2, MU, 2.0)
    shadows = shadow_polygons(terrain, q, 80.0, R2 + 10)
    vis = visible_zone(zone, shadows)
    blocked = shapely.union_all([s for s in shadows if not s.is_empty])
    assert vis.intersection(blocked).area < 1e-9
    assert vis.union(zone.intersection(blocked)).symmetric_difference(zone).area < 1e-6
    assert 0.1 * zone.area < zone.area - vis.area < 0.9 * zone.area           # a real cut, not all
    assert visible_zone(zone, shadow_union(terrain, q, 80.0, R2 + 10)).symmetric_difference(vis).area < 1e-9
    # Points of the visible zone see the target; points of the zone outside it do not.
    rng = np.random.default_rng(2)
    xy = sample(rng, q[:2], 20000)
    xy = xy[shapely.contains_xy(zone, xy[:, 0], xy[:, 1])]
    in_vis = shapely.contains_xy(vis, xy[:, 0], xy[:, 1])
    far = shapely.distance(vis.boundary, shapely.points(xy)) > 0.01
    clear = line_of_sight(terrain, xy, 80.0, q)
    np.testing.assert_array_equal(clear[far], in_vis[far])
    # Config version.
    cfg = Config()
    assert visible_zone_cfg(terrain, q, 0.0, cfg).symmetric_difference(vis).area < 1e-9


def test_visible_zone_edge_cases():
    zone = feasible_zone((0, 0), 0.0, R1, R2, MU)
    assert visible_zone(zone, []).equals(zone)
    assert visible_zone(zone, [Polygon()]).equals(zone)
    assert visible_zone(zone, Polygon()).equals(zone)
    assert visible_zone(zone, [Point(0, 0).buffer(200)]).is_empty
    split = visible_zone(zone, [Polygon([(-200, -1), (0, -1), (0, 1), (-200, 1)])])
    assert split.geom_type == "MultiPolygon" and len(split.geoms) == 2


def test_config_wrappers_match():
    cfg = Config(r_u=3.0)
    q, phi = np.array([3.0, 4.0]), 2.5
    assert feasible_zone_cfg(q, phi, cfg).equals(feasible_zone(q, phi, cfg.r1, cfg.r2, cfg.mu, 3.0))
    plain = feasible_zone(q, phi, cfg.r1, cfg.r2, cfg.mu)
    assert feasible_zone_cfg(q, phi, cfg, uncertain=False).equals(plain)
    assert ARC_RESOLUTION == pytest.approx(math.radians(0.25))
