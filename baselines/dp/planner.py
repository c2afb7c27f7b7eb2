"""One UAV's (or a batch of independent UAVs') receding-horizon plan: :class:`DPPlanner`."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from baselines.dp.fallback import fallback_penalties, nearest_zone_node
from baselines.dp.lattice import StageCache
from baselines.dp.path_checks import PathChecker
from baselines.dp.plan import DPPlan, flown_paths
from baselines.dp.possible_targets import PossibleTargets
from baselines.dp.recursion import ForwardRecursion, backtrack
from baselines.dp.states import Layer, Problem, SolveCounts, batch_layers, best_cost, depths, layers_of
from baselines.dp.table import manoeuvre_bounds_table
from covert_env.geometry.angles import wrap_heading
from covert_env.geometry.cost import uav_target_angle, uav_target_distance
from covert_env.geometry.zone import zone_lattice
from covert_env.world.config import MAX_HORIZON, Config
from covert_env.world.engine import MAX_PATH_SAMPLES
from covert_env.world.road import Road
from covert_env.world.terrain import Terrain

__all__ = ["DPPlanner", "HEADING_MODES"]

HEADING_MODES = ("inherited", "binned")


@dataclass
class _Outcome:
    """Which recursion's layers hold UAV i's plan: ``layers`` with the UAV as batch row ``row``."""

    layers: list[Layer]
    row: int
    depth: int
    status: str


class DPPlanner:
    """Receding-horizon DP planner (paper §2.5, eqs. 17-21); see :mod:`baselines.dp`.

    Args:
        config: model parameters (horizon N, delta, V_max, W_max, eta, lambda, zone, grid_step, ...).
        terrain: the polytopes (for line of sight).
        shadow_aware: plan over the visible zone (eq. 10, the paper's method); False plans over the plain
            eroded zone (the comparison method [1]).
        heading: ``"inherited"`` (position-only states, heading from the best predecessor: the paper) or
            ``"binned"`` (state = node x heading bin).
        heading_bins: number B of heading bins for ``"binned"``.
        check_path: also require, at ``path_samples`` instants along every manoeuvre, a clear line of
            sight to the target at the same instant and membership of the zone of eq. 4 around it (a
            guarantee between slots that the paper does not give).
        path_samples: samples per slot for ``check_path`` (endpoints included; 21 contains the engine's
            default 11 instants).
        prune: use the inherited plan as an upper bound to prune the binned search (never worse, much
            faster; off only for testing).
        cache_size: stages (and stage pairs) kept in the cache; default N + 2. A pair costs ~5-10 MB at the
            2 m grid (L = 577 nodes), ~100 MB at 1 m.
        los_margin: prediction-error radius (m) of the line-of-sight check: a node is visible only if its line
            of sight is clear to every true target position within this margin of the predicted one
            (:mod:`baselines.dp.possible_targets`). None (default): ``config.r_u`` when
            ``config.prediction_error > 0``, else 0 -- the paper's eq. 10, the predicted target only
            (docs/decisions/model.md#prediction-los).
        road: the target's road; with a margin, the possible positions are the road within arc length
            ``los_margin`` of the prediction; None: the disk of radius ``los_margin`` (eq. 5's gamma(q)).
        path_cost: None (the paper: LoS only at slot times), or per stage j = 1..N a cost (m of eq. 18's g) per
            unit of blocked path share: a manoeuvre into stage j costs ``path_cost[j-1]`` times the share of its
            ``path_samples`` (after the start, the end included) without LoS to the predicted target at the same
            instant (:meth:`~baselines.dp.path_checks.PathChecker.blocked_share`). The env's reward charges
            ``los_path_penalty * reward_scale`` = 100 m per slot fully blocked; the learned planner
            (:mod:`training.dp_cost`) fits these numbers. Not with ``check_path`` (that makes LoS a constraint).

    Example::

        planner = DPPlanner(Config(), scenario.terrain)
        plan = planner.plan(xy, theta, target_xyz, target_phi)   # target_* for slots k..k+N
        plan.nodes[0]                                            # the waypoint action now

    Several UAVs are planned together with :meth:`plan_batch` (same results, the exact manoeuvre solves
    of all UAVs batched into one call per round).
    """

    def __init__(self, config: Config, terrain: Terrain, *, shadow_aware: bool = True,
                 heading: str = "inherited", heading_bins: int = 16, check_path: bool = False,
                 path_samples: int = 21, prune: bool = True, cache_size: int | None = None,
                 los_margin: float | None = None, road: Road | None = None, path_cost=None):
        if not isinstance(config, Config):
            raise TypeError(f"DPPlanner: config must be a covert_env.Config, got {type(config).__name__}")
        if not isinstance(terrain, Terrain):
            raise TypeError(f"DPPlanner: terrain must be a covert_env.world.terrain.Terrain (Terrain() for none), got "
                            f"{type(terrain).__name__}")
        if road is not None and not isinstance(road, Road):
            raise TypeError(f"DPPlanner: road must be None or a covert_env.world.road.Road, got {type(road).__name__}")
        if heading not in HEADING_MODES:
            raise ValueError(f"DPPlanner: heading must be one of {HEADING_MODES}, got {heading!r}")
        for name, value, low, high in (("heading_bins", heading_bins, 1, 360), ("path_samples", path_samples, 2,
                                                                                 MAX_PATH_SAMPLES),
                                       ("cache_size", config.horizon + 2 if cache_size is None else cache_size, 1,
                                        10 * MAX_HORIZON)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
                raise ValueError(f"DPPlanner: {name} must be an integer in [{low}, {high}], got {value!r}")
        if los_margin is None:
            los_margin = config.r_u if config.prediction_error > 0 else 0.0
        if isinstance(los_margin, bool) or not isinstance(los_margin, (int, float, np.integer, np.floating)) \
                or not (np.isfinite(los_margin) and los_margin >= 0):
            raise ValueError(f"DPPlanner: los_margin must be None or a finite number >= 0 (m), got {los_margin!r}")
        self.path_cost = _check_path_cost(path_cost, config.horizon, check_path)
        self.config = config
        self.terrain = terrain
        self.los_margin = float(los_margin)
        #: Where the true target may be around a prediction (None: at the prediction, the paper's eq. 10).
        self.possible_targets = PossibleTargets(self.los_margin, road) if self.los_margin > 0 else None
        self.shadow_aware = bool(shadow_aware)
        self.heading = heading
        self.heading_bins = int(heading_bins) if heading == "binned" else 1
        self.check_path = bool(check_path)
        self.path_samples = int(path_samples)
        self.prune = bool(prune)
        self.lattice = zone_lattice(config)
        self.table = manoeuvre_bounds_table(config.v_max, config.w_max, config.delta)
        # A replan at slot k+1 reuses N - 1 of the stages and N - 2 of the pairs of the one at slot k.
        size = int(cache_size) if cache_size is not None else config.horizon + 2
        self.cache = StageCache(self.lattice, self.table, config.lam, config.eta, size)
        self.paths = PathChecker(config, terrain, self.path_samples)
        self.recursion = ForwardRecursion(config, self.lattice, self.table, self.cache, self.paths)

    @property
    def samples_path(self) -> bool:
        """Whether plans read the target between slot times (``check_path`` or a ``path_cost``)."""
        return self.check_path or self.path_cost is not None

    @property
    def name(self) -> str:
        """A label such as ``dp-aware-inherited`` or ``dp-blind-binned16-path``."""
        h = "inherited" if self.heading == "inherited" else f"binned{self.heading_bins}"
        margin = f"-los{self.los_margin:g}" if self.los_margin > 0 else ""
        cost = "-pathcost" if self.path_cost is not None else ""
        return (f"dp-{'aware' if self.shadow_aware else 'blind'}-{h}{'-path' if self.check_path else ''}{cost}"
                f"{margin}")

    def visible_nodes(self, q, phi) -> np.ndarray:
        """(L,) bool: lattice nodes at target pose (q, phi) with a clear line of sight (cached): to q (eq. 10),
        or with a ``los_margin`` to every possible true target position around q."""
        return self.cache.stage(q, phi).visible(self.terrain, self.config.altitude, self.possible_targets).copy()

    def clear_nodes(self, q, phi) -> np.ndarray:
        """(L,) bool: lattice nodes at target pose (q, phi) at least d_safe2 from every polytope top (eq. 3)."""
        return self.paths.clearance.clear(self.cache.stage(q, phi).xy)

    def allowed_nodes(self, q, phi) -> np.ndarray:
        """(L,) bool: the nodes this planner may use at target pose (q, phi): clear of the tops (eq. 3) and
        visible (eq. 10), or only clear if shadow-blind."""
        ok = self.visible_nodes(q, phi) if self.shadow_aware else np.ones(len(self.lattice), bool)
        if self.paths.clearance.active:
            ok &= self.clear_nodes(q, phi)
        return ok

    def plan(self, start_xy, start_theta: float, target_xyz, target_phi, *, blocked=None,
             target_path=None) -> DPPlan:
        """Plan N slots ahead from the pose (start_xy, start_theta) at slot k.

        Args:
            start_xy: (2,) current position; start_theta: current heading (rad).
            target_xyz: (N+1, 3) target positions for slots k, k+1, ..., k+N (current + predictions).
            target_phi: (N+1,) target headings for the same slots.
            blocked: optional (N, L) bool, nodes removed per stage (team negotiation).
            target_path: optional (N, P, 3) target positions at ``path_samples`` = P equally spaced instants
                of each slot k+j-1 -> k+j (for ``check_path``); default: linear interpolation.

        Returns:
            A :class:`DPPlan`. Never raises for lack of a feasible plan (see :mod:`baselines.dp`).
        """
        blk = None if blocked is None else np.asarray(blocked, bool)[None]
        return self.plan_batch(np.reshape(start_xy, (1, 2)), np.reshape(start_theta, (1,)), target_xyz,
                               target_phi, blocked=blk, target_path=target_path)[0]

    def plan_batch(self, start_xy, start_theta, target_xyz, target_phi, *, blocked=None,
                   target_path=None, avoid=None, avoid_dist: float = 0.0, resume=None) -> list[DPPlan]:
        """:meth:`plan` for U UAVs at once: ``start_xy`` (U, 2), ``start_theta`` (U,), ``blocked`` (U, N, L).

        Each plan is the one :meth:`plan` would return for that UAV alone; ``time`` is the batch's time
        split evenly.

        Args:
            avoid: optional (U, M, N, P, 2) path samples of up to M other UAVs' plans per UAV (P equally
                spaced instants per slot, NaN where absent); transitions that come closer than
                ``avoid_dist`` to one of them at the same instant are removed (team negotiation).
            resume: optional ``(plans, t0)``: the previous plans of these UAVs, whose ``blocked`` and
                ``avoid`` constraints before stage t0 were the same; their DP layers before t0 are reused
                (incremental replanning in the negotiation; the result is the same as from scratch).
        """
        t0 = time.perf_counter()
        start = np.asarray(start_xy, dtype=float).reshape(-1, 2)
        theta0 = wrap_heading(np.asarray(start_theta, dtype=float).reshape(-1))
        u = len(start)
        tq = np.asarray(target_xyz, dtype=float).reshape(-1, 3)
        tphi = np.asarray(target_phi, dtype=float).reshape(-1)
        n = len(tq) - 1
        if n < 1 or len(tphi) != n + 1:
            raise ValueError(f"DPPlanner.plan: need target_xyz (N+1, 3) and target_phi (N+1,) with N >= 1, "
                             f"got {tq.shape} and {tphi.shape}")
        if len(theta0) != u or not (np.all(np.isfinite(start)) and np.all(np.isfinite(theta0))):
            raise ValueError("DPPlanner.plan: need finite start poses, one heading per position")
        L = len(self.lattice)
        removed = np.zeros((u, n, L), bool) if blocked is None else np.asarray(blocked, bool).reshape(u, n, L)
        stages = [self.cache.stage(tq[j], tphi[j]) for j in range(1, n + 1)]
        path = self.paths.context(tq, tphi, target_path) if self.samples_path else None
        counts = SolveCounts()
        alpha0 = np.atleast_1d(uav_target_angle(start, tq[0, :2], tphi[0]))
        d0 = np.atleast_1d(uav_target_distance(start, tq[0, :2]))
        allowed = np.stack([self.allowed_nodes(tq[j], tphi[j]) for j in range(1, n + 1)])     # (N, L)
        base = [np.where(allowed[j], 0.0, np.inf)[None] for j in range(n)]
        any_removed = removed.any()
        penalties = [np.where(removed[:, j], np.inf, base[j]) if any_removed else base[j] for j in range(n)]
        avoid = None if avoid is None else np.asarray(avoid, float).reshape(u, -1, n, np.shape(avoid)[-2], 2)
        prob = Problem(start=start, theta=theta0, alpha0=alpha0, d0=d0, stages=stages, penalties=penalties, path=path,
                       avoid=avoid, avoid_dist=float(avoid_dist),
                       path_cost=None if self.path_cost is None else self.path_cost[:n])

        outcomes, strict = self._strict_outcomes(prob, base, u, n, counts, self._resumed_layers(resume, u))
        todo = [i for i in range(u) if outcomes[i] is None]
        if self.paths.clearance.active:
            # Eq. 3 is a constraint at every fallback level too: nodes too near a top are never offered.
            removed = removed | ~np.stack([self.paths.clearance.clear(st.xy) for st in stages])[None]
        if todo and self.shadow_aware:
            # Level 2: every zone node, a penalty per node without LoS, earlier stages weigh more.
            idx = np.array(todo)
            sub = Problem(start=start[idx], theta=theta0[idx], alpha0=alpha0[idx], d0=d0[idx], stages=stages,
                          penalties=fallback_penalties(allowed, removed[idx]), path=path,
                          avoid=None if avoid is None else avoid[idx], avoid_dist=float(avoid_dist), path_soft=True)
            fallback_layers = self.recursion.run(sub, counts)
            fallback_depth = depths(fallback_layers, len(idx))
            for s, i in enumerate(todo):
                if fallback_depth[s]:
                    outcomes[i] = _Outcome(fallback_layers, s, int(fallback_depth[s]), "fallback")
        plans = []
        c = self.config
        common = dict(time=(time.perf_counter() - t0) / u, n_exact=counts.exact, n_bounded=counts.bounded,
                      v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        for i in range(u):
            pose = dict(start_xy=np.array(start[i]), start_theta=float(theta0[i]))
            o = outcomes[i]
            if o is None:
                # Level 3: no zone node reachable in one slot; head for the nearest one whose best effort keeps
                # eq. 3 along the path the engine flies (it does not end on the node).
                blocked = removed[i, 0]
                if self.paths.clearance.active:
                    flown = flown_paths(np.broadcast_to(start[i], stages[0].xy.shape), np.full(L, theta0[i]),
                                        stages[0].xy, c, self.path_samples)
                    blocked = blocked | ~self.paths.clearance.paths_clear(flown)
                node = nearest_zone_node(self.config, stages[0], start[i], allowed[0], blocked)
                plans.append(DPPlan(**_single_move(node, stages[0], n), status="fallback", infeasible=True,
                                    **pose, **common))
            else:
                plans.append(DPPlan(**backtrack(o.layers, o.row, o.depth, stages), status=o.status,
                                    infeasible=o.status == "fallback", **pose, **common,
                                    layers=layers_of(strict, i)))
        return plans

    def _strict_outcomes(self, prob: Problem, base, u: int, n: int, counts: SolveCounts, prefix):
        """The strict DP (allowed nodes only): per UAV an ``_Outcome`` or None; and the inherited pass's layers.

        With binned headings, the inherited plan's cost bounds the binned search, and the binned plan is
        kept only where it goes deeper or costs less.
        """
        layers = self.recursion.run(prob, counts, prefix=prefix)
        depth = depths(layers, u)
        if self.heading_bins > 1 and depth.any():
            upper_bound = np.array([best_cost(layers, i, depth[i]) if (depth[i] == n and self.prune) else np.inf
                                    for i in range(u)])
            cost_to_go = (self.recursion.cost_to_go_bounds(prob.stages, base) if np.isfinite(upper_bound).any()
                          else None)
            binned = self.recursion.run(prob, counts, bins=self.heading_bins, upper_bound=upper_bound,
                                        cost_to_go=cost_to_go)
            bdepth = depths(binned, u)
        out: list = [None] * u
        for i in range(u):
            if depth[i] == 0:
                continue
            src, d = layers, depth[i]
            if self.heading_bins > 1 and (bdepth[i] > d or (bdepth[i] == d and
                                                            best_cost(binned, i, d) < best_cost(layers, i, d))):
                src, d = binned, bdepth[i]
            out[i] = _Outcome(src, i, int(d), "ok" if d == n else "truncated")
        return out, layers

    @staticmethod
    def _resumed_layers(resume, u: int) -> list[Layer] | None:
        """The first t0 layers of the previous plans, batched; None when they cannot be reused."""
        if resume is None:
            return None
        plans, t0 = resume
        if t0 < 1 or len(plans) != u or any(p.layers is None or len(p.layers) < t0 for p in plans):
            return None
        return batch_layers([p.layers for p in plans], t0)


def _check_path_cost(path_cost, horizon: int, check_path: bool) -> np.ndarray | None:
    """``path_cost`` as a read-only (N,) float array (None stays None); errors name the value and the range."""
    if path_cost is None:
        return None
    if check_path:
        raise ValueError("DPPlanner: path_cost does not go with check_path (check_path makes LoS along the path a "
                         "constraint; path_cost makes it a cost)")
    try:
        w = np.array(path_cost, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"DPPlanner: path_cost must be None or {horizon} numbers (one per stage), got "
                         f"{path_cost!r}") from None
    if np.shape(path_cost) != (horizon,) or not np.all(np.isfinite(w)) or np.any(w < 0) or np.any(w > 1e6):
        raise ValueError(f"DPPlanner: path_cost must be None or {horizon} numbers in [0, 1e6] (one per stage of "
                         f"config.horizon = {horizon}; m of stage cost per unit of blocked path share), got "
                         f"{path_cost!r}")
    w.setflags(write=False)
    return w


def _single_move(node: int, stage, n: int) -> dict:
    """DPPlan fields of a one-slot move to ``node`` without a known manoeuvre (a best-effort fallback)."""
    nodes = np.full(n, -1, np.int64)
    nodes[0] = node
    wp = np.full((n, 2), np.nan)
    wp[0] = stage.xy[node]
    nan = np.full(n, np.nan)
    return dict(nodes=nodes, waypoints=wp, headings=nan.copy(), speeds=nan.copy(), stage_costs=nan.copy(),
                cost=float("nan"), depth=1)
