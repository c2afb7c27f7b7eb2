"""Every parameter of the model, with the paper's defaults (Almuzaini & Savkin 2024, §3).

Parameters the paper leaves open (target speed and height, uncertainty radius, grid step, the shadow
truncation height ``h_min``, the random terrain generator's ranges) are chosen here and documented;
they are ordinary fields, so a study can vary them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Config"]


@dataclass(frozen=True)
class Config:
    """Parameters of the covert-sensing model. Units: metres, seconds, radians.

    Construct with keywords; invalid values raise :class:`ValueError` naming the field and the
    allowed range. ``Config.from_json(cfg.to_json()) == cfg``.
    """

    # --- UAV kinematics (eq. 1) ------------------------------------------------------------
    v_max: float = 50.0
    """Maximum linear speed V_max (m/s); speeds lie in (0, V_max]."""
    w_max: float = 3.0
    """Maximum angular speed W_max (rad/s); turn rates lie in [-W_max, W_max]."""
    altitude: float = 80.0
    """Flight altitude h (m) of every UAV: the operational plane O is z = h."""

    # --- planning horizon ------------------------------------------------------------------
    horizon: int = 5
    """Number of predicted slots N the planner looks ahead (T = N * delta)."""
    delta: float = 1.0
    """Slot length delta (s)."""
    n_slots: int = 70
    """Length of an episode in slots (the paper's target drives for 70 slots)."""

    # --- objective (eqs. 11-18) ------------------------------------------------------------
    eta: float = 55.0
    """Weight eta of the angle change in the disguise measure kappa (eq. 11)."""
    lam: float = 10.0
    """Weight lambda of disguise against path length in the stage cost g (eqs. 16-18)."""

    # --- safety (eqs. 2-3) -----------------------------------------------------------------
    d_safe1: float = 5.0
    """Minimum UAV-UAV horizontal separation d_safe1 (m), eq. 2."""
    d_safe2: float = 10.0
    """Minimum distance d_safe2 (m) from a UAV to the highest point of every polytope, eq. 3."""

    # --- feasible flight zone (eqs. 4-5) ---------------------------------------------------
    mu: float = math.pi / 4
    """Full opening angle mu (rad) of the annular sector behind the target, in (0, 2 pi)."""
    r1: float = 55.0
    """Inner radius R1 (m): closer than this the target notices the UAV."""
    r2: float = 100.0
    """Outer radius R2 (m): farther than this the video is too poor."""
    r_u: float = 2.0
    """(decided) Radius (m) of the disk gamma(q) bounding the target-prediction error (eq. 5)."""

    # --- terrain ----------------------------------------------------------------------------
    n_polytopes: int = 16
    """Number M of terrain polytopes (buildings, hills) the random generator places."""
    min_vertices: int = 4
    """(decided) Fewest base vertices of a random polytope."""
    max_vertices: int = 8
    """(decided) Most base vertices of a random polytope."""
    min_height: float = 20.0
    """(decided) Lowest top vertex height (m) of a random polytope."""
    max_height: float | None = None
    """Highest top vertex height (m) of a random polytope; None means altitude - d_safe2 (eq. 3)."""
    min_radius: float = 8.0
    """(decided) Smallest footprint circumradius (m) of a random polytope."""
    max_radius: float = 22.0
    """(decided) Largest footprint circumradius (m) of a random polytope."""
    road_clearance: float = 6.0
    """(decided) Minimum horizontal gap (m) between a footprint and the road centreline."""
    road_max_offset: float = 45.0
    """(decided) Random footprints lie within this distance (m) of the road centreline (radius
    permitting): buildings close to the road are the ones whose shadows fall on the zone behind the
    target (55-100 m behind it, at most ~40 m to its side)."""

    # --- target -----------------------------------------------------------------------------
    target_speed: float = 10.0
    """(decided) Target speed (m/s) along the road; the paper does not give it."""
    target_height: float = 1.5
    """(decided) Height z_q (m) of the filmed point of the target (a car's roof)."""

    # --- discretisation and shadows -----------------------------------------------------------
    grid_step: float = 2.0
    """(decided) Spacing (m) of the grid nodes / waypoint lattice in the target's frame."""
    h_min: float | None = None
    """Shadow truncation height (m, eq. 9). None (default) picks it per polytope so that the
    truncated shadow is exact within ``r2 + shadow_margin`` of the target (docs/decisions.md#shadow-truncation-h_min);
    a number uses that fixed height for every polytope, as the paper does (then shadows may be incomplete)."""
    shadow_margin: float = 10.0
    """(decided) Extra radius (m) beyond R2 inside which the automatic h_min keeps shadows exact."""

    n_uavs: int = 3
    """Number of UAVs U in the team."""

    def __post_init__(self) -> None:
        _validate(self)

    # ------------------------------------------------------------------ derived quantities
    @property
    def max_polytope_height(self) -> float:
        """The effective cap on random polytope heights (``max_height`` or ``h - d_safe2``)."""
        return self.altitude - self.d_safe2 if self.max_height is None else self.max_height

    @property
    def min_turn_radius_per_speed(self) -> float:
        """r / v = 1 / W_max: the turning radius at speed v is v / W_max."""
        return 1.0 / self.w_max

    # ------------------------------------------------------------------ (de)serialisation
    def replace(self, **changes: Any) -> Config:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Config:
        """Build from a mapping; unknown keys raise ValueError naming them."""
        if not isinstance(data, dict):
            raise ValueError(f"Config must be a JSON object, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"Config: unknown field(s) {unknown}; known fields are {sorted(known)}")
        return cls(**data)

    def to_json(self, path: str | Path | None = None, **kwargs: Any) -> str:
        """Serialise to a JSON string, and write it to ``path`` if given."""
        text = json.dumps(self.to_dict(), indent=kwargs.pop("indent", 2), **kwargs)
        if path is not None:
            Path(path).write_text(text + "\n")
        return text

    @classmethod
    def from_json(cls, text_or_path: str | Path) -> Config:
        """Parse a JSON string, or read a ``.json`` file if given a path that exists."""
        p = Path(text_or_path) if not str(text_or_path).lstrip().startswith("{") else None
        text = p.read_text() if p is not None else str(text_or_path)
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"Config: invalid JSON ({exc})") from exc
        return cls.from_dict(data)


_POSITIVE = ("v_max", "w_max", "altitude", "delta", "eta", "lam", "d_safe1", "d_safe2", "r1", "r2",
             "min_height", "min_radius", "max_radius", "target_speed", "grid_step")
_NON_NEGATIVE = ("r_u", "road_clearance", "road_max_offset", "target_height", "shadow_margin")
_INTS = {"horizon": 1, "n_slots": 1, "n_polytopes": 0, "min_vertices": 3, "max_vertices": 3, "n_uavs": 1}


def _validate(c: Config) -> None:
    for name, low in _INTS.items():
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise ValueError(f"Config.{name} must be an integer >= {low}, got {v!r}")
    for name in _POSITIVE + _NON_NEGATIVE + ("mu",):
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"Config.{name} must be a finite number, got {v!r}")
    for name in _POSITIVE:
        if getattr(c, name) <= 0:
            raise ValueError(f"Config.{name} must be > 0, got {getattr(c, name)!r}")
    for name in _NON_NEGATIVE:
        if getattr(c, name) < 0:
            raise ValueError(f"Config.{name} must be >= 0, got {getattr(c, name)!r}")
    if not 0 < c.mu < 2 * math.pi:
        raise ValueError(f"Config.mu must lie in (0, 2*pi), got {c.mu!r}")
    if c.r1 >= c.r2:
        raise ValueError(f"Config.r1 must be < Config.r2 (got r1={c.r1!r}, r2={c.r2!r})")
    if 2 * c.r_u >= c.r2 - c.r1:
        raise ValueError(
            f"Config.r_u must be < (r2 - r1) / 2 = {(c.r2 - c.r1) / 2:g} or the eroded zone is empty, got {c.r_u!r}")
    if c.min_vertices > c.max_vertices:
        raise ValueError(f"Config.min_vertices must be <= max_vertices ({c.max_vertices}), got {c.min_vertices}")
    if c.min_radius > c.max_radius:
        raise ValueError(f"Config.min_radius must be <= max_radius ({c.max_radius:g}), got {c.min_radius:g}")
    if c.target_height >= c.altitude:
        raise ValueError(f"Config.target_height must be in [0, altitude={c.altitude:g}), got {c.target_height!r}")
    if c.max_height is not None:
        if isinstance(c.max_height, bool) or not isinstance(c.max_height, (int, float)) \
                or not math.isfinite(c.max_height) or not c.min_height <= c.max_height < c.altitude:
            raise ValueError(f"Config.max_height must be None or in [min_height={c.min_height:g}, "
                             f"altitude={c.altitude:g}), got {c.max_height!r}")
    elif c.min_height > c.max_polytope_height:
        raise ValueError(f"Config.min_height must be <= altitude - d_safe2 = {c.max_polytope_height:g}, "
                         f"got {c.min_height!r}")
    if c.h_min is not None:
        if isinstance(c.h_min, bool) or not isinstance(c.h_min, (int, float)) or not math.isfinite(c.h_min) \
                or not c.target_height < c.h_min < c.altitude:
            raise ValueError(f"Config.h_min must be None or in (target_height={c.target_height:g}, "
                             f"altitude={c.altitude:g}), got {c.h_min!r}")

