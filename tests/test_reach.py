"""The reachability table gives exactly solve_manoeuvre's feasibility, on many random poses and waypoints."""

from __future__ import annotations

import numpy as np
import pytest

from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.reach import BOUNDARY, FEASIBLE, INFEASIBLE, ReachTable, reach_table
from covert_env.geometry.zone import to_world, zone_lattice
from covert_env.world.config import Config

LIMITS = [(50.0, 3.0, 1.0), (30.0, 5.0, 1.0), (50.0, 1.0, 0.5)]   # W_max delta > pi: two roots behind the UAV


def _exact(xy, theta, q, phi, offsets, limits):
    goals = np.stack([to_world(offsets, q[b], phi[b]) for b in range(len(q))])            # (B, L, 2)
    v, w, d = limits
    return solve_manoeuvre(xy[:, :, None], theta[:, :, None], goals[:, None], v_max=v, w_max=w, delta=d).feasible


@pytest.mark.parametrize("limits", LIMITS)
def test_table_equals_solve_manoeuvre_on_random_poses(limits):
    v, w, d = limits
    table = reach_table(*limits)
    rng = np.random.default_rng(7)
    b, u, n = 400, 3, 150
    q = rng.uniform(-3000, 3000, (b, 2))
    phi = rng.uniform(-10, 10, b)
    offsets = rng.uniform(-1.3 * v * d, 1.3 * v * d, (n, 2))
    xy = q[:, None] + rng.uniform(-0.4 * v * d, 0.4 * v * d, (b, u, 2))
    xy[:, 0] = to_world(offsets[:1], q, phi)[:, 0] + rng.normal(0, 1e-7, (b, 2))       # on top of a goal
    theta = rng.uniform(-7, 7, (b, u))
    got = table.reachable(xy, theta, q, phi, offsets)
    want = _exact(xy, theta, q, phi, offsets, limits)
    assert got.shape == want.shape and got.dtype == bool
    assert np.array_equal(got, want), np.argwhere(got != want)[:5]
    assert 0.01 < want.mean() < 0.95                       # both outcomes are exercised


def _near_lattice(seed: int, b: int):
    """``b`` random targets with 3 UAVs each near the default lattice's nodes: (xy, theta, q, phi, lattice,
    table)."""
    c = Config()
    lattice, table = zone_lattice(c), reach_table(c.v_max, c.w_max, c.delta)
    rng = np.random.default_rng(seed)
    q, phi = rng.uniform(-500, 500, (b, 2)), rng.uniform(0, 2 * np.pi, b)
    nodes = np.stack([to_world(lattice, q[j], phi[j]) for j in range(b)])
    xy = nodes[np.arange(b)[:, None], rng.integers(0, len(lattice), (b, 3))] + rng.normal(0, 15, (b, 3, 2))
    theta = rng.uniform(0, 2 * np.pi, (b, 3))
    return xy, theta, q, phi, lattice, table


def test_table_equals_solve_manoeuvre_on_the_lattice():
    c = Config()
    xy, theta, q, phi, lattice, table = _near_lattice(2, 300)
    assert np.array_equal(table.reachable(xy, theta, q, phi, lattice),
                          _exact(xy, theta, q, phi, lattice, (c.v_max, c.w_max, c.delta)))


def test_without_the_solver_reachable_is_a_subset():
    """``exact=False`` (no manoeuvre solver, boundary cells counted unreachable): every point it calls reachable
    is, and it misses a small share of the reachable ones."""
    xy, theta, q, phi, lattice, table = _near_lattice(3, 200)
    exact = table.reachable(xy, theta, q, phi, lattice)
    certain = table.reachable(xy, theta, q, phi, lattice, exact=False)
    assert certain.dtype == bool and not (certain & ~exact).any()
    assert 0 < (exact & ~certain).sum() < 0.2 * exact.sum()


def test_labels_are_mostly_certain_and_far_points_infeasible():
    table = reach_table(50.0, 3.0, 1.0)
    labels = table.labels
    assert set(np.unique(labels).tolist()) == {INFEASIBLE, FEASIBLE, BOUNDARY}
    assert (labels == BOUNDARY).mean() < 0.03              # few points need the exact solver
    far = np.array([1e6, -1e6, 51.0, -51.0, 0.0])
    assert (table.classify(far, np.abs(far[::-1]) + 60.0) == INFEASIBLE).all()
    assert table.classify(np.array([25.0]), np.array([0.0]))[0] == FEASIBLE       # straight ahead, half speed
    assert reach_table(50.0, 3.0, 1.0) is table            # built once per process


def test_a_coarser_table_is_still_exact():
    table = ReachTable(50.0, 3.0, 1.0, cells=32, refine=2)
    rng = np.random.default_rng(4)
    q, phi = rng.uniform(-100, 100, (200, 2)), rng.uniform(0, 7, 200)
    offsets = rng.uniform(-60, 60, (100, 2))
    xy, theta = q[:, None] + rng.uniform(-20, 20, (200, 2, 2)), rng.uniform(0, 7, (200, 2))
    assert np.array_equal(table.reachable(xy, theta, q, phi, offsets),
                          _exact(xy, theta, q, phi, offsets, (50.0, 3.0, 1.0)))


@pytest.mark.parametrize("limits", LIMITS)
def test_the_coarse_level_holds_the_fine_labels(limits):
    """The lookup's first level: a coarse cell's label, where it is not _MIXED, is every one of its fine cells'
    label (so the two-level lookup reads the fine table's labels), and most coarse cells are not mixed."""
    from covert_env.geometry.reach import _MIXED

    table = reach_table(*limits)
    r = 1 << table._shift
    coarse = table.coarse_labels[np.arange(table.shape[0])[:, None] // r, np.arange(table.shape[1])[None] // r]
    assert ((coarse == _MIXED) | (coarse == table.labels)).all()
    assert (table.coarse_labels == _MIXED).mean() < 0.1


def test_refine_must_be_a_power_of_two():
    with pytest.raises(ValueError, match="refine must be a power of two"):
        ReachTable(50.0, 3.0, 1.0, cells=16, refine=3)


def test_a_nan_pose_reads_no_cell_outside_the_table():
    """The compiled lookup clips NaN coordinates into the table (no read out of bounds) instead of failing."""
    table = reach_table(50.0, 3.0, 1.0)
    lattice = zone_lattice(Config())
    got = table.reachable(np.full((1, 1, 2), np.nan), np.zeros((1, 1)), np.zeros((1, 2)), np.zeros(1), lattice,
                          exact=False)
    assert got.shape == (1, 1, len(lattice))
