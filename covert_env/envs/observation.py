"""The observation's layout, in one place: named slices, bounds, the spaces, the rows and the docstring table.

An agent's observation row is its own features (offset, heading, speed, LoS, zone), the shared features (the
target's next displacement, the time remaining), its teammates' offsets, two visibility maps and, with the envs'
``target_path=P`` > 0, the target's path predicted over P slots. ``state()`` is every UAV's own features followed
by the shared features, the maps and the path. Every consumer (the envs' spaces, the
observation and state builders, the scene cache's shared block, the class docstrings' table) reads the layout
from :class:`ObservationLayout`, so it cannot drift between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

__all__ = ["FIELDS", "OFFSET_CLIP", "OWN_SIZE", "OWN_SLICES", "ObservationLayout", "field_slices", "observation_table",
           "shared_block_size", "shared_block_slices"]

#: Offsets in observations are divided by R2 and clipped to this magnitude (500 m at R2 = 100 m).
OFFSET_CLIP = 5.0


@dataclass(frozen=True)
class Field:
    """One named block of the observation row: its size (``"U-1"`` pairs, ``"S*S"`` cells or a number), bounds
    and the docstring's wording."""

    name: str
    size: object
    low: float
    high: float
    meaning: str
    scale: str


#: The row in order. Sizes: an int, ``"mates"`` (2 (U - 1)), ``"map"`` (S * S) or ``"path"`` (2 P, P = the envs'
#: ``target_path``, 0 by default: the path's fields come last, so without them the row is the same).
FIELDS = (
    Field("offset", 2, -OFFSET_CLIP, OFFSET_CLIP, "own offset from the target", "/ R2, clipped to +-5"),
    Field("heading", 2, -1.0, 1.0, "cos, sin of own heading minus target heading", ""),
    Field("speed", 1, 0.0, 1.0, "own speed in the last slot", "/ V_max"),
    Field("los", 1, 0.0, 1.0, "LoS to the target is clear (eq. 6)", "0 or 1"),
    Field("in_zone", 1, 0.0, 1.0, "inside the feasible zone (eq. 4)", "0 or 1"),
    Field("zone_distance", 1, -OFFSET_CLIP, OFFSET_CLIP, "signed distance to the zone boundary (negative inside)",
          "/ (R2 - R1), clipped to +-5"),
    Field("target_displacement", 2, -2.0, 2.0, "target's displacement to its next slot, in the current target frame",
          "/ (V_max delta)"),
    Field("remaining", 1, 0.0, 1.0, "fraction of the episode remaining", "0..1"),
    Field("teammates", "mates", -OFFSET_CLIP, OFFSET_CLIP, "teammates' offsets from the target, by agent index",
          "/ R2, clipped to +-5"),
    Field("map_now", "map", 0.0, 1.0, "map of cells around the zone: 1 if in the eroded zone with clear LoS, now",
          "0 or 1"),
    Field("map_next", "map", 0.0, 1.0, "the same map at the next predicted slot k+1", "0 or 1"),
    Field("target_path", "path", -OFFSET_CLIP, OFFSET_CLIP, "with target_path=P: the target's positions predicted "
          "at slots k+1..k+P, in the current target frame (x1, y1, x2, y2, ...)", "/ R2, clipped to +-5"),
    Field("target_path_heading", "path", -1.0, 1.0, "with target_path=P: cos, sin of the target's predicted "
          "heading at k+1..k+P minus its heading now (cos1, sin1, cos2, ...)", ""),
)
#: Fields of the per-UAV block (``state()`` repeats it for every UAV) and of the block shared by all agents.
OWN = ("offset", "heading", "speed", "los", "in_zone", "zone_distance")
SHARED = ("target_displacement", "remaining", "map_now", "map_next", "target_path", "target_path_heading")
#: The own block's slices (the same for every team size and map size: it comes first) and its length.
OWN_SLICES: dict[str, slice] = {}
_start = 0
for _f in FIELDS[:len(OWN)]:
    OWN_SLICES[_f.name] = slice(_start, _start + _f.size)
    _start += _f.size
OWN_SIZE = _start


def shared_block_slices(map_cells: int, path_slots: int = 0) -> dict[str, slice]:
    """Slices of the block every agent shares (target displacement, time remaining, maps now and next, the target's
    predicted path over ``path_slots`` slots) within the block: what a scene gives per slot, whatever the UAVs (the
    scene cache stores these blocks)."""
    sizes = {"map": int(map_cells), "path": 2 * int(path_slots)}
    out, start = {}, 0
    for f in FIELDS:
        if f.name in SHARED:
            n = sizes[f.size] if isinstance(f.size, str) else f.size
            out[f.name] = slice(start, start + n)
            start += n
    return out


def shared_block_size(map_cells: int, path_slots: int = 0) -> int:
    """Length of the shared block (:func:`shared_block_slices`)."""
    return shared_block_slices(map_cells, path_slots)[SHARED[-1]].stop


