"""Prediction error (``Config.prediction_error``, docs/decisions/model.md#prediction-error).

Default off: the truth is the prediction, bit for bit. On: the true target deviates from every
prediction (made from its true current position) by at most the bound; the planner and the
observations read the prediction, the metrics the truth; the zone eroded by r_u >= the bound
(eq. 5) keeps the UAV in the true target's zone where r_u = 0 does not, and the planner's shadows widened
to every position the error allows (docs/decisions/model.md#prediction-los) keep the line of sight to the true
target where the prediction's shadows lose it.
"""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Point

from baselines.dp import DPTeamPlanner
from covert_env import Config, Engine, Road, Scenario, TargetTrack
from covert_env.geometry.zone import in_feasible_zone, to_world, zone_lattice
from covert_env.world.road import speed_noise_offsets

BOUND = 4.0


def straight_track(n=40, speed=10.0):
    return TargetTrack.constant(Road.from_points([[0.0, 0.0], [2000.0, 0.0]]), speed, n, s0=100.0)


# ----------------------------------------------------------------------------- default: the truth is the prediction
def test_default_config_leaves_the_track_exact():
    assert Config().prediction_error == 0.0
    sc = Scenario.paper(Config())
    assert sc.track.exact and sc.track.nominal_speeds is None
    assert sc.track.with_speed_noise(0.0) is sc.track
    rnd = Scenario.random(1_000_002, Config())
    assert rnd.track.exact


def test_exact_predictions_are_the_track_bit_for_bit():
    tr = Scenario.paper(Config()).track
    f = np.linspace(0.0, 1.0, 11)
    for k in (0, 7, tr.n_slots - 3, tr.n_slots):
        q, phi = tr.predict(k, 5)
        ks = np.arange(k + 1, k + 6)
        assert np.array_equal(q, tr.position(ks)) and np.array_equal(phi, tr.heading(ks))
        if k < tr.n_slots:
            old = np.stack([tr.position_between(k + j, f) for j in range(5)])   # what the planner read before
            assert np.array_equal(tr.predict_between(k, 5, f), old)
    nxt = np.minimum(np.arange(tr.n_slots + 1) + 1, tr.n_slots)
    assert np.array_equal(tr.next_predicted[0], tr.positions[nxt])
    assert np.array_equal(tr.next_predicted[1], tr.headings[nxt])


def test_option_leaves_road_terrain_and_starts_unchanged():
    for make in (lambda c: Scenario.paper(c), lambda c: Scenario.random(1_000_001, c)):
        a, b = make(Config()), make(Config(prediction_error=BOUND))
        assert np.array_equal(a.road.points, b.road.points)
        assert np.array_equal(a.terrain.z_max, b.terrain.z_max)
        assert np.array_equal(a.uav_xy, b.uav_xy) and np.array_equal(a.uav_theta, b.uav_theta)
        assert not b.track.exact
        assert np.array_equal(b.track.nominal_speeds, a.track.speeds)
        assert np.array_equal(b.track.position(0), a.track.position(0))


# ----------------------------------------------------------------------------- the noise model
def test_speed_noise_offsets_stay_within_half_the_bound_and_never_reverse():
    rng = np.random.default_rng(0)
    step = np.full(5000, 3.0)
    e = speed_noise_offsets(step, 5.0, rng)
    assert e[0] == 0.0 and np.all(np.abs(e) <= 2.5 + 1e-12)
    assert np.all(step + np.diff(e) >= -1e-12)
    assert np.abs(np.diff(e)).max() > 4.0            # one-slot errors reach the bound: the noise is not negligible


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_prediction_error_is_bounded_over_the_horizon(seed):
    c = Config(prediction_error=BOUND)
    sc = Scenario.random(1_000_000 + seed, c)
    tr = sc.track
    assert np.all(tr.speeds >= 0) and np.all(np.diff(tr.arc) >= 0)
    worst = 0.0
    for k in range(tr.n_slots):
        q, _ = tr.predict(k, c.horizon)
        ks = np.arange(k + 1, k + c.horizon + 1)
        worst = max(worst, float(np.linalg.norm(q - tr.position(ks), axis=1).max()))
    assert worst <= BOUND + 1e-9
    assert worst > 0.5 * BOUND                       # and the option does something


