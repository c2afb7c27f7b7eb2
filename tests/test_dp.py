"""baselines.dp: the paper's DP planner (eqs. 17-21), its heading variants, team negotiation and fallbacks.

References here are independent of the planner's pruning: a dense DP that solves every transition
exactly, and a brute force over every node sequence with the heading propagated continuously.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _dense_dp import dense_dp

from baselines.dp import DPPlanner, DPTeamPlanner, brute_force_plan, evaluate_plan, manoeuvre_bounds_table
from baselines.reproduce import HELDOUT_SEED_BASE, make_scenario, rollout
from covert_env import Config, Engine, Road, Scenario, TargetTrack, Terrain
from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.cost import uav_target_angle, uav_target_distance
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.zone import to_world, zone_lattice
from covert_env.world.metrics import episode_metrics, slot_quantities
from covert_env.world.terrain import Polytope

TWO_PI = 2 * np.pi


def targets(scenario: Scenario, k: int):
    """(N+1, 3) and (N+1,) target poses for slots k..k+N."""
    n = scenario.config.horizon
    ks = np.arange(k, k + n + 1)
    return scenario.track.position(ks), np.asarray(scenario.track.heading(ks))


# ------------------------------------------------------------------------------------ the table
def test_table_bounds_hold_against_exact_manoeuvres():
    """The lookup table only decides which transitions are solved: its length bound must never exceed the
    exact path length, it must never call a feasible goal unreachable, and its heading-change interval must
    contain the exact heading change (4e5 random goals)."""
    c = Config()
    tab = manoeuvre_bounds_table(c.v_max, c.w_max, c.delta)
    rng = np.random.default_rng(0)
    n = 400_000
    rho = rng.uniform(0, c.v_max * c.delta * 1.02, n)
    psi = rng.uniform(-np.pi, np.pi, n)
    theta = rng.uniform(0, TWO_PI, n)
    rel = np.column_stack([rho * np.cos(psi + theta), rho * np.sin(psi + theta)])
    m = solve_manoeuvre(np.zeros((n, 2)), theta, rel, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
    ok = np.asarray(m.feasible)
    cell = tab.cell(tab.base_index(rel), theta)
    lb = tab.lb[cell]
    assert np.all(np.isfinite(lb[ok]))
    assert np.all(lb[ok] <= m.length[ok] + 1e-9)
    dth = wrap_angle(m.heading_after[ok] - theta[ok])
    assert np.all(tab.dlo[cell[ok]] <= dth + 1e-9) and np.all(dth <= tab.dhi[cell[ok]] + 1e-9)
    # The bound is tight: the median gap is well under a metre.
    assert np.median(m.length[ok] - lb[ok]) < 0.6



def test_planner_stage_costs_are_the_models_stage_cost():
    """One home for eq. 18: every planned stage cost is covert_env.geometry.cost.stage_cost of the planned manoeuvre
    (bit for bit), and the planner's float32 disguise bound per node pair is -lambda times
    covert_env.geometry.cost.disguise (eq. 11) to float32 rounding."""
    from baselines.dp.lattice import StageCache
    from covert_env.geometry.cost import disguise, stage_cost

    c = Config()
    sc = Scenario.paper(c)
    tq, tp = targets(sc, 12)
    pl = DPPlanner(c, sc.terrain)
    start = to_world(zone_lattice(c)[[300]], tq[0, :2], tp[0])[0]
    plan = pl.plan(start, float(tp[0]), tq, tp)
    assert plan.status == "ok" and plan.depth == c.horizon
    m = plan.manoeuvres()
    pos = np.vstack([start[None], plan.waypoints])
    al = uav_target_angle(pos, tq[:, :2], tp)
    d = uav_target_distance(pos, tq[:, :2])
    g = stage_cost(m.length, al[:-1], al[1:], d[:-1], d[1:], c.eta, c.lam)
    np.testing.assert_array_equal(plan.stage_costs, g)
    assert plan.cost == float(np.sum(g))
    cache = StageCache(zone_lattice(c), pl.table, c.lam, c.eta, 4)
    a, b = cache.stage(tq[1], tp[1]), cache.stage(tq[2], tp[2])
    pair = cache.pair(a, b)
    ref = -c.lam * disguise(a.alpha[:, None], b.alpha[None, :], a.d[:, None], b.d[None, :], c.eta)
    assert pair.disguise.dtype == np.float32
    # float32 inputs and arithmetic: a few ulps of values up to ~1.5e3.
    np.testing.assert_allclose(pair.disguise, ref, rtol=0, atol=2e-3)


# ------------------------------------------------------------------ exactness of the pruned recursion
def test_inherited_dp_equals_dense_reference_on_the_paper_lattice():
    """At the default 2 m grid (577 nodes per stage) the pruned planner returns exactly the dense DP."""
    c = Config()
    sc = Scenario.paper(c, 1)
    tq, tp = targets(sc, 0)
    pl = DPPlanner(c, sc.terrain)
    allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, c.horizon + 1)])
    ref, ref_nodes = dense_dp(c, sc.uav_xy[0], sc.uav_theta[0], tq, tp, allowed, 1)
    plan = pl.plan(sc.uav_xy[0], sc.uav_theta[0], tq, tp)
    assert plan.status == "ok" and not plan.infeasible
    assert plan.cost == pytest.approx(ref, abs=1e-9)
    np.testing.assert_array_equal(plan.nodes, ref_nodes)
    # The plan is what the engine flies: re-evaluating it with continuous headings gives the same cost.
    assert evaluate_plan(c, sc.uav_xy[0], sc.uav_theta[0], tq, tp, plan.waypoints) == pytest.approx(plan.cost)
    assert plan.n_exact < 0.02 * plan.n_bounded    # few transitions are solved exactly


def _turning(seed_offset: int, k: int, horizon: int | None = None):
    """A held-out scene at a slot where its target turns (0.38 rad over the 5 slots after k=52 of scene 0; the
    other slot is checked by the assertion); the UAV starts at the zone's centre, heading along the road."""
    c = Config() if horizon is None else Config(horizon=horizon)
    sc = make_scenario("random", HELDOUT_SEED_BASE + seed_offset, 1, c)
    ks = np.arange(k, k + c.horizon + 1)
    tq, tp = sc.track.position(ks), np.asarray(sc.track.heading(ks))
    assert abs(wrap_angle(tp[-1] - tp[0])) > 0.1 * c.horizon / 5
    start = tq[0, :2] - 0.5 * (c.r1 + c.r2) * np.array([np.cos(tp[0]), np.sin(tp[0])])
    return c, sc, start, float(tp[0]), tq, tp


