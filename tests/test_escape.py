"""The safety layer's best-effort escape (docs/decisions/planner.md#best-effort-escape)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.dp import DPPlanner, DPTeamPlanner
from baselines.dp.safety import _FirstSlot
from baselines.learned_cost import load_cost_planner
from baselines.policies import DPPolicy
from covert_env import Config, Scenario
from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from covert_env.geometry.separation import separation

#: Slot 28 of held-out scene 1,000,002 of downtown-3uav-deviating, flown by a learned path cost (one seed's, stage 1
#: first) with the look-ahead. The target left its prediction: uav_0 reaches no node of the next slot (a best
#: effort) and uav_1 has one manoeuvre, and no pair of those keeps d_safe1 (the two came within 2.9 m).
COST = [207.34073760430692, 175.01439781651072, 147.72803355957396, 124.695866006744, 105.25462652219912]
XY = [[300.7547809335062, 66.1592495398094], [294.98595299077186, 67.80868100765761],
      [312.29243681897475, 62.86038660411296]]
THETA = [3.4900709315494747, 4.506619781620827, 5.131466788857299]
K = 28


@pytest.fixture(scope="module")
def scene() -> Scenario:
    env = CovertSensingParallelEnv(task="downtown-3uav-deviating", n_uavs=3, action_mode="waypoint")
    env.reset(seed=1_000_002, options={"scene_seed": 1_000_002})
    sc = env.scenario
    env.close()
    return sc


def _plan(sc: Scenario, *, escape: bool):
    c = sc.config
    planner = DPPlanner(c, sc.terrain, road=sc.track.road, path_cost=COST)
    team = DPTeamPlanner(planner, separated_continuation=True, best_effort_escape=escape)
    q, phi = sc.track.predict(K, c.horizon)
    tq = np.vstack([sc.track.position(K)[None], q])
    tp = np.concatenate([[sc.track.heading(K)], phi])
    path = sc.track.predict_between(K, c.horizon, np.linspace(0.0, 1.0, planner.path_samples))
    return team, team.plan(np.array(XY), np.array(THETA), tq, tp, target_path=path), (tq, tp, path)


def _flown_gaps(plans) -> np.ndarray:
    """(3,) smallest distance over the slot flown of the pairs (0, 1), (0, 2), (1, 2)."""
    pts = [p.path_points(21)[0][1:] for p in plans]
    return np.array([separation(pts[i], pts[j]).min() for i, j in ((0, 1), (0, 2), (1, 2))])


def test_no_pair_of_manoeuvres_separates_the_trap(scene):
    """The premise: uav_0's best efforts against uav_1's manoeuvres leave no separated pair, and without the escape
    the slot flown breaks d_safe1 (both stuck moves flagged, as the safety layer always flagged them)."""
    team, plain, (tq, tp, path) = _plan(scene, escape=False)
    assert [p.status for p in plain.plans] == ["fallback", "safety", "ok"]
    assert [p.infeasible for p in plain.plans] == [True, True, False]
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    c0, c1 = slot.candidates(0), slot.candidates(1)
    assert c0.best_effort and not c1.best_effort and c1.flyable.sum() == 1
    pairs = separation(c0.samples[c0.flyable][:, None], c1.samples[c1.flyable][None])
    assert pairs.max() < team.config.d_safe1
    assert _flown_gaps(plain.plans)[0] < team.config.d_safe1


def test_a_best_effort_escape_separates_the_slot_flown(scene):
    """With the escape, uav_1 flies a best effort toward a node it cannot reach (flagged, no planned heading or
    cost, the engine's path) and every pair keeps d_safe1 + margin along the slot flown; uav_2's plan is
    untouched. The escape settles the order that stands once more and solves uav_1's best efforts once."""
    _, plain, _ = _plan(scene, escape=False)
    off = dict(plain.work)
    team, safe, (tq, tp, path) = _plan(scene, escape=True)
    assert (_flown_gaps(safe.plans) >= team.separation - 1e-9).all()
    p1 = safe.plans[1]
    assert p1.status == "safety" and p1.infeasible and np.isnan(p1.headings[0]) and np.isnan(p1.cost)
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    node = int(p1.nodes[0])
    assert not slot.candidates(1).flyable[node] and slot.escape_efforts(1).flyable[node]
    np.testing.assert_allclose(p1.path_points(21)[0][1:], slot.escape_efforts(1).samples[node], atol=1e-9)
    assert np.array_equal(safe.plans[2].nodes, plain.plans[2].nodes)
    assert not any(c.stage == 0 for c in team.conflicts(safe.plans))
    assert safe.work["safety_orders"] == off["safety_orders"] + 1
    assert safe.work["safety_solves"] == off["safety_solves"] + 1


def _cands(xs, cost, allowed, flyable=None, effort=False):
    """Synthetic one-sample moves at (x, 0)."""
    from baselines.dp.safety import _Candidates

    n = len(xs)
    return _Candidates(heading=np.full(n, np.nan if effort else 0.0), speed=np.full(n, np.nan if effort else 1.0),
                       flyable=np.ones(n, bool) if flyable is None else np.array(flyable),
                       samples=np.array([[[x, 0.0]] for x in xs]), cost=np.array(cost, float),
                       allowed=np.array(allowed), best_effort=effort)


def test_a_re_chosen_pair_takes_the_fewest_best_efforts_before_the_lowest_cost(scene):
    """Two UAVs on a line, one sample per move, three nodes. uav_0 is settled at x = 0; its manoeuvres (x = 0, 2)
    and uav_1's one manoeuvre (x = 1, off the allowed nodes) are all too close, and so are uav_1's best efforts
    (x = 3, 4) to uav_0's path. Separated pairs: uav_0's best effort (x = 100) with uav_1's manoeuvre (one best
    effort), or with a best effort of uav_1 (two, cheaper). The pair with one best effort wins and uav_0's
    path moves."""
    from baselines.dp.safety import _Move

    team, plain, (tq, tp, path) = _plan(scene, escape=True)
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    slot._candidates = {0: _cands([0.0, 2.0, 0.0], [1, 1, np.inf], [True, True, False], [True, True, False]),
                        1: _cands([1.0, 0.0, 0.0], [10, np.inf, np.inf], [False] * 3, [True, False, False])}
    slot._reachable = {0: np.array([True, True, False]), 1: np.array([True, False, False])}
    slot._efforts = {0: _cands([0.0, 0.0, 100.0], [0.5] * 3, [False] * 3, [False, False, True], effort=True),
                     1: _cands([0.0, 3.0, 4.0], [0.1] * 3, [False] * 3, [False, True, True], effort=True)}
    fixed, moves = {0: np.array([[0.0, 0.0]])}, {0: None}
    assert slot.pick(1, fixed) is None and slot.repair(1, 0, fixed) is None
    assert slot.escape(1, fixed, moves) == _Move(0, True, False)
    assert moves[0] == _Move(2, True, True) and np.array_equal(fixed[0], [[100.0, 0.0]])
    assert np.array_equal(slot.path_of(0, moves[0]), [[100.0, 0.0]])


def test_the_escape_acts_only_where_no_order_separates_the_team(scene):
    """uav_2 (x = 10, one manoeuvre) between uav_0 (x = 6) and uav_1 (x = 14) is stuck in the order 0, 1, 2, and no
    joint re-choice frees it; promoted to the front, the team separates with manoeuvres. The escape, which would
    have freed it with a best effort in the first order, changes nothing."""
    from baselines.dp.safety import _Move

    team, plain, (tq, tp, path) = _plan(scene, escape=False)
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    slot.own = [np.array([[6.0, 0.0]]), np.array([[14.0, 0.0]]), np.array([[10.0, 0.0]])]
    slot._candidates = {0: _cands([6.0, 0.0], [0, 1], [True, True]), 1: _cands([14.0, 20.0], [0, 1], [True, True]),
                        2: _cands([10.0, 10.0], [0, np.inf], [True, True], [True, False])}
    slot._reachable = {0: np.ones(2, bool), 1: np.ones(2, bool), 2: np.array([True, False])}
    slot._efforts = {i: _cands([30.0, 30.0], [1, 1], [False, False], [False, i == 2], effort=True) for i in range(3)}
    assert slot.settle([0, 1, 2])[1] == 2 and slot.settle([0, 1, 2], escape=True)[1] is None
    plain_moves = slot.negotiate()
    slot.escapes = True
    assert slot.negotiate() == plain_moves == {2: None, 0: _Move(1, False), 1: _Move(1, False)}


def test_where_nothing_separates_the_most_separated_move_counts_the_best_efforts(scene):
    """uav_1 (one manoeuvre, to x = 1) and its best effort toward an unreachable node (x = 4) are both too close
    to uav_0 at x = 0, whose moves (x = 0, 2) free nothing: uav_1 stays stuck and takes the farther best effort,
    flagged; without the escape, its manoeuvre."""
    from baselines.dp.safety import _Move

    team, plain, (tq, tp, path) = _plan(scene, escape=True)
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    slot.own = [np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]])]
    slot._candidates = {0: _cands([0.0, 2.0], [0, 1], [True, True]),
                        1: _cands([1.0, 0.0], [0, np.inf], [True, True], [True, False])}
    slot._reachable = {0: np.ones(2, bool), 1: np.array([True, False])}
    slot._efforts = {0: None, 1: _cands([0.0, 4.0], [1, 1], [False, False], [False, True], effort=True)}
    moves, stuck = slot.settle([0, 1], escape=True)
    assert stuck == 1 and moves == {0: None, 1: _Move(1, True, True)}
    moves, stuck = slot.settle([0, 1])
    assert stuck == 1 and moves == {0: None, 1: _Move(0, True, False)}


