"""The team's one-slot look-ahead past plans of depth 1 (docs/decisions/planner.md#separated-continuation)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.dp import DPPlanner, DPTeamPlanner
from baselines.dp.continuation import _end_pose, _room
from baselines.dp.safety import _clear_of, _FirstSlot
from baselines.learned_cost import load_cost_planner
from covert_env import Config, Scenario
from covert_env.envs.covert_sensing import CovertSensingParallelEnv

#: Slot 62 of held-out scene 1,000,002 of downtown-3uav, flown by a learned path cost (one seed's, stage 1 first):
#: the negotiation leaves uav_2 a plan of depth 1 that ends 6.3 m from uav_1, the two flying at each other. Without
#: the look-ahead, no pair of their next moves keeps d_safe1 (they came within 2.9 m in the next slot).
SLOT62_COST = [207.34073760430692, 175.01439781651072, 147.72803355957396, 124.695866006744, 105.25462652219912]
SLOT62_XY = [[634.0233611109492, 10.45003234828442], [633.8614853526524, -0.3190807182069726],
             [591.0893987407189, -4.133344324889103]]
SLOT62_THETA = [2.050931581627246, 5.388589480474471, 4.063344383545434]


#: Slot 22 of scene 1,000,001, the same cost flown with heading bins: uav_2's plan of depth 1 ends between its two
#: teammates, and none of its own moves leaves it room next slot; uav_1 has to make way.
SLOT22_XY = [[258.45291357888556, 26.242107372115914], [228.4240736878617, 45.380257094574844],
             [270.14120733921015, 47.29878776035272]]
SLOT22_THETA = [6.1332912970564495, 4.831905243992068, 5.353099668971478]


def _downtown_scene(seed: int) -> Scenario:
    env = CovertSensingParallelEnv(task="downtown-3uav", n_uavs=3, action_mode="waypoint")
    env.reset(seed=seed, options={"scene_seed": seed})
    sc = env.scenario
    env.close()
    return sc


@pytest.fixture(scope="module")
def downtown():
    return _downtown_scene(1_000_002)


def _plan(sc: Scenario, k: int, xy, th, *, continuation: bool, heading: str = "inherited"):
    c = sc.config
    planner = DPPlanner(c, sc.terrain, road=sc.track.road, path_cost=SLOT62_COST, heading=heading)
    team = DPTeamPlanner(planner, separated_continuation=continuation)
    q, phi = sc.track.predict(k, c.horizon)
    tq = np.vstack([sc.track.position(k)[None], q])
    tp = np.concatenate([[sc.track.heading(k)], phi])
    path = sc.track.predict_between(k, c.horizon, np.linspace(0.0, 1.0, planner.path_samples))
    return team, team.plan(np.array(xy), np.array(th), tq, tp, target_path=path), tq, tp


def _rooms(team, plans, tq, tp) -> list[float]:
    """Each depth-1 plan's room in the next slot against its teammates' planned moves there."""
    nxt = team.planner.cache.stage(tq[2], tp[2])
    out = []
    for i, p in enumerate(plans):
        if p.depth == 1:
            ahead = [q.path_points(21)[1][1:] for j, q in enumerate(plans) if j != i and q.depth > 1]
            xy, th = _end_pose(p, team.config, 21)
            out.append(float(_room(team, nxt, xy[None], np.array([th]), ahead)[0]))
    return out


def test_a_plan_of_depth_one_ends_where_its_uav_can_still_separate(downtown):
    """The trap above, without and with the look-ahead: with it, uav_2 ends the slot with a separated next move, and
    the slot flown stays separated."""
    team, plain, tq, tp = _plan(downtown, 62, SLOT62_XY, SLOT62_THETA, continuation=False)
    assert [p.depth for p in plain.plans] == [5, 5, 1]
    lim = team.separation
    assert _rooms(team, plain.plans, tq, tp)[0] < lim             # the trap: no separated move next slot

    team, safe, tq, tp = _plan(downtown, 62, SLOT62_XY, SLOT62_THETA, continuation=True)
    assert [p.status for p in safe.plans] == ["ok", "ok", "safety"]
    assert all(np.array_equal(a.nodes, b.nodes) for a, b in zip(safe.plans[:2], plain.plans[:2], strict=True))
    assert _rooms(team, safe.plans, tq, tp)[0] >= lim
    assert not any(c.stage == 0 for c in team.conflicts(safe.plans))
    assert team.stats["continuation_solves"] > 1
    # The re-choice is the cheapest allowed separated move with room: every cheaper one lacks it.
    path = downtown.track.predict_between(62, downtown.config.horizon, np.linspace(0.0, 1.0, 21))
    slot = _FirstSlot(team, plain.plans, np.array(SLOT62_XY), np.array(SLOT62_THETA), tq, tp, path)
    cand, node = slot.candidates(2), int(safe.plans[2].nodes[0])
    assert cand.allowed[node] and not safe.plans[2].infeasible
    ok = cand.flyable & cand.allowed & (_clear_of(cand.samples, slot.own[:2]) >= lim)
    cheaper = np.flatnonzero(ok & (cand.cost < cand.cost[node]))
    assert cheaper.size > 0                                        # the plan's own move is among them
    ahead = [p.path_points(21)[1][1:] for p in plain.plans[:2]]
    nxt = team.planner.cache.stage(tq[2], tp[2])
    assert (_room(team, nxt, cand.samples[cheaper, -1], cand.heading[cheaper], ahead) < lim).all()
    pts = [p.path_points(21)[0][1:] for p in safe.plans]
    for i in range(3):
        for j in range(i + 1, 3):
            assert np.hypot(*(pts[i] - pts[j]).T).min() >= lim - 1e-9


def test_a_teammate_makes_way_when_no_move_of_its_own_leaves_room():
    """The sandwich above: uav_2 keeps its move, uav_1 replans its next two slots around uav_2's continuation."""
    sc = _downtown_scene(1_000_001)
    team, plain, tq, tp = _plan(sc, 22, SLOT22_XY, SLOT22_THETA, continuation=False, heading="binned")
    assert [p.depth for p in plain.plans] == [5, 5, 1]
    assert _rooms(team, plain.plans, tq, tp)[0] < team.separation
    team, safe, tq, tp = _plan(sc, 22, SLOT22_XY, SLOT22_THETA, continuation=True, heading="binned")
    assert safe.plans[1].depth >= 2 and not np.array_equal(safe.plans[1].nodes, plain.plans[1].nodes)
    assert np.array_equal(safe.plans[0].nodes, plain.plans[0].nodes)
    assert _rooms(team, safe.plans, tq, tp)[0] >= team.separation
    assert not any(c.stage == 0 for c in team.conflicts(safe.plans))