@pytest.mark.parametrize("seed_offset, k", [(0, 52), (4, 58)])
def test_inherited_dp_equals_dense_reference_while_the_target_turns(seed_offset, k):
    """The 2 m grid, N = 5, a turning target (the zone swings sideways under the UAV): pruned = dense DP."""
    c, sc, start, theta, tq, tp = _turning(seed_offset, k)
    pl = DPPlanner(c, sc.terrain)
    allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, c.horizon + 1)])
    ref, ref_nodes = dense_dp(c, start, theta, tq, tp, allowed, 1)
    plan = pl.plan(start, theta, tq, tp)
    assert plan.status == "ok" and math.isfinite(ref)
    assert plan.cost == pytest.approx(ref, abs=1e-9)
    np.testing.assert_array_equal(plan.nodes, ref_nodes)


@pytest.mark.parametrize("heading", ["inherited", "binned"])
@pytest.mark.parametrize("seed_offset, k", [(0, 52), (4, 58)])
def test_planner_equals_brute_force_at_the_2m_grid_while_the_target_turns(heading, seed_offset, k):
    """N = 2 at the 2 m grid (577 nodes per stage, ~2e5 sequences): every stage-1 state has one arrival (from
    the start), so even the paper's inherited heading is exact, and the planner must return J* of the
    enumeration over every node sequence with continuous headings."""
    c, sc, start, theta, tq, tp = _turning(seed_offset, k, horizon=2)
    pl = DPPlanner(c, sc.terrain, heading=heading)
    allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, c.horizon + 1)])
    assert len(pl.lattice) > 500 and allowed.sum() > 500
    jstar, nodes = brute_force_plan(c, start, theta, tq, tp, allowed)
    plan = pl.plan(start, theta, tq, tp)
    assert plan.status == "ok" and math.isfinite(jstar)
    assert plan.cost == pytest.approx(jstar, abs=1e-9)
    np.testing.assert_array_equal(plan.nodes, nodes)
    assert evaluate_plan(c, start, theta, tq, tp, plan.waypoints) == pytest.approx(jstar, abs=1e-9)


@pytest.mark.parametrize("bins", [4, 16])
def test_binned_dp_equals_dense_reference(bins):
    """Binned (hybrid) states with and without the upper-bound pruning equal the dense recursion."""
    c = Config(grid_step=6.0)
    rng = np.random.default_rng(bins)
    done = 0
    while done < 3:
        sc = make_scenario("random", HELDOUT_SEED_BASE + int(rng.integers(0, 4)), 1, c)
        k = int(rng.integers(0, 40))
        tq, tp = targets(sc, k)
        start = to_world(zone_lattice(c)[[rng.integers(len(zone_lattice(c)))]], tq[0, :2], tp[0])[0]
        theta = float(tp[0] + rng.uniform(-1.5, 1.5))          # roughly along the road: plans exist
        pl = DPPlanner(c, sc.terrain, heading="binned", heading_bins=bins)
        allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, c.horizon + 1)])
        ref, ref_nodes = dense_dp(c, start, theta, tq, tp, allowed, bins)
        inh, _ = dense_dp(c, start, theta, tq, tp, allowed, 1)
        if not math.isfinite(min(ref, inh)):
            continue
        done += 1
        for prune in (True, False):
            plan = DPPlanner(c, sc.terrain, heading="binned", heading_bins=bins, prune=prune).plan(start, theta, tq, tp)
            # The planner returns the better of its inherited and binned passes (both exact recursions).
            assert plan.cost == pytest.approx(min(ref, inh), abs=1e-9)


# --------------------------------------------------------------------------- optimality vs brute force
def _optimality_instances(count: int, grid_step: float = 14.0):
    c = Config(grid_step=grid_step, horizon=3)
    lat = zone_lattice(c)
    assert len(lat) <= 12
    rng = np.random.default_rng(2024)
    out = []
    seeds = [HELDOUT_SEED_BASE + i for i in range(6)]
    scenes = {s: make_scenario("random", s, 1, c) for s in seeds}
    while len(out) < count:
        sc = scenes[seeds[int(rng.integers(len(seeds)))]]
        k = int(rng.integers(0, 60))
        tq, tp = targets(sc, k)
        # A start near the zone at slot k (zone nodes jittered), any heading: the planner's real situation.
        p = to_world(lat[[rng.integers(len(lat))]], tq[0, :2], tp[0])[0] + rng.normal(0, 4.0, 2)
        theta = float(rng.uniform(0, TWO_PI))
        pl = DPPlanner(c, sc.terrain)
        allowed = np.stack([pl.allowed_nodes(tq[j], tp[j]) for j in range(1, c.horizon + 1)])
        jstar, _ = brute_force_plan(c, p, theta, tq, tp, allowed)
        if math.isfinite(jstar):
            out.append((c, sc, p, theta, tq, tp, jstar))
    return out


