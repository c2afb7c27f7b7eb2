"""The protocols of covert_env.world.roles: the classes that play each role have its members (with signatures that
accept the protocol's calls), and an object missing one does not play it."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import covert_env
from covert_env import Config, Engine, Scenario, Terrain
from covert_env.world.metrics import terrain_clearance
from covert_env.world.roles import EngineView, PolytopeTops, TerrainPerCopy
from covert_env.world.visibility import line_of_sight


def _members(proto) -> tuple[list[str], list[str]]:
    """The protocol's (attributes and properties, methods), read from its class body."""
    body = {n: v for n, v in vars(proto).items() if not n.startswith("_")}
    methods = [n for n, v in body.items() if inspect.isfunction(v)]
    return sorted(set(body) - set(methods) | set(proto.__annotations__)), methods


def assert_plays(obj, proto) -> None:
    """``obj`` has every member of ``proto`` (isinstance on the runtime-checkable protocol), and each of its methods
    accepts the protocol method's arguments by name."""
    assert isinstance(obj, proto), f"{type(obj).__name__} is not a {proto.__name__}"
    for name in _members(proto)[1]:
        params = list(inspect.signature(getattr(proto, name)).parameters)[1:]          # without self
        inspect.signature(getattr(obj, name)).bind(**{p: None for p in params})


def _without(proto, missing: str):
    """An object with every member of ``proto`` but ``missing``."""
    attrs, methods = _members(proto)
    ns = {n: None for n in attrs if n != missing}
    ns.update({n: (lambda self, *a, **k: None) for n in methods if n != missing})
    return type(f"No_{missing}", (), ns)()


def test_members_are_read_from_the_protocols():
    assert _members(PolytopeTops) == (["highest_points"], [])
    assert _members(TerrainPerCopy) == (["highest_points"], ["line_of_sight"])
    attrs, methods = _members(EngineView)
    assert {"k", "uav_xy", "uav_theta", "target_xyz", "target_phi", "track", "positions"} <= set(attrs)
    assert sorted(methods) == ["predict", "trajectory"]


@pytest.mark.parametrize("proto", [PolytopeTops, TerrainPerCopy, EngineView])
def test_an_object_missing_a_member_does_not_play_the_role(proto):
    attrs, methods = _members(proto)
    for name in attrs + methods:
        assert not isinstance(_without(proto, name), proto), name
    assert isinstance(_without(proto, "not a member"), proto)


def test_engine_and_a_copy_of_the_vector_env_are_engine_views():
    eng = Engine(Scenario.paper(Config()))
    assert_plays(eng, EngineView)
    venv = covert_env.vector_env(num_envs=2, n_uavs=2, record=True)
    venv.reset(seed=0)
    assert_plays(venv.copy_view(1), EngineView)
    par = covert_env.parallel_env(n_uavs=2)
    par.reset(seed=0)
    assert_plays(par.engine, EngineView)


def test_terrains_play_their_roles():
    """A Terrain gives its tops (eq. 3), not a line of sight per copy; the vector env's copies' terrains give both,
    each copy's equal to its own scene's Terrain."""
    terrain = Scenario.paper(Config()).terrain
    assert_plays(terrain, PolytopeTops)
    assert not isinstance(terrain, TerrainPerCopy)

    venv = covert_env.vector_env(num_envs=3, n_uavs=2)
    venv.reset(options={"scene_seed": [1, 2, 1]})
    pool, rows = venv._pool, venv.copies.rows
    copies = pool.copy_terrains(rows)
    assert_plays(copies, TerrainPerCopy)
    assert_plays(copies, PolytopeTops)
    c = venv.config
    q = pool.q[rows, 0]
    xy = q[:, None, :2] + np.random.default_rng(0).uniform(-120, 120, (3, 5, 2))
    scenes = [venv.scene(b).terrain for b in range(3)]
    want = np.stack([line_of_sight(t, xy[b], c.altitude, q[b]) for b, t in enumerate(scenes)])
    np.testing.assert_array_equal(copies.line_of_sight(xy, c.altitude, q[:, None]), want)
    np.testing.assert_array_equal(terrain_clearance(xy, c.altitude, copies),
                                  np.stack([terrain_clearance(xy[b], c.altitude, t) for b, t in enumerate(scenes)]))
    assert isinstance(Terrain(), PolytopeTops)
