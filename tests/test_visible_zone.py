"""Eq. 10 on the waypoint lattice has one home, :func:`covert_env.visibility.visible_nodes`: the env's action mask,
its observation maps, the start sampler and the DP planner's states all read it."""

from __future__ import annotations

import numpy as np

from baselines.dp.planner import DPPlanner
from covert_env import Config, Scenario, Terrain
from covert_env.envs.scene_cache import SceneCache
from covert_env.envs.settings import EnvSettings
from covert_env.scenario import start_candidates
from covert_env.visibility import SAFE_LOS_TOLERANCE, line_of_sight, visible_nodes
from covert_env.zone import in_feasible_zone, to_world, zone_lattice


def _cache(sc: Scenario) -> SceneCache:
    s = EnvSettings(sc.config, action_mode="waypoint")
    return SceneCache(sc, s.map_offsets, s.map_in_zone, s.lattice, config=sc.config)


def test_env_mask_rows_are_the_planners_visible_nodes():
    """Slot by slot on a random scene (exact predictions: the mask's poses are the track's), the env's lattice
    visibility is the DP planner's node visibility, node for node."""
    sc = Scenario.random(1_000_003)
    c, track = sc.config, sc.track
    rows = _cache(sc).lattice_visible()
    planner = DPPlanner(c, sc.terrain)
    for k in range(1, track.n_slots + 1):
        np.testing.assert_array_equal(rows[k], planner.visible_nodes(track.position(k), track.heading(k)))
    assert 0 < rows.mean() < 1                                   # shadows on this scene, and visible nodes


def test_every_lattice_node_is_offered_without_terrain_whatever_the_heading():
    """The lattice is in the eroded zone by construction (decided in the target frame): no heading may drop a
    node by the rounding of the rotation to world coordinates (a second, world-frame zone test did, on the
    eroded boundary), and the start sampler sees the same nodes."""
    c = Config()
    lattice = zone_lattice(c)
    rng = np.random.default_rng(0)
    phi = rng.uniform(-np.pi, np.pi, 200)
    q = np.column_stack([rng.uniform(-500, 500, (200, 2)), np.full(200, c.target_height)])
    assert visible_nodes(Terrain(), lattice, q, phi, c.altitude).all()
    world = to_world(lattice, q[:, :2], phi)
    dropped = ~in_feasible_zone(world, q[:, None, :2], phi[:, None], c.r1, c.r2, c.mu, c.r_u)
    assert dropped.any()                                         # what the world-frame test would have removed


def test_maps_and_starts_read_the_same_rule():
    """The observation maps' cells and the start candidates at slot 0 are visible_nodes of their offsets."""
    sc = Scenario.random(1_000_007)
    c, track = sc.config, sc.track
    s = EnvSettings(c, action_mode="waypoint")
    q, phi = track.positions[:3], track.headings[:3]
    cache = _cache(sc)
    maps = cache._maps(q, phi)
    want = visible_nodes(sc.terrain, s.map_offsets[s.map_in_zone], q, phi, c.altitude)
    np.testing.assert_array_equal(maps[:, s.map_in_zone], want.astype(np.float32))
    assert not maps[:, ~s.map_in_zone].any()
    nodes, vis, shadowed = start_candidates(c, sc.terrain, track)
    at0 = visible_nodes(sc.terrain, zone_lattice(c), track.position(0), track.heading(0), c.altitude)
    assert set(vis) | set(shadowed) <= set(range(len(nodes)))
    assert at0[vis].all() and not at0[shadowed].any()


def test_safe_tolerance_is_stricter_than_scoring():
    """A node called visible is visible when scored (polytopes grown, not shrunk)."""
    sc = Scenario.random(1_000_003)
    c, track = sc.config, sc.track
    lattice = zone_lattice(c)
    q, phi = track.positions[:20], track.headings[:20]
    safe = visible_nodes(sc.terrain, lattice, q, phi, c.altitude)
    scored = line_of_sight(sc.terrain, to_world(lattice, q[:, :2], phi), c.altitude, q[:, None, :])
    assert SAFE_LOS_TOLERANCE < 0 and not (safe & ~scored).any()
