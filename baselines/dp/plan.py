"""What the planner returns: one UAV's plan (:class:`DPPlan`) and a team's negotiated plans (:class:`TeamPlan`).

Both are built with keyword arguments only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from covert_env.geometry.dynamics import Manoeuvre, solve_manoeuvre
from covert_env.geometry.flight import fly_waypoints

__all__ = ["DPPlan", "TeamPlan", "flown_paths"]


@dataclass(frozen=True, eq=False, kw_only=True)
class DPPlan:
    """One UAV's plan over the horizon (the result of :meth:`DPPlanner.plan`).

    Arrays have length N = horizon; entries past ``depth`` are -1 / NaN.

    Attributes:
        nodes: (N,) lattice indices (into ``zone_lattice(config)``, i.e. waypoint actions) per stage.
        waypoints: (N, 2) world positions of those nodes at slots k+1..k+N.
        headings: (N,) heading on arrival at each waypoint (NaN for a best-effort fallback move).
        speeds: (N,) speed of the manoeuvre into each waypoint (NaN for a best-effort fallback move).
        stage_costs: (N,) stage cost g of each step (eq. 18).
        cost: sum of ``stage_costs`` over the planned stages (eq. 17); NaN for a best-effort move.
        depth: number of planned stages (N unless truncated).
        status: ``"ok"``, ``"truncated"`` (the visible zone becomes unreachable after ``depth`` stages),
            ``"fallback"`` (no allowed node reachable now; see :mod:`baselines.dp`) or ``"safety"`` (the team
            negotiation ended with a conflict in the slot to fly; the first move was replaced by the best
            separated one-slot move, see :class:`DPTeamPlanner`).
        infeasible: the first move is not a reachable allowed node (a fallback, or a safety move that had to
            leave the visible zone).
        time: wall-clock seconds of the planning call.
        n_exact: manoeuvres solved exactly (eq. 29 root solves), by the whole :meth:`DPPlanner.plan_batch` call.
        n_bounded: transitions bounded through the lookup table, by the whole call.
        start_xy, start_theta: the pose the plan starts from.
        delta: slot length (for :meth:`manoeuvres`).
    """

    nodes: np.ndarray
    waypoints: np.ndarray
    headings: np.ndarray
    speeds: np.ndarray
    stage_costs: np.ndarray
    cost: float
    depth: int
    status: str
    infeasible: bool
    time: float
    n_exact: int
    n_bounded: int
    start_xy: np.ndarray
    start_theta: float
    v_max: float = 50.0
    w_max: float = 3.0
    delta: float = 1.0
    #: Internal: the strict inherited pass's DP layers of this UAV (incremental replanning by the team).
    layers: list | None = field(default=None, repr=False)
    #: Internal: path samples already computed, per sample count (the team checks the same plan many times).
    _points: dict = field(default_factory=dict, init=False, repr=False)

    @property
    def first_node(self) -> int:
        """Lattice index of the first waypoint: the action to take now."""
        return int(self.nodes[0])

    def manoeuvres(self) -> Manoeuvre:
        """The ``depth`` planned manoeuvres as one batch (re-solved; exact for a non-fallback plan)."""
        d = self.depth
        start = np.vstack([self.start_xy[None], self.waypoints[: d - 1]])
        theta = np.concatenate([[self.start_theta], self.headings[: d - 1]])
        return solve_manoeuvre(start, np.nan_to_num(theta), self.waypoints[:d], v_max=self.v_max,
                               w_max=self.w_max, delta=self.delta)

    def path_points(self, n: int) -> np.ndarray:
        """(depth, n, 2) positions at n equally spaced instants of each slot along the path the engine flies.

        A planned manoeuvre is flown as planned; a best-effort fallback move (always a plan's only move) as the
        engine flies it (:func:`flown_paths`), which does not end on its waypoint. Cached: treat the result as
        read-only.
        """
        if n in self._points:
            return self._points[n]
        m = self.manoeuvres()
        pts = m.points(n)
        bad = ~np.asarray(m.feasible, bool).reshape(-1)
        if bad.any():
            start = np.vstack([self.start_xy[None], self.waypoints[: self.depth - 1]])
            theta = np.nan_to_num(np.concatenate([[self.start_theta], self.headings[: self.depth - 1]]))
            pts[bad] = flown_paths(start[bad], theta[bad], self.waypoints[: self.depth][bad], self, n)
        pts.setflags(write=False)
        self._points[n] = pts
        return pts


def flown_paths(xy, theta, goals, limits, n: int) -> np.ndarray:
    """(K, n, 2) the paths the engine flies in one slot from poses ``xy`` (K, 2), ``theta`` (K,) to waypoints
    ``goals`` (K, 2), at n equally spaced instants (the start first): the manoeuvre (eqs. 22-29) where the waypoint
    is reachable, else the engine's best effort (:func:`covert_env.geometry.flight.waypoint_controls`). ``limits``:
    anything with ``v_max``, ``w_max`` and ``delta`` (a :class:`~covert_env.world.config.Config`, a :class:`DPPlan`)."""
    times = np.linspace(0.0, 1.0, n) * limits.delta                   # the engine's sample times
    xy, theta, goals = (np.asarray(a, float) for a in (xy, theta, goals))
    return fly_waypoints(xy.reshape(-1, 2), theta.reshape(-1), goals.reshape(-1, 2), limits, times)[0]


@dataclass(frozen=True, eq=False, kw_only=True)
class TeamPlan:
    """The negotiated plans of a team (the result of :meth:`DPTeamPlanner.plan`).

    Attributes:
        plans: one :class:`DPPlan` per UAV.
        nodes: (U,) first-stage lattice indices (the waypoint actions to take now).
        waypoints: (U, 2) first-stage world positions.
        infeasible: (U,) per-UAV fallback flags.
        rounds: negotiation rounds used (0 if the first plans were conflict-free).
        conflicts: conflicts found in the final plans (0 unless ``max_rounds`` ran out).
        replans: DP calls made for losers.
        time: wall-clock seconds for the whole team (all plans plus negotiation), one core.
        n_exact: manoeuvres solved exactly, all plans and replans together.
        n_bounded: transitions bounded through the lookup table, all plans and replans together.
        work: the negotiation's work counters (:data:`baselines.dp.team.WORK_COUNTERS`).
    """

    plans: list
    nodes: np.ndarray
    waypoints: np.ndarray
    infeasible: np.ndarray
    rounds: int
    conflicts: int
    replans: int
    time: float
    n_exact: int = 0
    n_bounded: int = 0
    work: dict = field(default_factory=dict)

