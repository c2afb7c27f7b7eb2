"""covert_env.world.scenario: the paper preset (§3) and seeded random scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from covert_env.geometry.zone import grid_nodes, in_feasible_zone
from covert_env.world.config import Config
from covert_env.world.road import Road, TargetTrack
from covert_env.world.scenario import PAPER_UAV_STARTS, Scenario
from covert_env.world.terrain import Terrain
from covert_env.world.visibility import line_of_sight

PAPER_XY = np.array([[40.0, 10.0], [60.0, 0.0], [50.0, -10.0]])
PAPER_THETA = np.array([2 * math.pi, math.pi, math.pi / 2])


@pytest.fixture(scope="module")
def paper():
    return Scenario.paper()


def terrain_vertices(terrain):
    return [np.asarray(p.vertices) for p in terrain]


def assert_same_terrain(a, b):
    va, vb = terrain_vertices(a), terrain_vertices(b)
    assert len(va) == len(vb)
    for x, y in zip(va, vb, strict=True):
        np.testing.assert_array_equal(x, y)


# ----------------------------------------------------------------------------- paper preset
def test_paper_target_at_slot_0(paper):
    c = paper.config
    np.testing.assert_allclose(paper.track.position(0), [120.0, 0.0, c.target_height], atol=1e-9)
    assert paper.track.heading(0) == pytest.approx(0.0, abs=1e-12)
    # The road is straight through the zone at the start: the target keeps heading 0 for the first slots.
    for k in range(3):
        assert paper.track.heading(k) == pytest.approx(0.0, abs=1e-12)
        assert paper.track.position(k)[1] == pytest.approx(0.0, abs=1e-9)
    assert paper.track.position(1)[0] == pytest.approx(120.0 + c.target_speed * c.delta, abs=1e-9)


def test_paper_starts_are_the_papers(paper):
    assert paper.n_uavs == 3
    np.testing.assert_array_equal(paper.uav_xy, PAPER_XY)
    np.testing.assert_allclose(paper.uav_theta, PAPER_THETA, atol=1e-12)
    np.testing.assert_array_equal(PAPER_UAV_STARTS[:, :2], PAPER_XY)


def test_paper_starts_are_in_the_eroded_zone_with_clear_los(paper):
    c = paper.config
    q0, phi0 = paper.track.position(0), paper.track.heading(0)
    assert c.r_u > 0
    assert in_feasible_zone(paper.uav_xy, q0[:2], phi0, c.r1, c.r2, c.mu, c.r_u).all()
    assert line_of_sight(paper.terrain, paper.uav_xy, c.altitude, q0).all()


def test_paper_terrain_and_track(paper):
    c = paper.config
    assert len(paper.terrain) == 16 == c.n_polytopes
    assert paper.track.n_slots >= c.n_slots + c.horizon
    assert paper.track.position(c.n_slots + c.horizon).shape == (3,)
    # The track really drives at target_speed until n_slots + horizon (no clamping at the road's end).
    arc = paper.track.arc
    assert arc[c.n_slots + c.horizon] <= paper.road.length
    steps = np.linalg.norm(np.diff(paper.track.position(np.arange(c.n_slots + c.horizon + 1))[:, :2], axis=0), axis=1)
    assert np.all(steps <= c.target_speed * c.delta + 1e-9)
    assert np.all(steps >= 0.9 * c.target_speed * c.delta)      # chords of a gently curving road
    for p in paper.terrain:
        assert p.z_max < c.altitude


def test_paper_is_deterministic():
    a, b = Scenario.paper(), Scenario.paper()
    assert_same_terrain(a.terrain, b.terrain)
    np.testing.assert_array_equal(a.road.points, b.road.points)


@pytest.mark.parametrize("u", [1, 2, 3])
def test_paper_team_sizes(u):
    s = Scenario.paper(n_uavs=u)
    assert s.n_uavs == u
    np.testing.assert_array_equal(s.uav_xy, PAPER_XY[:u])
    np.testing.assert_allclose(s.uav_theta, PAPER_THETA[:u])


def test_paper_team_size_from_config():
    s = Scenario.paper(Config(n_uavs=1))
    assert s.n_uavs == 1
    np.testing.assert_array_equal(s.uav_xy, PAPER_XY[:1])


@pytest.mark.parametrize("u", [0, 4, -1])
def test_paper_invalid_team_size_names_n_uavs(u):
    with pytest.raises(ValueError, match="n_uavs"):
        Scenario.paper(n_uavs=u)


def test_paper_respects_config_lengths():
    c = Config(n_slots=12, horizon=3)
    s = Scenario.paper(c)
    assert s.config is c
    assert s.track.n_slots >= 15


# ----------------------------------------------------------------------------- random scenes
@pytest.mark.parametrize("seed", [0, 5, 123])
def test_random_is_deterministic_per_seed(seed):
    a, b = Scenario.random(seed), Scenario.random(seed)
    assert_same_terrain(a.terrain, b.terrain)
    np.testing.assert_array_equal(a.road.points, b.road.points)
    np.testing.assert_array_equal(a.uav_xy, b.uav_xy)
    np.testing.assert_array_equal(a.uav_theta, b.uav_theta)
    np.testing.assert_array_equal(a.track.speeds, b.track.speeds)


def test_random_differs_between_seeds():
    a, b = Scenario.random(1), Scenario.random(2)
    assert not (a.road.points.shape == b.road.points.shape and np.allclose(a.road.points, b.road.points))
    assert not np.allclose(terrain_vertices(a.terrain)[0].mean(0), terrain_vertices(b.terrain)[0].mean(0))


@pytest.mark.parametrize("seed", range(8))
def test_random_starts_visible_and_separated(seed):
    s = Scenario.random(seed)
    c = s.config
    assert s.n_uavs == c.n_uavs == 3
    assert len(s.terrain) == c.n_polytopes
    q0, phi0 = s.track.position(0), s.track.heading(0)
    assert in_feasible_zone(s.uav_xy, q0[:2], phi0, c.r1, c.r2, c.mu, c.r_u).all()
    assert line_of_sight(s.terrain, s.uav_xy, c.altitude, q0).all()
    diff = s.uav_xy[:, None] - s.uav_xy[None]
    dist = np.hypot(diff[..., 0], diff[..., 1])[np.triu_indices(s.n_uavs, 1)]
    assert dist.min() >= 2 * c.d_safe1 - 1e-9
    assert np.all((s.uav_theta >= 0) & (s.uav_theta < 2 * math.pi))
    assert s.track.n_slots >= c.n_slots + c.horizon
    # Starts are waypoint-lattice nodes: multiples of grid_step in the target's frame.
    rel = s.uav_xy - q0[:2]
    cph, sph = math.cos(phi0), math.sin(phi0)
    local = np.column_stack([cph * rel[:, 0] + sph * rel[:, 1], -sph * rel[:, 0] + cph * rel[:, 1]])
    np.testing.assert_allclose(local / c.grid_step, np.round(local / c.grid_step), atol=1e-6)


@pytest.mark.parametrize("seed", [4, 12, 21])
def test_starts_keep_clear_of_tall_tops(seed):
    """Eq. 3 at the start. With tops up to 79 m (1 m below the flight altitude) 25-28 zone nodes of these scenes
    lie within d_safe2 of a top at slot 0; the starts a scene and the env place never do, and stay d_safe1 apart
    (eq. 2)."""
    import covert_env

    c = Config(max_height=79.0)

    def clearance(xy):                                     # eq. 3, measured here independently
        tops = s.terrain.highest_points
        flat = np.concatenate([xy, np.full((len(xy), 1), c.altitude)], axis=1)
        return np.linalg.norm(flat[:, None] - tops[None], axis=-1).min(axis=1)

    s = Scenario.random(seed, c)
    q0, phi0 = s.track.position(0), float(s.track.heading(0))
    assert (clearance(grid_nodes(q0[:2], phi0, c.grid_step, c.r1, c.r2, c.mu, c.r_u)) < c.d_safe2).any()
    env = covert_env.vector_env(num_envs=8, config=c, random_starts=True)
    env.reset(seed=seed, options={"scene_seed": seed})
    for xy in [s.uav_xy, *env.uav_xy]:
        assert clearance(xy).min() >= c.d_safe2
        assert np.linalg.norm(xy[:, None] - xy[None], axis=-1)[np.triu_indices(len(xy), 1)].min() >= c.d_safe1


@pytest.mark.parametrize("u", [1, 3, 5])
def test_random_team_sizes(u):
    s = Scenario.random(4, n_uavs=u)
    assert s.uav_xy.shape == (u, 2) and s.uav_theta.shape == (u,)


@pytest.mark.parametrize("u", [0, -1])
def test_random_invalid_team_size_names_n_uavs(u):
    with pytest.raises(ValueError, match="n_uavs"):
        Scenario.random(0, n_uavs=u)


# ----------------------------------------------------------------------------- validation
def _track(n, road=None):
    road = road or Road([[0.0, 0.0], [2000.0, 0.0]])
    return TargetTrack.constant(road, 10.0, n, s0=100.0)


def test_scenario_requires_track_long_enough():
    c = Config(n_slots=10, horizon=5)
    Scenario(c, Terrain(), _track(15), [[0.0, 0.0]], [0.0])
    with pytest.raises(ValueError, match="track"):
        Scenario(c, Terrain(), _track(14), [[0.0, 0.0]], [0.0])


def test_scenario_rejects_mismatched_or_non_finite_starts():
    c = Config(n_slots=10, horizon=5)
    with pytest.raises(ValueError, match="start"):
        Scenario(c, Terrain(), _track(20), [[0.0, 0.0], [1.0, 1.0]], [0.0])
    with pytest.raises(ValueError, match="finite"):
        Scenario(c, Terrain(), _track(20), [[0.0, np.nan]], [0.0])
    with pytest.raises(ValueError, match="finite"):
        Scenario(c, Terrain(), _track(20), [[0.0, 0.0]], [np.inf])


def test_scenario_normalises_start_arrays():
    c = Config(n_slots=10, horizon=5)
    s = Scenario(c, Terrain(), _track(20), [1.0, 2.0], 0.5)
    assert s.uav_xy.shape == (1, 2) and s.uav_theta.shape == (1,)
    assert s.n_uavs == 1


def _pick_one_by_one(c, nodes, visible, shadowed, rng, u):
    """The start rule of Scenario.sample_starts written one candidate at a time: the visible nodes in random order at
    2 d_safe1 apart, then with the shadowed ones after them, then at d_safe1, then on the zone lattice with the
    margin; a candidate is taken if eq. 2's distance to every earlier pick is at least the spacing."""
    from covert_env.geometry.zone import SPREAD_MARGIN, zone_lattice

    def greedy(points, order, spacing):
        picked = []
        for i in order:
            if len(picked) < u and all(np.hypot(*(points[i] - points[j])) >= spacing for j in picked):
                picked.append(int(i))
        return picked

    order = visible[rng.permutation(len(visible))]
    picked = greedy(nodes, order, 2 * c.d_safe1)
    if len(picked) < u:
        order = np.concatenate([order, shadowed[rng.permutation(len(shadowed))]])
        for spacing in (2 * c.d_safe1, c.d_safe1):
            picked = greedy(nodes, order, spacing)
            if len(picked) == u:
                break
        else:
            picked = greedy(zone_lattice(c), np.union1d(visible, shadowed), c.d_safe1 * (1 + SPREAD_MARGIN))
    return nodes[picked], rng.uniform(0, 2 * np.pi, u)


