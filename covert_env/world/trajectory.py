"""A recorded episode: everything the metrics need, and nothing a policy could fake.

The engine and the vector env write one :class:`Trajectory` per episode, whatever drives the UAVs (the DP planner,
a trained agent, a random policy), through one :class:`EpisodeRecorder` (the engine's with B = 1);
:mod:`covert_env.world.metrics` scores it. It saves to and loads from plain JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

__all__ = ["EpisodeRecorder", "Trajectory"]


@dataclass(eq=False)
class Trajectory:
    """Positions of the team and the target over T slots.

    Shapes use T = number of slots flown, U = number of UAVs, P = samples per slot along the path
    (both slot endpoints included).

    Attributes:
        uav_xy: (T+1, U, 2) UAV positions at slot times 0..T.
        uav_theta: (T+1, U) headings at slot times.
        path_xy: (T, U, P, 2) positions along the path flown during each slot.
        path_length: (T, U) distance flown in each slot (v[k] delta; eq. 15).
        target_xyz: (T+1, 3) target positions q[k].
        target_phi: (T+1,) target headings phi[k].
        target_path_xyz: (T, P, 3) target positions at the same instants as ``path_xy``.
        max_speed: (T, U) highest speed commanded during each slot.
        max_turn_rate: (T, U) highest |omega| commanded during each slot.
        infeasible: (T, U) True where the move was flagged as a fallback: by the policy (no feasible plan), or
            by the engine for a waypoint it flew as its best effort (out of the manoeuvre's reach).
        decision_time: (T, U) seconds the policy took to choose the move (NaN if not measured).
    """

    uav_xy: np.ndarray
    uav_theta: np.ndarray
    path_xy: np.ndarray
    path_length: np.ndarray
    target_xyz: np.ndarray
    target_phi: np.ndarray
    target_path_xyz: np.ndarray
    max_speed: np.ndarray
    max_turn_rate: np.ndarray
    infeasible: np.ndarray
    decision_time: np.ndarray

    @property
    def n_slots(self) -> int:
        return len(self.path_length)

    @property
    def n_uavs(self) -> int:
        return self.uav_xy.shape[1]

    def to_dict(self) -> dict:
        """Plain JSON types: nested lists, NaN written as null, and each field's shape under ``"shapes"``
        (so an empty episode keeps its (0, U, P, 2)-style shapes)."""
        out: dict = {}
        for f in fields(self):
            a = np.asarray(getattr(self, f.name))
            out[f.name] = np.where(np.isnan(a), None, a).tolist() if a.dtype.kind == "f" else a.tolist()
        out["shapes"] = {f.name: list(np.shape(getattr(self, f.name))) for f in fields(self)}
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Trajectory:
        names = [f.name for f in fields(cls)]
        missing = sorted(set(names) - set(data))
        if missing:
            raise ValueError(f"Trajectory: missing field(s) {missing}")
        shapes = data.get("shapes", {})
        kw = {}
        for n in names:
            if n == "infeasible":
                a = np.asarray(data[n], dtype=bool)
            else:
                a = np.asarray(data[n], dtype=object)
                a = np.where(a == None, np.nan, a).astype(float)  # noqa: E711 - null -> NaN elementwise
            kw[n] = a.reshape(shapes[n]) if n in shapes else a
        return cls(**kw)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), allow_nan=False))

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        return cls.from_dict(json.loads(Path(path).read_text()))


class EpisodeRecorder:
    """B episodes being flown, at most ``n_slots`` slots of U UAVs with P path samples per slot, batch-first:
    preallocated arrays written by one array operation per slot, read back as a :class:`Trajectory`. The engine
    records its one episode in one (B = 1), the vector env its copies' (``record=True``)."""

    def __init__(self, b: int, u: int, n_slots: int, path_samples: int):
        n, p = n_slots, path_samples
        self.xy, self.theta = np.zeros((b, n + 1, u, 2)), np.zeros((b, n + 1, u))
        self.path = np.zeros((b, n, u, p, 2))
        self.length, self.max_speed, self.max_turn_rate = np.zeros((b, n, u)), np.zeros((b, n, u)), np.zeros((b, n, u))
        self.infeasible = np.zeros((b, n, u), bool)
        self.decision_time = np.full((b, n, u), np.nan)                 # NaN: not measured
        self.fractions = np.linspace(0.0, 1.0, p)

    def start(self, idx, xy: np.ndarray, theta: np.ndarray) -> None:
        """Episodes ``idx`` begin at poses ``xy`` (len(idx), U, 2), ``theta`` (len(idx), U)."""
        self.xy[idx, 0], self.theta[idx, 0] = xy, theta
        self.decision_time[idx] = np.nan

    def record(self, k: np.ndarray, path, *, end_theta, v, w, flagged, delta: float, decision_time=None) -> None:
        """Slot ``k`` (B,) -> k + 1 of every episode: path samples (B, U, P, 2), end headings (wrapped), controls v
        and w, the fallback flags and (if measured) the policy's decision times (B, U)."""
        b = np.arange(len(k))
        self.path[b, k], self.length[b, k] = path, v * delta
        self.max_speed[b, k], self.max_turn_rate[b, k], self.infeasible[b, k] = v, np.abs(w), flagged
        self.xy[b, k + 1], self.theta[b, k + 1] = path[..., -1, :], end_theta
        if decision_time is not None:
            self.decision_time[b, k] = decision_time

    def trajectory(self, i: int, k: int, track, first: int = 0) -> Trajectory:
        """Episode i's slots ``first`` .. k on the target's ``track`` (a :class:`Trajectory` of k - first slots)."""
        ks = np.arange(first, k + 1)
        p = len(self.fractions)
        return Trajectory(
            uav_xy=self.xy[i, first:k + 1].copy(), uav_theta=self.theta[i, first:k + 1].copy(),
            path_xy=self.path[i, first:k].copy(), path_length=self.length[i, first:k].copy(),
            target_xyz=track.position(ks), target_phi=np.asarray(track.heading(ks)).reshape(-1),
            target_path_xyz=np.array(track.position_between(ks[:-1], self.fractions)).reshape(-1, p, 3),
            max_speed=self.max_speed[i, first:k].copy(), max_turn_rate=self.max_turn_rate[i, first:k].copy(),
            infeasible=self.infeasible[i, first:k].copy(), decision_time=self.decision_time[i, first:k].copy())
