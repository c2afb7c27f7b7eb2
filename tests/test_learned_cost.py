"""The planner with a learned path cost: the blocked share it charges, its DP against a dense reference, the learning
script and the files it writes (docs/decisions/planner.md#a-learned-cost-in-the-planners-search)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from _dense_dp import dense_dp
from hypothesis import example, given, settings
from hypothesis import strategies as st

from baselines.dp import DPPlanner
from baselines.dp.clearance import take_manoeuvres
from baselines.dp.path_checks import PathChecker, PathContext
from baselines.learned_cost import load_cost_planner, path_cost_of
from baselines.reproduce import HELDOUT_SEED_BASE, make_scenario
from covert_env import Config, Polytope, Scenario, Terrain
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.zone import to_world
from covert_env.world.shadows import shadow_union_cfg
from covert_env.world.tasks import get_task
from covert_env.world.visibility import SAFE_LOS_TOLERANCE, line_of_sight

P = 21  # the planner's path samples per slot


def _poses(sc: Scenario, k: int, horizon: int):
    ks = np.arange(k, k + horizon + 1)
    return sc.track.position(ks), np.asarray(sc.track.heading(ks))


def _blocked_reference(terrain, config, m, target_samples) -> np.ndarray:
    """(K, P - 1): whether sample i (1..P-1) of each manoeuvre is without LoS (eq. 6, exact, at the tolerance of a
    promised line of sight) to the target at the same instant, one instant at a time."""
    pts = m.points(P)[..., 1:, :]
    return np.stack([~line_of_sight(terrain, pts[:, i], config.altitude, target_samples[i], tol=SAFE_LOS_TOLERANCE)
                     for i in range(P - 1)], axis=1)


#: Growth (m) of the shadows in the independent check: shadows equal the blocked set up to ~1e-8 m at their boundary
#: (tests/test_visibility.py checks 1 cm).
SHADOW_GROWTH = 0.01


def _shadow_blocked(terrain, config, pts, target_samples) -> tuple[np.ndarray, np.ndarray]:
    """An oracle independent of the line-of-sight kernel, per sample (K, S): inside the shadows (eqs. 8-9) grown by
    SHADOW_GROWTH, and within SHADOW_GROWTH (+1 mm) of a shadow boundary."""
    blocked, near = np.zeros(pts.shape[:2], bool), np.zeros(pts.shape[:2], bool)
    for i, q in enumerate(target_samples):
        sh = shadow_union_cfg(terrain, q, config)
        if sh.is_empty:
            continue
        blocked[:, i] = shapely.intersects_xy(sh.buffer(SHADOW_GROWTH, quad_segs=2), pts[:, i, 0], pts[:, i, 1])
        near[:, i] = shapely.dwithin(sh.boundary, shapely.points(pts[:, i]), SHADOW_GROWTH + 1e-3)
    return blocked, near


def _random_manoeuvres(c, scene, k, seed, n, outward=1.0):
    """A planner with a path cost on scene ``scene`` (0: the paper's), the target samples of slots k..k+N, and ``n``
    random manoeuvres (random start headings) from stage-1 to stage-2 zone nodes, every second start moved
    ``outward`` times as far from the target; returns (scenario, planner, context, manoeuvres, feasible)."""
    sc = Scenario.paper(c, 1) if scene == 0 else make_scenario("random", HELDOUT_SEED_BASE + scene, 1, c)
    pl = DPPlanner(c, sc.terrain, path_cost=[100.0] * c.horizon)
    tq, tp = _poses(sc, k, c.horizon)
    ctx = pl.paths.context(tq, tp, None)
    a_stage, b_stage = pl.cache.stage(tq[1], tp[1]), pl.cache.stage(tq[2], tp[2])
    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, len(pl.lattice), (2, n))
    start = a_stage.xy[a]
    if outward != 1.0:
        start[::2] = tq[1, :2] + outward * (start[::2] - tq[1, :2])
    m = solve_manoeuvre(start, rng.uniform(-np.pi, np.pi, n), b_stage.xy[b], v_max=c.v_max, w_max=c.w_max,
                        delta=c.delta)
    return sc, pl, ctx, m, np.asarray(m.feasible, bool).copy()


@settings(max_examples=12, deadline=None)
@given(scene=st.integers(0, 3), k=st.integers(0, 64), seed=st.integers(0, 2**16), h_min=st.sampled_from([None, 30.0]),
       outward=st.sampled_from([1.0, 1.3]))
@example(scene=0, k=60, seed=60, h_min=None, outward=1.3)
@example(scene=3, k=30, seed=30, h_min=None, outward=1.3)
@example(scene=0, k=56, seed=1, h_min=None, outward=1.3)   # 504 blocked samples in reach; 1 in the shadows' growth
def test_blocked_share_is_the_exact_los_along_the_manoeuvre(scene, k, seed, h_min, outward):
    """Property: for random manoeuvres between zone nodes of consecutive stages (with ``outward``, every second start
    moved that many times as far from the target, beyond the zone), the planner's share, every (manoeuvre, instant) in
    one call, equals eq. 6 checked one instant at a time at every sample, bit for bit, at the tolerance of a promised
    line of sight; and, where the shadows (eqs. 8-9, an oracle without the kernel) reach, every sample agrees with
    them but within their growth of a boundary."""
    sc, pl, ctx, m, ok = _random_manoeuvres(Config(h_min=h_min), scene, k, seed, 300, outward)
    c = pl.config
    share = pl.paths.blocked_share(m, ok, ctx, 1)
    ref = _blocked_reference(sc.terrain, c, take_manoeuvres(m, np.flatnonzero(ok)), ctx.target[1, 1:])
    np.testing.assert_array_equal(share, ref.sum(axis=1) / (P - 1))
    # Against the shadows, sample by sample where a sample is within their radius: the same decisions, except that the
    # grown shadows may call a sample blocked within their growth of a boundary.
    pts = take_manoeuvres(m, np.flatnonzero(ok)).points(P)[:, 1:]
    inside = (np.hypot(*(pts - ctx.target[1, 1:, None, :2].transpose(1, 0, 2)).transpose(2, 0, 1))
              < c.r2 + c.shadow_margin - 2 * SHADOW_GROWTH)
    if h_min is None:
        grown, near = _shadow_blocked(sc.terrain, c, pts, ctx.target[1, 1:])
        differ = inside & (grown != ref)
        assert np.all(grown[differ] & near[differ])


@pytest.mark.parametrize("gap,blocked", [(0.5e-6, True), (5e-6, False)])
def test_blocked_share_is_conservative_by_a_micrometre(gap, blocked):
    """The planner promises LoS ahead, so it checks it on polytopes grown by 1 um (SAFE_LOS_TOLERANCE), which the env
    scores on polytopes shrunk by 1e-8 m: a sample whose segment passes 0.5 um above a building's edge counts as
    blocked for the planner and is clear for the env; 5 um above, it is clear for both. A straight manoeuvre along +y
    at x = 40 m, the target fixed at the origin, a thin building whose near top edge (x = 20 m) the last sample's
    segment clears by ``gap``; the earlier samples' segments pass beside it."""
    c = Config()
    top = c.altitude * 20.0 / 40.0 - gap                     # the segment from (40, 0, h) is at h / 2 over x = 20
    terrain = Terrain((Polytope.prism([[20.0, -0.5], [30.0, -0.5], [30.0, 0.5], [20.0, 0.5]], top),))
    m = solve_manoeuvre(np.array([[40.0, -40.0]]), np.array([np.pi / 2]), np.array([[40.0, 0.0]]), v_max=c.v_max,
                        w_max=c.w_max, delta=c.delta)
    ok = np.asarray(m.feasible, bool)
    assert ok.all() and float(np.asarray(m.turn)[0]) == 0.0
    checker = PathChecker(c, terrain, P)
    ctx = PathContext(np.zeros((1, P, 3)), np.zeros((1, P)))
    assert checker.blocked_share(m, ok, ctx, 0)[0] == (1 / (P - 1) if blocked else 0.0)
    end = m.points(P)[0, -1]
    assert line_of_sight(terrain, end, c.altitude, np.zeros(3))              # the env (LOS_TOLERANCE): clear
    assert checker.keeps_sight(m, ok, ctx, 0, zone=False)[0]   # its interior samples pass beside (the end: the node's)


def test_blocked_share_counts_what_a_building_hides():
    """A share that can fail: on the paper scene at a slot where shadows cross the zone (slot 57), some manoeuvres
    lose LoS for part of the slot and the share is a multiple of 1/(P-1) between 0 and 1."""
    c = Config()
    sc = Scenario.paper(c, 1)
    pl = DPPlanner(c, sc.terrain, path_cost=[100.0] * c.horizon)
    tq, tp = _poses(sc, 56, c.horizon)          # slot 57: 181 of 577 zone nodes in shadow
    ctx = pl.paths.context(tq, tp, None)
    a_stage, b_stage = pl.cache.stage(tq[1], tp[1]), pl.cache.stage(tq[2], tp[2])
    a, b = np.meshgrid(np.arange(0, len(pl.lattice), 7), np.arange(0, len(pl.lattice), 7))
    m = solve_manoeuvre(a_stage.xy[a.ravel()], np.full(a.size, tp[1]), b_stage.xy[b.ravel()], v_max=c.v_max,
                        w_max=c.w_max, delta=c.delta)
    ok = np.asarray(m.feasible, bool).copy()
    share = pl.paths.blocked_share(m, ok, ctx, 1)
    assert 0 < np.count_nonzero(share) < len(share)
    assert share.max() <= 1.0
    np.testing.assert_allclose(share * (P - 1), np.round(share * (P - 1)), atol=1e-9)


def _dense_path_cost_dp(config, terrain, start, theta, tq, tphi, allowed, path_cost, ctx):
    """Reference: eqs. 19-21 with the inherited heading, every transition solved exactly, each charged
    ``path_cost[j]`` times its exact blocked share (LoS checked at every sample with eq. 6)."""
    def charged(j, m, feasible):
        share = np.zeros(feasible.shape)
        share[feasible] = _blocked_reference(terrain, config, take_manoeuvres(m, np.flatnonzero(feasible)),
                                             ctx.target[j, 1:]).sum(axis=1) / (P - 1)
        return path_cost[j] * share

    return dense_dp(config, start, theta, tq, tphi, allowed, 1, extra_cost=charged)


def test_path_cost_dp_equals_the_dense_reference_and_changes_the_plan():
    """At a 4 m grid, N = 3, on the paper scene at a slot where shadows cross the zone, from several starts and at
    several weights: the pruned planner with a path cost returns the dense DP's plan (the cost enters the exact
    transition costs, and the table's bounds stay lower bounds), and at some of them that plan differs from the
    paper's."""
    c = Config(grid_step=4.0, horizon=3)
    sc = Scenario.paper(c, 1)
    tq, tp = _poses(sc, 56, c.horizon)
    plain = DPPlanner(c, sc.terrain)
    changed = 0
    for offset in ([-60.0, -12.0], [-50.0, 10.0], [-70.0, 0.0]):
        start = to_world(np.array([offset]), tq[0, :2], tp[0])[0]
        theta = float(tp[0])
        base = plain.plan(start, theta, tq, tp)
        for scale in (0.1, 0.3, 1.0, 4.0):
            w = path_cost_of(scale, 0.5, c.horizon)
            pl = DPPlanner(c, sc.terrain, path_cost=w)
            allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, c.horizon + 1)])
            ctx = pl.paths.context(tq, tp, None)
            ref, ref_nodes = _dense_path_cost_dp(c, sc.terrain, start, theta, tq, tp, allowed, w, ctx)
            plan = pl.plan(start, theta, tq, tp)
            assert plan.status == "ok" and base.status == "ok"
            np.testing.assert_array_equal(plan.nodes, ref_nodes)
            changed += not np.array_equal(plan.nodes, base.nodes)
    assert changed >= 2


