"""The paper's receding-horizon dynamic-programming planner (Almuzaini & Savkin 2024, §2.5, eqs. 17-21).

## What it solves

At slot k every UAV i plans the next N slots (N = ``config.horizon``). Its states at stage j = 1..N
are grid nodes of the zone around the predicted target pose q[k+j], phi[k+j]: the offsets of
:func:`covert_env.zone.zone_lattice` (spacing ``grid_step``, the eroded zone of eq. 5) placed with
:func:`covert_env.zone.to_world`. The *same* lattice is the action set of the waypoint environments, so
a node index is an action. The allowed nodes are

* ``shadow_aware=True`` (the paper's method): nodes of the visible zone F[k+j] (eq. 10), i.e. eroded zone
  and a clear line of sight (eq. 6) to q[k+j];
* ``shadow_aware=False`` (the earlier method [1], the paper's comparison): every node of the eroded zone.

The cost of moving from node a at stage j to node b at stage j+1 is the stage cost of eq. 18,

    c_ab = g = v delta - lambda eta |wrap(alpha_b - alpha_a)| - lambda |d_b - d_a|,

with alpha, d (eqs. 12-13) measured against the target's pose at each stage and v the speed of the
turn-then-straight manoeuvre (eqs. 22-29, :func:`covert_env.dynamics.solve_manoeuvre`) that flies from
a (with the heading the UAV has there) to b in one slot; c_ab = inf when no manoeuvre exists. The
forward recursion is eqs. 19-20, ``J_0(b) = c_sb`` from the start s and
``J_j(b) = min_a (c_ab + J_{j-1}(a))``; a virtual final state f with ``c_af = 0`` (eq. 21) makes the
optimum ``min_a J_{N-1}(a)``, and backtracking returns the node sequence. Only its first move is
flown; the UAV replans at the next slot.

## Headings: "inherited" and "binned"

The manoeuvre, hence c_ab, depends on the heading at a, which depends on how the UAV got to a. The
paper keeps position-only states: each node stores the heading of its best predecessor's manoeuvre
(``heading="inherited"``). That is not optimal: a slightly costlier arrival with a better heading can
make the rest of the path much cheaper. ``heading="binned"`` makes the state (node, heading bin) with
``heading_bins`` = B equal bins of [0, 2 pi); like the inherited variant each state stores the exact
continuous heading of its best arrival (a "hybrid-state" DP, as in Hybrid A*), so every cost in the
recursion is the exact cost of a flyable path, the inherited variant is the special case B = 1, and the
binned optimum converges to the true optimum J* (continuous heading) as B grows.

## Exact, but not dense: bounds before manoeuvres

A stage has S ~ 577 nodes at the default 2 m grid, so a dense stage is S^2 ~ 3e5 manoeuvres, each an
iterative root solve of eq. 29. Instead:

1. A lookup table of the manoeuvre in the UAV's own frame (polar: range rho and bearing psi of the goal
   relative to the heading; the manoeuvre is invariant under rigid motions) gives, per table cell, a
   lower bound on the path length v delta (the minimum over the cell's 4 x 4 neighbouring vertices) and
   marks cells no manoeuvre can reach. The disguise part of c_ab depends on positions only and is cached
   per pair of stages (shared by all UAVs and by the N - 1 replans that reuse it). So a vectorised lower
   bound LB >= J(a) + c_ab costs a few array passes per transition.
2. The exact manoeuvre is solved only where it can matter. Per target node: every transition within
   0.5 m of the node's smallest bound (this usually contains the winner), then, once some transition
   is feasible, every other one whose bound is still below the best exact value (the rest provably
   cannot win); nodes without a feasible transition yet get the next 1, 2, 4, ... smallest bounds.
   Each round is one vectorised solve for all UAVs of a team. The result equals the dense recursion's
   (tested against it at the 2 m grid), with ~1% of the transitions solved exactly.
3. For the binned variant the inherited plan is computed first; its cost is an upper bound U on the
   optimum. A heading-free backward recursion over the cached pair bounds gives a lower bound H on every
   node's cost-to-go, and states or transitions with ``J + bound + H > U`` are dropped (they cannot
   complete into anything better than the inherited plan, which is kept as the answer if the binned
   search finds nothing better).

The only approximation is the table's: its bounds are taken over a neighbourhood of table vertices
rather than proven. A test checks them against 4e5 exact manoeuvres (no violation); a violation could
only make the planner skip a transition, never accept an infeasible one. Under negotiation constraints
(below) the search for a node whose best transitions are all removed stops after a few rounds: the
loser's plan stays valid but may not be its constrained optimum.

``check_path=True`` adds, for every solved manoeuvre, ``path_samples`` instants at which the UAV must be
in the zone of eq. 4 around the target at that instant and outside its shadows (eqs. 8-9, exact within
R2 of the target, grown by 1 cm): a line-of-sight guarantee between slot times.

## When the visible zone is empty or unreachable

The planner never raises for lack of a plan. In order:

1. If the strict DP reaches stage N: ``status="ok"``. If it reaches only stage j < N (the visible zone
   becomes unreachable later), the plan is truncated there: ``status="truncated"``; the first move is
   still a reachable visible node, so the slot is fine.
2. If no allowed node is reachable at stage 1 (shadow-aware only): the DP is rerun over every node of the
   eroded zone, with a large penalty on nodes without line of sight that weighs earlier stages more
   (keep LoS as soon as possible); with ``check_path`` a manoeuvre losing LoS along the way pays the same
   penalty, and leaving the zone between slots is tolerated. ``status="fallback"``.
3. If no zone node at all is reachable in one slot: the waypoint is the zone node nearest to the UAV
   (a visible one if one is as near), which the engine flies as its documented best effort (the
   admissible constant control ending closest to it, see :class:`covert_env.engine.Engine`).
   ``status="fallback"``.

``plan.infeasible`` is True exactly for ``status="fallback"``: the slot is then flagged to the engine.

## Decentralised team (:class:`DPTeamPlanner`)

Each UAV plans on its own (all UAVs in one batched DP); the plans are exchanged and checked pairwise for
conflicts: distance below ``d_safe1 + separation_margin`` between two UAVs' nodes at the same stage, or
between their manoeuvres sampled at the same instants. **Priority rule (decided):** the UAV with the
lower agent index keeps its plan (fixed priorities, as in prioritised planning). The loser records the
winner's node and manoeuvre at the conflicting stage, removes from that stage every node within
``d_safe1 + separation_margin`` of the node and every transition whose manoeuvre comes that close to the
winner's at the same instants, and replans (reusing its DP layers before that stage). Rounds repeat
until no conflict remains or ``max_rounds``. Records only accumulate and the top UAV never replans, so
the negotiation terminates; usually one or two rounds suffice. If a conflict is left in the slot that
is actually flown (the records can leave a loser no separated move, so it falls back), a safety layer
replaces, in priority order, the conflicting UAV's first move by its best one-slot move that keeps the
distance to every higher-priority UAV's first manoeuvre (``status="safety"``); when the priority order
leaves some UAV no such move (a fast teammate sweeping past), the other priority orders are tried.

## Caching

Per scene and slot (keyed by the target pose), the world positions, alpha, d and visibility of the
lattice nodes are cached; per pair of consecutive slots, the disguise term and the table indices of
every node pair. None of this depends on the UAV, so a team and successive replans share it.
"""

from __future__ import annotations

import itertools
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
import shapely

from covert_env.angles import wrap_angle
from covert_env.config import Config
from covert_env.cost import uav_target_angle, uav_target_distance
from covert_env.dynamics import Manoeuvre, solve_manoeuvre
from covert_env.terrain import Terrain
from covert_env.visibility import line_of_sight, shadow_union_cfg
from covert_env.zone import in_feasible_zone, to_world, zone_lattice

__all__ = [
    "DPPlan",
    "DPPlanner",
    "DPTeamPlanner",
    "HEADING_MODES",
    "ManoeuvreTable",
    "TeamPlan",
    "brute_force_plan",
    "evaluate_plan",
    "manoeuvre_table",
]

HEADING_MODES = ("inherited", "binned")
TWO_PI = 2.0 * math.pi

#: Line-of-sight tolerance (m) used for nodes and path samples: polytopes grown by 1 micrometre, so a node
#: the planner calls visible stays visible under the engine's rounding when it is flown to.
VISIBILITY_TOL = -1e-6
#: Growth (m) of the shadows used for ``check_path``: shadows equal the blocked set up to ~1e-8 m at their
#: boundary (tests/test_visibility.py checks 1 cm); a point within 1 cm of a shadow counts as blocked.
SHADOW_MARGIN = 0.01
#: Penalty per non-visible node in fallback level 2, for the last stage; earlier stages weigh 2x more
#: each, so keeping LoS sooner always wins. Far above any plan cost (|g| < ~1e4 per stage).
FALLBACK_PENALTY = 1e6
#: Absolute slack when comparing float32 bounds with float64 exact costs (a few float32 ulps at ~1e4).
_BOUND_TOL = 1e-2
#: First-round band (cost units = metres of path): the table's bound is within ~0.9 m of the exact path
#: length for 99% of transitions, so solving every transition this close to its column's smallest bound
#: usually settles the column in one batch.
_FIRST_BAND = 0.5
#: Under negotiation constraints, best-first rounds (1 + 2 transitions) before an unsolved node is given up.
_OPEN_ROUNDS_CONSTRAINED = 2
#: Entries per chunk of the binned variant's dense bound (~16 MB of float32).
_CHUNK = 1 << 22


