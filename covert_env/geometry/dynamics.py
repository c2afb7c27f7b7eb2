"""UAV kinematics and the turn-then-straight manoeuvre (Almuzaini & Savkin 2024, eqs. 1, 7, 22-29).

Every UAV flies at the fixed altitude h as a unicycle (eq. 1)::

    x' = v cos(theta),   y' = v sin(theta),   theta' = omega,   0 < v <= V_max,   |omega| <= W_max.

Two tools live here:

* :func:`unicycle_arc` integrates the unicycle **exactly** for constant ``(v, omega)``: the path is a
  circular arc (a segment when ``omega = 0``). It is eq. 1's one home: :func:`unicycle_step`,
  :func:`unicycle_path`, :meth:`Manoeuvre.points` and the batched flight of :mod:`covert_env.geometry.flight` all call
  it. The paper's discrete model (eq. 7) is one explicit Euler step; over a whole slot of ``delta = 1 s`` at
  ``omega = 3 rad/s`` that step would put the UAV tens of metres from where the kinematics actually take it,
  so we never use it.
* :func:`solve_manoeuvre` finds, for many (start pose, waypoint) pairs at once, the paper's
  turn-then-straight manoeuvre (eqs. 22-29): turn at ``+-W_max`` with constant speed ``v`` until the
  heading points at the waypoint (the tangent point ``z``), then fly straight to it at the same ``v``,
  arriving exactly at the end of the slot. It returns a :class:`Manoeuvre` (speed, turn side, turn time,
  heading on arrival, feasibility), which :func:`fly_manoeuvre` and :meth:`Manoeuvre.points` fly exactly.

Geometry of the manoeuvre (derived here; the paper's text copy lost its layout)
------------------------------------------------------------------------------------
Work in the UAV frame: start at the origin, heading +x, and mirror y so that the waypoint lies on the
turn side, ``g = (a, b)`` with ``b >= 0``. Turning left at radius ``r = v / W_max`` (eq. 23) goes around
the centre ``c = (0, r)``; after turning by ``tau`` the UAV is at ``z = (r sin tau, r (1 - cos tau))``
with heading ``tau``. ``z`` is the tangent point iff ``g = z + L (cos tau, sin tau)`` with ``L >= 0``.
Writing ``g - c = r e2 + L e1`` with ``e1 = (cos tau, sin tau)`` and the outward radius
``e2 = (sin tau, -cos tau)`` gives

* ``D = |g - c| = sqrt(a^2 + (b - r)^2)`` and ``L = sqrt(D^2 - r^2) = sqrt(|g - p|^2 - 2 b r)``;
* ``tau = (atan2(b - r, a) - arccos(r / D) + pi / 2) mod 2 pi`` (``arccos(r / D)`` is the paper's rho,
  eq. 24: the angle between ``c -> z`` and ``c -> g``).

So this tau **is correct** (docs/model.md#turn-then-straight-manoeuvre-eqs-22-29).
Two remarks: the paper's eq. 28, ``tau = arccos(...)``, only returns
angles in ``[0, pi]``, which is wrong for turns beyond a half circle (possible when ``W_max delta > pi``),
hence the ``mod 2 pi`` form. We do not evaluate that form literally: at ``r = R_c`` (waypoint on the
circle, an end of the root bracket below) ``r / D`` rounds above 1 in about one case in six and
``arccos`` returns NaN, and for small ``b`` it subtracts O(1) terms, so a small tau keeps few correct
digits. Instead we use the equivalent heading vector ``e1 ~ (L a - r (b - r), r (a - L) + L b)`` (solve
the 2x2 system above for ``e1``), with ``a - L = b (2 r - b) / (a + L)`` when ``a > 0``, so that no
terms cancel.

The speed solves eq. 29, arc plus straight equals the distance flown in one slot::

    F(r) = r tau(r) + L(r) - delta W_max r = 0,        v = W_max r.

A root counts only if ``D >= r``, i.e. ``r <= R_c = |g - p|^2 / (2 b)`` (the waypoint is not inside
the turning circle), and ``r <= V_max / W_max``. Since the path is at least ``|g - p|`` long, every root has
``r >= |g - p| / (delta W_max)``.

**Root structure (verified; one root only for waypoints ahead: docs/decisions/flight.md#manoeuvre-speed-root).** With
``h(r) = F(r) / r + delta W_max = tau + L / r`` one finds ``h'(r) = -phi(r) / D^2`` where
``phi(r) = L (L^2 + r b) / r^2 + a``. ``phi`` is strictly decreasing in r, so h is strictly decreasing when
``a >= 0`` (exactly one root, found by bracketing) but, for a waypoint *behind* the UAV (``a < 0``), h
decreases to a minimum at ``phi(r*) = 0`` and then increases, so eq. 29 can have **two** roots. We take
the smaller one, the slowest and therefore shortest and cheapest manoeuvre (the stage cost, eq. 18,
charges the path length ``v delta``); it is the unique root in ``(0, min(r*, R_c, V_max / W_max)]``,
found by a vectorised safeguarded Newton iteration (Newton steps kept inside a shrinking sign-change
bracket, bisection otherwise) with the closed-form derivative
``F'(r) = tau + (L (r - b) - a r) / D^2 - delta W_max``, which stays finite as ``L -> 0``.
With the paper's defaults the second root never matters: when ``W_max delta <= pi`` no waypoint behind
the UAV (``a < 0``) is reachable in one slot by *any* admissible control, since
``|theta(t)| <= W_max t <= pi`` gives ``x(delta) >= (v / W_max) sin(W_max delta) >= 0``. Two roots do
occur for e.g. ``W_max = 5`` (waypoint ``(-6.88, -4.66)`` in the UAV frame).

Turn side (eq. 22): with sigma the bearing of ``g - p`` and theta the heading, the paper turns left for
sigma - theta in (-2 pi, -pi) u (0, pi), right for [-pi, 0) u [pi, 2 pi), and not at all for 0. That is
the sign of ``cross(heading, g - p)``, and a waypoint dead behind (sigma - theta = +-pi, cross = 0) is
taken with a right turn, as the paper states. Conventions (decided): a waypoint dead ahead needs no turn
(``v = |g - p| / delta``); a waypoint equal to the start is infeasible (v must be > 0). Infeasible entries have
NaN in every float field and are never reported feasible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from covert_env.geometry.angles import wrap_heading
from covert_env.geometry.turn_root import root_bracket, solve_turn, turn_angle

__all__ = [
    "Manoeuvre",
    "arc_point",
    "fly_manoeuvre",
    "manoeuvre_controls",
    "manoeuvre_feasible",
    "solve_manoeuvre",
    "unicycle_arc",
    "unicycle_heading",
    "unicycle_path",
    "unicycle_step",
]
# A waypoint whose lateral offset is below this fraction of its distance counts as dead ahead: flying
# straight then misses it by at most 1e-12 of the distance, far below any tolerance that matters.
_STRAIGHT_REL = 1e-12


MIN_GOAL_DISTANCE = 1e-9
"""Goals closer than this (m) to the start count as the start itself: infeasible, since v > 0 (eq. 1).
(Below it the side of the turn is decided by rounding, and mirrored goals would disagree.)"""


def _turn_side(cross):
    """Eq. 22: +1 (left) for a waypoint left of the heading, -1 (right) otherwise.

    ``cross = cross(heading, g - p)`` is > 0 exactly when sigma - theta lies in (0, pi) mod 2 pi, the paper's
    left set; it is 0 at sigma - theta = +-pi (dead behind), which the paper puts in the right set. (Dead
    ahead, also cross = 0, is the no-turn case, set by the caller.)
    """
    return np.where(cross > 0, 1, -1).astype(np.int8)


def _scalar_or_array(a):
    a = np.asarray(a)
    return a[()] if a.ndim == 0 else a


# --------------------------------------------------------------------------------------- unicycle


def unicycle_arc(x, y, theta, v, omega, dt, *, out=None, heading: bool = True):
    """Eq. 1 integrated exactly: the pose after flying constant ``(v, omega)`` for ``dt`` seconds from
    ``(x, y, theta)``.

    ``x' = v cos(theta), y' = v sin(theta), theta' = omega``: the path is a circular arc of radius
    ``v / omega``, whose chord has length ``v dt sinc(omega dt / 2)`` and direction ``theta + omega dt / 2``.
    Writing it with ``sinc(u) = sin(u) / u`` instead of ``(v / omega)(sin(theta + omega dt) - sin(theta))``
    keeps it accurate as ``omega -> 0`` (no 0/0; ``omega = 0`` gives the straight segment). This replaces
    the paper's Euler step (eq. 7), which ignores the heading change within the slot.

    Batch-first: the arguments broadcast against each other (numpy rules), and each factor is evaluated at the
    shape of the arguments it depends on: the chord's ratio at that of ``omega dt``, its direction at that of
    ``theta + omega dt / 2``. So speeds (K, V, 1) against turn rates (K, 1, W) take one sine per turn rate, and a
    straight leg (``omega`` the scalar 0) one sine and cosine per heading, not per time. Every caller gets the
    same bits for the same operands, whatever the batch around them.

    Args:
        x, y: start position (m). theta: start heading (rad, counter-clockwise from +x).
        v: linear speed (m/s). omega: turn rate (rad/s, positive = left). dt: duration (s).
        out: optional ``(x_out, y_out)`` arrays of the broadcast shape that receive the position (large batches
            write their path samples in place instead of through temporaries).
        heading: False skips the heading (None is returned): path samples need only positions, and their
            callers ask :func:`unicycle_heading` for the end heading alone.

    Returns:
        ``(x1, y1, theta1)``: the position, and the heading :func:`unicycle_heading` unwrapped
        (:func:`~covert_env.geometry.angles.wrap_heading` brings it into ``[0, 2 pi)``).
    """
    if np.ndim(omega) == 0 and omega == 0:
        chord = v * dt
        mid = theta + 0.0
    else:
        half = 0.5 * omega * dt
        # sin(half) / half: the exact arc-to-chord ratio, 1 at half = 0. No cancellation near 0 (sin(h) ~ h in
        # floating point too), and several times cheaper than np.sinc on the few-element arrays of an env step.
        straight = half == 0.0
        safe = np.where(straight, 1.0, half)
        ratio = np.sin(safe)
        if np.ndim(ratio):
            ratio /= safe
            ratio[straight] = 1.0
        else:
            ratio = 1.0 if straight else ratio / safe
        chord = _into_first(np.multiply, v * dt, ratio)
        mid = _into_first(np.add, half, theta)          # half is not needed again
    theta1 = unicycle_heading(theta, omega, dt) if heading else None
    if out is None:
        return x + chord * np.cos(mid), y + chord * np.sin(mid), theta1
    for trig, dst, start in ((np.cos, out[0], x), (np.sin, out[1], y)):
        if np.shape(mid) == dst.shape:
            trig(mid, out=dst)
            dst *= chord
        else:                                           # at mid's shape, before broadcasting against the chord
            np.multiply(trig(mid), chord, out=dst)
        dst += start
    return out[0], out[1], theta1


@numba.njit(cache=True, nogil=True)
def arc_point(x, y, theta, v, omega, dt):  # pragma: no cover
    """:func:`unicycle_arc`'s position for one pose, compiled, operation for operation (the same bits: numpy's float64
    sines and cosines are the C library's, as numba's are): what the compiled flights call per sample."""
    half = 0.5 * omega * dt
    ratio = 1.0 if half == 0.0 else np.sin(half) / half
    chord = (v * dt) * ratio
    mid = half + theta
    return x + chord * np.cos(mid), y + chord * np.sin(mid)


def unicycle_heading(theta, omega, dt):
    """The heading part of eq. 1, ``theta' = omega``: ``theta + omega dt``, unwrapped (any broadcast shape).
    :func:`unicycle_arc` returns it with the position; this is it alone, for a slot's end heading."""
    return theta + omega * dt