@pytest.mark.slow
def test_dp_against_brute_force_on_small_lattices(record_property):
    """N = 3, <= 12 nodes per stage: J* by enumeration with continuous headings. Both variants' plans cost
    >= J*; the binned variant converges to J* as B grows (B = 64 within 1% on >= 95% of instances); the
    paper's inherited variant misses J* on some instances (reported)."""
    inst = _optimality_instances(80)
    gaps = {"inherited": [], 4: [], 16: [], 64: []}
    for c, sc, p, theta, tq, tp, jstar in inst:
        for key in gaps:
            kw = dict(heading="inherited") if key == "inherited" else dict(heading="binned", heading_bins=key)
            plan = DPPlanner(c, sc.terrain, **kw).plan(p, theta, tq, tp)
            assert plan.status in ("ok", "truncated")
            if plan.depth < c.horizon:
                # Inherited headings can dead-end although a full sequence exists: a miss.
                gaps[key].append(np.inf)
                continue
            cost = evaluate_plan(c, p, theta, tq, tp, plan.waypoints)
            assert cost == pytest.approx(plan.cost, abs=1e-6)          # plans are flyable as reported
            assert cost >= jstar - 1e-6
            gaps[key].append((cost - jstar) / abs(jstar))
    g = {k: np.array(v) for k, v in gaps.items()}
    miss = g["inherited"] > 1e-9
    record_property("inherited_miss_rate", float(miss.mean()))
    record_property("inherited_mean_gap_when_missing", float(g["inherited"][miss].mean()) if miss.any() else 0.0)
    print(f"\ninherited misses J* on {miss.mean():.0%} of {len(inst)} instances "
          f"(mean gap {g['inherited'][miss].mean() if miss.any() else 0:.2%}, max {g['inherited'].max():.2%}); "
          f"binned B=4/16/64 within 1%: {(g[4] <= 0.01).mean():.0%} / {(g[16] <= 0.01).mean():.0%} / "
          f"{(g[64] <= 0.01).mean():.0%}")
    assert (g[64] <= 0.01).mean() >= 0.95
    assert g[64].mean() <= g[16].mean() + 1e-12 <= g[4].mean() + 2e-12
    assert g[64].mean() <= g["inherited"].mean()
    assert miss.any(), "the position-only DP is not optimal: some instance should show it"


# ---------------------------------------------------------------------------------- never crash
def _wall_scenario(n_uavs: int = 1) -> Scenario:
    """A straight road with a 70 m wall 30-95 m behind the target's start: the whole zone is in shadow."""
    c = Config(n_slots=12, n_uavs=n_uavs)
    road = Road.from_points([[0.0, 0.0], [400.0, 0.0]])
    track = TargetTrack.constant(road, c.target_speed, c.n_slots + c.horizon + 1, z=c.target_height, s0=120.0)
    wall = Polytope.prism([[25.0, -60.0], [90.0, -60.0], [90.0, 60.0], [25.0, 60.0]], 70.0)
    starts = np.array([[40.0, 10.0], [45.0, -10.0], [50.0, 25.0]])[:n_uavs]
    return Scenario(c, Terrain((wall,)), track, starts, np.zeros(n_uavs), name="wall")


def test_planner_never_crashes_when_the_visible_zone_is_empty():
    sc = _wall_scenario()
    tq, tp = targets(sc, 0)
    c = sc.config
    pl = DPPlanner(c, sc.terrain)
    assert not pl.visible_nodes(tq[1], tp[1]).any()
    plan = pl.plan(sc.uav_xy[0], sc.uav_theta[0], tq, tp)
    # Level 2: the plain zone with a penalty per node without LoS; flagged.
    assert plan.status == "fallback" and plan.infeasible and plan.depth == c.horizon
    assert 0 <= plan.nodes[0] < len(pl.lattice) and np.all(np.isfinite(plan.waypoints))
    # The shadow-blind planner does not care: its zone is all there.
    blind = DPPlanner(c, sc.terrain, shadow_aware=False).plan(sc.uav_xy[0], sc.uav_theta[0], tq, tp)
    assert blind.status == "ok" and not blind.infeasible


def test_planner_never_crashes_when_the_zone_is_unreachable():
    sc = Scenario.paper(Config(), 1)
    tq, tp = targets(sc, 0)
    for aware in (True, False):
        pl = DPPlanner(sc.config, sc.terrain, shadow_aware=aware)
        far = pl.plan(np.array([600.0, 400.0]), 1.0, tq, tp)      # hundreds of metres away
        assert far.status == "fallback" and far.infeasible and far.depth == 1
        node = far.nodes[0]
        assert 0 <= node < len(pl.lattice)
        # Level 3 heads for the zone node nearest to the UAV.
        nodes = to_world(pl.lattice, tq[1, :2], tp[1])
        d = np.hypot(*(nodes - [600.0, 400.0]).T)
        assert d[node] <= d.min() + sc.config.grid_step + 1e-9


