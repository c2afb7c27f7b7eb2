"""A recorded episode: everything the metrics need, and nothing a policy could fake.

The engine writes one :class:`Trajectory` per episode, whatever drives the UAVs (the DP planner, a
trained agent, a random policy); :mod:`covert_env.world.metrics` scores it. It saves to and loads from
plain JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

__all__ = ["Trajectory"]


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