def _into_first(op, a, b):
    """``op(a, b)`` in ``a``'s memory when ``a`` is an array of the result's shape (commutative ``op`` only)."""
    if isinstance(a, np.ndarray) and a.ndim >= np.ndim(b):
        try:
            return op(a, b, out=a)
        except (ValueError, TypeError):                 # b broadcasts a to a larger shape, or a is not float
            pass
    return op(a, b)


def unicycle_step(x, y, theta, v, omega, dt):
    """Fly the unicycle (eq. 1, :func:`unicycle_arc`) for ``dt`` seconds with constant speed ``v`` and turn rate
    ``omega``.

    Args:
        x, y: start position (m). theta: start heading (rad, counter-clockwise from +x).
        v: linear speed (m/s). omega: turn rate (rad/s, positive = left). dt: duration (s).
        All arguments broadcast against each other (numpy rules).

    Returns:
        ``(x, y, theta)`` after ``dt``, broadcast; theta wrapped into ``[0, 2 pi)``. Scalars for scalar input.
    """
    x, y, theta = np.asarray(x, dtype=float), np.asarray(y, dtype=float), np.asarray(theta, dtype=float)
    v, omega, dt = np.asarray(v, dtype=float), np.asarray(omega, dtype=float), np.asarray(dt, dtype=float)
    x1, y1, th1 = unicycle_arc(x, y, theta, v, omega, dt)
    x1, y1, th1 = np.asarray(x1), np.asarray(y1), np.asarray(wrap_heading(th1))
    if not x1.shape == y1.shape == th1.shape:
        x1, y1, th1 = np.broadcast_arrays(x1, y1, th1)
    if x1.ndim:
        return x1, y1, th1
    return _scalar_or_array(x1), _scalar_or_array(y1), _scalar_or_array(th1)