def observation_table(single_agent: bool = False) -> str:
    """The observation table of the envs' docstrings (markdown), generated from :data:`FIELDS`; ``single_agent``:
    without the teammates' block (one UAV, the Gymnasium envs)."""
    lines = ["| index | observation | scale |", "|---|---|---|"]
    start, symbolic = 0, None
    for f in FIELDS:
        if single_agent and f.size == "mates":
            continue
        if isinstance(f.size, int) and symbolic is None:
            idx = f"{start}" if f.size == 1 else f"{start}-{start + f.size - 1}"
            start += f.size
        else:
            n = {"mates": "2(U-1)", "map": "S*S", "path": "2P"}.get(f.size, str(f.size))
            idx = f"{start} .. {start}+{n}" if symbolic is None else f"then {n}"
            symbolic = True
        lines.append(f"| {idx} | {f.meaning} | {f.scale} |")
    return "\n".join(lines)


def field_slices(n_uavs: int, map_size: int, path_slots: int = 0) -> dict[str, slice]:
    """Field name -> slice of the observation row (:data:`FIELDS` in order) for U UAVs, S x S maps and the target's
    path over P = ``path_slots`` slots."""
    sizes = {"mates": 2 * (int(n_uavs) - 1), "map": int(map_size) ** 2, "path": 2 * int(path_slots)}
    out, start = {}, 0
    for f in FIELDS:
        n = sizes[f.size] if isinstance(f.size, str) else f.size
        out[f.name] = slice(start, start + n)
        start += n
    return out


class ObservationLayout:
    """Slices, bounds and builders of the observation row and ``state()`` for U UAVs, S x S maps and the target's
    path over P = ``path_slots`` predicted slots (0: no path fields).

    Attributes:
        slices: field name -> slice of the observation row.
        size: D, the row's length; ``own_size`` (the own block's length, :data:`OWN_SIZE`) and ``shared_size`` (the
            scene cache's block: target displacement, time remaining, both maps, the path; ``shared_slices`` within
            it).
        state_size: S_state = U * own_size + shared_size.
    """

    def __init__(self, n_uavs: int, map_size: int, path_slots: int = 0):
        self.n_uavs, self.map_size, self.path_slots = int(n_uavs), int(map_size), int(path_slots)
        self.slices = field_slices(self.n_uavs, self.map_size, self.path_slots)
        low, high = [], []
        for f in FIELDS:
            n = self.slices[f.name].stop - self.slices[f.name].start
            low += [f.low] * n
            high += [f.high] * n
        self.size = self.slices[FIELDS[-1].name].stop
        self.low, self.high = np.array(low, np.float32), np.array(high, np.float32)
        self.own_size = OWN_SIZE
        self.shared_slices = shared_block_slices(self.map_size ** 2, self.path_slots)
        self.shared_size = self.shared_slices[SHARED[-1]].stop
        self.state_size = self.n_uavs * self.own_size + self.shared_size
        self._state_index = np.concatenate([np.tile(np.arange(self.own_size), self.n_uavs)]
                                           + [np.arange(self.size)[self.slices[n]] for n in SHARED])
        # Teammates of agent i, by index, skipping i: the row's fixed-size teammate block.
        u = self.n_uavs
        self.mates = np.array([[j for j in range(u) if j != i] for i in range(u)], dtype=int).reshape(u, u - 1)

    def box(self) -> spaces.Box:
        """One agent's observation space."""
        return spaces.Box(self.low, self.high, dtype=np.float32)

    def state_box(self) -> spaces.Box:
        """The space of ``state()``: the own-feature bounds per UAV, then the shared ones."""
        return spaces.Box(self.low[self._state_index], self.high[self._state_index], dtype=np.float32)

    def observations(self, own: np.ndarray, shared: np.ndarray, remaining: np.ndarray) -> np.ndarray:
        """(B, U, D) float32 rows from own features (B, U, own_size), shared blocks (B, shared_size) and the time
        remaining (B,)."""
        n, u = own.shape[:2]
        s, b = self.slices, self.shared_slices
        rows = np.empty((n, u, self.size), np.float32)
        rows[..., :self.own_size] = own
        # Target displacement and time remaining lie side by side in both: one copy, then the row's own time.
        rows[..., s["target_displacement"].start:s["remaining"].stop] = \
            shared[:, None, b["target_displacement"].start:b["remaining"].stop]
        rows[..., s["remaining"].start] = remaining[:, None]
        rows[..., s["teammates"]] = own[:, self.mates, :2].reshape(n, u, -1)
        # The maps and the path lie side by side in both too.
        rows[..., s["map_now"].start:] = shared[:, None, b["map_now"].start:]
        return rows

    def state(self, own: np.ndarray, shared: np.ndarray, remaining: np.ndarray) -> np.ndarray:
        """(B, state_size) float32: every UAV's own features, then the shared block with the time remaining."""
        shared = shared.copy()
        shared[:, self.shared_slices["remaining"].start] = remaining
        return np.concatenate([own.reshape(len(own), -1).astype(np.float32), shared], axis=1)