def test_noise_is_seeded_by_the_scene():
    c = Config(prediction_error=BOUND)
    assert np.array_equal(Scenario.random(5, c).track.speeds, Scenario.random(5, c).track.speeds)
    assert not np.array_equal(Scenario.random(5, c).track.speeds, Scenario.random(6, c).track.speeds)
    assert np.array_equal(Scenario.paper(c).track.speeds, Scenario.paper(c).track.speeds)


def test_predict_between_starts_at_the_truth_and_ends_at_the_prediction():
    tr = straight_track().with_speed_noise(BOUND, 3)
    f = np.linspace(0.0, 1.0, 5)
    path = tr.predict_between(4, 3, f)
    q, _ = tr.predict(4, 3)
    assert np.array_equal(path[0, 0], tr.position(4))
    np.testing.assert_allclose(path[:, -1], q, atol=1e-12)
    np.testing.assert_allclose(tr.next_predicted[0][4], q[0], atol=1e-12)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), 10.5, True])
def test_config_rejects_bad_bounds(bad):
    with pytest.raises(ValueError, match="prediction_error"):
        Config(prediction_error=bad)


def test_config_accepts_r_u_below_the_bound_and_the_upper_limit():
    assert Config(prediction_error=10.0).prediction_error == 10.0          # target_speed * delta
    assert Config(prediction_error=4.0, r_u=0.0).r_u == 0.0                # allowed, without eq. 5's guarantee
    assert Config.from_json(Config(prediction_error=3.0).to_json()).prediction_error == 3.0


# ----------------------------------------------------------------------------- who sees what
def test_engine_moves_the_truth_and_predicts_from_it():
    sc = Scenario.paper(Config(prediction_error=BOUND, n_uavs=1))
    eng = Engine(sc)
    for _ in range(3):
        q_pred, _ = eng.predict()
        eng.step(waypoints=eng.uav_xy + 10.0)
        assert np.array_equal(eng.target_xyz, sc.track.position(eng.k))      # the truth
        assert np.linalg.norm(eng.target_xyz - q_pred[0]) <= BOUND + 1e-9
    traj = eng.trajectory()
    assert np.array_equal(traj.target_xyz, sc.track.positions[:4])


def test_planner_reads_the_prediction_not_the_truth():
    from baselines.dp import DPPlanner

    sc = Scenario.paper(Config(prediction_error=BOUND, n_uavs=1))
    eng = Engine(sc)
    seen = {}
    team = DPTeamPlanner(DPPlanner(sc.config, sc.terrain, check_path=True))

    def spy(uav_xy, uav_theta, target_xyz, target_phi, *, target_path=None):
        seen.update(q=np.asarray(target_xyz), path=target_path)
        return plan(uav_xy, uav_theta, target_xyz, target_phi, target_path=target_path)

    plan, team.plan = team.plan, spy
    for _ in range(4):
        team.plan_engine(eng)
        q_pred, _ = sc.track.predict(eng.k, sc.config.horizon)
        assert np.array_equal(seen["q"][0], eng.target_xyz)             # the present is observed
        assert np.array_equal(seen["q"][1:], q_pred)
        f = np.linspace(0.0, 1.0, team.planner.path_samples)
        assert np.array_equal(seen["path"], sc.track.predict_between(eng.k, sc.config.horizon, f))
        eng.step(waypoints=team.plan_engine(eng).waypoints)
    assert not np.allclose(seen["q"][1:], sc.track.position(np.arange(eng.k + 1, eng.k + 6)))