def unicycle_path(x, y, theta, v, omega, dt, n_points):
    """Poses at ``n_points`` equally spaced times in ``[0, dt]`` along the exact arc of :func:`unicycle_step`.

    Used to check line of sight and separation *between* slot times, where the paper only checks
    the slot end points.

    Returns:
        Array of shape ``(n_points, *batch, 3)`` holding ``(x, y, theta)``; the first entry is the start
        pose (heading wrapped into ``[0, 2 pi)``), the last the pose after ``dt``.
    """
    n_points = int(n_points)
    if n_points < 1:
        raise ValueError(f"unicycle_path: n_points must be >= 1, got {n_points}")
    args = np.broadcast_arrays(*(np.asarray(t, dtype=float) for t in (x, y, theta, v, omega, dt)))
    batch = args[0].shape
    frac = np.linspace(0.0, 1.0, n_points).reshape((n_points,) + (1,) * len(batch))
    x, y, theta, v, omega, dt = args
    xs, ys, ths = unicycle_step(x, y, theta, v, omega, frac * dt)
    return np.stack(np.broadcast_arrays(xs, ys, ths), axis=-1)


# ------------------------------------------------------------------------------------ Manoeuvre


@dataclass(frozen=True, eq=False)
class Manoeuvre:
    """Turn-then-straight manoeuvres for a batch of (start pose, waypoint) pairs (eqs. 22-29).

    Every field has the batch shape (``()`` for a single pair, then numpy scalars). Float fields are NaN
    where ``feasible`` is False.

    Attributes:
        feasible: bool, a manoeuvre with ``0 < v <= v_max`` exists (eq. 29 has a root, the waypoint is not
            inside the turning circle).
        v: speed (m/s) held for the whole slot.
        turn: +1 left (``omega = +W_max``), -1 right, 0 no turn (waypoint dead ahead). 0 where infeasible.
        omega: signed turn rate ``turn * W_max`` (rad/s) during the turn phase.
        turn_time: seconds of turning, ``tau / W_max``, in ``[0, delta]``; the rest of the slot is straight.
        heading_after: heading (rad, ``[0, 2 pi)``) at the waypoint, ``theta + turn * tau``.
        length: path length ``v * delta`` (m), the energy term of the stage cost (eq. 18).
        tangent: ``(..., 2)`` tangent point z (eq. 26) where the turn ends.
        start, theta0, goal: the inputs, broadcast to the batch shape.
        delta: slot length (s).
    """

    feasible: np.ndarray
    v: np.ndarray
    turn: np.ndarray
    omega: np.ndarray
    turn_time: np.ndarray
    heading_after: np.ndarray
    length: np.ndarray
    tangent: np.ndarray
    start: np.ndarray
    theta0: np.ndarray
    goal: np.ndarray
    delta: float

    @property
    def shape(self) -> tuple[int, ...]:
        """Batch shape (``()`` for a single pair)."""
        return np.shape(self.feasible)

    def controls(self):
        """Piecewise-constant controls ``(v, omega, turn_time)``.

        Fly ``(v, omega)`` for ``turn_time`` seconds, then ``(v, 0)`` for ``delta - turn_time``.
        """
        return self.v, self.omega, self.turn_time

    def points(self, n: int = 20, *, by_instant: bool = False) -> np.ndarray:
        """Positions at ``n`` equally spaced times in ``[0, delta]`` along the path (turn, then straight).

        Speed is constant, so the points are also equally spaced in arc length; the first is the start and
        the last the waypoint. Use them to check line of sight and UAV separation between slot times.

        Args:
            n: samples per manoeuvre, >= 1.
            by_instant: lay the samples out instant-major, ``(n, *batch, 2)``: the same numbers, grouped as the
                line-of-sight kernel reads them (every manoeuvre's sample at one instant against the target then),
                without a transposed copy.

        Returns:
            ``(*batch, n, 2)`` array (``(K, n, 2)`` for K pairs), or ``(n, *batch, 2)`` with ``by_instant``; NaN rows
            where infeasible.
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"Manoeuvre.points: n must be >= 1, got {n}")
        t = np.linspace(0.0, self.delta, n)
        parts = [np.asarray(q, dtype=float) for q in (self.v, self.omega, self.turn_time, self.theta0,
                                                      self.heading_after)]
        parts += [self.start[..., 0], self.start[..., 1], self.tangent[..., 0], self.tangent[..., 1]]
        batch = np.broadcast_shapes(*(np.shape(a) for a in parts))
        flat = [np.ascontiguousarray(np.broadcast_to(a, batch), dtype=float).reshape(-1) for a in parts]
        if by_instant:
            out = np.empty((n,) + batch + (2,))
            _manoeuvre_samples(*flat, t, out.reshape(n, -1, 2).transpose(1, 0, 2))
            return out
        out = np.empty(batch + (n, 2))
        _manoeuvre_samples(*flat, t, out.reshape(-1, n, 2))
        return out


@numba.njit(cache=True, nogil=True)
def _manoeuvre_samples(v, omega, turn_time, theta0, heading_after, sx, sy, zx, zy, t, out):  # pragma: no cover
    """:meth:`Manoeuvre.points`' samples, manoeuvre by manoeuvre: each phase flown exactly from its own start,
    positions only. While ``t <= turn_time``: ``unicycle_arc(sx, sy, theta0, v, omega, t)``; after it, the straight
    leg from the tangent point, ``unicycle_arc(zx, zy, heading_after, v, 0.0, t - turn_time)`` with its sine and
    cosine once per manoeuvre (:func:`arc_point`; tests/test_dynamics.py checks the bits)."""
    for i in range(len(v)):
        vi, wi, tt = v[i], omega[i], turn_time[i]
        mid_s = heading_after[i] + 0.0
        cs, sn = np.cos(mid_s), np.sin(mid_s)
        for j in range(len(t)):
            tj = t[j]
            if tj <= tt:
                out[i, j, 0], out[i, j, 1] = arc_point(sx[i], sy[i], theta0[i], vi, wi, tj)
            else:
                t2 = tj - tt
                if t2 < 0.0:                             # np.maximum(t - turn_time, 0.0): NaN stays NaN
                    t2 = 0.0
                chord = vi * t2
                out[i, j, 0] = zx[i] + chord * cs
                out[i, j, 1] = zy[i] + chord * sn


def _uav_frame(P, c, s, G, v_max: float, delta: float):
    """Goals ``G`` (n, 2) in the frames of poses ``P`` (n, 2) with headings of cosine ``c`` and sine ``s`` (n,):
    forward offset ``a``, lateral ``cross`` (> 0 left), ``b = |cross|``, ``d2``, ``d = |g - p|``, ``usable`` (d in
    (MIN_GOAL_DISTANCE, V_max delta]: the path is at least the chord) and ``straight`` (usable and dead ahead: no
    turn). The caller takes the cosines and sines once per heading (many goals share a start)."""
    rx, ry = G[:, 0] - P[:, 0], G[:, 1] - P[:, 1]
    a = c * rx + s * ry
    cross = c * ry - s * rx
    b = np.abs(cross)
    d2 = a * a + b * b
    d = np.sqrt(d2)
    usable = np.isfinite(d) & (d > MIN_GOAL_DISTANCE) & (d <= v_max * delta)
    straight = usable & (a > 0) & (b <= _STRAIGHT_REL * d)
    return a, cross, b, d2, d, usable, straight


def manoeuvre_feasible(p, theta, goals, *, v_max: float, w_max: float, delta: float, cos_sin=None) -> np.ndarray:
    """``solve_manoeuvre(p, theta, goals, ...).feasible`` of flat batches (``p`` (n, 2), ``theta`` (n,), ``goals``
    (n, 2), limits already checked), without solving for the speed: a goal is feasible iff it is dead ahead or
    eq. 29 has a root bracket (:func:`~covert_env.geometry.turn_root.root_bracket`). What the waypoint masks and
    the reach table ask. ``cos_sin``: ``(np.cos(theta), np.sin(theta))`` if the caller has them already."""
    c, s = (np.cos(theta), np.sin(theta)) if cos_sin is None else cos_sin
    with np.errstate(all="ignore"):
        a, _, b, d2, d, usable, straight = _uav_frame(p, c, s, goals, v_max, delta)
        ti = np.flatnonzero(usable & ~straight)
        straight[ti[root_bracket(a[ti], b[ti], d[ti], d2[ti], w_max * delta, v_max / w_max)[0]]] = True
    return straight


def _controls(P, c, s, G, v_max: float, w_max: float, delta: float):
    """Eqs. 22-29 for flat batches: starts ``P`` (n, 2) with headings of cosine ``c`` and sine ``s`` (n,), goals
    ``G`` (n, 2). Returns ``feasible``, ``turn`` (int8, 0 where infeasible or straight), the turn radius ``r`` and
    angle ``tau``, and the controls ``v``, ``omega``, ``turn_time`` (NaN where infeasible), each (n,). The one
    home of the solve: :func:`solve_manoeuvre` adds the geometry, :func:`manoeuvre_controls` is this alone."""
    n = len(c)
    a, cross, b, d2, d, usable, straight = _uav_frame(P, c, s, G, v_max, delta)
    wd = w_max * delta
    turn = _turn_side(cross)
    turn[straight] = 0

    feasible = straight.copy()
    r = np.full(n, np.nan)
    tau = np.full(n, np.nan)
    v = np.full(n, np.nan)
    v[straight] = d[straight] / delta
    tau[straight] = 0.0

    ti = np.flatnonzero(usable & ~straight)
    ok_t, r_t = solve_turn(a[ti], b[ti], d[ti], d2[ti], wd, v_max / w_max)
    ti = ti[ok_t]
    r_t = r_t[ok_t]
    at, bt, d2t = a[ti], b[ti], d2[ti]
    tau_t = turn_angle(at, bt, r_t, d2t)
    # tau <= delta W_max holds at the root up to rounding; never report a turn longer than the slot.
    tau_t = np.minimum(tau_t, wd)
    feasible[ti] = True
    r[ti] = r_t
    tau[ti] = tau_t
    v[ti] = np.minimum(w_max * r_t, v_max)

    turn = np.where(feasible, turn, 0).astype(np.int8)
    omega = np.where(feasible, turn * w_max, np.nan)
    turn_time = np.where(feasible, np.minimum(tau / w_max, delta), np.nan)
    return feasible, turn, r, tau, v, omega, turn_time


def manoeuvre_controls(p, theta, goals, *, v_max: float, w_max: float, delta: float):
    """``solve_manoeuvre(p, theta, goals, ...)``'s ``feasible``, ``v``, ``omega`` and ``turn_time``, the same values,
    for flat batches (``p`` (n, 2), ``theta`` (n,), ``goals`` (n, 2) floats; limits already checked) without the
    manoeuvre's geometry: what flying a slot needs (:func:`~covert_env.geometry.flight.waypoint_controls`)."""
    with np.errstate(all="ignore"):
        feasible, _, _, _, v, omega, turn_time = _controls(p, np.cos(theta), np.sin(theta), goals, v_max, w_max,
                                                           delta)
    return feasible, v, omega, turn_time