def test_truncated_plan_when_a_later_stage_is_empty():
    c = Config()
    sc = Scenario.paper(c, 1)
    tq, tp = targets(sc, 0)
    pl = DPPlanner(c, sc.terrain)
    blocked = np.zeros((c.horizon, len(pl.lattice)), bool)
    blocked[2] = True
    plan = pl.plan(sc.uav_xy[0], sc.uav_theta[0], tq, tp, blocked=blocked)
    assert plan.status == "truncated" and not plan.infeasible and plan.depth == 2
    assert np.all(plan.nodes[2:] == -1) and pl.allowed_nodes(tq[1], tp[1])[plan.nodes[0]]


def test_rollout_through_a_fully_shadowed_zone_never_crashes():
    """Team of 3 in the wall scene: every slot is planned, fallbacks are flagged, nothing collides."""
    sc = _wall_scenario(3)
    out = rollout(sc)
    traj = out["trajectory"]
    assert traj.n_slots == sc.config.n_slots
    m = episode_metrics(traj, sc.terrain, sc.config)
    q = slot_quantities(traj, sc.terrain, sc.config)
    assert traj.infeasible.any()
    assert not np.any(~q.los & ~traj.infeasible)            # unflagged slots have LoS
    assert all(r["separation_violations"] == 0 and r["speed_violations"] == 0 for r in m)


# ------------------------------------------------------------------------------- eq. 3: tall tops
def _pole_scenario(n_uavs: int, height: float = 76.0) -> Scenario:
    """The paper scene plus a 2 m x 2 m pole of ``height`` on the road at x = 200, where the zone passes in the
    first 20 slots. The generator caps heights at h - d_safe2 = 70 m; a loaded terrain need not."""
    c = Config(n_uavs=n_uavs)
    sc = Scenario.paper(c)
    pole = Polytope.prism([[199.0, -1.0], [201.0, -1.0], [201.0, 1.0], [199.0, 1.0]], height)
    terrain = Terrain(tuple(sc.terrain.polytopes) + (pole,))
    terrain.validate(c.altitude)
    return Scenario(c, terrain, sc.track, sc.uav_xy, sc.uav_theta, name="pole")


def _fly(sc: Scenario, planner: DPPlanner, n_slots: int):
    eng = Engine(sc, path_samples=21)
    team = DPTeamPlanner(planner)
    for _ in range(n_slots):
        plan = team.plan_engine(eng)
        eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
    return eng.trajectory()


def _clearance_3d(xy, terrain, altitude):
    top = terrain.highest_points
    d = xy[..., None, :] - top[:, :2]
    return np.sqrt((d ** 2).sum(-1) + (altitude - top[:, 2]) ** 2).min(-1)