def test_env_observations_read_the_prediction():
    from covert_env.envs.covert_sensing import CovertSensingParallelEnv

    c = Config(prediction_error=BOUND, n_uavs=1)
    sc = Scenario.paper(c)
    env = CovertSensingParallelEnv(scenario=sc, action_mode="waypoint")
    obs, _ = env.reset(seed=0)
    tr = sc.track
    for k in range(3):
        block = obs["uav_0"][env.layout.slices["target_displacement"]]
        q, phi = tr.positions[k], tr.headings[k]
        qn = tr.next_predicted[0][k]
        d = qn[:2] - q[:2]
        scale = c.v_max * c.delta
        np.testing.assert_allclose(block[0], (np.cos(phi) * d[0] + np.sin(phi) * d[1]) / scale, rtol=1e-5)
        np.testing.assert_allclose(block[1], (np.cos(phi) * d[1] - np.sin(phi) * d[0]) / scale, atol=1e-6)
        obs, *_ = env.step({a: int(np.flatnonzero(env.action_mask(a))[0]) for a in env.agents})


# ----------------------------------------------------------------------------- eq. 5: what the erosion guarantees
def test_eroded_zone_around_the_prediction_lies_in_the_true_zone_on_a_straight_road():
    c = Config(prediction_error=BOUND, r_u=BOUND)
    tr = straight_track().with_speed_noise(BOUND, 11)
    off = zone_lattice(c)                                                   # nodes of the zone eroded by r_u
    for k in range(tr.n_slots - c.horizon):
        q, phi = tr.predict(k, c.horizon)
        for j in range(c.horizon):
            nodes = to_world(off, q[j, :2], float(phi[j]))
            qt = tr.position(k + 1 + j)
            assert in_feasible_zone(nodes, qt[:2], float(tr.heading(k + 1 + j)), c.r1, c.r2, c.mu).all()
    loose = Config(prediction_error=BOUND, r_u=0.0)
    q, phi = tr.predict(0, 1)
    nodes = to_world(zone_lattice(loose), q[0, :2], float(phi[0]))
    true_q = tr.position(1)
    if not np.array_equal(true_q, q[0]):
        assert not in_feasible_zone(nodes, true_q[:2], float(tr.heading(1)), c.r1, c.r2, c.mu).all()


@pytest.mark.slow
def test_dp_keeps_the_true_zone_with_r_u_at_the_bound_and_leaves_it_without(tmp_path):
    """The paper scene and held-out scene 1_000_003, 1 UAV, 25 slots, bound 4 m (counts of the
    deterministic runs; see baselines/prediction_study.py for the table, written here with its figure)."""
    from baselines.prediction_study import RATES, prediction_study, study_figure, study_markdown, variants

    loose_v, _, widened_v = variants(BOUND)
    rows = prediction_study(bound=BOUND, scenes=(("paper", 0), ("random", 1_000_003)), n_uavs=1, n_slots=25,
                            compared=(loose_v, widened_v))
    loose, eroded = rows
    assert loose["r_u"] == 0.0 and eroded["r_u"] == BOUND and eroded["los_margin"] == BOUND
    assert loose["uav_slots"] == eroded["uav_slots"] == 50
    assert loose["zone_violations"] >= 3
    assert eroded["zone_violations"] == 0 and eroded["max_zone_distance"] < 0.0
    table = study_markdown(rows, 2, 25, 1)
    assert table.count("\n| r_u = 0 | 0 | 0 | 50 | ") == 1
    assert table.count("\n| eroded + widened shadows | 4 | 4 | 50 | ") == 1
    assert f"({loose['zone_violations']})" in table
    for r in rows:                                                      # every rate with its interval over scenes
        line = next(ln for ln in table.splitlines() if ln.startswith(f"| {r['planner']} |"))
        assert line.count(" [") == len(RATES)
        lo, hi = r["rate_zone_violations_ci"]
        assert lo <= r["rate_zone_violations"] <= hi
    assert study_figure(rows, tmp_path / "fig.png", 2) == "fig.png"
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------- eq. 10 under the error: widened shadows
#: Held-out scenes and slots whose zone has shadows near its nodes (1_000_002: slots 0-30, 1_000_004: 0-10,
#: 1_000_005: 40-50), every 5 slots.
SHADOWED = ((2, range(0, 31, 5)), (4, range(0, 11, 5)), (5, range(40, 51, 5)))


