"""Calls in the wrong state, bad indices and live settings behave alike in the four env kinds (parallel, AEC,
Gymnasium, vector): a clear RuntimeError before ``reset()`` and after ``close()``, copy indices checked, unknown
reset options warned about, penalty weights validated on item assignment, AEC actions checked at the agent's own
``step()``."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

import covert_env

KINDS = ("parallel", "aec", "gymnasium", "vector")


def _make(kind: str, **kw):
    if kind == "parallel":
        return covert_env.parallel_env(n_uavs=2, max_cycles=3, **kw)
    if kind == "aec":
        return covert_env.env(n_uavs=2, max_cycles=3, **kw)
    if kind == "gymnasium":
        mode = kw.pop("action_mode", "unicycle")
        name = "covert_env/CovertSensingWaypoint-v4" if mode == "waypoint" else "covert_env/CovertSensing-v4"
        return gym.make(name, max_cycles=3, **kw)
    return covert_env.vector_env(num_envs=2, n_uavs=2, max_cycles=3, **kw)


def _reset(env, kind: str):
    return env.reset(seed=0)


def _step(env, kind: str):
    if kind == "parallel":
        return env.step({a: np.zeros(2, np.float32) for a in env.possible_agents})
    if kind == "aec":
        for _ in env.possible_agents:
            env.step(np.zeros(2, np.float32))
        return None
    if kind == "gymnasium":
        return env.step(np.zeros(2, np.float32))
    return env.step(np.zeros((2, 2, 2), np.float32))


@pytest.mark.parametrize("kind", KINDS)
def test_step_after_close_raises(kind):
    env = _make(kind)
    _reset(env, kind)
    _step(env, kind)
    env.close()
    with pytest.raises(RuntimeError, match=r"step\(\) called after close\(\); make a new env"):
        _step(env, kind)
    env.close()                                             # closing twice is harmless


@pytest.mark.parametrize("kind", KINDS)
def test_reset_after_close_raises(kind):
    env = _make(kind)
    _reset(env, kind)
    env.close()
    with pytest.raises(RuntimeError, match=r"reset\(\) called after close\(\)"):
        _reset(env, kind)


@pytest.mark.parametrize("kind", KINDS)
def test_step_before_reset_raises(kind):
    env = _make(kind)
    # Gymnasium's and PettingZoo's order enforcing answer first where they wrap the env (PettingZoo with an
    # AssertionError); ours otherwise.
    with pytest.raises((RuntimeError, AssertionError, gym.error.ResetNeeded, AttributeError), match=r"reset"):
        _step(env, kind)


@pytest.mark.parametrize("kind", ("parallel", "aec", "gymnasium"))
def test_render_before_reset_and_after_close_raises(kind):
    env = _make(kind, render_mode="rgb_array")
    with pytest.raises((RuntimeError, AssertionError, gym.error.ResetNeeded, AttributeError), match=r"reset"):
        env.render()
    _reset(env, kind)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    env.close()
    with pytest.raises(RuntimeError, match=r"render\(\) called after close\(\)"):
        env.render()


@pytest.mark.parametrize("mode", ("unicycle", "waypoint"))
def test_action_masks_before_reset_raise_in_every_kind(mode):
    calls = {
        "parallel": lambda: covert_env.parallel_env(action_mode=mode).action_mask("uav_0"),
        "vector": lambda: covert_env.vector_env(2, action_mode=mode).action_masks(),
    }
    if mode == "waypoint":
        calls["gymnasium"] = lambda: gym.make("covert_env/CovertSensingWaypoint-v4").unwrapped.action_masks()
    assert len(calls) == (3 if mode == "waypoint" else 2)
    for call in calls.values():
        with pytest.raises(RuntimeError, match=r"action_masks?\(\) called before reset\(\); call reset\(\) first"):
            call()


@pytest.mark.parametrize("what", ("scene", "scenario", "trajectory"))
@pytest.mark.parametrize("index, exc, pattern", [
    (-1, ValueError, r"copy index must be an integer in \[0, 1\], got -1"),
    (2, ValueError, r"copy index must be an integer in \[0, 1\], got 2"),
    (True, TypeError, r"copy index must be an integer, got True"),
    (1.5, TypeError, r"copy index must be an integer, got float 1\.5"),
    (np.int64(1), None, None),
])
def test_copy_indices_are_checked(what, index, exc, pattern):
    venv = covert_env.vector_env(2, n_uavs=2, record=True)
    venv.reset(seed=0)
    call = getattr(venv, what)
    if exc is None:
        assert call(index) is not None
        return
    with pytest.raises(exc, match=rf"{what}\(\): {pattern}"):
        call(index)


def test_copy_accessors_before_reset_and_after_close():
    venv = covert_env.vector_env(2, n_uavs=2, record=True)
    for what in ("scene", "scenario", "trajectory"):
        with pytest.raises(RuntimeError, match=rf"{what}\(\) called before reset\(\)"):
            getattr(venv, what)(0)
    venv.reset(seed=0)
    venv.close()
    for what in ("scene", "scenario", "trajectory", "state", "action_masks"):
        with pytest.raises(RuntimeError, match=r"called after close\(\)"):
            getattr(venv, what)(*((0,) if what in ("scene", "scenario", "trajectory") else ()))


@pytest.mark.parametrize("kind", ("parallel", "vector"))
def test_unknown_reset_options_warn_alike(kind):
    env = _make(kind)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.reset(seed=0, options={"scene_sed": 3})
    messages = [str(w.message) for w in caught]
    assert any("ignoring unknown option(s) ['scene_sed']; known: ['scene_seed'" in m for m in messages), messages


@pytest.mark.parametrize("kind", ("parallel", "vector", "gymnasium"))
def test_penalty_items_are_validated(kind):
    env = _make(kind)
    penalties = env.unwrapped.par.penalties if kind == "gymnasium" else env.penalties
    for bad, exc, pattern in ((math.nan, ValueError, r"los_penalty must be finite, got nan"),
                              (-1.0, ValueError, r"los_penalty must be a finite number in \[0, 1e\+06\], got -1\.0"),
                              (1e308, ValueError, r"los_penalty must be a finite number in \[0, 1e\+06\], got 1e\+308"),
                              ("2", TypeError, r"los_penalty must be a number, got str '2'")):
        with pytest.raises(exc, match=pattern):
            penalties["los"] = bad
    with pytest.raises(KeyError, match=r"unknown term 'lso'"):
        penalties["lso"] = 1.0
    with pytest.raises(TypeError, match=r"set a weight to 0\.0 to turn a term off"):
        del penalties["los"]
    with pytest.raises(ValueError, match=r"zone_penalty must be finite"):
        penalties.update(zone=math.inf)
    penalties["los"] = 0.0                                   # live: the next step's reward has no LoS term
    _reset(env, kind)
    out = _step(env, kind)
    rewards = out[1]
    values = np.asarray(list(rewards.values()) if isinstance(rewards, dict) else rewards, float)
    assert np.isfinite(values).all()
    assert dict(penalties) == {"los": 0.0, "los_path": 1.0, "zone": 1.0, "separation": 1.0, "terrain": 1.0}


def test_vector_misuse_is_named():
    venv = covert_env.vector_env(2, n_uavs=2, action_mode="waypoint")
    with pytest.raises(RuntimeError, match=r"copy_view\(\) called before reset\(\)"):
        venv.copy_view(0)
    venv.reset(seed=0)
    with pytest.raises(AttributeError, match=r"num_envs"):
        venv.num_envs = 3
    with pytest.raises(ValueError, match=r"at most \d+ nodes per UAV \(the lattice's\), got M = 100000"):
        venv.waypoint_paths(np.full((2, 2, 100_000), -1))
    with pytest.raises(ValueError, match=r"waypoint actions must have shape \(2, 2\) \(copies, agents\), got a ragged"):
        venv.step([[0, 1], [2]])
    env = covert_env.parallel_env(action_mode="waypoint")
    with pytest.raises(ValueError, match=r"read-only"):
        env.lattice[0] = 0.0


@pytest.mark.parametrize("mode, bad, exc, pattern", [
    ("unicycle", np.array([np.nan, 0.0]), ValueError, r"action for uav_0 must be finite"),
    ("unicycle", "x", TypeError, r"action for uav_0 must be 2 numbers"),
    ("unicycle", np.zeros(3), ValueError, r"action for uav_0 must have shape \(2,\)"),
    ("waypoint", 10**6, ValueError, r"action for uav_0 must be an integer in \[0, \d+\], got 1000000"),
    ("waypoint", 2.5, ValueError, r"action for uav_0 must be an integer in"),
])
def test_aec_checks_each_action_at_its_own_step(mode, bad, exc, pattern):
    env = covert_env.env(n_uavs=2, action_mode=mode)
    env.reset(seed=0)
    with pytest.raises(exc, match=pattern):
        env.step(bad)
    assert env.agent_selection == "uav_0"                   # refused: the turn did not pass
    env.step(np.zeros(2, np.float32) if mode == "unicycle" else 0)
    assert env.agent_selection == "uav_1"