@pytest.mark.parametrize("option", ["best_effort_escape", "separated_continuation"])
@pytest.mark.parametrize("bad", [1, "yes", None])
def test_the_safety_options_must_be_bools(option, bad):
    """The team planner's and the policy's safety options (the escape, the separated look-ahead) refuse a non-bool,
    naming the option."""
    c = Config()
    with pytest.raises(ValueError, match=f"{option} must be True or False"):
        DPTeamPlanner(DPPlanner(c, Scenario.paper(c, 1).terrain), **{option: bad})
    with pytest.raises(ValueError, match=f"DPPolicy: {option} must be True or False"):
        DPPolicy(**{option: bad})


def test_a_card_turns_the_escape_on_and_old_cards_fly_without(tmp_path):
    np.savez(tmp_path / "m.npz", path_cost=np.array(COST))
    card = {"kind": "dp-cost", "planner": {"heading": "inherited", "separated_continuation": True}}
    (tmp_path / "m.json").write_text(json.dumps(card))
    assert load_cost_planner(tmp_path / "m.npz").team_kw["best_effort_escape"] is False
    card["planner"]["best_effort_escape"] = True
    (tmp_path / "m.json").write_text(json.dumps(card))
    pol = load_cost_planner(tmp_path / "m.npz")
    assert pol.team_kw == {"max_rounds": 5, "separation_margin": 0.5, "separated_continuation": True,
                           "best_effort_escape": True}
    card["planner"]["best_effort_escape"] = 1
    (tmp_path / "m.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"planner.best_effort_escape must be true or false, got 1"):
        load_cost_planner(tmp_path / "m.npz")
