"""The safety layer's best-effort escape (docs/decisions.md#best-effort-escape)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.dp import DPPlanner, DPTeamPlanner
from baselines.dp.safety import _FirstSlot
from baselines.policies import DPPolicy
from covert_env import Config, Scenario
from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from covert_env.separation import separation
from training.pretrained.learned_cost import load_cost_planner

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
    the slot flown breaks d_safe1."""
    team, plain, (tq, tp, path) = _plan(scene, escape=False)
    assert [p.status for p in plain.plans] == ["fallback", "safety", "ok"]
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    c0, c1 = slot.candidates(0), slot.candidates(1)
    assert c0.best_effort and not c1.best_effort and c1.flyable.sum() == 1
    pairs = separation(c0.samples[c0.flyable][:, None], c1.samples[c1.flyable][None])
    assert pairs.max() < team.config.d_safe1
    assert _flown_gaps(plain.plans)[0] < team.config.d_safe1


def test_a_best_effort_escape_separates_the_slot_flown(scene):
    """With the escape, uav_1 flies a best effort (flagged, no planned heading) and every pair keeps d_safe1 +
    margin along the slot flown; uav_2's plan is untouched."""
    _, plain, _ = _plan(scene, escape=False)
    team, safe, _ = _plan(scene, escape=True)
    assert (_flown_gaps(safe.plans) >= team.separation - 1e-9).all()
    assert safe.plans[1].status == "safety" and safe.plans[1].infeasible and np.isnan(safe.plans[1].headings[0])
    assert np.array_equal(safe.plans[2].nodes, plain.plans[2].nodes)
    assert not any(c.stage == 0 for c in team.conflicts(safe.plans))


def test_the_escape_takes_the_fewest_best_efforts(scene):
    """Where one UAV's own best effort is separated from the settled paths, the settled UAV keeps its move, and
    the escape is the nearest such best effort (level 3's rule)."""
    team, plain, (tq, tp, path) = _plan(scene, escape=True)
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)
    fixed = {2: slot.own[2]}
    moves = {2: None}
    mv = slot.escape(1, fixed, moves)
    eff = slot.best_efforts(1)
    gap = separation(eff.samples[:, None], slot.own[2][None]).min(axis=-1).reshape(-1)
    ok = eff.flyable & (gap >= team.separation)
    assert mv.best_effort and mv.infeasible and moves == {2: None}
    assert mv.node == int(np.argmin(np.where(ok, eff.cost, np.inf)))


def test_a_re_chosen_pair_takes_the_fewest_best_efforts_before_the_lowest_cost(scene):
    """Two UAVs on a line, one sample per move. uav_1's best efforts all sit 1 m from uav_0's path; separated pairs:
    two manoeuvres (cost 100), uav_0's best effort and a manoeuvre (1.5), two best efforts (0.5). The pair without
    a best effort wins."""
    from baselines.dp.safety import _Candidates, _Move

    team, plain, (tq, tp, path) = _plan(scene, escape=True)
    slot = _FirstSlot(team, plain.plans, np.array(XY), np.array(THETA), tq, tp, path)

    def cands(xs, cost, effort):
        n = len(xs)
        return _Candidates(heading=np.full(n, np.nan if effort else 0.0), speed=np.full(n, np.nan if effort else 1.0),
                           flyable=np.ones(n, bool), samples=np.array([[[x, 0.0]] for x in xs]),
                           cost=np.array(cost, float), allowed=np.full(n, not effort), best_effort=effort)

    slot._candidates = {0: cands([0.0, 0.0], [50, 50], False), 1: cands([1.0, 20.0], [1, 50], False)}
    slot._efforts = {0: cands([100.0, 100.0], [0.5, 0.5], True), 1: cands([1.0, 1.0], [0, 0], True)}
    fixed, moves = {0: np.array([[0.0, 0.0]])}, {0: None}
    assert slot.escape(1, fixed, moves) == _Move(1, False, False)
    assert moves[0] == _Move(0, False, False) and np.array_equal(fixed[0], [[0.0, 0.0]])


@pytest.mark.parametrize("bad", [1, "yes", None])
def test_the_option_must_be_a_bool(bad):
    c = Config()
    with pytest.raises(ValueError, match="best_effort_escape must be True or False"):
        DPTeamPlanner(DPPlanner(c, Scenario.paper(c, 1).terrain), best_effort_escape=bad)
    with pytest.raises(ValueError, match="DPPolicy: best_effort_escape must be True or False"):
        DPPolicy(best_effort_escape=bad)


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
