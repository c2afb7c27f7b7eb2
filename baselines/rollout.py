"""The DP team planner flown through a scenario on an :class:`~covert_env.world.engine.Engine`: what ``reproduce``, the
prediction study and the planner's tests fly."""

from __future__ import annotations

import numpy as np

from baselines.dp import DPPlanner, DPTeamPlanner
from covert_env.world.engine import Engine
from covert_env.world.scenario import Scenario

__all__ = ["rollout"]


def rollout(scenario: Scenario, *, shadow_aware: bool = True, heading: str = "inherited", heading_bins: int = 16,
            check_path: bool = False, max_rounds: int = 5, separation_margin: float = 0.5,
            n_slots: int | None = None, los_margin: float | None = None) -> dict:
    """Fly the DP team planner through a scenario on an :class:`Engine` (one team replan per slot).

    This is what :class:`baselines.policies.DPPolicy` does through the waypoint environment; the first
    waypoint of every UAV's plan is handed to the engine, which flies the manoeuvre. ``los_margin``: see
    :class:`DPPlanner` (default: r_u under a prediction error, else 0; the possible true target positions
    are taken along the scenario's road).

    Returns:
        dict with ``engine`` (finished), ``trajectory``, per-slot arrays ``team_time`` (s), ``rounds``,
        ``conflicts`` and ``status`` ((T, U) strings), and ``planner`` (the :class:`DPPlanner`).
    """
    planner = DPPlanner(scenario.config, scenario.terrain, shadow_aware=shadow_aware, heading=heading,
                        heading_bins=heading_bins, check_path=check_path, los_margin=los_margin,
                        road=scenario.track.road)
    team = DPTeamPlanner(planner, max_rounds=max_rounds, separation_margin=separation_margin)
    eng = Engine(scenario)
    t_max = scenario.config.n_slots if n_slots is None else int(n_slots)
    times, rounds, conflicts, status = [], [], [], []
    while eng.k < t_max:
        plan = team.plan_engine(eng)
        u = len(plan.plans)
        eng.step(waypoints=plan.waypoints, infeasible=plan.infeasible, decision_time=np.full(u, plan.time / u))
        times.append(plan.time)
        rounds.append(plan.rounds)
        conflicts.append(plan.conflicts)
        status.append([p.status for p in plan.plans])
    return {"engine": eng, "trajectory": eng.trajectory(), "team_time": np.array(times),
            "rounds": np.array(rounds), "conflicts": np.array(conflicts), "status": np.array(status),
            "planner": planner}