def test_zero_path_cost_is_the_paper_planner():
    c = Config()
    sc = Scenario.paper(c, 1)
    tq, tp = _poses(sc, 56, c.horizon)
    start = to_world(np.array([[-60.0, -12.0]]), tq[0, :2], tp[0])[0]
    a = DPPlanner(c, sc.terrain).plan(start, float(tp[0]), tq, tp)
    b = DPPlanner(c, sc.terrain, path_cost=[0.0] * c.horizon).plan(start, float(tp[0]), tq, tp)
    assert a.status == "ok"
    np.testing.assert_array_equal(a.nodes, b.nodes)
    assert a.cost == b.cost


@pytest.mark.parametrize("bad, match", [([1.0, 2.0], "5 numbers"), ([-1.0] * 5, r"\[0, 1e6\]"),
                                        ([np.nan] * 5, r"\[0, 1e6\]"), ("abc", "path_cost"),
                                        ([[1.0] * 5], "5 numbers")])
def test_path_cost_rejects_bad_values(bad, match):
    with pytest.raises(ValueError, match=match):
        DPPlanner(Config(), Terrain(()), path_cost=bad)


def test_path_cost_does_not_go_with_check_path():
    with pytest.raises(ValueError, match="check_path"):
        DPPlanner(Config(), Terrain(()), path_cost=[1.0] * 5, check_path=True)