def solve_manoeuvre(p, theta, goals, *, v_max: float = 50.0, w_max: float = 3.0,
                    delta: float = 1.0) -> Manoeuvre:
    """Turn-then-straight manoeuvres from poses ``(p, theta)`` to waypoints ``goals`` (eqs. 22-29).

    Turn at ``+-w_max`` (left if the waypoint is left of the heading, right if right of it or dead behind,
    eq. 22) at constant speed v until the
    heading points at the waypoint (tangent point z, eq. 26), then fly straight at the same v, arriving
    exactly after ``delta`` seconds (eq. 27/29). See the module docstring for the geometry, the verified
    formula for tau and the root structure of eq. 29 (the slowest root is returned).

    Vectorised over any batch shape: ``p`` is ``(..., 2)``, ``theta`` is ``(...)``, ``goals`` is ``(..., 2)``,
    broadcast against each other (e.g. ``p`` ``(2,)`` with ``goals`` ``(K, 2)``, or ``p`` ``(S, 1, 2)`` with
    ``goals`` ``(1, S, 2)`` for all S x S node pairs). No Python loop runs over pairs.

    Args:
        p: start positions (m). theta: start headings (rad). goals: waypoints (m).
        v_max, w_max, delta: V_max (m/s), W_max (rad/s) and the slot length (s); defaults as in ``Config``.

    Returns:
        A :class:`Manoeuvre` with the broadcast batch shape.
    """
    for name, val in (("v_max", v_max), ("w_max", w_max), ("delta", delta)):
        if not (isinstance(val, (int, float, np.floating, np.integer)) and math.isfinite(val) and val > 0):
            raise ValueError(f"solve_manoeuvre: {name} must be a finite number > 0, got {val!r}")
    v_max, w_max, delta = float(v_max), float(w_max), float(delta)
    p = np.asarray(p, dtype=float)
    goals = np.asarray(goals, dtype=float)
    theta = np.asarray(theta, dtype=float)
    if p.ndim < 1 or p.shape[-1] != 2:
        raise ValueError(f"solve_manoeuvre: p must have shape (..., 2), got {p.shape}")
    if goals.ndim < 1 or goals.shape[-1] != 2:
        raise ValueError(f"solve_manoeuvre: goals must have shape (..., 2), got {goals.shape}")
    shape = np.broadcast_shapes(p.shape[:-1], goals.shape[:-1], theta.shape)
    start = np.broadcast_to(p, shape + (2,))
    goal = np.broadcast_to(goals, shape + (2,))
    th0 = np.broadcast_to(theta, shape)
    P = start.reshape(-1, 2)
    G = goal.reshape(-1, 2)
    TH = th0.reshape(-1)

    with np.errstate(all="ignore"):
        # One cosine and sine per start heading, shared by every goal from it.
        c = np.broadcast_to(np.cos(theta), shape).reshape(-1)
        s = np.broadcast_to(np.sin(theta), shape).reshape(-1)
        feasible, turn, r, tau, v, omega, turn_time = _controls(P, c, s, G, v_max, w_max, delta)
        heading_after = np.where(feasible, wrap_heading(TH + turn * tau), np.nan)
        length = v * delta
        # Tangent point z, mapped back from the UAV frame: (r sin tau, turn * r (1 - cos tau)).
        rr = np.where(turn != 0, r, 0.0)
        zf = rr * np.sin(tau)
        zl = turn * rr * (1.0 - np.cos(tau))
        tangent = np.stack([P[:, 0] + c * zf - s * zl, P[:, 1] + s * zf + c * zl], axis=-1)
        tangent[~feasible] = np.nan

    def shaped(arr, extra=()):
        out = arr.reshape(shape + extra)
        return out[()] if out.ndim == 0 else out

    return Manoeuvre(
        feasible=shaped(feasible),
        v=shaped(v),
        turn=shaped(turn),
        omega=shaped(omega),
        turn_time=shaped(turn_time),
        heading_after=shaped(heading_after),
        length=shaped(length),
        tangent=tangent.reshape(shape + (2,)),
        start=np.array(start),
        theta0=shaped(np.array(TH)),
        goal=np.array(goal),
        delta=delta,
    )


def fly_manoeuvre(p, theta, m: Manoeuvre):
    """Fly a :class:`Manoeuvre` from ``(p, theta)`` with two exact :func:`unicycle_step` calls.

    ``(v, omega)`` for ``turn_time``, then ``(v, 0)`` for ``delta - turn_time``; vectorised over the batch.
    ``p`` and ``theta`` broadcast against the manoeuvre's batch shape (normally they are the start pose
    it was solved for; another pose flies the same controls from there).

    Returns:
        ``(end_xy, end_theta)``: ``(*batch, 2)`` positions and headings in ``[0, 2 pi)``; NaN if infeasible.
    """
    p = np.asarray(p, dtype=float)
    v, om, tt = (np.asarray(q, dtype=float) for q in m.controls())
    x1, y1, th1 = unicycle_step(p[..., 0], p[..., 1], theta, v, om, tt)
    x2, y2, th2 = unicycle_step(x1, y1, th1, v, 0.0, m.delta - tt)
    end = np.stack(np.broadcast_arrays(x2, y2), axis=-1)
    return end, _scalar_or_array(th2)