def test_room_is_the_best_separated_move_next_slot():
    """``_room`` against a brute force over the next slot's nodes: the largest smallest gap to a teammate's move."""
    from covert_env.geometry.dynamics import solve_manoeuvre

    c = Config()
    sc = Scenario.paper(c, 3)
    team = DPTeamPlanner(DPPlanner(c, sc.terrain))
    tq, tp = sc.track.position(np.arange(3)), np.asarray(sc.track.heading(np.arange(3)))
    nxt = team.planner.cache.stage(tq[2], tp[2])
    rng = np.random.default_rng(0)
    ends = nxt.xy[rng.choice(len(nxt.xy), 6, replace=False)] + rng.normal(0, 5, (6, 2))
    heads = rng.uniform(0, 2 * np.pi, 6)
    mate = solve_manoeuvre(nxt.xy[3], 0.3, nxt.xy[len(nxt.xy) // 2], v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    ahead = [mate.points(21)[1:]]
    got = _room(team, nxt, ends, heads, ahead)
    for e, h, r in zip(ends, heads, got, strict=True):
        best = -np.inf
        for node in nxt.xy:
            m = solve_manoeuvre(e, h, node, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
            if m.feasible:
                best = max(best, float(np.hypot(*(m.points(21)[1:] - ahead[0]).T).min()))
        assert r == pytest.approx(best, abs=1e-9)


def test_plans_past_the_first_slot_are_left_alone():
    """With every plan reaching stage 2, the look-ahead does nothing and costs nothing."""
    c = Config()
    sc = Scenario.paper(c, 3)
    tq, tp = sc.track.position(np.arange(c.horizon + 1)), np.asarray(sc.track.heading(np.arange(c.horizon + 1)))
    now = DPTeamPlanner(DPPlanner(c, sc.terrain)).planner.cache.stage(tq[0], tp[0]).xy
    xy, th = now[[100, len(now) // 2, len(now) - 100]], np.full(3, tp[0])      # in the zone, on the road's heading
    plain = DPTeamPlanner(DPPlanner(c, sc.terrain)).plan(xy, th, tq, tp)
    team = DPTeamPlanner(DPPlanner(c, sc.terrain), separated_continuation=True)
    ahead = team.plan(xy, th, tq, tp)
    assert all(p.depth == c.horizon for p in plain.plans)
    assert np.array_equal(ahead.nodes, plain.nodes)
    assert team.stats["continuation_solves"] == 0


def test_a_card_turns_the_look_ahead_on_and_old_cards_fly_without(tmp_path):
    np.savez(tmp_path / "m.npz", path_cost=np.array(SLOT62_COST))
    card = {"kind": "dp-cost", "planner": {"heading": "inherited"}}
    (tmp_path / "m.json").write_text(json.dumps(card))
    assert load_cost_planner(tmp_path / "m.npz").team_kw["separated_continuation"] is False
    card["planner"]["separated_continuation"] = True
    (tmp_path / "m.json").write_text(json.dumps(card))
    assert load_cost_planner(tmp_path / "m.npz").team_kw["separated_continuation"] is True
    card["planner"]["separated_continuation"] = "true"
    (tmp_path / "m.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"planner.separated_continuation must be true or false, got 'true'"):
        load_cost_planner(tmp_path / "m.npz")
