"""Every parameter of the model, with the paper's defaults (Almuzaini & Savkin 2024, §3).

Parameters the paper leaves open (target speed and height, uncertainty radius, grid step, the shadow
truncation height ``h_min``, the random terrain generator's ranges) are chosen here and documented;
they are ordinary fields, so a study can vary them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import operator
import os
import reprlib
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from covert_env.geometry.zone import MAX_LATTICE, lattice_size, zone_capacity

__all__ = ["Config", "check_coordinates", "short_repr", "polytope_capacity", "scene_road_length", "MAX_COORDINATE",
           "MAX_HORIZON", "MAX_LATTICE", "MAX_LENGTH", "MAX_N_POLYTOPES", "MAX_N_SLOTS", "MAX_N_UAVS", "MAX_ROUTE",
           "MAX_VERTICES", "MAX_WEIGHT"]


@dataclass(frozen=True)
class Config:
    """Parameters of the covert-sensing model. Units: metres, seconds, radians.

    Construct with keywords; invalid values raise :class:`ValueError` naming the field, the value and
    the allowed range. Integer fields take ints or numpy integers (stored as int; floats such as 3.0
    and bools are rejected), the others any real number (stored as float). Sizes have upper bounds
    (stated per field) so that a typo fails here rather than as a hang or a MemoryError later, and a
    config whose eroded zone holds no lattice node, or no room for the team's starts, is rejected. Real
    fields have finite upper bounds too: lengths at most ``MAX_LENGTH`` (100 km), ``v_max`` and
    ``target_speed`` at most ``MAX_SPEED`` (10 km/s), ``w_max`` at most ``MAX_TURN_RATE`` (1000 rad/s),
    ``delta`` at most ``MAX_DELTA`` (1 h), ``eta`` and ``lam`` at most ``MAX_WEIGHT`` (1e6).
    ``Config.from_json(cfg.to_json()) == cfg``.
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
    """Number of predicted slots N the planner looks ahead (T = N * delta); 1 <= N <= 1000."""
    delta: float = 1.0
    """Slot length delta (s)."""
    n_slots: int = 70
    """Length of an episode in slots (the paper's target drives for 70 slots); 1 <= n_slots <= 10_000.

    The target's route, ``target_speed * delta * (n_slots + horizon + 1)``, must be <= 200 km."""

    # --- objective (eqs. 11-18) ------------------------------------------------------------
    eta: float = 55.0
    """Weight eta of the angle change in the disguise measure kappa (eq. 11); 0 < eta <= 1e6."""
    lam: float = 10.0
    """Weight lambda of disguise against path length in the stage cost g (eqs. 16-18); 0 < lambda <= 1e6."""

    # --- safety (eqs. 2-3) -----------------------------------------------------------------
    d_safe1: float = 5.0
    """Minimum UAV-UAV horizontal separation d_safe1 (m), eq. 2. The eroded zone's lattice must hold
    ``n_uavs`` nodes this far apart (picked greedily in lattice order), or there is no legal start."""
    d_safe2: float = 10.0
    """Minimum distance d_safe2 (m) from a UAV to the highest point of every polytope, eq. 3.

    Polytope tops must lie below ``altitude``; a top within d_safe2 of it is legal (eq. 3 then only
    forbids the points of the operational plane near it), but the random generator keeps its tops
    at or below ``altitude - d_safe2`` unless ``max_height`` says otherwise."""

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
    """Number M of terrain polytopes (buildings, hills) the random generator places; 0 <= M <= 10_000.

    They are placed by rejection sampling beside the route, so the route must have room for them. Config
    rejects a count whose expected footprint area (with the 2 m streets between footprints) exceeds the
    area of the band they can occupy beside the scenario road (:func:`polytope_capacity`; about 165 at
    the defaults). Below that bound the generator may still fail: at the default sizes the 960 m default
    road took 80 on every seed tried, while about 100 and more fail (ValueError at reset naming this
    field) on some or all seeds."""
    min_vertices: int = 4
    """(decided) Fewest base vertices of a random polytope; 3 <= min_vertices <= max_vertices."""
    max_vertices: int = 8
    """(decided) Most base vertices of a random polytope; at most 64."""
    min_height: float = 20.0
    """(decided) Lowest top vertex height (m) of a random polytope."""
    max_height: float | None = None
    """Highest top vertex height (m) of a random polytope; None means altitude - d_safe2 (eq. 3)."""
    min_radius: float = 8.0
    """(decided) Smallest footprint circumradius (m) of a random polytope."""
    max_radius: float = 22.0
    """(decided) Largest footprint circumradius (m) of a random polytope; at most half the scenario
    road's length (:func:`scene_road_length`: a footprint no longer than the road it lines)."""
    road_clearance: float = 6.0
    """(decided) Minimum horizontal gap (m) between a footprint and the road centreline."""
    road_max_offset: float = 45.0
    """(decided) Random footprints lie within this distance (m) of the road centreline (radius
    permitting): buildings close to the road are the ones whose shadows fall on the zone behind the
    target (55-100 m behind it, at most ~40 m to its side)."""
    road_max_curvature: float = 1 / 120
    """(decided) Largest curvature (1/m) of a random road (:meth:`Road.random`): 0 is straight, 1/120 (a 120 m
    turn radius, the default) gentle bends, 1/30 sharp turns; in [0, 0.1] (turn radius >= 10 m)."""

    # --- target -----------------------------------------------------------------------------
    target_speed: float = 10.0
    """(decided) Target speed (m/s) along the road; the paper does not give it."""
    target_height: float = 1.5
    """(decided) Height z_q (m) of the filmed point of the target (a car's roof)."""
    prediction_error: float = 0.0
    """Bound (m) on the target-prediction error along the road; 0 (default, the paper's setting) means
    the prediction is the truth. Otherwise the scenario's target drives with bounded speed noise
    (docs/decisions/model.md#prediction-error), seeded by the scene, so that a prediction made from its true
    position is off by at most this at every predicted slot; planner and observations see the
    prediction, the metrics the truth. 0 <= prediction_error <= target_speed * delta (the noise never
    makes the target reverse). Eq. 5 keeps the UAVs in the zone only if r_u >= prediction_error; a
    smaller r_u is allowed (to study what happens without that guarantee)."""

    # --- discretisation and shadows -----------------------------------------------------------
    grid_step: float = 2.0
    """(decided) Spacing (m) of the grid nodes / waypoint lattice in the target's frame. The lattice's
    bounding box (:func:`covert_env.geometry.zone.lattice_size`) must have <= 200_000 nodes (975 by default)
    and the eroded zone at least one node (more: see ``d_safe1``)."""
    h_min: float | None = None
    """Shadow truncation height (m, eq. 9). None (default) picks it per polytope so that the
    truncated shadow is exact within ``r2 + shadow_margin`` of the target
    (docs/decisions/model.md#shadow-truncation-h_min); a number uses that fixed height for every polytope, as the
    paper does (then shadows may be incomplete)."""
    shadow_margin: float = 10.0
    """(decided) Extra radius (m) beyond R2 inside which the automatic h_min keeps shadows exact."""

    n_uavs: int = 3
    """Number of UAVs U in the team; 1 <= U <= 64."""

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
        unknown = sorted(set(data) - known, key=str)
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
        """Parse a JSON string (one starting with ``{`` or ``[``), or read the JSON file at a path.

        Every problem is a ValueError naming the file (or "JSON text") and the problem: invalid or
        too deeply nested JSON, bytes that are not UTF-8, a top level that is not an object, unknown
        or invalid fields, an empty or blank string. A missing file is a FileNotFoundError naming the path.
        """
        if not isinstance(text_or_path, (str, Path)):
            raise TypeError(f"Config.from_json takes a JSON string or a path, got {type(text_or_path).__name__}")
        if isinstance(text_or_path, str) and not text_or_path.strip():
            raise ValueError(f"Config.from_json: empty JSON text or path {text_or_path!r}; give a JSON object "
                             f"('{{\"n_uavs\": 2}}') or the path of a JSON file")
        if isinstance(text_or_path, str) and text_or_path.lstrip()[:1] in ("{", "["):
            where, data = "Config JSON text", parse_json(text_or_path, "Config JSON text")
        else:
            where, data = f"Config file {text_or_path}", read_json(text_or_path, "Config file")
        try:
            return cls.from_dict(data)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict:
    # A repeated key would silently keep its last value: in a config that hides a typo or a merge mistake.
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key {key!r} appears twice in one object; give each field once")
        out[key] = value
    return out