def test_allowed_nodes_exclude_the_disk_around_a_tall_top():
    """Eq. 3 at the nodes: exactly the nodes closer than d_safe2 (in 3D) to a top are removed, aware or blind;
    for a 76 m top at h = 80 that is a horizontal disk of radius sqrt(10^2 - 4^2) = 9.17 m."""
    sc = _pole_scenario(1)
    c = sc.config
    ks = np.arange(14, 14 + c.horizon + 1)                         # the zone is around the pole at slot 15
    tq, tp = sc.track.position(ks), np.asarray(sc.track.heading(ks))
    xy = to_world(zone_lattice(c), tq[1, :2], tp[1])
    near = _clearance_3d(xy, sc.terrain, c.altitude) < c.d_safe2
    assert 20 < near.sum() < 200
    assert np.all(np.hypot(*(xy[near] - [200.0, 0.0]).T) < math.sqrt(c.d_safe2 ** 2 - 4.0 ** 2) + 1.5)
    for aware in (True, False):
        pl = DPPlanner(c, sc.terrain, shadow_aware=aware)
        allowed = pl.allowed_nodes(tq[1], tp[1])
        assert not allowed[near].any()
        if not aware:
            np.testing.assert_array_equal(allowed, ~near)
        # From the zone's centre at slot 14, a dozen metres short of the pole, heading along the road.
        start = tq[0, :2] - 0.5 * (c.r1 + c.r2) * np.array([np.cos(tp[0]), np.sin(tp[0])])
        plan = pl.plan(start, tp[0], tq, tp)
        assert plan.status == "ok"
        assert np.all(_clearance_3d(plan.path_points(21), sc.terrain, c.altitude) >= c.d_safe2 - 1e-9)
        # A UAV that is already too near (4 m short of the top, 5.7 m in 3D, heading at it) may leave: it gets
        # a plan, clear of the top from the first waypoint on.
        inside = np.array([195.0, -1.0])
        assert _clearance_3d(inside, sc.terrain, c.altitude) < c.d_safe2
        plan = pl.plan(inside, 0.0, tq, tp)
        assert plan.status == "ok"
        assert np.all(_clearance_3d(plan.path_points(21)[1:], sc.terrain, c.altitude) >= c.d_safe2 - 1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("aware", [True, False])
def test_team_keeps_d_safe2_from_a_tall_pole_where_a_planner_without_eq_3_does_not(aware):
    """A 76 m pole where the zone passes: the team ends no slot within d_safe2 of its top (the metrics'
    terrain_violations) and keeps d_safe2 along every flown path; the same planner with eq. 3
    switched off (the planner before eq. 3 was enforced) ends slots closer than d_safe2: the scene tests it."""
    from baselines.dp.clearance import TerrainClearance

    sc = _pole_scenario(3)
    c = sc.config
    traj = _fly(sc, DPPlanner(c, sc.terrain, shadow_aware=aware), 20)
    m = episode_metrics(traj, sc.terrain, c)
    assert all(r["terrain_violations"] == 0 for r in m)
    along = _clearance_3d(traj.path_xy, sc.terrain, c.altitude).min(axis=-1)        # (T, U)
    assert np.all(along >= c.d_safe2 - 1e-9)
    without = DPPlanner(c, sc.terrain, shadow_aware=aware)
    without.paths.clearance = TerrainClearance(Terrain(()), c.altitude, c.d_safe2, without.path_samples)
    old = _fly(sc, without, 20)
    assert sum(r["terrain_violations"] for r in episode_metrics(old, sc.terrain, c)) > 0



def test_a_last_resort_flight_keeps_d_safe2_along_the_path_the_engine_flies():
    """A UAV 110 m behind the zone can reach no zone node: it heads for the nearest (level 3), flown as the engine's
    best effort, which passes a 76 m pole 45 m ahead. It takes a node whose best effort keeps d_safe2 from the top
    instead; without eq. 3 the same planner flies within 4.9 m of it."""
    from baselines.dp.clearance import TerrainClearance

    sc = _pole_scenario(1)
    c = sc.config
    pole = Polytope.prism([[104.0, -1.0], [106.0, -1.0], [106.0, 1.0], [104.0, 1.0]], 76.0)
    terrain = Terrain(tuple(sc.terrain.polytopes) + (pole,))
    sc = _from_slot(Scenario(c, terrain, sc.track, sc.uav_xy, sc.uav_theta), 14, [[60.0, 0.0]], [0.0], 1)
    traj = _fly(sc, DPPlanner(c, terrain), 1)
    assert traj.infeasible.all()                                     # a best effort
    assert _clearance_3d(traj.path_xy, terrain, c.altitude).min() >= c.d_safe2
    without = DPPlanner(c, terrain)
    without.paths.clearance = TerrainClearance(Terrain(()), c.altitude, c.d_safe2, without.path_samples)
    assert _clearance_3d(_fly(sc, without, 1).path_xy, terrain, c.altitude).min() < c.d_safe2


def test_dense_bound_threads_change_nothing(monkeypatch):
    """COVERT_DP_THREADS splits the dense bound's targets between threads: a team rollout (negotiation
    included) plans the same nodes at the same costs with 1 and 3 threads, and several threads did run."""
    import threading

    import baselines.dp.recursion as recursion

    def rollout_plans():
        c = Config()
        sc = Scenario.paper(c, 3)
        team, eng, out = DPTeamPlanner(DPPlanner(c, sc.terrain)), Engine(sc), []
        for _ in range(6):
            plan = team.plan_engine(eng)
            out.append([(p.nodes.tolist(), repr(p.cost)) for p in plan.plans])   # repr: NaN == NaN
            eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
        return out

    serial = rollout_plans()
    seen = set()
    run_rows = recursion._map

    def spy(f, tasks):
        return run_rows(lambda t: (seen.add(threading.get_ident()), f(t))[1], tasks)

    monkeypatch.setattr(recursion, "BOUND_THREADS", 3)
    monkeypatch.setattr(recursion, "_map", spy)
    assert rollout_plans() == serial
    assert len(seen) >= 2                      # the pool makes its threads as the work needs them
    with pytest.raises(ValueError, match="COVERT_DP_THREADS"):
        monkeypatch.setenv("COVERT_DP_THREADS", "0")
        recursion._bound_threads()


# ------------------------------------------------------------------------------------------ team
def test_team_plans_are_conflict_free_at_slots_and_along_manoeuvres():
    c = Config()
    sc = Scenario.paper(c, 3)
    eng = Engine(sc)
    team = DPTeamPlanner(DPPlanner(c, sc.terrain))
    lim = c.d_safe1 + team.margin
    negotiated = 0
    for _ in range(12):
        tp = team.plan_engine(eng)
        negotiated += tp.rounds > 0
        assert tp.conflicts == 0
        pts = [p.path_points(21) for p in tp.plans]
        for i in range(3):
            for j in range(i + 1, 3):
                d = min(tp.plans[i].depth, tp.plans[j].depth)
                assert np.hypot(*(pts[i][:d, 1:] - pts[j][:d, 1:]).transpose(2, 0, 1)).min() >= lim - 1e-9
        eng.step(waypoints=tp.waypoints, infeasible=tp.infeasible)
    assert negotiated > 0, "the negotiation should have been exercised"


def test_negotiation_priority_rule_lower_index_keeps_its_plan():
    c = Config()
    sc = Scenario.paper(c, 3)
    tq, tp = targets(sc, 3)
    pl = DPPlanner(c, sc.terrain)
    # Three UAVs side by side (7 m apart) with the same heading want similar plans: conflicts.
    xy = np.array([[60.0, 0.0], [60.0, 7.0], [60.0, -7.0]])
    th = np.array([0.1, 0.1, 0.1])
    alone = pl.plan_batch(xy, th, tq, tp)
    team = DPTeamPlanner(pl).plan(xy, th, tq, tp)
    assert team.rounds >= 1 and team.conflicts == 0
    np.testing.assert_array_equal(team.plans[0].nodes, alone[0].nodes)     # uav_0 has priority
    assert team.plans[2].cost >= alone[2].cost - 1e-9                       # losers only lose


def test_safety_layer_separates_the_flown_slot_when_negotiation_gives_up():
    """With no negotiation rounds at all, the first moves are still separated (status "safety")."""
    c = Config()
    sc = Scenario.paper(c, 3)
    tq, tp = targets(sc, 3)
    xy = np.array([[60.0, 0.0], [60.0, 6.0], [60.0, -6.0]])
    th = np.array([0.1, 0.1, 0.1])
    team = DPTeamPlanner(DPPlanner(c, sc.terrain), max_rounds=0)
    before = team.conflicts(team.planner.plan_batch(xy, th, tq, tp))
    assert any(t == 0 for _, _, t, _ in before)
    plan = team.plan(xy, th, tq, tp)
    assert not any(t == 0 for _, _, t, _ in team.conflicts(plan.plans))
    assert "safety" in [p.status for p in plan.plans] and plan.plans[0].status == "ok"
    pts = [p.path_points(21)[0] for p in plan.plans]
    for i in range(3):
        for j in range(i + 1, 3):
            assert np.hypot(*(pts[i][1:] - pts[j][1:]).T).min() >= c.d_safe1 + team.margin - 1e-9


#: A 5-UAV team at slot 31 of ``Scenario.random(6_000_002)``, placed so that uav_1 and uav_3 can reach no lattice
#: node: they fly last-resort fallbacks, which the engine flies as a best effort, off the straight line to their
#: waypoints (a team that checked only that line could come within d_safe1 of a teammate).
SLOT31_XY = [[370.65413828554034, 6.233087369228483], [362.2380936053306, 48.484361810844014],
             [338.96568245432866, -0.07894614092876395], [333.15708997554873, 23.37868062341935],
             [371.75126739283814, 12.13192689255167]]
SLOT31_THETA = [3.868822475440151, 2.503586598476417, 5.218843725777844, 2.044877386318647, 5.931849694156942]


def _from_slot(scenario: Scenario, k: int, xy, theta, n_slots: int) -> Scenario:
    """``scenario`` from slot k on, for ``n_slots`` slots, with the team at (xy, theta) there."""
    tr = scenario.track
    track = TargetTrack(tr.road, tr.speeds[k:], delta=tr.delta, z=tr.z, s0=float(tr.arc[k]))
    return Scenario(scenario.config.replace(n_slots=n_slots), scenario.terrain, track, xy, theta)


@pytest.mark.parametrize("scene", ["random-6000002-slot31", "dense-5100002"])
def test_fallback_flights_keep_separation_and_clearance(scene):
    """Eqs. 2 and 3 on the paths the engine flies, measured as the metrics measure them, where a UAV's last-resort
    fallback is flown as a best effort (which does not follow a planned path)."""
    if scene == "dense-5100002":                 # 48 polytopes: uav_2 starts out of reach of the zone
        sc = Scenario.random(5_100_002, Config(n_polytopes=48))
        sc = _from_slot(sc, 0, sc.uav_xy, sc.uav_theta, 2)
    else:
        sc = _from_slot(Scenario.random(6_000_002, Config(n_uavs=5)), 31, SLOT31_XY, SLOT31_THETA, 2)
    c = sc.config
    team = DPTeamPlanner(DPPlanner(c, sc.terrain, road=sc.track.road))
    eng = Engine(sc)
    while not eng.done:
        plan = team.plan_engine(eng)
        eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible)
    traj = eng.trajectory()
    if scene == "dense-5100002":
        assert traj.infeasible[0, 2]             # the situation under test: a best-effort flight
    else:
        assert traj.infeasible[0, [1, 3]].all()
    path = traj.path_xy[:, :, 1:]                # (T, U, P - 1, 2); sample 0 is the previous slot's end
    gap = np.linalg.norm(path[:, :, None] - path[:, None], axis=-1).min(axis=-1)       # (T, U, U)
    gap[:, np.arange(sc.n_uavs), np.arange(sc.n_uavs)] = np.inf
    assert gap.min() >= c.d_safe1
    flown = np.concatenate([traj.path_xy, np.full(traj.path_xy.shape[:-1] + (1,), c.altitude)], axis=-1)
    assert np.linalg.norm(flown[..., None, :] - sc.terrain.highest_points, axis=-1).min() >= c.d_safe2
    assert all(m["separation_violations"] == 0 for m in episode_metrics(traj, sc.terrain, c))


