"""The road and the target driving along it (paper §2.1): q[k], phi[k] and their predictions.

The target follows a known route (a polyline) at a speed profile. The planner at slot k sees the
predicted positions q[k+1..k+N]; the prediction error is bounded by a disk gamma(q) of radius r_u
(eq. 5), which the feasible zone absorbs by erosion (see :mod:`covert_env.geometry.zone`).

By default the prediction is the truth (the paper's setting). :meth:`TargetTrack.with_speed_noise`
makes a track whose true speed deviates from the nominal profile the tracker assumes, within a bound
on the prediction error (docs/decisions/model.md#prediction-error).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np
from shapely.geometry import LineString

from covert_env.world.config import MAX_HORIZON, MAX_N_SLOTS, MAX_ROUTE, MAX_SPEED, check_coordinates, short_repr

__all__ = ["Road", "TargetTrack", "arc_lengths", "cumulative_lengths", "headings_along", "points_along",
           "points_along_rows", "segments_at", "speed_noise_offsets"]


_MAX_POINTS = 1_000_000
"""Most points Road.random samples (a 2,000 km road at the default 2 m step)."""


def _bad_real(v) -> bool:
    """Not a finite real number (bools are not numbers here: True as a length is a mistake)."""
    return isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v)


def _numbers(v, where: str) -> np.ndarray:
    """``v`` as a float array of finite numbers (ints and floats; no bools, strings or NaN)."""
    a = np.asarray(v)
    if a.dtype.kind not in "iuf":
        raise TypeError(f"{where} must be numbers, got {short_repr(v)}")
    a = a.astype(float, copy=False)
    if not np.isfinite(a).all():
        raise ValueError(f"{where} must be finite, got {short_repr(v)}")
    return a


def _arc_lengths(s, where: str) -> np.ndarray:
    return _numbers(s, f"{where}: arc length s")


def _slots(k, where: str) -> np.ndarray:
    """Slot indices as an integer array (ints or numpy integers; no floats, bools or strings)."""
    a = np.asarray(k)
    if a.dtype.kind not in "iu":
        raise TypeError(f"{where}: slot k must be an integer or an integer array, got {short_repr(k)}")
    return a


def _fractions(f, where: str) -> np.ndarray:
    """Fractions of a slot, each in [0, 1]."""
    a = _numbers(f, f"{where}: fractions")
    if ((a < 0) | (a > 1)).any():
        raise ValueError(f"{where}: fractions must lie in [0, 1] (of a slot), got {short_repr(f)}")
    return a


def _check_prediction(k, horizon, where: str) -> None:
    """A prediction's slot ``k`` (an integer >= -1: -1 predicts slot 0 before the episode starts) and ``horizon``
    (an integer in [0, MAX_HORIZON])."""
    for name, v, low, high in (("k", k, -1, None), ("horizon", horizon, 0, MAX_HORIZON)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low or (high is not None and v > high):
            allowed = f"in [{low}, {high}]" if high is not None else f">= {low}"
            raise ValueError(f"{where}: {name} must be an integer {allowed}, got {short_repr(v)}")



def _generator(seed, where: str) -> np.random.Generator:
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: seed must be None, an integer >= 0 or a numpy Generator, got {short_repr(seed)} "
                         f"({exc})") from None


def cumulative_lengths(points: np.ndarray) -> np.ndarray:
    """(..., K) arc length at each vertex of polylines ``points`` (..., K, 2) (many roads at once)."""
    step = np.linalg.norm(np.diff(points, axis=-2), axis=-1)
    return np.concatenate([np.zeros(step.shape[:-1] + (1,)), np.cumsum(step, axis=-1)], axis=-1)


def _segment_at(cumulative: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The segment index of arc lengths ``s`` (clamped to the road) and the clamped ``s``: one road (K,) and any
    ``s``, or N roads (N, K) and ``s`` (N, ...) (a guess from the mean spacing, walked to searchsorted's index)."""
    cl = cumulative
    if cl.ndim == 1:
        s = np.clip(s, 0.0, cl[-1])
        return np.clip(np.searchsorted(cl, s, side="right") - 1, 0, len(cl) - 2), s
    s = np.clip(s, 0.0, cl[:, -1].reshape((-1,) + (1,) * (s.ndim - 1)))
    flat = s.reshape(len(cl), -1)
    # A guess from the mean vertex spacing, moved until cl[i] <= s < cl[i + 1] (the last index with cl <= s, as
    # searchsorted finds it): a few passes on roads of near-uniform spacing (the generator's), at most K on any.
    last = cl.shape[-1] - 1
    step = np.maximum(cl[:, -1:] / max(last, 1), 1e-300)
    i = np.clip((flat / step).astype(np.intp), 0, last)
    while True:
        high = np.take_along_axis(cl, i, axis=1) > flat
        if not high.any():
            break
        i -= high
    while True:
        low = (i < last) & (np.take_along_axis(cl, np.minimum(i + 1, last), axis=1) <= flat)
        if not low.any():
            break
        i += low
    return np.clip(i, 0, last - 1).reshape(s.shape), s


