"""The planner's states: the zone lattice placed at each predicted target pose, and node-pair quantities.

A :class:`Stage` is the lattice of :func:`covert_env.geometry.zone.zone_lattice` (the waypoint actions) placed at
one predicted target pose q[k+j], phi[k+j]: world positions, alpha and d (eqs. 12-13) and line of sight
(eq. 6; under a prediction error, to every true position it allows: :mod:`baselines.dp.possible_targets`).
A :class:`StagePair` holds what the transitions between two consecutive stages share whatever the UAV:
the disguise part of the stage cost (eq. 18) and the manoeuvre-table index of every node pair.
Neither depends on the UAV, so a team and its successive replans share them through a :class:`StageCache`.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from baselines.dp.possible_targets import PossibleTargets
from baselines.dp.table import ManoeuvreBoundsTable
from covert_env.geometry.angles import abs_wrapped
from covert_env.geometry.cost import uav_target_angle, uav_target_distance
from covert_env.geometry.zone import to_world
from covert_env.world.terrain import Terrain
from covert_env.world.visibility import SAFE_LOS_TOLERANCE, visible_nodes

__all__ = ["Stage", "StageCache", "StagePair"]


class Stage:
    """Lattice nodes at one predicted target pose: world xy, alpha, d (eqs. 12-13) and visibility."""

    __slots__ = ("key", "q", "phi", "xy", "alpha", "d", "_lattice", "_visible")

    def __init__(self, key, q: np.ndarray, phi: float, lattice: np.ndarray):
        self.key = key
        self.q = q
        self.phi = phi
        self.xy = to_world(lattice, q[:2], phi)
        self.alpha = uav_target_angle(self.xy, q[:2], phi)
        self.d = uav_target_distance(self.xy, q[:2])
        self._lattice = lattice
        self._visible = None

    def visible(self, terrain: Terrain, altitude: float, targets: PossibleTargets | None = None) -> np.ndarray:
        """(L,) the visible nodes at this slot (eq. 10, :func:`~covert_env.world.visibility.visible_nodes`, as the
        waypoint action mask); every lattice node is in the eroded zone by construction.

        ``targets``: None checks the predicted target q only (eq. 10 as the paper states it); otherwise every
        possible true position around q (:class:`PossibleTargets`). A stage belongs to one planner's cache, so
        it is always asked with the same ``targets``.
        """
        if self._visible is None:
            if targets is None:
                self._visible = visible_nodes(terrain, self._lattice, self.q, self.phi, altitude)
            else:
                self._visible = targets.visible(terrain, self.xy, altitude, self.q, SAFE_LOS_TOLERANCE)
            self._visible.setflags(write=False)
        return self._visible


class StagePair:
    """Quantities of every node pair between two consecutive stages that do not depend on the UAV.

    disguise: float32 (L, L) [source a, target b], ``-lambda (eta |d alpha| + |d d|)``, the disguise part of
        eq. 18 (:func:`covert_env.geometry.cost.disguise` in float32: it feeds bounds only, exact costs come from
        :func:`covert_env.geometry.cost.stage_cost`).
    table_base: float32 (L, L) [a, b], :meth:`ManoeuvreBoundsTable.base_index` of b - a.
    heading_free_bound: float32 (L, L) [a, b], ``disguise + chord`` (inf beyond V_max delta), a lower bound
        on c_ab whatever the heading.

    The recursion scans transitions per target node, so the arrays are built target-major (:meth:`by_target`);
    the source-major views above are their transposes, made on first use (binned headings, cost-to-go).
    """

    __slots__ = ("_base_t", "_disguise_t", "_chord_t", "_reach", "_with_penalty", "_heading_free_bound",
                 "_table_base", "_disguise")

    def __init__(self, a: Stage, b: Stage, lam: float, eta: float, table: ManoeuvreBoundsTable):
        # Everything here feeds bounds only (exact costs are recomputed in float64 from the nodes' alpha
        # and d), so float32 throughout: half the memory traffic of the S x S arrays. Element by element the
        # same arithmetic as source-major arrays, laid out [target b, source a].
        f = np.float32
        dx = b.xy[:, None, 0].astype(f) - a.xy[None, :, 0].astype(f)
        dy = b.xy[:, None, 1].astype(f) - a.xy[None, :, 1].astype(f)
        chord = np.hypot(dx, dy)
        # alpha lies in (-pi, pi], so the difference is one abs_wrapped takes.
        dal = b.alpha.astype(f)[:, None] - a.alpha.astype(f)[None, :]
        abs_wrapped(dal, out=dal)
        dal *= f(eta)
        dal += np.abs(b.d.astype(f)[:, None] - a.d.astype(f)[None, :])
        dal *= f(-lam)
        self._disguise_t = dal
        self._base_t = table.base_index(None, chord, np.arctan2(dy, dx))
        self._chord_t, self._reach = chord, table.reach
        self._heading_free_bound = self._table_base = self._disguise = None
        self._with_penalty: dict = {}

    def by_target(self) -> tuple[np.ndarray, np.ndarray]:
        """``(table_base, disguise)`` laid out [target b, source a], C-contiguous: a target's transitions are
        one contiguous row."""
        return self._base_t, self._disguise_t

    @property
    def table_base(self) -> np.ndarray:
        if self._table_base is None:
            self._table_base = np.ascontiguousarray(self._base_t.T)
        return self._table_base

    @property
    def disguise(self) -> np.ndarray:
        if self._disguise is None:
            self._disguise = np.ascontiguousarray(self._disguise_t.T)
        return self._disguise

    @property
    def heading_free_bound(self) -> np.ndarray:
        if self._heading_free_bound is None:
            bound = np.where(self._chord_t <= self._reach, self._disguise_t + self._chord_t, np.inf)
            self._heading_free_bound = np.ascontiguousarray(bound.astype(np.float32).T)
        return self._heading_free_bound

    def disguise_plus(self, penalty: np.ndarray, by_target: bool = False) -> np.ndarray:
        """``disguise + penalty[None, :]`` (float32), cached per penalty vector (few distinct ones per pair);
        ``by_target``: its transpose (see :meth:`by_target`), the same numbers."""
        key = (penalty.tobytes(), by_target)
        out = self._with_penalty.get(key)
        if out is None:
            if by_target:
                out = self._disguise_t + penalty.astype(np.float32)[:, None]
            else:
                out = self.disguise + penalty.astype(np.float32)[None, :]
            if len(self._with_penalty) >= 4:
                self._with_penalty.pop(next(iter(self._with_penalty)))
            self._with_penalty[key] = out
        return out


class StageCache:
    """Least-recently-used stages (keyed by the target pose) and stage pairs of one scene."""

    def __init__(self, lattice: np.ndarray, table: ManoeuvreBoundsTable, lam: float, eta: float, size: int):
        self.lattice, self.table, self.lam, self.eta, self.size = lattice, table, lam, eta, int(size)
        self._stages: OrderedDict = OrderedDict()
        self._pairs: OrderedDict = OrderedDict()

    def stage(self, q, phi) -> Stage:
        q = np.asarray(q, dtype=float).reshape(3)
        key = (q.tobytes(), float(phi))
        return self._recent(self._stages, key, lambda: Stage(key, q.copy(), float(phi), self.lattice))

    def pair(self, a: Stage, b: Stage) -> StagePair:
        return self._recent(self._pairs, (a.key, b.key), lambda: StagePair(a, b, self.lam, self.eta, self.table))

    def _recent(self, cache: OrderedDict, key, make):
        """``cache[key]``, made by ``make()`` if absent, marked as the most recently used; the least recently used
        entries beyond ``size`` are dropped."""
        value = cache.get(key)
        if value is None:
            value = cache[key] = make()
            while len(cache) > self.size:
                cache.popitem(last=False)
        else:
            cache.move_to_end(key)
        return value