def test_negotiation_work_is_polynomial_in_the_team_size():
    """The counters of docs/model.md#team-negotiation: O(R U^2) conflict checks, <= U safety orders."""
    u = 8
    c = Config(n_uavs=u)
    sc = Scenario.random(11, c)
    tq, tp = targets(sc, 3)
    # Eight UAVs 7 m apart on a 2 x 4 grid, same heading: neighbours want the same nodes.
    xy = np.array([[60.0 + 7.0 * (i % 2), 7.0 * (i // 2) - 10.5] for i in range(u)])
    th = np.full(u, 0.1)
    pairs = u * (u - 1)
    for rounds, ahead, escape in ((0, False, False), (5, False, False), (0, True, False), (5, True, False),
                                  (0, False, True), (5, True, True)):
        team = DPTeamPlanner(DPPlanner(c, sc.terrain), max_rounds=rounds, separated_continuation=ahead,
                             best_effort_escape=escape)
        plan = team.plan(xy, th, tq, tp)
        w = plan.work
        extra = pairs if ahead else 0            # the look-ahead's single-UAV replans (baselines.dp.team)
        assert w["dp_calls"] <= 1 + rounds + extra
        assert w["uav_plans"] <= u + rounds * (u - 1) + extra
        assert w["conflict_checks"] <= (rounds + 2 + (1 + pairs if ahead else 0)) * pairs // 2
        assert w["safety_orders"] <= u + escape and w["safety_solves"] <= (1 + ahead + escape) * u
        assert w["continuation_solves"] <= (u * (len(team.planner.lattice) + 2) if ahead else 0)
        assert not any(t == 0 for _, _, t, _ in team.conflicts(plan.plans))
    assert w["dp_calls"] >= 2, "the negotiation should have been exercised"


def test_separation_check_equals_the_sample_by_sample_test():
    """baselines.dp.path_checks.separated (lens and circle prefilters) against every sample measured."""
    from baselines.dp.path_checks import separated

    rng = np.random.default_rng(3)
    p, n_stages, lim = 21, 3, 5.5
    verdicts = []
    for trial in range(20):
        u, n = 3, 400
        start = rng.uniform(-30, 30, (n, 2))
        m = solve_manoeuvre(start, rng.uniform(0, 2 * np.pi, n), start + rng.uniform(-45, 45, (n, 2)))
        ok = np.asarray(m.feasible, bool)
        uav = rng.integers(0, u, n)
        avoid = np.full((u, 4, n_stages, p, 2), np.nan)
        for i in range(u):
            for o in range(int(rng.integers(0, 5))):
                a = rng.uniform(-30, 30, 2)
                rec = solve_manoeuvre(a, rng.uniform(0, 2 * np.pi), a + rng.uniform(-30, 30, 2))
                if rec.feasible:
                    avoid[i, o, 1] = rec.points(p)
        got = separated(m, ok, avoid, lim, uav, 1)
        pts = m.points(p)[ok][:, 1:]
        obs = avoid[uav[ok], :, 1, 1:]                                      # (n_ok, M, P - 1, 2)
        with np.errstate(invalid="ignore"):
            d = np.hypot(*(pts[:, None] - obs).transpose(3, 0, 1, 2))
        want = ~(d < lim).any(axis=(1, 2))
        np.testing.assert_array_equal(got, want, err_msg=f"trial {trial}")
        verdicts.append(want)
    verdicts = np.concatenate(verdicts)
    assert verdicts.mean() > 0.5 and (~verdicts).sum() > 100


# ------------------------------------------------------------------------------ the paper's claims
@pytest.fixture(scope="module")
def claim_runs():
    """A reduced but honest run: the paper scene (3 UAVs) and the first 4 held-out scenes (1 UAV), the
    first 30 of their 70 slots, both methods. Same scenes and code as `covert-env reproduce`."""
    runs = []
    scenes = [("paper", 0, 3)] + [("random", HELDOUT_SEED_BASE + i, 1) for i in range(4)]
    for kind, seed, u in scenes:
        sc = make_scenario(kind, seed, u)
        for aware in (True, False):
            out = rollout(sc, shadow_aware=aware, n_slots=30)
            q = slot_quantities(out["trajectory"], sc.terrain, sc.config)
            runs.append(dict(aware=aware, sc=sc, out=out, q=q,
                             m=episode_metrics(out["trajectory"], sc.terrain, sc.config, q)))
    return runs


@pytest.mark.slow
def test_shadow_aware_keeps_los_at_every_unflagged_slot(claim_runs):
    aware = [r for r in claim_runs if r["aware"]]
    blocked_unflagged = sum(int((~r["q"].los & ~r["out"]["trajectory"].infeasible).sum()) for r in aware)
    flagged = sum(int(r["out"]["trajectory"].infeasible.sum()) for r in aware)
    assert blocked_unflagged == 0
    assert flagged <= 2


@pytest.mark.slow
def test_shadow_blind_loses_los_where_the_aware_planner_keeps_it(claim_runs):
    """The paper's comparison: on the same scenes and slots the blind method ends UAV-slots with blocked LoS
    (at least 5, in at least 2 of the 5 scenes), never fewer than the aware method, which has none."""
    aware = [int((~r["q"].los).sum()) for r in claim_runs if r["aware"]]
    blind = [int((~r["q"].los).sum()) for r in claim_runs if not r["aware"]]
    assert sum(aware) == 0
    assert sum(blind) >= 5 and sum(b > 0 for b in blind) >= 2


@pytest.mark.slow
def test_disguise_of_aware_is_at_least_80_percent_of_blind(claim_runs):
    k_aware = np.mean([m["mean_disguise"] for r in claim_runs if r["aware"] for m in r["m"]])
    k_blind = np.mean([m["mean_disguise"] for r in claim_runs if not r["aware"] for m in r["m"]])
    assert k_aware >= 0.8 * k_blind


@pytest.mark.slow
def test_claim_runs_keep_separation_and_fly_the_planned_moves(claim_runs):
    """No separation violation (eq. 2; the paper scene has 3 UAVs), and every unflagged slot ends exactly on a
    lattice node of the zone at that slot: the planner only plans manoeuvres within V_max and W_max, so the
    engine never had to fall back to its best-effort control. (Eq. 3 cannot be violated on these scenes, whose
    tops are capped at h - d_safe2: see the tall-pole tests.)"""
    for r in claim_runs:
        traj, c = r["out"]["trajectory"], r["sc"].config
        assert all(m["separation_violations"] == 0 for m in r["m"])
        lat = zone_lattice(c)
        for k in range(traj.n_slots):
            nodes = to_world(lat, traj.target_xyz[k + 1, :2], traj.target_phi[k + 1])
            gap = np.hypot(*(traj.uav_xy[k + 1][:, None] - nodes[None]).transpose(2, 0, 1)).min(axis=1)
            assert np.all(gap[~traj.infeasible[k]] < 1e-6), (k, gap)


@pytest.mark.slow
def test_check_path_keeps_los_between_slots():
    """With check_path=True no UAV-slot has blocked LoS along the flown path (held-out scenes)."""
    total = flagged = 0
    for i in range(3):
        sc = make_scenario("random", HELDOUT_SEED_BASE + i, 1)
        out = rollout(sc, check_path=True, n_slots=25)
        traj = out["trajectory"]
        q = slot_quantities(traj, sc.terrain, sc.config)
        total += int((~q.los_path & ~traj.infeasible).sum())
        flagged += int(traj.infeasible.sum())
    assert total == 0
    assert flagged <= 2


def test_planner_rejects_bad_arguments():
    c = Config()
    t = Terrain(())
    with pytest.raises(ValueError, match="heading"):
        DPPlanner(c, t, heading="sideways")
    with pytest.raises(ValueError, match="heading_bins"):
        DPPlanner(c, t, heading="binned", heading_bins=0)
    pl = DPPlanner(c, t)
    with pytest.raises(ValueError, match="target_xyz"):
        pl.plan([0.0, 0.0], 0.0, np.zeros((1, 3)), np.zeros(1))
    with pytest.raises(ValueError, match="finite"):
        pl.plan([np.nan, 0.0], 0.0, np.zeros((6, 3)), np.zeros(6))


def test_stage_pair_disguise_is_eq_11_in_float32():
    """The planner's bounds hold the disguise part of eq. 18 for every node pair, computed in float32 in place (S x
    S arrays); it must be -lambda times covert_env.geometry.cost.disguise (eq. 11's one home) to float32 rounding."""
    from covert_env.geometry.cost import disguise

    sc = Scenario.random(1_000_001)
    c, track = sc.config, sc.track
    pl = DPPlanner(c, sc.terrain)
    a = pl.cache.stage(track.position(3), track.heading(3))
    b = pl.cache.stage(track.position(4), track.heading(4))
    _, got = pl.cache.pair(a, b).by_target()                           # [target b, source a]
    want = -c.lam * disguise(a.alpha[None, :], b.alpha[:, None], a.d[None, :], b.d[:, None], c.eta)
    assert got.dtype == np.float32 and got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=2e-3 * c.lam)


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.parametrize("ctg_dtype", [None, np.float64, np.float32])
def test_compiled_dense_bound_equals_its_array_form(shared, ctg_dtype):
    """The recursion's dense bound and round 0 (recursion._bound_rows) are the array operations they replace, to the
    bit: the float32 cells, the table's gather, the float32 sums in their order, the cut by the cost-to-go in its
    dtype, each target's smallest bound and the (target, source) pairs within FIRST_BAND of it, in C order."""
    from baselines.dp.recursion import _bound_rows
    from baselines.dp.selection import FIRST_BAND

    rng = np.random.default_rng(5 + shared)
    n, cells = 40, 500
    base = rng.uniform(50, 450, (n, n)).astype(np.float32)
    heading = rng.uniform(-40, 40, n).astype(np.float32)
    table_lb = rng.uniform(0, 60, cells).astype(np.float32)
    table_lb[::17] = np.inf                                          # unreachable cells
    disguise = rng.uniform(0, 30, (n, n)).astype(np.float32)
    pen = rng.uniform(0, 5, n).astype(np.float32)
    both = (disguise + pen[:, None]).astype(np.float32)
    cost_grid = rng.uniform(0, 300, n).astype(np.float32)
    cost_grid[rng.random(n) < 0.3] = np.inf                          # absent sources
    ctg = None if ctg_dtype is None else rng.uniform(0, 100, n).astype(ctg_dtype)
    thr = np.float32(380.0)

    want = table_lb.take((base - heading).astype(np.int32))           # the array form, step by step
    if shared:
        want += both
    else:
        want += disguise
        want += pen[:, None]
    want += cost_grid
    if ctg is not None:
        want[want + ctg[:, None] > thr] = np.inf
    colmin = want.min(axis=1)
    cut = np.where(np.isfinite(colmin), colmin + FIRST_BAND, -np.inf)
    t_want, s_want = np.nonzero(want <= cut[:, None])

    out, got_min = np.empty((n, n), np.float32), np.empty(n, np.float32)
    cand_t, cand_s = np.empty(n * n, np.int64), np.empty(n * n, np.int64)
    k = _bound_rows(base, heading, table_lb, disguise, pen, both if shared else np.zeros((0, 0), np.float32), shared,
                    cost_grid, np.zeros(0) if ctg is None else ctg, ctg is not None, thr, 0, n, out, got_min, cand_t,
                    cand_s)
    assert np.array_equal(out, want) and np.array_equal(got_min, colmin)
    assert np.array_equal(cand_t[:k], t_want) and np.array_equal(cand_s[:k], s_want)
    assert 0 < k < n * n and np.isinf(out).any()
    base[3, 4], cost_grid[4] = 1e6, 10.0                             # a cell beyond the table, of a state
    assert _bound_rows(base, heading, table_lb, disguise, pen, both, shared, cost_grid, np.zeros(0), False, thr, 0,
                       n, out, got_min, cand_t, cand_s) == -1
