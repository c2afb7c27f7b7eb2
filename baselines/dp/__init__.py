"""The paper's receding-horizon dynamic-programming planner (Almuzaini & Savkin 2024, §2.5, eqs. 17-21).

## What it solves

At slot k every UAV i plans the next N slots (N = ``config.horizon``). Its states at stage j = 1..N
are grid nodes of the zone around the predicted target pose q[k+j], phi[k+j]: the offsets of
:func:`covert_env.geometry.zone.zone_lattice` (spacing ``grid_step``, the eroded zone of eq. 5) placed with
:func:`covert_env.geometry.zone.to_world`. The *same* lattice is the action set of the waypoint environments, so
a node index is an action. The allowed nodes are

* ``shadow_aware=True`` (the paper's method): nodes of the visible zone F[k+j] (eq. 10), i.e. eroded zone
  and a clear line of sight (eq. 6) to q[k+j] -- under a prediction error (``Config.prediction_error > 0``)
  to every true target position within ``los_margin`` (default r_u) of it along the road
  (:mod:`baselines.dp.possible_targets`, docs/decisions/model.md#prediction-los);
* ``shadow_aware=False`` (the earlier method [1], the paper's comparison): every node of the eroded zone;

and, for both, only nodes at least ``d_safe2`` from every polytope's highest point (eq. 3,
:mod:`baselines.dp.clearance`). Eq. 3 also removes every manoeuvre that comes closer than ``d_safe2`` to a
top at one of its ``path_samples`` instants, at every fallback level and in the team's safety layer. Only
tops higher than h - d_safe2 can matter; the random generator caps heights there, so on generated scenes
the check removes nothing.

The cost of moving from node a at stage j to node b at stage j+1 is the stage cost of eq. 18,

    c_ab = g = v delta - lambda eta |wrap(alpha_b - alpha_a)| - lambda |d_b - d_a|,

with alpha, d (eqs. 12-13) measured against the target's pose at each stage and v the speed of the
turn-then-straight manoeuvre (eqs. 22-29, :func:`covert_env.geometry.dynamics.solve_manoeuvre`) that flies from
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
   (tested against it at the 2 m grid), solving a small share of the transitions exactly
   (docs/decisions/planner.md gives it).
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
in the zone of eq. 4 around the target at that instant and see it (eq. 6, the env's line-of-sight kernel, at
``SAFE_LOS_TOLERANCE``: the polytopes grown by 1 um): a line-of-sight guarantee between slot times.

``path_cost`` (per stage, m of stage cost) instead makes LoS along the manoeuvre a cost: a transition into stage
j pays ``path_cost[j-1]`` times the share of its samples without LoS to the predicted target at the same instant.
The extra cost is non-negative, so the table's bounds stay lower bounds and the recursion stays exact (tested
against the dense DP). :mod:`training.dp_cost` learns the numbers
(docs/decisions/planner.md#a-learned-cost-in-the-planners-search).

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
   admissible constant control ending closest to it, see :class:`covert_env.world.engine.Engine`); that flight
   does not end on the node, so eq. 3 is checked along it (the nearest node whose best effort keeps clear).
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
distance to every higher-priority UAV's first move (``status="safety"``), all checked on the paths the engine
will fly (a fallback's best effort included); when the priority order leaves some UAV no such move (a fast
teammate sweeping past), that UAV is promoted to the front and the layer runs again (each UAV at most once,
at most U orders: :func:`covert_env.geometry.separation.priority_negotiation`). The work is polynomial in U
(``TeamPlan.work``, docs/model.md#team-negotiation).

## Caching

Per scene and slot (keyed by the target pose), the world positions, alpha, d and visibility of the
lattice nodes are cached; per pair of consecutive slots, the disguise term and the table indices of
every node pair. None of this depends on the UAV, so a team and successive replans share it.

## Modules

* :mod:`~baselines.dp.planner` -- :class:`DPPlanner`: one UAV (or a batch of independent UAVs), fallbacks.
* :mod:`~baselines.dp.team` -- :class:`DPTeamPlanner`: the negotiation; :mod:`~baselines.dp.safety`: the
  safety layer for the slot that is flown; :mod:`~baselines.dp.continuation`: the optional one-slot look-ahead
  past plans of depth 1.
* :mod:`~baselines.dp.recursion` -- the forward recursion (eqs. 19-21) and backtracking;
  :mod:`~baselines.dp.selection` -- which transitions are solved exactly; :mod:`~baselines.dp.transitions`
  -- exact transition costs (eq. 18); :mod:`~baselines.dp.states` -- DP layers.
* :mod:`~baselines.dp.lattice` -- lattice stages and node pairs (cached); :mod:`~baselines.dp.possible_targets`
  -- line of sight to every position a prediction error allows; :mod:`~baselines.dp.table` -- bounds on
  the manoeuvre's length and heading change; :mod:`~baselines.dp.path_checks` -- checks along a manoeuvre;
  :mod:`~baselines.dp.fallback` -- fallback levels 2 and 3.
* :mod:`~baselines.dp.plan` -- the results :class:`DPPlan`, :class:`TeamPlan`;
  :mod:`~baselines.dp.reference` -- exact references (:func:`evaluate_plan`, :func:`brute_force_plan`).
"""

from baselines.dp.plan import DPPlan, TeamPlan
from baselines.dp.planner import HEADING_MODES, DPPlanner
from baselines.dp.reference import brute_force_plan, evaluate_plan
from baselines.dp.table import ManoeuvreBoundsTable, manoeuvre_bounds_table
from baselines.dp.team import DPTeamPlanner

__all__ = [
    "DPPlan",
    "DPPlanner",
    "DPTeamPlanner",
    "HEADING_MODES",
    "ManoeuvreBoundsTable",
    "TeamPlan",
    "brute_force_plan",
    "evaluate_plan",
    "manoeuvre_bounds_table",
]
