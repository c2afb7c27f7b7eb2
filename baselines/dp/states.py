"""DP states of a batch of UAVs (one :class:`Layer` per stage) and the problem one recursion solves."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from baselines.dp.path_checks import PathContext

__all__ = ["Layer", "Problem", "SolveCounts", "batch_layers", "best_cost", "depths", "layers_of"]


@dataclass
class Layer:
    """DP states of one stage for a batch of UAVs, sorted by (uav, node, bin).

    uav: which UAV of the batch; node: lattice index; theta: the exact heading of the state's best
    arrival; J: cost so far (J_j of eqs. 19-20, with penalties); parent: row of the previous layer; v, g: the
    step's speed and stage cost (eq. 18).
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

    def fields(self) -> tuple:
        return self.uav, self.node, self.theta, self.J, self.parent, self.v, self.g

    def take(self, idx) -> Layer:
        return Layer(*(a[idx] for a in self.fields()))

    @classmethod
    def empty(cls) -> Layer:
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
class SolveCounts:
    """Transitions solved exactly (eq. 29 root solves) and bounded through the manoeuvre table."""

    exact: int = 0
    bounded: int = 0


@dataclass
class Problem:
    """One batched DP run: shared stages, per-UAV start poses and per-stage penalties."""

    start: np.ndarray        # (U, 2)
    theta: np.ndarray        # (U,)
    alpha0: np.ndarray       # (U,) alpha at the start (eq. 12)
    d0: np.ndarray           # (U,) d at the start (eq. 13)
    stages: list             # N lattice.Stage
    penalties: list          # N arrays (U, L) or (1, L) when shared: 0 allowed, inf removed, > 0 penalised
    path: PathContext | None
    avoid: np.ndarray | None = None   # (U, M, N, P, 2) other UAVs' planned path samples (NaN: none)
    avoid_dist: float = 0.0           # required distance to them at every sample
    path_soft: bool = False           # check_path in fallback: blocked LoS along a path is a penalty, zone ignored
    path_cost: np.ndarray | None = None   # (N,) cost per unit of blocked path share per stage (planner's path_cost)
    #: per stage, path_checks.record_circles of ``avoid`` (computed once, used by every round's solve)
    avoid_circles: dict = field(default_factory=dict, repr=False)


def depths(layers: list[Layer], u: int) -> np.ndarray:
    """Stages reached by each UAV of the batch (states at stage j exist only if they did at j - 1)."""
    depth = np.zeros(u, np.int64)
    for j, lay in enumerate(layers):
        depth[np.unique(lay.uav)] = j + 1
    return depth


def best_cost(layers: list[Layer], i: int, depth: int) -> float:
    """UAV i's smallest J at stage ``depth`` (eq. 21: the virtual final state costs nothing)."""
    lay = layers[depth - 1]
    return float(lay.J[lay.uav == i].min())


def layers_of(layers: list[Layer], i: int) -> list[Layer]:
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


def batch_layers(per_uav: list[list[Layer]], t0: int) -> list[Layer]:
    """The first t0 layers of several single-UAV layer lists, batched (UAV i = list i; parents shifted)."""
    out = []
    for j in range(t0):
        parts, offs = [], 0
        prev_sizes = [lays[j - 1].n for lays in per_uav] if j else None
        for i, lays in enumerate(per_uav):
            lay = lays[j]
            par = lay.parent if j == 0 else lay.parent + offs
            parts.append(Layer(uav=np.full(lay.n, i), node=lay.node, theta=lay.theta, J=lay.J, parent=par, v=lay.v,
                               g=lay.g))
            if j:
                offs += prev_sizes[i]
        out.append(Layer(*(np.concatenate(x) for x in zip(*(q.fields() for q in parts), strict=True))))
    return out