def _shadowed_slots(c, scenes=SHADOWED):
    """(scene, q, phi) at slot times of held-out scenes, the predicted target exact."""
    for seed, slots in scenes:
        sc = Scenario.random(1_000_000 + seed, c)
        for k in slots:
            yield sc, sc.track.position(k), float(sc.track.heading(k))


def test_widened_visibility_covers_every_position_along_the_road():
    """The sampled check (17 samples, polytopes grown by 0.25 m) is a proof, not an estimate: a node it keeps
    sees all 401 road points within the margin (2 cm apart) with the planner's own LoS check; it drops more
    nodes than the prediction-only check somewhere, and with one target and no growth it is line_of_sight."""
    from baselines.dp.possible_targets import PossibleTargets, clear_to_all
    from covert_env.world.visibility import SAFE_LOS_TOLERANCE as VISIBILITY_TOL
    from covert_env.world.visibility import line_of_sight

    c = Config(prediction_error=BOUND, r_u=BOUND)
    off = zone_lattice(c)
    widened_more = dense_more = 0
    for sc, q, phi in _shadowed_slots(c):
        xy = to_world(off, q[:2], phi)
        pt = PossibleTargets(BOUND, sc.track.road)
        keep = pt.visible(sc.terrain, xy, c.altitude, q, VISIBILITY_TOL)
        at_q = line_of_sight(sc.terrain, xy, c.altitude, q, tol=VISIBILITY_TOL)
        np.testing.assert_array_equal(clear_to_all(sc.terrain, xy, c.altitude, q[None], -VISIBILITY_TOL), at_q)
        s = sc.road.linestring.project(Point(q[0], q[1])) + np.linspace(-BOUND, BOUND, 401)
        dense = np.column_stack([sc.road.point_at(s), np.full(401, q[2])])
        sees_all = line_of_sight(sc.terrain, np.repeat(xy[:, None], 401, axis=1), c.altitude, dense[None],
                                 tol=VISIBILITY_TOL).all(axis=1)
        assert not (keep & ~sees_all).any()                      # never keeps a node that loses some position
        assert not (keep & ~at_q).any()
        widened_more += int((at_q & ~keep).sum())
        dense_more += int((at_q & ~sees_all).sum())
    assert dense_more > 0 and widened_more >= dense_more          # the error does hide nodes the paper keeps


def test_disk_without_a_road_is_more_cautious_than_the_road_piece():
    """Without a road the possible positions are eq. 5's disk: every node it keeps, the road piece keeps too,
    and it drops some the road piece keeps; its samples stay within the margin plus their covering radius."""
    from baselines.dp.possible_targets import PossibleTargets
    from covert_env.world.visibility import SAFE_LOS_TOLERANCE as VISIBILITY_TOL

    c = Config(prediction_error=BOUND, r_u=BOUND)
    off = zone_lattice(c)
    tighter = 0
    for sc, q, phi in _shadowed_slots(c, ((2, (0, 15)), (4, (0,)))):
        xy = to_world(off, q[:2], phi)
        on_road = PossibleTargets(BOUND, sc.track.road).visible(sc.terrain, xy, c.altitude, q, VISIBILITY_TOL)
        disk = PossibleTargets(BOUND).visible(sc.terrain, xy, c.altitude, q, VISIBILITY_TOL)
        assert not (disk & ~on_road).any()
        tighter += int((on_road & ~disk).sum())
        pts = PossibleTargets(BOUND).samples(q)
        assert np.hypot(*(pts[:, :2] - q[:2]).T).max() <= BOUND + 0.25 + 1e-12
    assert tighter > 0