# ===================================================================================== results
@dataclass(frozen=True, eq=False)
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
            ``"fallback"`` (no allowed node reachable now; see the module docstring) or ``"safety"`` (the team
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
        """(depth, n, 2) positions at n equally spaced instants of each slot along the planned path.

        A best-effort fallback move is drawn as the straight segment to its waypoint (the engine flies its own
        best-effort control instead, so this is an approximation used only for conflict checks).
        """
        m = self.manoeuvres()
        pts = m.points(n)
        bad = ~np.asarray(m.feasible, bool).reshape(-1)
        if bad.any():
            start = np.vstack([self.start_xy[None], self.waypoints[: self.depth - 1]])
            f = np.linspace(0.0, 1.0, n)[:, None]
            seg = start[:, None, :] * (1 - f) + self.waypoints[: self.depth, None, :] * f
            pts[bad] = seg[bad]
        return pts


@dataclass(frozen=True, eq=False)
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


# ============================================================================= manoeuvre table
class ManoeuvreTable:
    """Bounds on the turn-then-straight manoeuvre (eqs. 22-29), tabulated in the UAV's own frame.

    A goal at range rho and bearing psi from the UAV (relative to its heading) needs a path of length
    ``ell(rho, psi) = v delta`` and ends with heading change ``dth(rho, psi)``; both are independent of
    where the UAV is and where it points. Vertices ``rho_i = i R / n_rho`` (R = V_max delta) and
    ``psi_j = 2 pi j / n_psi`` are solved exactly once. For the cell [rho_i, rho_i+1] x [psi_j, psi_j+1]:

    * ``lb`` = min of ell over the 4 x 4 vertices around the cell: a lower bound on ell anywhere in the
      cell (the vertex at rho = 0 counts as 0, its limit); inf if none of the cell's own 4 corners is
      feasible (the reachable set is not thinner than a cell);
    * ``dlo``, ``dhi`` = min / max of dth over the same vertices, widened by 1e-3 rad (and, next to the edge
      of the reachable set, where dth climbs steeply to the full turn W_max delta, widened to it): the
      interval the heading change lies in, which places a transition in a few heading bins before solving.

    Row ``n_rho + 1`` is a sentinel of infinite bounds for ranges beyond R. The planner uses the table only
    to decide which transitions to solve exactly; every cost it returns comes from the exact solver.
    """

    def __init__(self, v_max: float, w_max: float, delta: float, n_rho: int = 256, n_psi: int = 1024):
        if n_psi & (n_psi - 1):
            raise ValueError(f"ManoeuvreTable: n_psi must be a power of two, got {n_psi}")
        self.v_max, self.w_max, self.delta = float(v_max), float(w_max), float(delta)
        self.n_rho, self.n_psi = int(n_rho), int(n_psi)
        self.reach = self.v_max * self.delta
        self.rho_step = self.reach / self.n_rho
        self.psi_scale = self.n_psi / TWO_PI          # cells per radian
        rho = np.arange(self.n_rho + 1) * self.rho_step
        psi = np.arange(self.n_psi) / self.psi_scale
        goals = np.stack([rho[:, None] * np.cos(psi), rho[:, None] * np.sin(psi)], axis=-1)
        m = solve_manoeuvre(np.zeros(2), 0.0, goals, v_max=v_max, w_max=w_max, delta=delta)
        ok = np.asarray(m.feasible, bool)
        ell = np.where(ok, m.length, np.inf)
        ell[0] = 0.0                                    # rho -> 0: the path length tends to 0
        dth = np.where(ok, wrap_angle(np.where(ok, m.heading_after, 0.0)), np.nan)
        dth[0] = 0.0
        lb = self._block(ell, np.minimum, np.inf)
        # Reachability from the cell's own 4 corners only (the dilated block would call many unreachable
        # transitions at the edge of the reachable set possible and send them to the exact solver).
        corner = np.zeros_like(ok)
        for di in (0, 1):
            rows = np.vstack([ok, np.zeros((1, self.n_psi), bool)])[di:di + self.n_rho + 1]
            corner |= rows | np.roll(rows, -1, axis=1)
        corner[0] = True                              # rho -> 0 is reachable in the limit
        lb[~corner] = np.inf
        with np.errstate(invalid="ignore"):
            lo = self._block(np.where(np.isnan(dth), np.inf, dth), np.minimum, np.inf) - 1e-3
            hi = self._block(np.where(np.isnan(dth), -np.inf, dth), np.maximum, -np.inf) + 1e-3
        # Next to the edge of the reachable set the turn angle climbs steeply to W_max delta between a
        # feasible and an infeasible vertex, beyond the feasible vertices' range: widen those cells.
        edge = self._block(np.where(ok, 0.0, 1.0), np.maximum, 0.0) > 0
        turn = min(self.w_max * self.delta, math.pi)
        hi = np.where(edge & (hi > 0), np.maximum(hi, turn + 1e-3), hi)
        lo = np.where(edge & (lo < 0), np.minimum(lo, -turn - 1e-3), lo)
        bad = ~np.isfinite(lb)
        lo[bad], hi[bad] = 0.0, 0.0
        sentinel = np.full((1, self.n_psi), np.inf, np.float32)
        # Rows repeat psi three times: an index "range row * width + (bearing - heading) in cells, shifted
        # into [0, 3 n_psi)" then needs no modulo, only a subtraction and a truncation per transition.
        self.width = 3 * self.n_psi
        self.lb = np.tile(np.vstack([lb.astype(np.float32), sentinel]), 3).reshape(-1)
        self.dlo = np.tile(np.vstack([lo.astype(np.float32), np.zeros_like(sentinel)]), 3).reshape(-1)
        self.dhi = np.tile(np.vstack([hi.astype(np.float32), np.zeros_like(sentinel)]), 3).reshape(-1)
        for a in (self.lb, self.dlo, self.dhi):
            a.setflags(write=False)

    def _block(self, vert: np.ndarray, op, fill: float) -> np.ndarray:
        """(n_rho + 1, n_psi) cell values: ``op`` over vertices i-1..i+2, j-1..j+2 (periodic in psi)."""
        nr = self.n_rho + 1
        padded = np.full((nr + 3, self.n_psi), fill)
        padded[1:nr + 1] = vert
        out = np.full((nr, self.n_psi), fill)
        for di in range(4):
            rows = padded[di:di + nr]
            for dj in (-1, 0, 1, 2):
                out = op(out, np.roll(rows, -dj, axis=1))
        return out

    def base_index(self, rel_xy, rho=None, bearing=None) -> np.ndarray:
        """float32 ``row * width + bearing in cells + 2 n_psi`` of goals at ``rel_xy`` (goal - start).

        Subtracting a heading in cells (in [0, n_psi)) and truncating gives the cell index: the offset keeps
        the result in [n_psi, 3 n_psi) of the periodically repeated row. Ranges beyond the reach use the
        sentinel row. float32 is exact to ~0.1 cell here, inside the bounds' one-cell margin. ``rho`` and
        ``bearing`` may be passed instead of ``rel_xy`` when already known.
        """
        if rho is None:
            rel = np.asarray(rel_xy, float)
            rho, bearing = np.hypot(rel[..., 0], rel[..., 1]), np.arctan2(rel[..., 1], rel[..., 0])
        row = np.minimum(np.floor(rho / self.rho_step), self.n_rho + 1)
        cells = bearing * self.psi_scale + 2 * self.n_psi
        return (row * self.width + cells).astype(np.float32)

    def cell(self, base, theta) -> np.ndarray:
        """int32 cell indices from :meth:`base_index` values and headings (rad, any range)."""
        th = np.mod(np.asarray(theta, float), TWO_PI) * self.psi_scale
        return (np.asarray(base, np.float32) - th.astype(np.float32)).astype(np.int32)

    def lower_bound(self, rel_xy, theta) -> np.ndarray:
        """Lower bound on the manoeuvre length to goals at ``rel_xy`` (goal - start) from heading ``theta``."""
        return self.lb[self.cell(self.base_index(rel_xy), theta)]


@lru_cache(maxsize=8)
def manoeuvre_table(v_max: float, w_max: float, delta: float) -> ManoeuvreTable:
    """The :class:`ManoeuvreTable` for these limits, built once per process (~0.1 s)."""
    return ManoeuvreTable(v_max, w_max, delta)


# ===================================================================================== caches
class _Stage:
    """Lattice nodes at one predicted target pose: world xy, alpha, d (eqs. 12-13) and visibility."""

    __slots__ = ("key", "q", "phi", "xy", "alpha", "d", "_visible")

    def __init__(self, key, q: np.ndarray, phi: float, lattice: np.ndarray):
        self.key = key
        self.q = q
        self.phi = phi
        self.xy = to_world(lattice, q[:2], phi)
        self.alpha = uav_target_angle(self.xy, q[:2], phi)
        self.d = uav_target_distance(self.xy, q[:2])
        self._visible = None

    def visible(self, terrain: Terrain, altitude: float) -> np.ndarray:
        """(L,) LoS clear at this slot (eq. 6); every lattice node is in the eroded zone by construction."""
        if self._visible is None:
            self._visible = line_of_sight(terrain, self.xy, altitude, self.q, tol=VISIBILITY_TOL)
            self._visible.setflags(write=False)
        return self._visible


class _Pair:
    """Quantities of every node pair between two consecutive stages that do not depend on the UAV.

    negkap: float32 (L, L), ``-lambda (eta |d alpha| + |d d|)``, the disguise part of eq. 18.
    c0: float32 (L, L), ``negkap + chord`` (inf beyond V_max delta): a heading-free lower bound on c_ab.
    base: float32 (L, L), :meth:`ManoeuvreTable.base_index` of b - a.
    with_pen: cache of ``negkap + pen`` for the penalty vectors used with this pair (shared by UAVs).
    """

    __slots__ = ("negkap", "base", "with_pen", "_c0", "_chord_ok")

    def __init__(self, a: _Stage, b: _Stage, lam: float, eta: float, table: ManoeuvreTable):
        # Everything here feeds bounds only (exact costs are recomputed in float64 from the nodes' alpha
        # and d), so float32 throughout: half the memory traffic of the S x S arrays.
        f = np.float32
        dx = b.xy[None, :, 0].astype(f) - a.xy[:, None, 0].astype(f)
        dy = b.xy[None, :, 1].astype(f) - a.xy[:, None, 1].astype(f)
        chord = np.hypot(dx, dy)
        # alpha lies in (-pi, pi], so the difference is in (-2 pi, 2 pi) and |wrap| = min(|x|, 2 pi - |x|).
        dal = np.abs(b.alpha.astype(f)[None, :] - a.alpha.astype(f)[:, None])
        np.minimum(dal, f(TWO_PI) - dal, out=dal)
        dal *= f(eta)
        dal += np.abs(b.d.astype(f)[None, :] - a.d.astype(f)[:, None])
        dal *= f(-lam)
        self.negkap = dal
        self.base = table.base_index(None, chord, np.arctan2(dy, dx))
        self._chord_ok = (chord, table.reach)
        self._c0 = None
        self.with_pen: dict = {}

    @property
    def c0(self) -> np.ndarray:
        """``negkap + chord`` (inf beyond V_max delta): a heading-free lower bound on c_ab (built on demand)."""
        if self._c0 is None:
            chord, reach = self._chord_ok
            self._c0 = np.where(chord <= reach, self.negkap + chord, np.inf).astype(np.float32)
        return self._c0

    def negkap_pen(self, pen: np.ndarray) -> np.ndarray:
        """``negkap + pen[None, :]`` (float32), cached per penalty vector (few distinct ones per pair)."""
        key = pen.tobytes()
        out = self.with_pen.get(key)
        if out is None:
            out = self.negkap + pen.astype(np.float32)[None, :]
            if len(self.with_pen) >= 4:
                self.with_pen.pop(next(iter(self.with_pen)))
            self.with_pen[key] = out
        return out


@dataclass
class _Layer:
    """DP states of one stage for a batch of UAVs, sorted by (uav, node, bin).

    uav: which UAV of the batch; node: lattice index; theta: the exact heading of the state's best
    arrival; J: cost so far (with penalties); parent: row of the previous layer; v, g: the step's speed and
    stage cost (eq. 18).
    """

    uav: np.ndarray
    node: np.ndarray
    theta: np.ndarray
    J: np.ndarray
    parent: np.ndarray
    v: np.ndarray
    g: np.ndarray

    @property
    def n(self) -> int:
        return len(self.node)

    def take(self, idx) -> _Layer:
        return _Layer(*(a[idx] for a in (self.uav, self.node, self.theta, self.J, self.parent, self.v, self.g)))

    @classmethod
    def empty(cls) -> _Layer:
        e, i = np.zeros(0), np.zeros(0, np.int64)
        return cls(i, i, e, e, i, e, e)

    def blocks(self):
        """(uav, start, stop) of the contiguous row block of every UAV present."""
        if self.n == 0:
            return []
        cut = np.flatnonzero(np.diff(self.uav)) + 1
        starts = np.concatenate([[0], cut])
        stops = np.concatenate([cut, [self.n]])
        return list(zip(self.uav[starts].tolist(), starts.tolist(), stops.tolist(), strict=True))


@dataclass
class _Counters:
    exact: int = 0
    bounded: int = 0


@dataclass
class _PathContext:
    """Target samples between slots, for ``check_path``: per stage (P, 3) positions and (P,) headings."""

    target: np.ndarray
    phi: np.ndarray


@dataclass
class _Problem:
    """One batched DP run: shared stages, per-UAV start poses and per-stage penalties."""

    start: np.ndarray        # (U, 2)
    theta: np.ndarray        # (U,)
    a0: np.ndarray           # (U,) alpha at the start (eq. 12)
    d0: np.ndarray           # (U,) d at the start (eq. 13)
    stages: list             # N _Stage
    pens: list               # N arrays (U, L) or (1, L) when shared: 0 allowed, inf removed, > 0 penalised
    ctx: _PathContext | None
    avoid: np.ndarray | None = None   # (U, M, N, P, 2) other UAVs' planned path samples (NaN: none)
    avoid_dist: float = 0.0           # required distance to them at every sample
    path_soft: bool = False           # check_path in fallback: blocked LoS along a path is a penalty, zone ignored


# ===================================================================================== planner
class DPPlanner:
    """Receding-horizon DP planner (paper §2.5, eqs. 17-21); see the module docstring.

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

    Example::

        planner = DPPlanner(Config(), scenario.terrain)
        plan = planner.plan(xy, theta, target_xyz, target_phi)   # target_* for slots k..k+N
        plan.nodes[0]                                            # the waypoint action now

    Several UAVs are planned together with :meth:`plan_batch` (same results, the exact manoeuvre solves
    of all UAVs batched into one call per round).
    """

    def __init__(self, config: Config, terrain: Terrain, *, shadow_aware: bool = True,
                 heading: str = "inherited", heading_bins: int = 16, check_path: bool = False,
                 path_samples: int = 21, prune: bool = True, cache_size: int | None = None):
        if heading not in HEADING_MODES:
            raise ValueError(f"DPPlanner: heading must be one of {HEADING_MODES}, got {heading!r}")
        if not (isinstance(heading_bins, (int, np.integer)) and heading_bins >= 1):
            raise ValueError(f"DPPlanner: heading_bins must be an integer >= 1, got {heading_bins!r}")
        if not (isinstance(path_samples, (int, np.integer)) and path_samples >= 2):
            raise ValueError(f"DPPlanner: path_samples must be an integer >= 2, got {path_samples!r}")
        self.config = config
        self.terrain = terrain
        self.shadow_aware = bool(shadow_aware)
        self.heading = heading
        self.heading_bins = int(heading_bins) if heading == "binned" else 1
        self.check_path = bool(check_path)
        self.path_samples = int(path_samples)
        self.prune = bool(prune)
        self.lattice = zone_lattice(config)
        self.table = manoeuvre_table(config.v_max, config.w_max, config.delta)
        # A replan at slot k+1 reuses N - 1 of the stages and N - 2 of the pairs of the one at slot k.
        self._cache_size = int(cache_size) if cache_size is not None else config.horizon + 2
        self._stages: OrderedDict = OrderedDict()
        self._pairs: OrderedDict = OrderedDict()
        self._shadows: OrderedDict = OrderedDict()

    @property
    def name(self) -> str:
        """A label such as ``dp-aware-inherited`` or ``dp-blind-binned16-path``."""
        h = "inherited" if self.heading == "inherited" else f"binned{self.heading_bins}"
        return f"dp-{'aware' if self.shadow_aware else 'blind'}-{h}{'-path' if self.check_path else ''}"

    # ------------------------------------------------------------------ caches
    def _stage(self, q, phi) -> _Stage:
        q = np.asarray(q, dtype=float).reshape(3)
        key = (q.tobytes(), float(phi))
        st = self._stages.get(key)
        if st is None:
            st = _Stage(key, q.copy(), float(phi), self.lattice)
            self._stages[key] = st
            while len(self._stages) > self._cache_size:
                self._stages.popitem(last=False)
        else:
            self._stages.move_to_end(key)
        return st

    def _pair(self, a: _Stage, b: _Stage) -> _Pair:
        key = (a.key, b.key)
        p = self._pairs.get(key)
        if p is None:
            p = _Pair(a, b, self.config.lam, self.config.eta, self.table)
            self._pairs[key] = p
            while len(self._pairs) > self._cache_size:
                self._pairs.popitem(last=False)
        else:
            self._pairs.move_to_end(key)
        return p

    def visible_nodes(self, q, phi) -> np.ndarray:
        """(L,) bool: lattice nodes at target pose (q, phi) with a clear line of sight (cached)."""
        return self._stage(q, phi).visible(self.terrain, self.config.altitude).copy()

    def allowed_nodes(self, q, phi) -> np.ndarray:
        """(L,) bool: the nodes this planner may use at target pose (q, phi) (visible, or all if blind)."""
        if self.shadow_aware:
            return self.visible_nodes(q, phi)
        return np.ones(len(self.lattice), bool)

    # ------------------------------------------------------------------ public API
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
            A :class:`DPPlan`. Never raises for lack of a feasible plan (see the module docstring).
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
        theta0 = np.mod(np.asarray(start_theta, dtype=float).reshape(-1), TWO_PI)
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
        blk = np.zeros((u, n, L), bool) if blocked is None else np.asarray(blocked, bool).reshape(u, n, L)
        stages = [self._stage(tq[j], tphi[j]) for j in range(1, n + 1)]
        ctx = self._path_context(tq, tphi, target_path) if self.check_path else None
        cnt = _Counters()
        a0 = np.atleast_1d(uav_target_angle(start, tq[0, :2], tphi[0]))
        d0 = np.atleast_1d(uav_target_distance(start, tq[0, :2]))
        allowed = np.stack([self.allowed_nodes(tq[j], tphi[j]) for j in range(1, n + 1)])     # (N, L)
        base = [np.where(allowed[j], 0.0, np.inf)[None] for j in range(n)]
        any_blk = blk.any()
        pens = [np.where(blk[:, j], np.inf, base[j]) if any_blk else base[j] for j in range(n)]
        avoid = None if avoid is None else np.asarray(avoid, float).reshape(u, -1, n, np.shape(avoid)[-2], 2)
        prob = _Problem(start, theta0, a0, d0, stages, pens, ctx, avoid, float(avoid_dist))

        prefix = self._prefix(resume, u)
        layers = self._dp(prob, 1, None, None, cnt, prefix)
        depth = self._depths(layers, u)
        strict = layers
        if self.heading_bins > 1 and depth.any():
            ub = np.array([self._best(layers, i, depth[i]) if (depth[i] == n and self.prune) else np.inf
                           for i in range(u)])
            H = self._cost_to_go_bounds(stages, base) if np.isfinite(ub).any() else None
            binned = self._dp(prob, self.heading_bins, ub, H, cnt)
            bdepth = self._depths(binned, u)
        results: list = [None] * u
        for i in range(u):
            if depth[i] == 0:
                continue
            src, d = layers, depth[i]
            if self.heading_bins > 1 and (bdepth[i] > d or (bdepth[i] == d and
                                                            self._best(binned, i, d) < self._best(layers, i, d))):
                src, d = binned, bdepth[i]
            results[i] = (src, d, "ok" if d == n else "truncated")
        todo = [i for i in range(u) if results[i] is None]
        if todo and self.shadow_aware:
            # Level 2: every zone node, a penalty per node without LoS, earlier stages weigh more.
            idx = np.array(todo)
            soft = [np.where(blk[idx, j], np.inf,
                             np.where(allowed[j], 0.0, FALLBACK_PENALTY * 2.0 ** (n - 1 - j))[None])
                    for j in range(n)]
            sub = _Problem(start[idx], theta0[idx], a0[idx], d0[idx], stages, soft, ctx,
                           None if avoid is None else avoid[idx], float(avoid_dist), path_soft=True)
            fl = self._dp(sub, 1, None, None, cnt)
            fdepth = self._depths(fl, len(idx))
            for s, i in enumerate(todo):
                if fdepth[s]:
                    results[i] = (fl, fdepth[s], "fallback", s)
        plans = []
        dt = (time.perf_counter() - t0) / u
        for i in range(u):
            r = results[i]
            if r is None:
                plans.append(self._nearest_move(start[i], theta0[i], stages, allowed, blk[i], dt, cnt))
            else:
                p = self._backtrack(r[0], r[3] if len(r) > 3 else i, r[1], stages, r[2], start[i], theta0[i], dt,
                                    cnt)
                plans.append(replace(p, layers=self._split(strict, i)))
        return plans

    @staticmethod
    def _split(layers: list[_Layer], i: int) -> list[_Layer]:
        """UAV i's rows of batched layers, re-indexed as a batch of one (parents remapped)."""
        out, prev = [], None
        for lay in layers:
            idx = np.flatnonzero(lay.uav == i)
            if idx.size == 0:
                break
            sub = lay.take(idx)
            sub.uav = np.zeros(idx.size, np.int64)
            if prev is not None:
                sub.parent = np.searchsorted(prev, sub.parent)
            out.append(sub)
            prev = idx
        return out

    @staticmethod
    def _prefix(resume, u: int) -> list[_Layer] | None:
        """The first t0 layers of the previous plans, batched; None when they cannot be reused."""
        if resume is None:
            return None
        plans, t0 = resume
        if t0 < 1 or len(plans) != u or any(p.layers is None or len(p.layers) < t0 for p in plans):
            return None
        out = []
        for j in range(t0):
            parts, offs = [], 0
            prev_sizes = [p.layers[j - 1].n for p in plans] if j else None
            for i, p in enumerate(plans):
                lay = p.layers[j]
                par = lay.parent if j == 0 else lay.parent + offs
                parts.append(_Layer(np.full(lay.n, i), lay.node, lay.theta, lay.J, par, lay.v, lay.g))
                if j:
                    offs += prev_sizes[i]
            out.append(_Layer(*(np.concatenate(x) for x in zip(*(
                (q.uav, q.node, q.theta, q.J, q.parent, q.v, q.g) for q in parts), strict=True))))
        return out

    # ------------------------------------------------------------------ DP core
    @staticmethod
    def _depths(layers: list[_Layer], u: int) -> np.ndarray:
        """Stages reached by each UAV of the batch (states at stage j exist only if they did at j - 1)."""
        depth = np.zeros(u, np.int64)
        for j, lay in enumerate(layers):
            depth[np.unique(lay.uav)] = j + 1
        return depth

    @staticmethod
    def _best(layers: list[_Layer], i: int, depth: int) -> float:
        lay = layers[depth - 1]
        return float(lay.J[lay.uav == i].min())

    def _dp(self, prob: _Problem, bins: int, ub, H, cnt, prefix=None) -> list[_Layer]:
        """Forward recursion (eqs. 19-20) over the stages for the whole batch; returns the non-empty layers.

        ``prefix``: already computed first layers (incremental replanning); the recursion continues after them.
        """
        n = len(prob.stages)
        if prefix:
            layers, j0 = list(prefix[:-1]), len(prefix) - 1
            layer = prefix[-1]
        else:
            layers, j0 = [], 0
            layer = self._first_layer(prob, cnt)
            if H is not None and layer.n:
                layer = layer.take(layer.J + H[0][layer.node] <= ub[layer.uav] + _BOUND_TOL)
        for j in range(j0, n):
            if layer.n == 0:
                break
            layers.append(layer)
            if j + 1 < n:
                layer = self._advance(prob, layer, j + 1, bins, ub, None if H is None else H[j + 1], cnt)
        return layers

    def _cost_to_go_bounds(self, stages, pens) -> list[np.ndarray]:
        """H[j](a) <= cost of any completion from node a at stage j (heading-free: c >= chord + disguise)."""
        n = len(stages)
        H = [np.zeros(len(self.lattice), np.float32)]
        for j in range(n - 2, -1, -1):
            pair = self._pair(stages[j], stages[j + 1])
            nxt = (pens[j + 1].min(axis=0) + H[0]).astype(np.float32)
            H.insert(0, (pair.c0 + nxt[None, :]).min(axis=1))
        return H

    def _first_layer(self, prob: _Problem, cnt) -> _Layer:
        """Eq. 19: each UAV's single start state s to every allowed node of stage 1, all solved exactly."""
        pen = np.broadcast_to(prob.pens[0], (len(prob.start), len(self.lattice)))
        uu, cols = np.nonzero(np.isfinite(pen))
        if cols.size == 0:
            return _Layer.empty()
        c = self.config
        st = prob.stages[0]
        m = solve_manoeuvre(prob.start[uu], prob.theta[uu], st.xy[cols], v_max=c.v_max, w_max=c.w_max,
                            delta=c.delta)
        cnt.exact += cols.size
        ok = np.asarray(m.feasible, bool).copy()
        extra = self._path_terms(m, ok, prob, 0)
        if prob.avoid is not None and ok.any():
            ok[ok] = self._separated(m, ok, prob, uu, 0)
        g = np.where(ok, np.nan_to_num(m.length)
                     + self._negkap(prob.a0[uu], prob.d0[uu], st.alpha[cols], st.d[cols]), np.inf)
        J = g + pen[uu, cols] + extra
        k = np.isfinite(J)
        return _Layer(uu[k], cols[k], np.asarray(m.heading_after)[k], J[k], np.full(int(k.sum()), -1),
                      np.asarray(m.v)[k], g[k])

    def _negkap(self, a_from, d_from, a_to, d_to):
        c = self.config
        return -c.lam * (c.eta * np.abs(wrap_angle(a_to - a_from)) + np.abs(d_to - d_from))

    def _advance(self, prob: _Problem, layer: _Layer, j: int, bins: int, ub, H_b, cnt) -> _Layer:
        """Eq. 20 from ``layer`` (stage j-1, 0-based) to stage j, exact on the transitions that matter."""
        sa, sb = prob.stages[j - 1], prob.stages[j]
        pair = self._pair(sa, sb)
        tab = self.table
        pen = prob.pens[j].astype(np.float32)
        ev = _Evaluated(self, prob, layer, j, cnt)
        # Dense bound LB(s, b) = J(s) + disguise(a, b) + table bound on the path length + pen(b), float32.
        if bins == 1:
            # One state per node: lay every UAV's states out on the full node grid (absent rows have J = inf),
            # so the cached (L, L) pair arrays broadcast instead of being gathered row by row.
            blocks = layer.blocks()
            L = len(self.lattice)
            Jf = np.full((len(blocks), L), np.inf, np.float32)
            thf = np.zeros((len(blocks), L), np.float32)     # headings in table cells
            rowmap = np.full((len(blocks), L), -1, np.int64)
            for b, (_, s, e) in enumerate(blocks):
                nd = layer.node[s:e]
                Jf[b, nd] = layer.J[s:e]
                thf[b, nd] = layer.theta[s:e] * tab.psi_scale
                rowmap[b, nd] = np.arange(s, e)
            cell = (pair.base[None] - thf[:, :, None]).astype(np.int32)
            lb = tab.lb[cell]
            del cell
            uav = np.array([u for u, _, _ in blocks])
            if len(pen) > 1:
                lb += pair.negkap[None]
                lb += pen[uav][:, None, :]
            else:
                lb += pair.negkap_pen(pen[0])[None]
            lb += Jf[:, :, None]
            cnt.bounded += int(np.isfinite(Jf).sum()) * L
            if H_b is not None:
                thr = (ub[uav] + _BOUND_TOL).astype(np.float32)
                lb[lb + H_b[None, None, :] > thr[:, None, None]] = np.inf
            self._select_columns(lb, rowmap, ev, _OPEN_ROUNDS_CONSTRAINED if prob.avoid is not None else None)
            return ev.winners(1, L)
        # (node, bin) states: many rows, so the dense bound is built in row chunks and kept sparse.
        L = len(self.lattice)
        th = (layer.theta * tab.psi_scale).astype(np.float32)
        J32 = layer.J.astype(np.float32)
        nkp = None if len(pen) > 1 else pair.negkap_pen(pen[0])
        thr = None if H_b is None else (ub[layer.uav] + _BOUND_TOL).astype(np.float32)
        step = max(1, _CHUNK // L)
        parts = []
        for s0 in range(0, layer.n, step):
            sl = slice(s0, s0 + step)
            rows = layer.node[sl]
            cell = pair.base[rows]
            cell -= th[sl, None]
            cell = cell.astype(np.int32)
            lb = tab.lb[cell]
            if nkp is None:
                lb += pair.negkap[rows]
                lb += pen[layer.uav[sl]]
            else:
                lb += nkp[rows]
            lb += J32[sl, None]
            if thr is not None:
                # Transitions whose every completion costs more than the known plan cannot matter.
                lb[lb + H_b[None, :] > thr[sl, None]] = np.inf
            r, c = np.nonzero(np.isfinite(lb))
            parts.append((r + s0, c, lb[r, c], cell[r, c]))
        cnt.bounded += layer.n * L
        r, c, lbv, cl = (np.concatenate(x) for x in zip(*parts, strict=True))
        self._select_binned(r, c, lbv, cl, layer, bins, ev, prob.avoid is not None)
        return ev.winners(bins, L)

    @staticmethod
    def _select_columns(lb, rowmap, ev, max_open_rounds) -> None:
        """One state per node (B = 1): best-first by bound until every node's winner is proven.

        ``lb`` is (blocks, L, L): per UAV, bound of every (node a -> node b). Round 0 solves, per column b,
        every transition within ``_FIRST_BAND`` of the column's smallest bound: the table's bounds are
        that tight, so this usually contains the winner and proves it (no unsolved bound is below it). A
        column whose value is above the band then solves every transition still bounded below its value
        (and is final); a column with no feasible transition yet ("open") solves the next 1, 2, 4, ...
        smallest bounds per round. Every round is one exact solve for all UAVs. With ``max_open_rounds``
        (used under negotiation constraints, where many transitions are removed) open columns are given
        up after that many rounds: the plan stays valid, the node is just not offered.
        """
        nb, _, L = lb.shape
        best = np.full((nb, L), np.inf)
        colmin = lb.min(axis=1)
        reach = np.isfinite(colmin)
        thr = np.where(reach, colmin + _FIRST_BAND, -np.inf)
        bb, r, c = np.nonzero(lb <= thr[:, None, :])

        def run(bb, r, c):
            cost = ev.evaluate(rowmap[bb, r], c)
            lb[bb, r, c] = np.inf
            np.minimum.at(best, (bb, c), cost)

        run(bb, r, c)
        solved = np.isfinite(best)
        band = solved & (best > thr + _BOUND_TOL)
        open_ = reach & ~solved
        k, rounds = 1, 0
        while True:
            parts = []
            for b in range(nb):
                cols = np.flatnonzero(band[b])
                if cols.size:
                    lim = best[b, cols] + _BOUND_TOL + 1e-6 * np.abs(best[b, cols])
                    rr, cc = np.nonzero(lb[b][:, cols] < lim[None, :])
                    parts.append((np.full(rr.size, b), rr, cols[cc]))
                cols = np.flatnonzero(open_[b])
                if cols.size and (max_open_rounds is None or rounds < max_open_rounds):
                    sub = lb[b][:, cols]
                    if k == 1:
                        rr = np.argmin(sub, axis=0)[None]
                    elif sub.shape[0] <= k:
                        rr = np.broadcast_to(np.arange(sub.shape[0])[:, None], sub.shape)
                    else:
                        rr = np.argpartition(sub, k - 1, axis=0)[:k]
                    cc = np.broadcast_to(np.arange(cols.size), rr.shape)
                    fin = np.isfinite(sub[rr, cc])
                    parts.append((np.full(int(fin.sum()), b), rr[fin], cols[cc[fin]]))
            if not parts or sum(p[1].size for p in parts) == 0:
                return
            bb, r, c = (np.concatenate(x) for x in zip(*parts, strict=True))
            run(bb, r, c)
            now = np.isfinite(best)
            band = open_ & now                     # newly solved: one band pass, then final
            open_ = open_ & ~now
            for b in range(nb):                    # columns with no finite bound left are unreachable
                cols = np.flatnonzero(open_[b])
                if cols.size:
                    open_[b, cols] = np.isfinite(lb[b][:, cols].min(axis=0))
            k, rounds = min(2 * k, 64), rounds + 1

    def _select_binned(self, r, cc, lbv, cl, layer: _Layer, bins: int, ev, constrained: bool) -> None:
        """(node, bin) states: the table's heading-change interval names the bins a transition can land in.

        ``r, cc, lbv, cl``: the candidate transitions (layer row, node), their bounds and table cells.
        """
        tab = self.table
        if r.size == 0:
            return
        scale = bins / TWO_PI
        th = layer.theta[r]
        blo = np.floor((th + tab.dlo[cl]) * scale).astype(np.int64)
        span = np.minimum(np.floor((th + tab.dhi[cl]) * scale).astype(np.int64) - blo, bins - 1)
        blo %= bins
        node_key = (layer.uav[r] * len(self.lattice) + cc) * bins
        key0 = node_key + blo
        K = (int(layer.uav.max()) + 1) * len(self.lattice) * bins
        # Round 1: per estimated key, the transition with the smallest bound.
        first = np.full(K, np.inf, np.float32)
        np.minimum.at(first, key0, lbv)
        cand = np.flatnonzero(lbv == first[key0])
        _, u = np.unique(key0[cand], return_index=True)
        pick = cand[u]
        done = np.zeros(r.size, bool)
        done[pick] = True
        ev.evaluate(r[pick], cc[pick])
        best = ev.best(K, bins)
        # Round 2: a transition is needed unless its bound exceeds the best of every bin it can land in.
        bound = best[key0]
        for o in range(1, int(span.max(initial=0)) + 1):
            other = best[node_key + (blo + o) % bins]
            bound = np.where(span >= o, np.maximum(bound, other), bound)
        if constrained:
            # Under negotiation constraints a bin whose first pick was removed is given up (bounded search).
            bound = np.where(np.isfinite(bound), bound, -np.inf)
        rem = np.flatnonzero(~done & (lbv < bound + _BOUND_TOL + 1e-6 * np.abs(np.nan_to_num(bound, posinf=0.0,
                                                                                            neginf=0.0))))
        if rem.size:
            ev.evaluate(r[rem], cc[rem])

    # ------------------------------------------------------------------ path checks
    def _path_context(self, tq, tphi, target_path) -> _PathContext:
        n, p = len(tq) - 1, self.path_samples
        f = np.linspace(0.0, 1.0, p)
        if target_path is None:
            tp = tq[:-1, None, :] * (1 - f[:, None]) + tq[1:, None, :] * f[:, None]
        else:
            tp = np.asarray(target_path, float).reshape(n, p, 3)
        dphi = wrap_angle(tphi[1:] - tphi[:-1])
        ph = tphi[:-1, None] + dphi[:, None] * f[None, :]
        return _PathContext(tp, ph)

    def _path_terms(self, m: Manoeuvre, ok: np.ndarray, prob: _Problem, j: int):
        """``check_path`` for manoeuvres into stage j: clears ``ok`` where the path fails; returns extra costs.

        Strict (the DP proper): LoS and zone along the path are constraints. Soft (fallback level 2):
        only LoS counts, as a penalty equal to losing the visible zone at that stage.
        """
        if prob.ctx is None or not ok.any():
            return 0.0
        if not prob.path_soft:
            ok[ok] = self._path_ok(m, ok, prob.ctx, j)
            return 0.0
        extra = np.zeros(len(ok))
        n = len(prob.stages)
        extra[ok] = np.where(self._path_ok(m, ok, prob.ctx, j, zone=False), 0.0,
                             FALLBACK_PENALTY * 2.0 ** (n - 1 - j))
        return extra

    def _path_ok(self, m: Manoeuvre, ok: np.ndarray, ctx: _PathContext, j: int, zone: bool = True) -> np.ndarray:
        """For feasible manoeuvres into stage j (0-based): LoS (and zone, eq. 4) at the interior samples."""
        c = self.config
        p = self.path_samples
        if p <= 2:
            return np.ones(int(ok.sum()), bool)
        pts = m.points(p).reshape(-1, p, 2)[ok][:, 1:-1]
        tq = ctx.target[j, 1:-1]
        good = np.ones(len(pts), bool)
        if zone:
            good = in_feasible_zone(pts, tq[:, :2], ctx.phi[j, 1:-1], c.r1, c.r2, c.mu, 0.0).all(axis=1)
        for i in range(p - 2):
            idx = np.flatnonzero(good)
            if idx.size == 0:
                break
            if c.h_min is None:
                # Samples in the zone are within R2 of the target, where the shadows (eqs. 8-9, automatic
                # h_min) are exactly the blocked set; grown by 1 cm they are a conservative, fast test.
                shadow = self._shadow(tq[i])
                if shadow is not None:
                    good[idx] = ~shapely.intersects_xy(shadow, pts[idx, i, 0], pts[idx, i, 1])
            else:
                good[idx] = line_of_sight(self.terrain, pts[idx, i], c.altitude, tq[i], tol=VISIBILITY_TOL)
        return good

    def _shadow(self, q):
        """Prepared union of the shadows at target position q, grown by 1 cm (None: no shadow); cached."""
        key = np.asarray(q, float).tobytes()
        if key in self._shadows:
            return self._shadows[key]
        geom = shadow_union_cfg(self.terrain, q, self.config)
        geom = None if geom.is_empty else geom.buffer(SHADOW_MARGIN, quad_segs=2)
        if geom is not None:
            shapely.prepare(geom)
        self._shadows[key] = geom
        while len(self._shadows) > 8 * self._cache_size * self.path_samples:
            self._shadows.popitem(last=False)
        return geom

    @staticmethod
    def _separated(m: Manoeuvre, ok: np.ndarray, prob: _Problem, uav: np.ndarray, j: int) -> np.ndarray:
        """For feasible manoeuvres into stage j: at least ``avoid_dist`` from every avoided path, sample by sample."""
        out = np.ones(int(ok.sum()), bool)
        # Records exist only at the stages where conflicts were found: elsewhere there is nothing to check.
        has = ~np.isnan(prob.avoid[:, :, j, -1, 0])          # (U, M)
        rows = np.flatnonzero(has.any(axis=1)[uav[ok]])
        if rows.size == 0:
            return out
        m_max = int(has.sum(axis=1).max())
        obs = prob.avoid[uav[ok][rows], :m_max, j, 1:]       # (n, M, P - 1, 2): sample 0 is the slot's start
        p = obs.shape[-2] + 1
        a = m.start.reshape(-1, 2)[ok][rows][:, None, None, :]
        b = m.goal.reshape(-1, 2)[ok][rows][:, None, None, :]
        ell = np.asarray(m.length).reshape(-1)[ok][rows][:, None, None]
        f = np.linspace(0.0, 1.0, p)[1:]
        # At constant speed the sample at fraction f lies within ell f of the start and ell (1 - f) of the goal:
        # a sample whose obstacle is farther than avoid_dist from that lens is safe without flying it.
        gap = np.maximum(np.hypot(*(obs - a).transpose(3, 0, 1, 2)) - ell * f,
                         np.hypot(*(obs - b).transpose(3, 0, 1, 2)) - ell * (1 - f))
        near = (gap < prob.avoid_dist).any(axis=(1, 2))     # NaN (no obstacle) compares False
        if near.any():
            sel = np.flatnonzero(ok)[rows[near]]
            pts = m.points(p).reshape(-1, p, 2)[sel][:, 1:]
            d = np.hypot(*(pts[:, None] - obs[near]).transpose(3, 0, 1, 2))
            out[rows[near]] = ~(d < prob.avoid_dist).any(axis=(1, 2))
        return out

    # ------------------------------------------------------------------ results
    def _backtrack(self, layers, i, depth, stages, status, start, theta0, dt, cnt) -> DPPlan:
        """Follow the backpointers from UAV i's best state at its deepest stage (eq. 21's virtual final state)."""
        n = len(stages)
        nodes = np.full(n, -1, np.int64)
        head = np.full(n, np.nan)
        v = np.full(n, np.nan)
        g = np.full(n, np.nan)
        last = layers[depth - 1]
        mine = np.flatnonzero(last.uav == i)
        s = int(mine[np.argmin(last.J[mine])])
        for j in range(depth - 1, -1, -1):
            lay = layers[j]
            nodes[j], head[j], v[j], g[j] = lay.node[s], lay.theta[s], lay.v[s], lay.g[s]
            s = int(lay.parent[s])
        wp = np.full((n, 2), np.nan)
        for j in range(depth):
            wp[j] = stages[j].xy[nodes[j]]
        c = self.config
        return DPPlan(nodes, wp, head, v, g, float(np.sum(g[:depth])), int(depth), status, status == "fallback",
                      dt, cnt.exact, cnt.bounded, np.array(start), float(theta0), c.v_max, c.w_max, c.delta)

    def _nearest_move(self, start, theta0, stages, allowed, blk, dt, cnt) -> DPPlan:
        """Fallback level 3: no zone node reachable; head for the nearest one (a visible one on near-ties)."""
        n = len(stages)
        st = stages[0]
        free = ~blk[0] if (~blk[0]).any() else np.ones(len(self.lattice), bool)
        dist = np.hypot(*(st.xy - start).T)
        # Visible nodes win near-ties: keeping LoS matters more than one grid step of distance.
        score = np.where(free, dist - np.where(allowed[0], self.config.grid_step, 0.0), np.inf)
        node = int(np.argmin(score))
        nodes = np.full(n, -1, np.int64)
        nodes[0] = node
        wp = np.full((n, 2), np.nan)
        wp[0] = st.xy[node]
        nan = np.full(n, np.nan)
        c = self.config
        return DPPlan(nodes, wp, nan.copy(), nan.copy(), nan.copy(), float("nan"), 1, "fallback", True,
                      dt, cnt.exact, cnt.bounded, np.array(start), float(theta0), c.v_max, c.w_max, c.delta)


class _Evaluated:
    """Exactly solved transitions into one stage, and the per-state winners among them."""

    def __init__(self, planner: DPPlanner, prob: _Problem, layer: _Layer, j: int, cnt: _Counters):
        self.planner, self.prob, self.layer, self.j, self.cnt = planner, prob, layer, j, cnt
        self.parts: list[tuple] = []

    def evaluate(self, r, cc) -> np.ndarray:
        """Solve transitions (row r of the layer -> node cc) exactly, record them, return J + c + pen."""
        pl, lay, c = self.planner, self.layer, self.planner.config
        sa, sb = self.prob.stages[self.j - 1], self.prob.stages[self.j]
        a = lay.node[r]
        m = solve_manoeuvre(sa.xy[a], lay.theta[r], sb.xy[cc], v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        self.cnt.exact += r.size
        ok = np.asarray(m.feasible, bool).reshape(-1).copy()
        extra = pl._path_terms(m, ok, self.prob, self.j)
        if self.prob.avoid is not None and ok.any():
            ok[ok] = pl._separated(m, ok, self.prob, lay.uav[r], self.j)
        g = np.where(ok, np.nan_to_num(m.length) + pl._negkap(sa.alpha[a], sa.d[a], sb.alpha[cc], sb.d[cc]),
                     np.inf)
        pen = self.prob.pens[self.j]
        cost = lay.J[r] + g + pen[lay.uav[r] if len(pen) > 1 else 0, cc] + extra
        self.parts.append((r, cc, cost, np.asarray(m.heading_after).reshape(-1), np.asarray(m.v).reshape(-1), g))
        return cost

    def _cat(self):
        return [np.concatenate(x) for x in zip(*self.parts, strict=True)]

    def _key(self, r, cc, head, bins):
        node_key = self.layer.uav[r] * len(self.planner.lattice) + cc
        if bins == 1:
            return node_key
        return node_key * bins + (np.floor(np.mod(head, TWO_PI) * (bins / TWO_PI)).astype(np.int64) % bins)

    def best(self, K: int, bins: int) -> np.ndarray:
        """(K,) best exact cost per (uav, node, bin) key so far."""
        best = np.full(K, np.inf)
        if self.parts:
            r, cc, cost, head, _, _ = self._cat()
            ok = np.isfinite(cost)
            np.minimum.at(best, self._key(r[ok], cc[ok], head[ok], bins), cost[ok])
        return best

    def winners(self, bins: int, L: int) -> _Layer:
        if not self.parts:
            return _Layer.empty()
        r, cc, cost, head, v, g = self._cat()
        ok = np.isfinite(cost)
        if not ok.any():
            return _Layer.empty()
        r, cc, cost, head, v, g = r[ok], cc[ok], cost[ok], head[ok], v[ok], g[ok]
        key = self._key(r, cc, head, bins)
        # Sort by (key, cost): the first row of every key is its winner, and layers come out sorted by uav.
        order = np.lexsort((cost, key))
        first = np.concatenate([[True], key[order][1:] != key[order][:-1]])
        w = order[first]
        return _Layer(self.layer.uav[r[w]], cc[w], np.mod(head[w], TWO_PI), cost[w], r[w], v[w], g[w])


# ============================================================================== team planner
class DPTeamPlanner:
    """Decentralised team planning with negotiation (paper §2.5); see the module docstring.

    Args:
        planner: the per-UAV :class:`DPPlanner` (shared, so are its caches).
        max_rounds: negotiation rounds before giving up on future-slot conflicts (reported in the result);
            a conflict left in the slot that is flown is always removed by the safety layer
            (:meth:`_secure_first_moves`).
        separation_margin: metres added to d_safe1 in the conflict test.
        path_samples: instants per slot at which manoeuvres are compared (21 contains the engine's 11).
    """

    def __init__(self, planner: DPPlanner, *, max_rounds: int = 5, separation_margin: float = 0.5,
                 path_samples: int = 21):
        self.planner = planner
        self.config = planner.config
        self.max_rounds = int(max_rounds)
        self.margin = float(separation_margin)
        self.path_samples = int(path_samples)

    def plan(self, uav_xy, uav_theta, target_xyz, target_phi, *, target_path=None) -> TeamPlan:
        """Plan every UAV, then negotiate conflicts (lower index keeps its plan) until none remain.

        For every conflict (winner, loser, stage t) the loser records, for stage t, the winner's node and its
        sampled manoeuvre into it; it then replans with, at each recorded stage, the nodes within
        ``d_safe1 + separation_margin`` of a recorded node removed and the transitions whose samples come
        that close to a recorded manoeuvre (at the same instants) removed. Records only accumulate, so a
        replan may reuse its previous DP layers up to the first newly constrained stage.

        Args:
            uav_xy: (U, 2) positions; uav_theta: (U,) headings.
            target_xyz, target_phi, target_path: as in :meth:`DPPlanner.plan` (shared by the team).
        """
        t0 = time.perf_counter()
        xy = np.asarray(uav_xy, float).reshape(-1, 2)
        th = np.asarray(uav_theta, float).reshape(-1)
        u = len(xy)
        n = len(np.asarray(target_xyz).reshape(-1, 3)) - 1
        L = len(self.planner.lattice)
        lim = self.config.d_safe1 + self.margin
        kw = dict(target_path=target_path)
        plans = self.planner.plan_batch(xy, th, target_xyz, target_phi, **kw)
        n_exact, n_bounded = plans[0].n_exact, plans[0].n_bounded
        blocked = np.zeros((u, n, L), bool)
        records: list[list[list[np.ndarray]]] = [[[] for _ in range(n)] for _ in range(u)]
        rounds = replans = 0
        conflicts = self._conflicts(plans)
        stages = None
        while conflicts and rounds < self.max_rounds:
            rounds += 1
            if stages is None:
                tq = np.asarray(target_xyz, float).reshape(-1, 3)
                tp = np.asarray(target_phi, float).reshape(-1)
                stages = [self.planner._stage(tq[j], tp[j]) for j in range(1, n + 1)]
            first: dict[int, int] = {}
            for win, lose, t, _ in conflicts:
                pw = plans[win]
                blocked[lose, t] |= np.hypot(*(stages[t].xy - pw.waypoints[t]).T) < lim
                records[lose][t].append(pw.path_points(self.path_samples)[t])
                first[lose] = min(first.get(lose, n), t)
            losers = sorted(first)
            m = max(len(records[i][t]) for i in losers for t in range(n))
            avoid = np.full((len(losers), m, n, self.path_samples, 2), np.nan)
            for s_, i in enumerate(losers):
                for t in range(n):
                    for o, pts in enumerate(records[i][t]):
                        avoid[s_, o, t] = pts
            idx = np.array(losers)
            new = self.planner.plan_batch(xy[idx], th[idx], target_xyz, target_phi, blocked=blocked[idx], avoid=avoid,
                                          avoid_dist=lim, resume=([plans[i] for i in losers], min(first.values())),
                                          **kw)
            for i, p in zip(losers, new, strict=True):
                plans[i] = p
            replans += len(losers)
            n_exact += new[0].n_exact
            n_bounded += new[0].n_bounded
            conflicts = self._conflicts(plans)
        if any(t == 0 for _, _, t, _ in conflicts):
            plans = self._secure_first_moves(plans, xy, th, target_xyz, target_phi, target_path)
            conflicts = self._conflicts(plans)
        nodes = np.array([p.nodes[0] for p in plans])
        wps = np.array([p.waypoints[0] for p in plans])
        infeasible = np.array([p.infeasible for p in plans])
        return TeamPlan(plans, nodes, wps, infeasible, rounds, len(conflicts), replans, time.perf_counter() - t0,
                        n_exact, n_bounded)

    def plan_engine(self, engine) -> TeamPlan:
        """:meth:`plan` for the current state of a :class:`covert_env.engine.Engine` (its track's predictions)."""
        q_pred, phi_pred = engine.predict()
        tq = np.vstack([engine.target_xyz[None], q_pred])
        tp = np.concatenate([[engine.target_phi], phi_pred])
        path = None
        if self.planner.check_path:
            f = np.linspace(0.0, 1.0, self.planner.path_samples)
            path = engine.track.predict_between(engine.k, len(phi_pred), f)   # the prediction, not the truth
        return self.plan(engine.uav_xy, engine.uav_theta, tq, tp, target_path=path)

    def _secure_first_moves(self, plans, xy, th, target_xyz, target_phi, target_path=None) -> list:
        """Safety layer for the slot that is flown, after the negotiation left a conflict in it.

        In priority order, a UAV keeps its plan if its first manoeuvre keeps ``d_safe1 + separation_margin``
        from those of the UAVs already settled, at every sample; otherwise it takes, among all lattice nodes
        of the next slot (solved exactly from its pose), the separated move to an allowed (visible) node with
        the lowest stage cost (eq. 18), else to any node (flagged infeasible). If it has no separated move
        at all, its move and that of one settled UAV are re-chosen together (every pair of their candidates;
        a fast teammate sweeping past can leave no single move). With ``check_path``, "allowed" also means
        LoS kept along the manoeuvre. Failing that, the other priority orders are
        tried (lexicographic), and if none works the priority order's result is kept with the most
        separated move (flagged). ``status="safety"``.
        """
        pl, c = self.planner, self.config
        tq = np.asarray(target_xyz, float).reshape(-1, 3)
        tp = np.asarray(target_phi, float).reshape(-1)
        st = pl._stage(tq[1], tp[1])
        allowed_nodes = pl.allowed_nodes(tq[1], tp[1])
        ctx = pl._path_context(tq, tp, target_path) if pl.check_path else None
        lim = c.d_safe1 + self.margin
        p = self.path_samples
        u = len(plans)
        own = [q.path_points(p)[0][1:] for q in plans]           # sample 0 (the current position) is fixed
        cands: dict = {}

        def candidates(i):
            if i not in cands:
                m = solve_manoeuvre(xy[i], th[i], st.xy, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
                ok = np.asarray(m.feasible, bool)
                a0 = uav_target_angle(xy[i], tq[0, :2], tp[0])
                d0 = uav_target_distance(xy[i], tq[0, :2])
                g = np.where(ok, np.nan_to_num(m.length) + pl._negkap(a0, d0, st.alpha, st.d), np.inf)
                good = allowed_nodes.copy()
                if ctx is not None and ok.any():
                    clear = np.zeros(len(ok), bool)
                    clear[ok] = pl._path_ok(m, ok, ctx, 0, zone=False)
                    good &= clear
                cands[i] = (m, ok, m.points(p)[:, 1:], g, good)
            return cands[i]

        def clear_of(pts, others):
            """(n,) smallest distance from candidate paths (n, P-1, 2) to the given settled paths."""
            d = np.full(len(pts), np.inf)
            for f in others:
                d = np.minimum(d, np.hypot(*(pts - f[None]).transpose(2, 0, 1)).min(axis=1))
            return d

        def pick(i, fixed):
            m, ok, pts, g, allowed = candidates(i)
            d = np.where(ok, clear_of(pts, fixed.values()), -np.inf)
            safe = d >= lim
            if (safe & allowed).any():
                return int(np.argmin(np.where(safe & allowed, g, np.inf))), False
            if safe.any():
                return int(np.argmin(np.where(safe, g, np.inf))), True
            return None

        def repair(i, h, fixed):
            """Re-choose the moves of i and of the settled h together (all pairs of their candidates)."""
            rest = [f for k, f in fixed.items() if k != h]
            (_, ok_i, p_i, g_i, al_i), (_, ok_h, p_h, g_h, al_h) = candidates(i), candidates(h)
            ci = np.flatnonzero(ok_i & (clear_of(p_i, rest) >= lim))
            ch = np.flatnonzero(ok_h & (clear_of(p_h, rest) >= lim))
            if ci.size == 0 or ch.size == 0:
                return None
            d = np.hypot(*(p_h[ch][:, None] - p_i[ci][None]).transpose(3, 0, 1, 2)).min(axis=2)
            # Prefer both visible, then the lowest total stage cost.
            score = g_h[ch][:, None] + g_i[ci][None] + FALLBACK_PENALTY * (
                (~al_h[ch])[:, None].astype(float) + (~al_i[ci])[None].astype(float))
            score = np.where(d >= lim, score, np.inf)
            if not np.isfinite(score).any():
                return None
            a_, b_ = np.unravel_index(int(np.argmin(score)), score.shape)
            return (int(ch[a_]), not al_h[ch[a_]]), (int(ci[b_]), not al_i[ci[b_]])

        def settle(order):
            fixed, moves, clean = {}, {}, True
            for i in order:
                if all(np.hypot(*(own[i] - f).T).min() >= lim for f in fixed.values()):
                    moves[i] = None                               # keeps its plan
                    fixed[i] = own[i]
                    continue
                mv = pick(i, fixed)
                if mv is None:
                    for h in reversed(list(fixed)):
                        both = repair(i, h, fixed)
                        if both is not None:
                            moves[h], mv = both
                            fixed[h] = candidates(h)[2][moves[h][0]]
                            break
                if mv is None:
                    m, ok, pts, g, _ = candidates(i)
                    if not ok.any():
                        moves[i] = None                           # nothing flyable: keep the (fallback) plan
                        fixed[i] = own[i]
                        clean = False
                        continue
                    d = np.where(ok, clear_of(pts, fixed.values()), -np.inf)
                    mv, clean = (int(np.argmax(d)), True), False
                moves[i] = mv
                fixed[i] = candidates(i)[2][mv[0]]
            return moves, clean

        first = None
        for order in itertools.permutations(range(u)):
            moves, clean = settle(order)
            first = first if first is not None else moves
            if clean:
                break
        else:
            moves = first
        out = list(plans)
        for i, mv in moves.items():
            if mv is None:
                continue
            node, flag = mv
            m, _, _, g, _ = candidates(i)
            n = len(out[i].nodes)
            nodes = np.full(n, -1, np.int64)
            nodes[0] = node
            wp = np.full((n, 2), np.nan)
            wp[0] = st.xy[node]
            head, v, cost = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
            head[0], v[0], cost[0] = m.heading_after[node], m.v[node], g[node]
            out[i] = replace(out[i], nodes=nodes, waypoints=wp, headings=head, speeds=v, stage_costs=cost,
                             cost=float(g[node]), depth=1, status="safety", infeasible=flag, layers=None)
        return out

    def _conflicts(self, plans) -> list[tuple[int, int, int, str]]:
        """(winner, loser, stage, "node" | "path") for every pair of UAVs too close at some stage."""
        u = len(plans)
        if u < 2:
            return []
        lim = self.config.d_safe1 + self.margin
        pts = [p.path_points(self.path_samples) for p in plans]
        out = []
        for i in range(u):
            for k in range(i + 1, u):
                d = min(plans[i].depth, plans[k].depth)
                if d == 0:
                    continue
                node = np.hypot(*(plans[i].waypoints[:d] - plans[k].waypoints[:d]).T)
                # Sample 0 of a slot is the previous slot's last one, or the current positions: nothing to plan.
                path = np.hypot(*(pts[i][:d, 1:] - pts[k][:d, 1:]).transpose(2, 0, 1)).min(axis=1)
                for t in range(d):
                    if node[t] < lim:
                        out.append((i, k, t, "node"))
                    elif path[t] < lim:
                        out.append((i, k, t, "path"))
        return out


# ============================================================================ exact references
def evaluate_plan(config: Config, start_xy, start_theta: float, target_xyz, target_phi, waypoints) -> float:
    """Exact cost (eq. 17) of flying ``waypoints`` (M, 2) for slots k+1..k+M, heading propagated continuously.

    inf if some manoeuvre is infeasible. The reference the DP is tested against.
    """
    c = config
    wp = np.asarray(waypoints, float).reshape(-1, 2)
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    tp = np.asarray(target_phi, float).reshape(-1)
    p, th = np.asarray(start_xy, float).reshape(2), float(start_theta)
    a = uav_target_angle(p, tq[0, :2], tp[0])
    d = uav_target_distance(p, tq[0, :2])
    total = 0.0
    for j, g in enumerate(wp, start=1):
        m = solve_manoeuvre(p, th, g, v_max=c.v_max, w_max=c.w_max, delta=c.delta)
        if not bool(m.feasible):
            return float("inf")
        a1 = uav_target_angle(g, tq[j, :2], tp[j])
        d1 = uav_target_distance(g, tq[j, :2])
        total += float(m.length) - c.lam * (c.eta * abs(wrap_angle(a1 - a)) + abs(d1 - d))
        p, th, a, d = g, float(m.heading_after), a1, d1
    return total


def brute_force_plan(config: Config, start_xy, start_theta: float, target_xyz, target_phi, allowed):
    """The true optimum J* over every node sequence (continuous heading propagated), by enumeration.

    Args:
        allowed: (N, L) bool, the nodes allowed per stage (e.g. ``DPPlanner.allowed_nodes``).

    Returns:
        ``(J*, nodes)``: the optimal cost and (N,) lattice indices; ``(inf, None)`` if nothing is feasible.
        Vectorised over sequences, so only for small lattices (prod of allowed counts up to ~1e5).
    """
    c = config
    lat = zone_lattice(c)
    tq = np.asarray(target_xyz, float).reshape(-1, 3)
    tp = np.asarray(target_phi, float).reshape(-1)
    n = len(tq) - 1
    ok = np.asarray(allowed, bool).reshape(n, len(lat))
    seq = np.zeros((1, 0), np.int64)
    pos = np.asarray(start_xy, float).reshape(1, 2)
    th = np.array([float(start_theta)])
    a = np.atleast_1d(uav_target_angle(pos, tq[0, :2], tp[0]))
    d = np.atleast_1d(uav_target_distance(pos, tq[0, :2]))
    J = np.zeros(1)
    for j in range(1, n + 1):
        cols = np.flatnonzero(ok[j - 1])
        xy = to_world(lat[cols], tq[j, :2], tp[j])
        m = solve_manoeuvre(pos[:, None, :], th[:, None], xy[None, :, :], v_max=c.v_max, w_max=c.w_max,
                            delta=c.delta)
        a1 = uav_target_angle(xy, tq[j, :2], tp[j])
        d1 = uav_target_distance(xy, tq[j, :2])
        g = m.length - c.lam * (c.eta * np.abs(wrap_angle(a1[None] - a[:, None])) + np.abs(d1[None] - d[:, None]))
        feas = np.asarray(m.feasible, bool)
        r, cc = np.nonzero(feas)
        if r.size == 0:
            return float("inf"), None
        seq = np.column_stack([seq[r], cols[cc]])
        J = J[r] + g[r, cc]
        pos, th, a, d = xy[cc], np.asarray(m.heading_after)[r, cc], a1[cc], d1[cc]
    best = int(np.argmin(J))
    return float(J[best]), seq[best]