class _LongInteger(str):
    """An integer literal too long for Python's int(): kept as text, so the field that holds it is named."""

    def __repr__(self) -> str:
        return f"<an integer of {len(self)} digits>"


def _parse_int(text: str) -> int | _LongInteger:
    return _LongInteger(text) if len(text) > 4000 else int(text)


def parse_json(text: str, where: str) -> Any:
    """``json.loads(text)``; a ValueError starting with ``where`` for invalid or too deeply nested JSON, a key
    repeated in one object, or a number Python will not parse (an integer of more than 4300 digits)."""
    try:
        return json.loads(text, object_pairs_hook=_unique_keys, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{where}: invalid JSON ({exc})") from None
    except RecursionError:
        # The stdlib parser recurses once per nesting level; no file of ours nests more than a few.
        raise ValueError(f"{where}: JSON nested too deeply to parse") from None
    except ValueError as exc:                   # a repeated key, or int()'s digit limit
        raise ValueError(f"{where}: invalid JSON ({exc})") from None


#: The largest JSON file :func:`read_json` reads (bytes): far above any config, terrain (10_000 polytopes of 64
#: vertices) or run file, low enough that a wrong path cannot exhaust memory.
MAX_JSON_BYTES = 64 * 2**20


def file_kind(mode: int) -> str:
    """What a ``stat`` mode names, for error messages: "a regular file", "a directory", "a named pipe" ..."""
    for test, kind in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


def read_json(path: str | Path, what: str, max_bytes: int = MAX_JSON_BYTES) -> Any:
    """Parse the JSON file at ``path`` (UTF-8, a byte-order mark allowed). Errors name ``what`` and the
    path: FileNotFoundError for a missing file, ValueError for anything else -- among them a path that is not a
    regular file (a folder, ``/dev/zero``, a named pipe: refused before reading, so nothing blocks) and a file
    larger than ``max_bytes``."""
    p = Path(path)
    where = f"{what} {p}"
    try:
        # O_NONBLOCK: opening a named pipe for reading does not wait for a writer (no effect on regular files).
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise FileNotFoundError(f"{where}: no such file") from None
    except OSError as exc:
        raise ValueError(f"{where}: cannot be read ({exc.strerror or exc})") from None
    except ValueError:                          # os.open's answer to a NUL byte in the path
        raise ValueError(f"{what} {str(path)!r}: a path cannot hold a NUL byte") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"{where}: cannot be read ({file_kind(st.st_mode)}, not a regular file)")
        if st.st_size > max_bytes:
            raise ValueError(f"{where}: {st.st_size} bytes, more than the {max_bytes} a JSON file may have")
        with os.fdopen(os.dup(fd), "rb") as f:
            raw = f.read(max_bytes + 1)
    except OSError as exc:
        raise ValueError(f"{where}: cannot be read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if len(raw) > max_bytes:
        raise ValueError(f"{where}: more than the {max_bytes} bytes a JSON file may have")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{where}: not UTF-8 text (byte {exc.start}: {exc.reason}); save it as UTF-8") from None
    return parse_json(text, where)


_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 60


def short_repr(v: Any) -> str:
    """A short repr for an error message: a bad value may be a huge string or a deeply nested list."""
    return _REPR.repr(v)


#: Upper bounds on sizes: generous for any study, low enough that a typo fails here, not as a hang
#: or a MemoryError in the first reset. Each is stated in its field's docstring.
MAX_N_UAVS = 64
MAX_HORIZON = 1_000
MAX_N_SLOTS = 10_000
MAX_N_POLYTOPES = 10_000
MAX_VERTICES = 64
#: Largest weights eta and lambda of the cost (eqs. 11, 18).
MAX_WEIGHT = 1e6
MAX_LENGTH = 100_000.0
"""Largest length field of a Config (m): altitude, radii, distances, heights, grid step. Any real scene is far
smaller; the bound keeps products of lengths (areas, the shadow projection's ratios) finite."""
MAX_SPEED = 10_000.0
"""Largest ``v_max`` and ``target_speed`` (m/s)."""
MAX_TURN_RATE = 1_000.0
"""Largest ``w_max`` (rad/s)."""
MAX_DELTA = 3_600.0
"""Longest slot ``delta`` (s)."""
MAX_COORDINATE = 1_000_000.0
"""Largest absolute world coordinate (m) of a road point, a polytope vertex or a UAV start: 1,000 km from the
origin. Beyond it distances between points lose the centimetres the geometry's tolerances rely on, and their
squares and areas overflow; check it with :func:`check_coordinates` where coordinates enter."""
MAX_ROUTE = 200_000.0
"""Longest target route (m), ``target_speed * delta * (n_slots + horizon + 1)``: the road is sampled
every 2 m, so this bounds its arrays (and the terrain generator's search along it)."""

#: Upper bounds of the real fields (mu, eta and lam have their own checks); lengths not listed here are bounded
#: by MAX_LENGTH.
_UPPER = {"v_max": (MAX_SPEED, "m/s"), "target_speed": (MAX_SPEED, "m/s"), "w_max": (MAX_TURN_RATE, "rad/s"),
          "delta": (MAX_DELTA, "s")}
_POSITIVE = ("v_max", "w_max", "altitude", "delta", "eta", "lam", "d_safe1", "d_safe2", "r1", "r2",
             "min_height", "min_radius", "max_radius", "target_speed", "grid_step")
_NON_NEGATIVE = ("r_u", "road_clearance", "road_max_offset", "road_max_curvature", "target_height", "shadow_margin",
                 "prediction_error")
#: Sharpest random road: a 10 m turn radius (a street corner).
MAX_ROAD_CURVATURE = 0.1
_OPTIONAL = ("max_height", "h_min")
#: Integer fields: (lowest, highest) allowed value.
_INTS = {"horizon": (1, MAX_HORIZON), "n_slots": (1, MAX_N_SLOTS), "n_polytopes": (0, MAX_N_POLYTOPES),
         "min_vertices": (3, MAX_VERTICES), "max_vertices": (3, MAX_VERTICES), "n_uavs": (1, MAX_N_UAVS)}


def check_coordinates(values, where: str) -> np.ndarray:
    """``values`` as a float array, every entry finite and within +-MAX_COORDINATE (m); otherwise a ValueError
    starting with ``where`` that names the first offending entry, its value and the bound. Callers check the shape
    and the types they accept first (this only takes numbers)."""
    a = np.asarray(values, dtype=float)
    bad = ~(np.abs(a) <= MAX_COORDINATE)          # NaN compares False: caught here too
    if bad.any():
        idx = np.unravel_index(int(np.argmax(bad)), a.shape) if a.ndim else ()
        at = "[" + ", ".join(str(int(i)) for i in idx) + "]" if idx else ""
        raise ValueError(f"{where}{at} = {float(a[idx])!r} must be a finite coordinate within +-{MAX_COORDINATE:g} m "
                         f"(1,000 km of the origin); shift the scene towards the origin")
    return a


def _as_int(name: str, v: Any, low: int, high: int) -> int:
    # numpy integers are counts too (operator.index accepts them); floats are not, even 3.0: a float
    # count is a computed value the caller should round deliberately, not one to truncate silently.
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise ValueError(f"Config.{name} must be an integer >= {low} and <= {high}, got {short_repr(v)} "
                         f"({type(v).__name__}); counts must be whole numbers (int or a numpy integer)")
    v = operator.index(v)
    if not low <= v <= high:
        raise ValueError(f"Config.{name} must be an integer >= {low} and <= {high}, got {v!r}")
    return v


def _as_float(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
        raise ValueError(f"Config.{name} must be a finite number, got {short_repr(v)} ({type(v).__name__})")
    return float(v)


def _normalise(c: Config) -> None:
    """Check every field's type and store it as a plain int / float (numpy scalars included)."""
    for name, (low, high) in _INTS.items():
        object.__setattr__(c, name, _as_int(name, getattr(c, name), low, high))
    for name in _POSITIVE + _NON_NEGATIVE + ("mu",):
        object.__setattr__(c, name, _as_float(name, getattr(c, name)))
    for name in _OPTIONAL:
        if getattr(c, name) is not None:
            object.__setattr__(c, name, _as_float(name, getattr(c, name)))


def _validate(c: Config) -> None:
    _normalise(c)
    for name in _POSITIVE:
        if getattr(c, name) <= 0:
            raise ValueError(f"Config.{name} must be > 0, got {getattr(c, name)!r}")
    for name in _NON_NEGATIVE:
        if getattr(c, name) < 0:
            raise ValueError(f"Config.{name} must be >= 0, got {getattr(c, name)!r}")
    for name in _POSITIVE + _NON_NEGATIVE + _OPTIONAL:
        if name in ("eta", "lam"):
            continue
        bound, unit = _UPPER.get(name, (MAX_LENGTH, "m"))
        v = getattr(c, name)
        if v is not None and v > bound:
            raise ValueError(f"Config.{name} must be <= {bound:g} {unit}, got {v!r}")
    for name in ("eta", "lam"):
        # The stage cost multiplies them (lambda * eta * |d alpha|): beyond this it overflows to inf.
        if getattr(c, name) > MAX_WEIGHT:
            raise ValueError(f"Config.{name} must be <= {MAX_WEIGHT:g}, got {getattr(c, name)!r}")
    if not 0 < c.mu < 2 * math.pi:
        raise ValueError(f"Config.mu must lie in (0, 2*pi), got {c.mu!r}")
    if c.r1 >= c.r2:
        raise ValueError(f"Config.r1 must be < Config.r2 (got r1={c.r1!r}, r2={c.r2!r})")
    if 2 * c.r_u >= c.r2 - c.r1:
        raise ValueError(
            f"Config.r_u must be < (r2 - r1) / 2 = {(c.r2 - c.r1) / 2:g} or the eroded zone is empty, got {c.r_u!r}")
    if not c.road_max_curvature <= MAX_ROAD_CURVATURE:
        raise ValueError(f"Config.road_max_curvature must be in [0, {MAX_ROAD_CURVATURE:g}] (1/m: a turn radius of at "
                         f"least {1 / MAX_ROAD_CURVATURE:g} m), got {c.road_max_curvature!r}")
    if c.prediction_error > c.target_speed * c.delta:
        raise ValueError(f"Config.prediction_error must be in [0, target_speed * delta = {c.target_speed * c.delta:g}] "
                         f"(m; larger speed noise would make the target reverse), got {c.prediction_error!r}")
    if c.min_vertices > c.max_vertices:
        raise ValueError(f"Config.min_vertices must be <= max_vertices ({c.max_vertices}), got {c.min_vertices}")
    if c.min_radius > c.max_radius:
        raise ValueError(f"Config.min_radius must be <= max_radius ({c.max_radius:g}), got {c.min_radius:g}")
    if c.target_height >= c.altitude:
        raise ValueError(f"Config.target_height must be in [0, altitude={c.altitude:g}), got {c.target_height!r}")
    if c.max_height is not None:
        if not c.min_height <= c.max_height < c.altitude:
            raise ValueError(f"Config.max_height must be None or in [min_height={c.min_height:g}, "
                             f"altitude={c.altitude:g}), got {c.max_height!r}")
    elif c.min_height > c.max_polytope_height:
        raise ValueError(f"Config.min_height must be <= altitude - d_safe2 = {c.max_polytope_height:g}, "
                         f"got {c.min_height!r}")
    if c.h_min is not None and not c.target_height < c.h_min < c.altitude:
        raise ValueError(f"Config.h_min must be None or in (target_height={c.target_height:g}, "
                         f"altitude={c.altitude:g}), got {c.h_min!r}")
    _check_sizes(c)
    _check_terrain(c)
    _check_zone(c)


def _check_sizes(c: Config) -> None:
    route = c.target_speed * c.delta * (c.n_slots + c.horizon + 1)
    if route > MAX_ROUTE:
        raise ValueError(f"Config: the target's route target_speed * delta * (n_slots + horizon + 1) = "
                         f"{c.target_speed:g} * {c.delta:g} * {c.n_slots + c.horizon + 1} = {route:.4g} m exceeds "
                         f"{MAX_ROUTE:g} m; reduce target_speed, delta or n_slots")
    size = lattice_size(c.r1, c.r2, c.mu, c.grid_step)
    if size > MAX_LATTICE:
        raise ValueError(f"Config: the waypoint lattice would have {size:.4g} nodes (r1={c.r1:g}, r2={c.r2:g}, "
                         f"mu={c.mu:g}, grid_step={c.grid_step:g}), more than {MAX_LATTICE}; increase grid_step "
                         f"or reduce r2 or mu")


#: Road the scenario constructors lay before the target's start and after its last slot (m).
SCENE_ROAD_LEAD_IN = 140.0
SCENE_ROAD_TAIL = 60.0


def scene_road_length(c: Config) -> float:
    """Length (m) of the road of :meth:`Scenario.paper` / :meth:`Scenario.random`: a lead-in, the
    target's route ``target_speed * delta * (n_slots + horizon + 1)`` and a tail (960 m by default)."""
    return SCENE_ROAD_LEAD_IN + c.target_speed * c.delta * (c.n_slots + c.horizon + 1) + SCENE_ROAD_TAIL


def polytope_capacity(c: Config, road_length: float | None = None) -> float:
    """An upper estimate of how many random polytopes fit beside a road (default: the scenario road).

    Every random footprint lies within ``rho = max(road_max_offset, road_clearance + 2 max_radius)`` of
    the centreline and at least ``road_clearance`` from it, so all of them lie in a band of area at most
    ``2 (rho - road_clearance) L + pi rho^2``. Each takes, on average, its area (a k-gon inscribed in an
    ellipse of semi-axes r and 0.8 r, k and r uniform in their ranges) plus a 1 m margin (half the 2 m
    street to its neighbours). The band's area over that mean is the estimate: more cannot fit; the
    generator's rejection sampling fills well under it (about half reliably, see ``n_polytopes``)."""
    length = scene_road_length(c) if road_length is None else road_length
    rho = max(c.road_max_offset, c.road_clearance + 2 * c.max_radius)
    band = 2 * (rho - c.road_clearance) * length + math.pi * rho * rho
    ks = range(c.min_vertices, c.max_vertices + 1)
    area_k = sum(k / 2 * math.sin(2 * math.pi / k) for k in ks) / len(ks)       # k-gon in a unit circle
    perim_k = sum(2 * k * math.sin(math.pi / k) for k in ks) / len(ks)
    lo, hi = c.min_radius, c.max_radius
    r1 = (lo + hi) / 2
    r2 = (lo * lo + lo * hi + hi * hi) / 3                                      # E[r^2], r ~ U(lo, hi)
    mean = 0.8 * area_k * r2 + 0.9 * perim_k * r1 * 1.0 + math.pi * 1.0
    return band / mean


def _check_terrain(c: Config) -> None:
    """The random terrain must fit beside the scenario road (see ``max_radius`` and ``n_polytopes``)."""
    length = scene_road_length(c)
    if c.max_radius > length / 2:
        raise ValueError(f"Config.max_radius must be <= half the scenario road's length ({length:g} m: lead-in, "
                         f"route and tail) = {length / 2:g} m, got {c.max_radius!r}; random footprints line the "
                         f"road, one larger than it leaves no room for the others")
    if c.n_polytopes:
        cap = polytope_capacity(c, length)
        if c.n_polytopes > cap:
            raise ValueError(f"Config.n_polytopes={c.n_polytopes} cannot fit beside the {length:g} m scenario road: "
                             f"the band within road_max_offset / road_clearance + 2 max_radius of it holds at most "
                             f"about {int(cap)} footprints of radius {c.min_radius:g}-{c.max_radius:g} m (and the "
                             f"generator reliably places about half that); reduce n_polytopes or max_radius, or "
                             f"raise road_max_offset")


def _check_zone(c: Config) -> None:
    """The eroded zone must hold a lattice node (the waypoint actions, the DP's states), and room for the
    team's starts: ``n_uavs`` nodes at least ``d_safe1`` apart (see :meth:`Scenario.sample_starts`)."""
    nodes, spread = zone_capacity(c.r1, c.r2, c.mu, c.grid_step, c.r_u, c.d_safe1, c.n_uavs)
    zone = f"r1={c.r1:g}, r2={c.r2:g}, mu={c.mu:g}, r_u={c.r_u:g}, grid_step={c.grid_step:g}"
    if nodes == 0:
        raise ValueError(f"Config: the eroded feasible zone ({zone}) holds no waypoint lattice node; "
                         f"increase mu or r2 - r1, or reduce grid_step or r_u")
    if spread < c.n_uavs:
        raise ValueError(f"Config: the eroded feasible zone ({zone}) has room for only {spread} start(s) "
                         f"d_safe1={c.d_safe1:g} m apart (of {nodes} lattice nodes), but n_uavs={c.n_uavs}; "
                         f"reduce n_uavs or d_safe1, or enlarge the zone")
