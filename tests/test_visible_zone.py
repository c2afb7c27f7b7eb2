"""Eq. 10 on the waypoint lattice has one home, :func:`covert_env.world.visibility.visible_nodes`: the env's action
mask, its observation maps, the start sampler and the DP planner's states all read it."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.dp.planner import DPPlanner
from covert_env import Config, Polytope, Scenario, Terrain
from covert_env.envs.observation import shared_block_slices
from covert_env.envs.scene_pool import ScenePool
from covert_env.envs.settings import EnvSettings
from covert_env.geometry.zone import in_feasible_zone, to_world, zone_distance, zone_lattice
from covert_env.world.families import family_config
from covert_env.world.scenario import start_candidates
from covert_env.world.visibility import LOS_TOLERANCE, line_of_sight, visible_nodes


def _pool(sc: Scenario) -> tuple[ScenePool, int]:
    """A waypoint env's scene pool holding the scene ``sc``, and its row."""
    s = EnvSettings(sc.config, action_mode="waypoint")
    pool = ScenePool(sc, sc.config, s.lattice, s.map_offsets, s.map_in_zone, waypoint=True, capacity=1)
    return pool, pool.row(pool.key(None), np.zeros(0, int))


def _lattice_visible(sc: Scenario) -> np.ndarray:
    pool, row = _pool(sc)
    return pool.lattice_ok[row]


def test_env_mask_rows_are_the_planners_visible_nodes():
    """Slot by slot on a random scene (exact predictions: the mask's poses are the track's), the env's lattice
    visibility is the DP planner's node visibility, node for node."""
    sc = Scenario.random(1_000_003)
    c, track = sc.config, sc.track
    rows = _lattice_visible(sc)
    planner = DPPlanner(c, sc.terrain)
    for k in range(1, track.n_slots + 1):
        np.testing.assert_array_equal(rows[k], planner.visible_nodes(track.position(k), track.heading(k)))
    assert 0 < rows.mean() < 1                                   # shadows on this scene, and visible nodes


def test_every_lattice_node_is_offered_without_terrain_whatever_the_heading():
    """The lattice is in the eroded zone by construction (decided in the target frame): on a scene without
    polytopes the env offers every node at every slot and the start sampler sees every node, whatever the heading
    (a second, world-frame zone test dropped nodes on the eroded boundary by rounding)."""
    c = family_config("winding")                                 # a road that turns: many rotations
    lattice = zone_lattice(c)
    sc = Scenario.random(1_000_005, c)
    empty = Scenario(c, Terrain(), sc.track, sc.uav_xy, sc.uav_theta, name="empty")
    assert _lattice_visible(empty).all()
    nodes, vis, shadowed = start_candidates(c, Terrain(), sc.track)
    assert len(vis) == len(nodes) == len(lattice) and len(shadowed) == 0
    rng = np.random.default_rng(0)
    phi = rng.uniform(-np.pi, np.pi, 200)
    q = np.column_stack([rng.uniform(-500, 500, (200, 2)), np.full(200, c.target_height)])
    assert visible_nodes(Terrain(), lattice, q, phi, c.altitude).all()
    world = to_world(lattice, q[:, :2], phi)
    dropped = ~in_feasible_zone(world, q[:, None, :2], phi[:, None], c.r1, c.r2, c.mu, c.r_u)
    assert dropped.any()                                         # what the world-frame test would have removed
    assert np.ptp(sc.track.headings) > 0.5


@pytest.mark.parametrize("r_u", [0.0, 2.0])
def test_no_offered_node_is_outside_the_zone_the_cost_checks(r_u):
    """With r_u = 0 lattice nodes could lie on the zone's boundary, and the rotation to world coordinates round
    them out of the zone the cost checks (zone_distance > 0): the lattice keeps ZONE_MARGIN inside it."""
    c = Config(r_u=r_u)
    lattice = zone_lattice(c)
    rng = np.random.default_rng(1)
    q = rng.uniform(-2000, 2000, (500, 2))
    phi = rng.uniform(-np.pi, np.pi, 500)
    assert (zone_distance(to_world(lattice, q, phi), q[:, None], phi[:, None], c.r1, c.r2, c.mu) <= 0).all()
    assert len(zone_lattice(Config())) == 577                    # the default lattice (the action space) as before


def test_the_mask_promises_more_than_scoring_needs():
    """A sight line lying in a polytope's face plane touches it: clear when scored (touching is clear), but not a
    visible node: the planner's and the mask's polytopes are grown by SAFE_LOS_TOLERANCE."""
    box = Polytope(np.array([[10.0, -5.0], [20.0, -5.0], [20.0, 5.0], [10.0, 5.0]]),
                   np.array([[10.0, -5.0, 40.0], [20.0, -5.0, 40.0], [20.0, 5.0, 40.0], [10.0, 5.0, 40.0]]))
    terrain = Terrain([box])
    q = np.array([0.0, 5.0, 1.5])                                 # the segment to (30, 5) runs in the face y = 5
    assert line_of_sight(terrain, np.array([[30.0, 5.0]]), 80.0, q)[0]
    assert not visible_nodes(terrain, np.array([[30.0, 0.0]]), q, 0.0, 80.0)[0]
    assert visible_nodes(terrain, np.array([[30.0, 0.0]]), q, 0.0, 80.0, tol=LOS_TOLERANCE)[0]


def test_maps_and_starts_read_the_same_rule():
    """The observation maps' cells and the start candidates at slot 0 are visible_nodes of their offsets."""
    sc = Scenario.random(1_000_007)
    c, track = sc.config, sc.track
    s = EnvSettings(c, action_mode="waypoint")
    q, phi = track.positions, track.headings
    pool, row = _pool(sc)
    at = shared_block_slices(len(s.map_offsets))
    maps = pool.blocks[row][:, at["map_now"]]
    want = visible_nodes(sc.terrain, s.map_offsets[s.map_in_zone], q, phi, c.altitude)
    np.testing.assert_array_equal(maps[:, s.map_in_zone], want.astype(np.float32))
    assert not maps[:, ~s.map_in_zone].any()
    assert 0 < maps[:, s.map_in_zone].mean() < 1
    nxt = np.minimum(np.arange(len(q)) + 1, len(q) - 1)
    np.testing.assert_array_equal(pool.blocks[row][:, at["map_next"]], maps[nxt])
    np.testing.assert_array_equal(pool.start_visible[row], visible_nodes(sc.terrain, zone_lattice(c), q[0], phi[0],
                                                                         c.altitude))
    nodes, vis, shadowed = start_candidates(c, sc.terrain, track)
    at0 = visible_nodes(sc.terrain, zone_lattice(c), track.position(0), track.heading(0), c.altitude)
    assert set(vis) | set(shadowed) <= set(range(len(nodes)))
    assert at0[vis].all() and not at0[shadowed].any()