def segments_at(cumulative: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The segment index (..., int) of arc lengths ``s`` (clamped to the road) along one road (K,) or N roads
    (N, K) with ``s`` (N, ...): the segment :func:`points_along` interpolates on."""
    return _segment_at(cumulative, s)[0]


def _gather(a: np.ndarray, i: np.ndarray, batched: bool) -> np.ndarray:
    """``a[i]`` for one road (``a`` (K, ...)), or row by row for N roads (``a`` (N, K, ...), ``i`` (N, ...))."""
    if not batched:
        return a[i]
    flat = i.reshape(len(a), -1).reshape((len(a), -1) + (1,) * (a.ndim - 2))
    return np.take_along_axis(a, flat, axis=1).reshape(i.shape + a.shape[2:])


def points_along(points: np.ndarray, cumulative: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Positions (..., 2) at arc lengths ``s`` (clamped) along a road (:meth:`Road.point_at`), or along N roads
    ``points`` (N, K, 2) with ``cumulative`` (N, K) and ``s`` (N, ...) (the scene pool's tracks)."""
    i, s = _segment_at(cumulative, s)
    many = cumulative.ndim == 2
    lo, hi = _gather(cumulative, i, many), _gather(cumulative, i + 1, many)
    t = ((s - lo) / (hi - lo))[..., None]
    return _gather(points, i, many) * (1 - t) + _gather(points, i + 1, many) * t


def points_along_rows(points: np.ndarray, cumulative: np.ndarray, last: np.ndarray, rows: np.ndarray,
                      s: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """Positions (B, S, 2) at arc lengths ``s`` (B, S) along road ``rows[b]`` of padded road rows ``points``
    (R, K, 2), ``cumulative`` (R, K), whose last vertex is ``last[r]``: :meth:`Road.point_at` of each row's road,
    bit for bit (the same clamp, segment and interpolation), without gathering whole roads (the vector env's target
    between slot times). ``guess`` (B, 1) or (B, S): a segment index to walk from, e.g. the segment of the slot's
    start; the walk takes a few steps when the guess is a few vertices off."""
    s = np.asarray(s, dtype=np.float64)
    rows = np.asarray(rows, dtype=np.int64)
    guess = np.ascontiguousarray(guess, dtype=np.int64)
    if s.ndim != 2 or rows.shape != s.shape[:1] or guess.shape not in ((len(s), 1), s.shape):
        raise ValueError(f"points_along_rows: s must be (B, S), rows (B,) and guess (B, 1) or (B, S); got "
                         f"{s.shape}, {rows.shape}, {np.shape(guess)}")
    n_rows, k = np.shape(cumulative)
    if np.shape(points) != (n_rows, k, 2) or np.shape(last) != (n_rows,):
        raise ValueError(f"points_along_rows: points must be (R, K, 2) and last (R,) with cumulative (R, K) "
                         f"{(n_rows, k)}; got {np.shape(points)}, {np.shape(last)}")
    # The kernel checks no bounds: every index it reads is checked here.
    last = np.ascontiguousarray(last, dtype=np.int64)
    if len(rows) and (rows.min() < 0 or rows.max() >= n_rows):
        raise ValueError(f"points_along_rows: rows must lie in [0, {n_rows}), got {rows.min()} to {rows.max()}")
    ends = last[rows]
    if len(ends) and (ends.min() < 1 or ends.max() >= k):
        raise ValueError(f"points_along_rows: the rows' last vertices must lie in [1, {k - 1}], got {ends.min()} to "
                         f"{ends.max()}")
    out = np.empty(s.shape + (2,))
    _points_along_rows(np.ascontiguousarray(points, dtype=np.float64),
                       np.ascontiguousarray(cumulative, dtype=np.float64), last, np.ascontiguousarray(rows),
                       np.ascontiguousarray(s), guess, out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _points_along_rows(points, cumulative, last, rows, s, guess, out):  # pragma: no cover
    """:func:`points_along_rows` into ``out``, one sample at a time: the clamp, the walk to the last vertex with
    ``cumulative <= s`` (searchsorted's, as :func:`_segment_at` finds it) and the interpolation, each written as
    the numpy expression of :meth:`Road.point_at` (no fused multiply-add), so the result is bit for bit the same."""
    one_guess = guess.shape[1] == 1
    for b in range(s.shape[0]):
        r = rows[b]
        end = last[r]
        cl = cumulative[r]
        for j in range(s.shape[1]):
            x = s[b, j]
            x = x if x >= 0.0 else 0.0                      # np.maximum(s, 0.0), then np.minimum(., end)
            x = x if x <= cl[end] else cl[end]
            i = min(max(guess[b, 0 if one_guess else j], 0), end)
            while i > 0 and cl[i] > x:
                i -= 1
            while i < end and cl[i + 1] <= x:
                i += 1
            i = min(max(i, 0), end - 1)
            t = (x - cl[i]) / (cl[i + 1] - cl[i])
            for c in range(2):
                out[b, j, c] = points[r, i, c] * (1 - t) + points[r, i + 1, c] * t


def headings_along(points: np.ndarray, cumulative: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Headings (rad, the tangent) at arc lengths ``s`` along one road or N roads, as :func:`points_along`."""
    i, _ = _segment_at(cumulative, s)
    many = cumulative.ndim == 2
    d = _gather(points, i + 1, many) - _gather(points, i, many)
    return np.arctan2(d[..., 1], d[..., 0])


def arc_lengths(speeds: np.ndarray, delta: float, s0: float) -> np.ndarray:
    """(n + 1,) the target's arc length at slots 0..n driving ``speeds`` (n,) from ``s0`` (:attr:`TargetTrack.arc`)."""
    return s0 + np.concatenate([[0.0], np.cumsum(speeds * delta)])


@dataclass(frozen=True, eq=False)
class Road:
    """A road centreline: a polyline parametrised by arc length.

    Attributes:
        points: (K, 2) vertices, K >= 2, consecutive points distinct.
    """

    points: np.ndarray

    def __post_init__(self) -> None:
        if np.asarray(self.points).dtype.kind not in "iuf":
            raise ValueError(f"Road.points must be a (K, 2) array of numbers (int or float), got "
                             f"{short_repr(self.points)}")
        try:
            pts = np.array(self.points, dtype=float)   # a copy: freezing it must not freeze the caller's
        except (TypeError, ValueError) as exc:
            raise ValueError(f"Road.points must be a (K, 2) array of numbers ({exc})") from None
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f"Road.points must be a (K, 2) array with K >= 2, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("Road.points must be finite (no NaN or inf)")
        check_coordinates(pts, "Road.points")
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if np.any(seg <= 1e-9):
            raise ValueError("Road.points: consecutive points must be distinct")
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)

    @classmethod
    def from_points(cls, points) -> Road:
        """A road through the given (K, 2) points, in driving order."""
        return cls(points)

    @classmethod
    def random(cls, seed: int | np.random.Generator | None = None, *, length: float = 900.0,
               start=(120.0, 0.0), heading: float = 0.0, step: float = 2.0,
               max_curvature: float = 1 / 120, straight_start: float = 60.0) -> Road:
        """A random smooth road: heading integrates a smooth random curvature, bounded by ``max_curvature``.

        The first ``straight_start`` metres are straight along ``heading``, so a scenario's UAV
        starts (placed relative to the start pose) sit in the zone regardless of the seed.
        """
        for name, v, low in (("length", length, 0.0), ("step", step, 0.0)):
            if _bad_real(v) or not v > low:
                raise ValueError(f"Road.random: {name} must be a finite number > {low:g}, got {v!r}")
        for name, v in (("max_curvature", max_curvature), ("straight_start", straight_start)):
            if _bad_real(v) or v < 0:
                raise ValueError(f"Road.random: {name} must be a finite number >= 0, got {v!r}")
        if _bad_real(heading):
            raise ValueError(f"Road.random: heading must be a finite number (rad), got {heading!r}")
        if length / step > _MAX_POINTS:
            raise ValueError(f"Road.random: length / step = {length:g} / {step:g} would give more than "
                             f"{_MAX_POINTS} points; use a shorter road or a larger step")
        if max_curvature > 1.0 or length > MAX_ROUTE or straight_start > length:
            raise ValueError(f"Road.random: max_curvature must be <= 1 (1/m: a turn radius of at least 1 m), length "
                             f"<= {MAX_ROUTE:g} m and straight_start <= length, got max_curvature={max_curvature!r}, "
                             f"length={length!r}, straight_start={straight_start!r}")
        try:
            start = np.array(start, dtype=float).reshape(2)
        except (TypeError, ValueError):
            raise ValueError(f"Road.random: start must be a point (x, y), got {start!r}") from None
        if not np.all(np.isfinite(start)):
            raise ValueError(f"Road.random: start must be finite, got {start.tolist()}")
        check_coordinates(start, "Road.random: start")
        rng = _generator(seed, "Road.random")
        n = max(2, int(np.ceil(length / step)) + 1)
        s = np.arange(n) * step
        # Smooth curvature: a few random sinusoids over arc length, scaled into the bound.
        kappa = np.zeros(n)
        for _ in range(4):
            wavelength = rng.uniform(150.0, 600.0)
            kappa += rng.normal() * np.sin(2 * np.pi * s / wavelength + rng.uniform(0, 2 * np.pi))
        kappa *= max_curvature / max(np.abs(kappa).max(), 1e-12) * rng.uniform(0.4, 1.0)
        kappa *= np.clip((s - straight_start) / 40.0, 0.0, 1.0)   # ease in after the straight start
        th = heading + np.concatenate([[0.0], np.cumsum(kappa[:-1] * step)])
        xy = start + np.concatenate(
            [[[0.0, 0.0]], np.cumsum(step * np.column_stack([np.cos(th[:-1]), np.sin(th[:-1])]), axis=0)])
        return cls(xy)

    # ------------------------------------------------------------------ arc-length queries
    @cached_property
    def cumulative_length(self) -> np.ndarray:
        """(K,) arc length at each vertex."""
        return cumulative_lengths(self.points)

    @property
    def length(self) -> float:
        return float(self.cumulative_length[-1])

    @cached_property
    def linestring(self) -> LineString:
        return LineString(self.points)

    def point_at(self, s) -> np.ndarray:
        """Position(s) at arc length ``s`` (clamped to [0, length]); shape (..., 2)."""
        return points_along(self.points, self.cumulative_length, _arc_lengths(s, "Road.point_at"))

    def heading_at(self, s) -> np.ndarray:
        """Heading(s) phi (rad, the road tangent) at arc length ``s``."""
        return headings_along(self.points, self.cumulative_length, _arc_lengths(s, "Road.heading_at"))

    def pose_at(self, s: float) -> tuple[np.ndarray, float]:
        """``(point_at(s), heading_at(s))`` for one float ``s`` with one lookup (the terrain generator's
        inner loop calls it per candidate; same arithmetic as the vectorised methods)."""
        cl = self.cumulative_length
        s = min(max(float(s), 0.0), float(cl[-1]))
        i = min(max(int(np.searchsorted(cl, s, side="right")) - 1, 0), len(cl) - 2)
        a, b = self.points[i], self.points[i + 1]
        t = (s - cl[i]) / (cl[i + 1] - cl[i])
        d = b - a
        return a * (1 - t) + b * t, float(np.arctan2(d[1], d[0]))

    def distance_to(self, xy) -> np.ndarray:
        """Horizontal distance(s) from point(s) ``xy`` (..., 2) to the centreline (vectorised)."""
        xy = _numbers(xy, "Road.distance_to: xy")
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise ValueError(f"Road.distance_to: xy must be points (..., 2), got shape {xy.shape}")
        a, b = self.points[:-1], self.points[1:]
        ab = b - a
        ap = xy[..., None, :] - a
        t = np.clip(np.einsum("...sk,sk->...s", ap, ab) / np.einsum("sk,sk->s", ab, ab), 0, 1)
        return np.linalg.norm(ap - t[..., None] * ab, axis=-1).min(axis=-1)

    def to_json(self) -> dict:
        return {"points": self.points.tolist()}


@dataclass(frozen=True, eq=False)
class TargetTrack:
    """The target's motion along a road: positions q[k] and headings phi[k] for every slot.

    Attributes:
        road: the route.
        speeds: (n,) speed (m/s) during each slot k -> k+1 (the speed profile), n >= number of slots.
        delta: slot length (s).
        z: height z_q of the filmed point (m).
        s0: arc length where the target is at slot 0.
        nominal_speeds: (n,) the speed profile a tracker assumes when it predicts (:meth:`predict`);
            None (default) means ``speeds``: the prediction is the truth. Built by
            :meth:`with_speed_noise`.
    """

    road: Road
    speeds: np.ndarray
    delta: float = 1.0
    z: float = 1.5
    s0: float = 0.0
    nominal_speeds: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.road, Road):
            raise TypeError(f"TargetTrack.road must be a Road, got {type(self.road).__name__}")
        try:
            sp = np.atleast_1d(np.array(self.speeds, dtype=float))
            if np.asarray(self.speeds).dtype.kind not in "iuf":
                raise TypeError("not numbers")
        except (TypeError, ValueError):
            sp = np.array([np.nan])                 # reported below, with the other malformed speeds
        if sp.ndim != 1 or len(sp) == 0 or not np.all(np.isfinite(sp)) or np.any(sp < 0) or np.any(sp > MAX_SPEED):
            raise ValueError(f"TargetTrack.speeds must be a non-empty 1-D array of numbers in [0, {MAX_SPEED:g}] "
                             f"(m/s), got {short_repr(self.speeds)}")
        if _bad_real(self.delta) or not self.delta > 0:
            raise ValueError(f"TargetTrack.delta must be a finite number > 0 (s), got {self.delta!r}")
        for name in ("z", "s0"):
            if _bad_real(getattr(self, name)):
                raise ValueError(f"TargetTrack.{name} must be a finite number (m), got {getattr(self, name)!r}")
        sp.setflags(write=False)
        object.__setattr__(self, "speeds", sp)
        if self.nominal_speeds is not None:
            try:
                nom = np.array(self.nominal_speeds, dtype=float)
            except (TypeError, ValueError):
                nom = np.array([np.nan])
            if nom.shape != sp.shape or not np.all(np.isfinite(nom)) or np.any(nom < 0):
                raise ValueError(f"TargetTrack.nominal_speeds must be None or {len(sp)} finite speeds >= 0 "
                                 f"(one per slot, like speeds), got {short_repr(self.nominal_speeds)}")
            nom.setflags(write=False)
            object.__setattr__(self, "nominal_speeds", nom)

    @classmethod
    def constant(cls, road: Road, speed: float, n_slots: int, *, delta: float = 1.0, z: float = 1.5,
                 s0: float = 0.0) -> TargetTrack:
        """A target at constant ``speed`` for ``n_slots`` slots."""
        # The bounds of Config: n_slots + horizon + 1 slots of at most MAX_N_SLOTS + MAX_HORIZON + 1, over a
        # route of at most MAX_ROUTE metres (the arrays are per slot; a typo must not be a MemoryError).
        most = 2 * MAX_N_SLOTS
        if isinstance(n_slots, bool) or not isinstance(n_slots, (int, np.integer)) or not 1 <= n_slots <= most:
            raise ValueError(f"TargetTrack.constant: n_slots must be an integer >= 1 and <= {most}, "
                             f"got {short_repr(n_slots)}")
        if _bad_real(speed) or speed < 0:
            raise ValueError(f"TargetTrack.constant: speed must be a finite number >= 0 (m/s), got {speed!r}")
        if _bad_real(delta) or not delta > 0:
            raise ValueError(f"TargetTrack.constant: delta must be a finite number > 0 (s), got {delta!r}")
        if speed * delta * n_slots > MAX_ROUTE:
            raise ValueError(f"TargetTrack.constant: the route speed * delta * n_slots = {speed:g} * {delta:g} * "
                             f"{int(n_slots)} = {speed * delta * n_slots:.4g} m exceeds {MAX_ROUTE:g} m; use fewer "
                             f"slots or a lower speed")
        return cls(road, np.full(int(n_slots), float(speed)), delta=delta, z=z, s0=s0)

    def with_speed_noise(self, bound: float, seed=None) -> TargetTrack:
        """The same nominal track driven with bounded speed noise: the true target of a prediction error.

        ``bound`` (m) bounds ``|true - predicted|`` along the road for every slot a prediction covers,
        when predictions start from the true current position (:meth:`predict`). See
        :func:`speed_noise_offsets` for the model. ``bound == 0`` returns ``self`` (the truth is the
        prediction, bit for bit).
        """
        most = float(self.speeds.max()) * self.delta
        if _bad_real(bound) or not 0 <= bound <= most:
            raise ValueError(f"TargetTrack.with_speed_noise: bound must be a number in [0, max(speeds) * delta = "
                             f"{most:g}] (m; larger noise would make the target reverse), got {bound!r}")
        if bound == 0:
            return self
        rng = _generator(seed, "TargetTrack.with_speed_noise")
        e = speed_noise_offsets(self.speeds * self.delta, float(bound), rng)
        true = self.speeds + np.diff(e) / self.delta
        return TargetTrack(self.road, np.maximum(true, 0.0), delta=self.delta, z=self.z, s0=self.s0,
                           nominal_speeds=self.speeds)

    @property
    def exact(self) -> bool:
        """True when the prediction is the truth (no :attr:`nominal_speeds`)."""
        return self.nominal_speeds is None

    @cached_property
    def arc(self) -> np.ndarray:
        """(n + 1,) arc length at slots 0..n."""
        return arc_lengths(self.speeds, self.delta, self.s0)

    @property
    def n_slots(self) -> int:
        return len(self.speeds)

    @cached_property
    def positions(self) -> np.ndarray:
        """(n + 1, 3) q[k] for every slot k = 0..n (read-only)."""
        xy = self.road.point_at(self.arc)
        out = np.column_stack([xy, np.full(len(xy), self.z)])
        out.setflags(write=False)
        return out

    @cached_property
    def headings(self) -> np.ndarray:
        """(n + 1,) phi[k] for every slot (read-only)."""
        out = self.road.heading_at(self.arc)
        out.setflags(write=False)
        return out

    def position(self, k) -> np.ndarray:
        """q[k] as (x, y, z); k may be an int or an integer array (clamped to the track's end)."""
        if isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            return self.positions[min(max(int(k), 0), self.n_slots)].copy()
        return self.positions[np.clip(_slots(k, "TargetTrack.position"), 0, self.n_slots)]

    def position_between(self, k: int, fractions) -> np.ndarray:
        """Target positions (len(fractions), 3) at times (k + f) delta within slot k, f in [0, 1].

        ``k`` may also be an integer array (..., ): the result is then (..., len(fractions), 3).
        """
        if isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            k = min(max(int(k), 0), self.n_slots - 1)
        else:
            k = np.clip(_slots(k, "TargetTrack.position_between"), 0, self.n_slots - 1)
        f = _fractions(fractions, "TargetTrack.position_between")
        key = f.tobytes()
        table = self._between.get(key)
        if table is None:   # one road lookup per set of fractions, for every slot at once
            s = self.arc[:-1, None] + f * np.diff(self.arc)[:, None]
            xy = self.road.point_at(s)
            table = np.concatenate([xy, np.full(xy.shape[:-1] + (1,), self.z)], axis=-1)
            table.setflags(write=False)
            self._between[key] = table
        return table[k]

    @cached_property
    def _between(self) -> dict:
        return {}

    def heading(self, k) -> np.ndarray | float:
        """phi[k], the road tangent at the target's position (rad)."""
        if isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            return float(self.headings[min(max(int(k), 0), self.n_slots)])
        return self.headings[np.clip(_slots(k, "TargetTrack.heading"), 0, self.n_slots)]

    def _predicted_arc(self, k: int, horizon: int) -> np.ndarray:
        """(horizon + 1,) arc lengths a tracker at slot k expects at slots k..k+horizon: the true current
        position, then the nominal speeds (clamped to the track's end, like :meth:`position`)."""
        k = min(max(int(k), 0), self.n_slots)
        nom = self.nominal_speeds[k:k + horizon]
        ahead = np.concatenate([[0.0], np.cumsum(nom * self.delta)])
        ahead = np.concatenate([ahead, np.full(horizon + 1 - len(ahead), ahead[-1])])
        return self.arc[k] + ahead

    def predict(self, k: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """Predicted (q, phi) for slots k+1..k+horizon: arrays (horizon, 3) and (horizon,).

        The route and speed profile are known (paper §2.1). Without prediction error (:attr:`exact`)
        the prediction is the track itself. Otherwise it is what a tracker that sees the target now
        predicts: the true position at slot k, driven ahead at the nominal speeds; it then differs from
        the truth by at most the bound of :meth:`with_speed_noise`, which an eroded zone with r_u >= that
        bound absorbs (eq. 5).
        """
        _check_prediction(k, horizon, "TargetTrack.predict")
        if self.exact:
            ks = np.arange(k + 1, k + horizon + 1)
            return self.position(ks), np.asarray(self.heading(ks))
        s = self._predicted_arc(k, horizon)[1:]
        xy = self.road.point_at(s)
        return np.column_stack([xy, np.full(len(s), self.z)]), self.road.heading_at(s)

    def predict_between(self, k: int, horizon: int, fractions) -> np.ndarray:
        """Predicted target positions (horizon, len(fractions), 3) within slots k..k+horizon-1, made at
        slot k: the :meth:`position_between` of the prediction (the track itself when :attr:`exact`)."""
        _check_prediction(k, horizon, "TargetTrack.predict_between")
        if self.exact:
            return self.position_between(np.arange(k, k + horizon), fractions)
        s = self._predicted_arc(k, horizon)
        f = _fractions(fractions, "TargetTrack.predict_between")
        xy = self.road.point_at(s[:-1, None] + f * np.diff(s)[:, None])
        return np.concatenate([xy, np.full(xy.shape[:-1] + (1,), self.z)], axis=-1)

    def predicted_ahead(self, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """((n + 1, horizon, 3), (n + 1, horizon)): row k is :meth:`predict` ``(k, horizon)``, for every slot
        k = 0..n at once (clamped at the track's end, like :meth:`predict`). Without prediction error the rows are
        the track's own slots, bit for bit; otherwise equal to :meth:`predict` up to rounding (the nominal arc is
        summed once for the whole track here, per prediction there)."""
        _check_prediction(0, horizon, "TargetTrack.predicted_ahead")
        k = np.arange(self.n_slots + 1)
        ks = np.minimum(k[:, None] + np.arange(1, horizon + 1), self.n_slots)          # (n + 1, H)
        if self.exact:
            return self.positions[ks], self.headings[ks]
        nominal = np.concatenate([[0.0], np.cumsum(self.nominal_speeds * self.delta)])
        s = self.arc[:, None] + nominal[ks] - nominal[k][:, None]
        xy = self.road.point_at(s.ravel()).reshape(s.shape + (2,))
        q = np.concatenate([xy, np.full(s.shape + (1,), self.z)], axis=-1)
        return q, self.road.heading_at(s.ravel()).reshape(s.shape)

    @cached_property
    def next_predicted(self) -> tuple[np.ndarray, np.ndarray]:
        """((n + 1, 3), (n + 1,)): the target's position and heading at slot k + 1 as predicted at slot k,
        for every k (row n: the track's end). Without prediction error, ``positions[min(k + 1, n)]``."""
        nxt = np.minimum(np.arange(self.n_slots + 1) + 1, self.n_slots)
        if self.exact:
            return self.positions[nxt], self.headings[nxt]
        nom = np.append(self.nominal_speeds, 0.0) * self.delta
        s = self.arc + nom
        xy = self.road.point_at(s)
        q = np.column_stack([xy, np.full(len(s), self.z)])
        phi = self.road.heading_at(s)
        q.setflags(write=False)
        phi.setflags(write=False)
        return q, phi


def speed_noise_offsets(step: np.ndarray, bound: float, rng: np.random.Generator) -> np.ndarray:
    """Offsets e[0..n] (m) of the true arc length from the nominal one: s_true(k) = s_nominal(k) + e(k).

    A bounded random walk (docs/decisions/model.md#prediction-error): e(0) = 0 and

        e(k+1) = clip(e(k) + bound * u(k), -bound / 2, bound / 2),   u(k) ~ U(-1, 1),

    so the true speed is the nominal one plus a noise of at most bound / delta, and because the offset
    stays within +-bound / 2, a prediction made from the true position at any slot k is off by
    |e(k+j) - e(k)| <= bound at every later slot k + j (Euclidean distance <= arc length difference).
    Each step is also kept >= -step(k) (the nominal distance of slot k): the target never reverses.

    Args:
        step: (n,) nominal distance driven in each slot (m).
        bound: the prediction-error bound (m), > 0.
        rng: the noise's generator.
    """
    u = rng.uniform(-1.0, 1.0, len(step))
    e = np.zeros(len(step) + 1)
    half = bound / 2.0
    for k in range(len(step)):   # sequential: each clip depends on the previous offset
        e[k + 1] = min(max(e[k] + bound * u[k], -half, e[k] - step[k]), half)
    return e