def test_path_cost_of_is_the_documented_parametrisation():
    np.testing.assert_allclose(path_cost_of(2.0, 0.5, 4), [200.0, 100.0, 50.0, 25.0])
    np.testing.assert_allclose(path_cost_of(1.0, 1.0, 3), [100.0, 100.0, 100.0])


# ---------------------------------------------------------------------- files
def _write(tmp_path, card: dict, **arrays):
    npz = tmp_path / "w.npz"
    np.savez(npz, **arrays)
    (tmp_path / "w.json").write_text(json.dumps(card))
    return npz


GOOD = {"kind": "dp-cost", "planner": {"heading": "inherited"}}


def test_loader_builds_the_planner_with_the_files_path_cost(tmp_path):
    pol = load_cost_planner(_write(tmp_path, GOOD, path_cost=np.array([50.0, 25.0, 0.0, 0.0, 0.0])))
    assert pol.kw["path_cost"].tolist() == [50.0, 25.0, 0.0, 0.0, 0.0]
    assert pol.env_settings == {"action_mode": "waypoint", "mask_mode": "visible"}
    assert pol.kw["shadow_aware"] is True                       # cards written before the field plan as the paper


def test_a_shadow_blind_card_plans_over_the_kinematic_mask(tmp_path):
    card = {**GOOD, "planner": {"heading": "inherited", "shadow_aware": False}}
    pol = load_cost_planner(_write(tmp_path, card, path_cost=np.ones(5)))
    assert pol.kw["shadow_aware"] is False and pol.name == "learned-cost(w)"
    assert pol.env_settings == {"action_mode": "waypoint", "mask_mode": "kinematic"}
    card["env_kwargs"] = {"action_mode": "waypoint", "mask_mode": "visible"}
    (tmp_path / "w.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"w.json: env_kwargs.mask_mode 'visible' contradicts planner.shadow_aware"):
        load_cost_planner(tmp_path / "w.npz")
    card["planner"]["shadow_aware"] = "no"
    (tmp_path / "w.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"w.json: planner.shadow_aware must be true or false, got 'no'"):
        load_cost_planner(tmp_path / "w.npz")


@pytest.mark.parametrize("card, arrays, match", [
    ({**GOOD, "kind": "mappo"}, {"path_cost": np.ones(5)}, "kind"),
    ({**GOOD, "planner": {"heading": "sideways"}}, {"path_cost": np.ones(5)}, "planner.heading"),
    (GOOD, {"other": np.ones(5)}, "path_cost"),
    (GOOD, {"path_cost": -np.ones(5)}, r"\[0, 1e6\]"),
    (GOOD, {"path_cost": np.ones((2, 5))}, r"\[0, 1e6\]"),
    (GOOD, {"path_cost": np.array([object()], dtype=object)}, "allow_pickle|weights"),
])
def test_loader_names_the_file_and_the_field(tmp_path, card, arrays, match):
    npz = _write(tmp_path, card, **arrays)
    with pytest.raises(ValueError, match=match):
        load_cost_planner(npz)


def test_loader_rejects_a_missing_card(tmp_path):
    np.savez(tmp_path / "w.npz", path_cost=np.ones(5))
    with pytest.raises(ValueError, match="NAME.json"):
        load_cost_planner(tmp_path / "w.npz")


# ---------------------------------------------------------------------- the learning script
def test_dp_cost_learns_and_writes_a_loadable_run(tmp_path):
    """One iteration of two candidates on one scene of one task: the curve compares with the paper's planner on the
    same episode, the card's path_cost is the mean's, and the harness loads the run folder as a planner."""
    from covert_env.evaluation.evaluate import load_policy
    from training.dp_cost import main

    run = main(["--iterations", "1", "--population", "2", "--elite", "1", "--tasks", "paper-3uav", "--jobs", "1",
                "--runs-dir", str(tmp_path), "--run-name", "r", "--progress-bar", "false"])
    line = json.loads((run / "curve.jsonl").read_text().splitlines()[0])
    assert line["candidates"][0] == [1.0, 0.5]                   # the first candidate is the mean
    assert line["gain_of_mean"] == pytest.approx(line["returns"][0] - line["paper_return"])
    card = json.loads((run / "model.json").read_text())
    assert card["kind"] == "dp-cost" and card["training"]["episodes"] == 3
    assert card["training"]["env_steps"] == 3 * 70
    pol, settings = load_policy(f"mappo:{run}", 3)
    assert settings == {"n_uavs": 3, "action_mode": "waypoint", "mask_mode": "visible"}
    np.testing.assert_allclose(pol.kw["path_cost"], path_cost_of(*card["params"].values(), 5))
    assert card["planner"] == {"heading": "inherited", "separated_continuation": True,       # learned and flown with
                               "best_effort_escape": True, "shadow_aware": True}
    assert pol.team_kw["separated_continuation"] is True and pol.team_kw["best_effort_escape"] is True
    fig = main(["--plot", str(run), "--plot-out", str(tmp_path / "c.png")])
    assert fig.stat().st_size > 10_000


def test_shadow_blind_candidates_fly_into_shadows_without_a_cost_but_the_paper_planner_does_not():
    """``shadow_aware=False`` changes the candidates only: with no cost they plan over shadowed nodes too (more of the
    path blocked than the paper's planner on the same scene), and the reference episode stays the paper's."""
    from training.dp_cost import episode_return

    seed = int(get_task("downtown-3uav").train_seeds[3])
    paper = episode_return("downtown-3uav", seed, None, "inherited")
    assert episode_return("downtown-3uav", seed, None, "inherited", shadow_aware=False) == paper
    blind = episode_return("downtown-3uav", seed, [0.0] * 5, "inherited", shadow_aware=False)
    assert blind["blocked_path_share"] > paper["blocked_path_share"] + 0.05
    assert blind["return"] < paper["return"]


@pytest.mark.parametrize("argv, match", [(["--elite", "7"], "elite"), (["--tasks", "nowhere-3uav"], "tasks"),
                                         (["--tasks", "paper-3uav,paper-1uav"], "team size"),
                                         (["--init-decay", "1.5"], "init-decay"),
                                         (["--heading", "sideways"], "heading"),
                                         (["--plot", "nowhere"], "no curve.jsonl")])
def test_dp_cost_rejects_bad_flags(tmp_path, argv, match, capsys):
    from training.dp_cost import main

    with pytest.raises(SystemExit) as exc:
        main([*argv, "--runs-dir", str(tmp_path)])
    assert match in str(exc.value) + capsys.readouterr().err


def test_a_planner_card_is_not_an_actor_to_start_from(tmp_path):
    from training import mappo

    npz = _write(tmp_path, GOOD, path_cost=np.ones(5))
    with pytest.raises(ValueError, match="planner with a learned cost .* not an actor"):
        mappo.init_actor_fits(mappo.Args(init_actor=str(npz), action_mode="waypoint", head="node"))