def test_possible_targets_refuse_a_prediction_off_their_road_and_bad_margins():
    from baselines.dp.possible_targets import PossibleTargets

    road = Road.from_points([[0.0, 0.0], [100.0, 0.0]])
    pt = PossibleTargets(BOUND, road)
    s = pt.samples([50.0, 0.0, 1.5])
    assert np.all(s[:, 1] == 0.0) and s[:, 0].min() == 46.0 and s[:, 0].max() == 54.0
    assert np.diff(s[:, 0]).max() <= 0.5 + 1e-12                       # at most 2 x SAMPLE_COVER apart
    end = pt.samples([99.0, 0.0, 1.5])
    assert end[:, 0].max() == 100.0 and end[:, 0].min() == 95.0         # clamped at the road's end, like the track
    with pytest.raises(ValueError, match="from the road"):
        pt.samples([50.0, 3.0, 1.5])
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match="margin"):
            PossibleTargets(bad, road)


def test_planner_margin_rule_and_the_paper_setting_unchanged():
    from baselines.dp import DPPlanner
    from covert_env.world.visibility import SAFE_LOS_TOLERANCE as VISIBILITY_TOL
    from covert_env.world.visibility import line_of_sight

    sc = Scenario.random(1_000_000, Config())
    paper = DPPlanner(Config(), sc.terrain, road=sc.track.road)
    assert paper.los_margin == 0.0 and paper.possible_targets is None and paper.name == "dp-aware-inherited"
    q, phi = sc.track.position(0), float(sc.track.heading(0))
    np.testing.assert_array_equal(paper.visible_nodes(q, phi),
                                  line_of_sight(sc.terrain, to_world(paper.lattice, q[:2], phi),
                                                Config().altitude, q, tol=VISIBILITY_TOL))
    noisy = Config(prediction_error=BOUND, r_u=3.0)
    assert DPPlanner(noisy, sc.terrain).los_margin == 3.0
    assert DPPlanner(noisy, sc.terrain, los_margin=0.0).possible_targets is None
    wide = DPPlanner(noisy, sc.terrain, road=sc.track.road)
    at_q = DPPlanner(noisy, sc.terrain, los_margin=0.0).visible_nodes(q, phi)
    assert wide.name == "dp-aware-inherited-los3"
    assert not (wide.visible_nodes(q, phi) & ~at_q).any()
    assert (at_q & ~wide.visible_nodes(q, phi)).any()                         # this slot is shadowed
    assert (at_q & ~wide.allowed_nodes(q, phi)).any()                          # and the DP sees the difference
    for bad in (-1.0, float("inf"), "2"):
        with pytest.raises(ValueError, match="los_margin"):
            DPPlanner(noisy, sc.terrain, los_margin=bad)


@pytest.mark.slow
def test_widened_shadows_keep_los_to_the_true_target_where_the_prediction_loses_it():
    """3 UAVs, bound 4 m. Held-out scene 1_000_000, 30 slots: the r_u = 0 planner loses LoS to the true target;
    held-out scene 1_000_002, 20 slots: the eroded zone with the prediction's shadows (the paper's eq. 10 with
    r_u = 4 m) loses it too. On the same slots the eroded zone with widened shadows keeps LoS on every planned move
    and stays in the true zone. (The first held-out scenes where each effect shows; the runs are deterministic.)"""
    from baselines.prediction_study import prediction_study, variants

    loose_v, eroded_v, widened_v = variants(BOUND)
    for scene, n_slots, baseline in ((("random", 1_000_000), 30, loose_v), (("random", 1_000_002), 20, eroded_v)):
        before, after = prediction_study(bound=BOUND, scenes=(scene,), n_uavs=3, n_slots=n_slots,
                                         compared=(baseline, widened_v))
        assert before["uav_slots"] == after["uav_slots"] == 3 * n_slots
        assert before["blocked_planned"] >= 1, scene                  # the effect is there to be removed
        assert after["blocked_planned"] == 0 and after["blocked"] == 0, scene
        assert after["zone_violations"] == 0 and after["max_zone_distance"] < 0.0, scene


def test_reproduce_has_the_prediction_study_flag():
    from baselines.reproduce import build_parser

    assert build_parser().parse_args(["--out", "x", "--prediction-study"]).prediction_study
    assert not build_parser().parse_args(["--out", "x"]).prediction_study