def test_starts_of_many_copies_are_each_copys_sequential_picks():
    """pick_starts_many (the vector env's reset: step 1 for every copy at once) gives each copy the starts of the
    sequential rule with its own generator, also for copies whose visible nodes are too few or none (the fallbacks),
    and leaves each generator where the sequential rule leaves it."""
    from covert_env.world.scenario import pick_starts_many, start_candidates

    c = Config()
    worlds = [Scenario.random_world(s, c) for s in range(8)]
    cands = [start_candidates(c, t, tr) for t, tr, _ in worlds]
    nodes = np.stack([n for n, _, _ in cands])
    vis, sh = [v for _, v, _ in cands], [s for _, _, s in cands]
    vis[1], sh[1] = vis[1][:2], np.concatenate([sh[1], vis[1][2:]])        # too few visible: fallback 2
    vis[2], sh[2] = vis[2][:0], np.concatenate([sh[2], vis[2]])            # none visible
    vis[3] = vis[3][:40]                                                    # few, close together
    for u in (1, 3, 5):
        got = pick_starts_many(c, nodes, vis, sh, [np.random.default_rng(n) for n in range(8)], u, ["x"] * 8)
        for n in range(8):
            rng = np.random.default_rng(n)
            xy, th = _pick_one_by_one(c, nodes[n], vis[n], sh[n], rng, u)
            np.testing.assert_array_equal(got[0][n], xy)
            np.testing.assert_array_equal(got[1][n], th)
    assert got[0].shape == (8, 5, 2)
