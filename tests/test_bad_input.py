"""Bad input to the model fails at the boundary, with a message naming the field, the value and the
allowed range or the fix: never a hang, a MemoryError, a silent coercion or a failure
in some later reset. One parametrised case per input."""

from __future__ import annotations

import copy
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from covert_env.geometry.zone import grid_nodes, in_feasible_zone, lattice_offsets, lattice_size
from covert_env.world.config import MAX_LATTICE, Config
from covert_env.world.road import Road, TargetTrack
from covert_env.world.scenario import Scenario, sample_starts_on
from covert_env.world.terrain import Polytope, Terrain, _first_overlap
from covert_env.world.visibility import line_of_sight

SQUARE = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]


def _road():
    return Road([[0.0, 0.0], [2000.0, 0.0]])


def _track(c: Config, **kw):
    args = dict(delta=c.delta, z=c.target_height, s0=100.0) | kw
    return TargetTrack.constant(_road(), c.target_speed, c.n_slots + c.horizon + 1, **args)


def _scenario(terrain=None, c=None, track=None):
    c = c or Config(n_slots=10)
    return Scenario(c, terrain or Terrain(), track or _track(c), [[0.0, 0.0]], [0.0])


# ----------------------------------------------------------------------------- Config
CONFIG_CASES = {
    "empty lattice (mu)": (dict(mu=0.01), r"eroded feasible zone \(r1=55, r2=100, mu=0\.01, r_u=2, grid_step=2\) "
                                          r"holds no waypoint lattice node; increase mu"),
    "empty lattice (grid_step)": (dict(grid_step=110.0), r"grid_step=110\) holds no waypoint lattice node"),
    "starts do not fit": (dict(d_safe1=50.0), r"room for only 1 start\(s\) d_safe1=50 m apart .* n_uavs=3; "
                                              r"reduce n_uavs or d_safe1"),
    "team too large for zone": (dict(n_uavs=64, d_safe1=10.0), r"room for only \d+ start.* n_uavs=64"),
    "n_slots huge": (dict(n_slots=10**9), r"Config\.n_slots must be an integer >= 1 and <= 10000, got 1000000000"),
    "horizon huge": (dict(horizon=10**6), r"Config\.horizon must be an integer >= 1 and <= 1000, got 1000000"),
    "max_vertices huge": (dict(max_vertices=10**9), r"Config\.max_vertices must be an integer >= 3 and <= 64"),
    "n_polytopes huge": (dict(n_polytopes=10**6), r"Config\.n_polytopes must be an integer >= 0 and <= 10000"),
    "n_uavs huge": (dict(n_uavs=65), r"Config\.n_uavs must be an integer >= 1 and <= 64, got 65"),
    "delta huge": (dict(delta=1e12), r"Config\.delta must be <= 3600 s, got 1000000000000\.0"),
    "route of a long slot": (dict(delta=3000.0), r"route target_speed \* delta \* \(n_slots \+ horizon \+ 1\) = "
                                                 r"10 \* 3000 \* 76 = 2\.28e\+06 m exceeds 200000 m"),
    "target_speed huge": (dict(target_speed=1e12), r"Config\.target_speed must be <= 10000 m/s"),
    "route of a fast target": (dict(target_speed=5000.0), r"route .* = 3\.8e\+05 m exceeds 200000 m; reduce "
                                                          r"target_speed"),
    "altitude absurd": (dict(altitude=1e308), r"Config\.altitude must be <= 100000 m, got 1e\+308"),
    "r1 absurd": (dict(r1=1e300, r2=2e300), r"Config\.r1 must be <= 100000 m"),
    "max_height absurd": (dict(max_height=1e200), r"Config\.max_height must be <= 100000 m"),
    "v_max absurd": (dict(v_max=1e308), r"Config\.v_max must be <= 10000 m/s"),
    "w_max absurd": (dict(w_max=1e9), r"Config\.w_max must be <= 1000 rad/s"),
    "route too long": (dict(n_slots=10_000, target_speed=30.0), r"route .* exceeds 200000 m"),
    "r2 huge": (dict(r2=5e4), r"waypoint lattice would have 4\.779e\+08 nodes .* more than 200000; "
                               r"increase grid_step"),
    "grid_step tiny": (dict(grid_step=0.01), r"waypoint lattice would have .* grid_step=0\.01\), more than"),
    "n_uavs fractional": (dict(n_uavs=2.7), r"Config\.n_uavs must be an integer .* got 2\.7 \(float\)"),
    "n_uavs float": (dict(n_uavs=3.0), r"Config\.n_uavs must be an integer .* got 3\.0 \(float\)"),
    "n_uavs numpy float": (dict(n_uavs=np.float64(3.0)), r"Config\.n_uavs must be an integer .*float64"),
    "n_uavs string": (dict(n_uavs="3"), r"Config\.n_uavs must be an integer .* got '3' \(str\)"),
    "n_uavs bool": (dict(n_uavs=True), r"Config\.n_uavs must be an integer .* got True \(bool\)"),
    "v_max string": (dict(v_max="50"), r"Config\.v_max must be a finite number, got '50' \(str\)"),
    "v_max bool": (dict(v_max=True), r"Config\.v_max must be a finite number, got True \(bool\)"),
    "v_max list": (dict(v_max=[50.0]), r"Config\.v_max must be a finite number, got \[50\.0\] \(list\)"),
    "v_max numpy nan": (dict(v_max=np.float64("nan")), r"Config\.v_max must be a finite number"),
    "h_min string": (dict(h_min="20"), r"Config\.h_min must be a finite number, got '20'"),
    "huge string shortened": (dict(eta="x" * 10**6),
                              r"Config\.eta must be a finite number, got 'x{10,}\.\.\.x+' \(str\)"),
}


@pytest.mark.parametrize("kwargs, pattern", CONFIG_CASES.values(), ids=CONFIG_CASES.keys())
def test_config_rejects(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        Config(**kwargs)


@pytest.mark.parametrize("field, value, kind", [
    ("n_uavs", np.int64(3), int), ("n_slots", np.int32(12), int), ("horizon", np.uint8(4), int),
    ("v_max", np.float64(40.0), float), ("v_max", np.float32(40.0), float), ("v_max", np.int64(40), float),
    ("r_u", 0, float), ("h_min", np.float64(20.0), float), ("max_height", 60, float),
])
def test_config_accepts_numpy_scalars_as_plain_numbers(field, value, kind):
    c = Config(**{field: value})
    got = getattr(c, field)
    assert type(got) is kind and got == value
    assert Config.from_json(c.to_json()) == c           # plain types: JSON works


def test_config_bounds_admit_the_paper_and_large_studies():
    Config()
    Config(n_slots=10_000, horizon=5)
    Config(n_uavs=3, d_safe1=40.0)
    Config(r2=400.0, grid_step=1.0)                     # about 100k lattice nodes
    assert lattice_size(55.0, 400.0, math.pi / 4, 1.0) < MAX_LATTICE


@pytest.mark.parametrize("r1, r2, mu, step", [(55, 100, math.pi / 4, 2), (40, 120, 1.2, 5), (0, 30, 6.0, 1.5),
                                              (10, 50, math.pi, 3), (55, 100, 0.01, 2), (1, 2, 0.3, 7)])
def test_lattice_size_is_the_lattice_length(r1, r2, mu, step):
    assert lattice_size(r1, r2, mu, step) == len(lattice_offsets(r1, r2, mu, step))


@pytest.mark.parametrize("r2, step", [(1e12, 2.0), (100.0, 1e-4), (math.nan, 2.0)])
def test_lattice_offsets_refuses_a_huge_lattice(r2, step):
    with pytest.raises(ValueError, match=r"the lattice for r1=55, r2=.* nodes, more than 200000; use a larger step"):
        lattice_offsets(55.0, r2, math.pi / 4, step)


def test_config_check_does_not_fill_the_shared_lattice_cache():
    from covert_env.geometry.zone import _lattice

    before = _lattice.cache_info().currsize
    Config(grid_step=1.7, r2=101.0)
    assert _lattice.cache_info().currsize == before


# ----------------------------------------------------------------------------- JSON files
def _bad_files(tmp_path):
    files = {
        "missing": tmp_path / "missing.json",
        "not utf-8": tmp_path / "latin1.json",
        "deep nesting": tmp_path / "deep.json",
        "invalid": tmp_path / "invalid.json",
        "top-level list": tmp_path / "list.json",
        "directory": tmp_path / "adir.json",
    }
    files["not utf-8"].write_bytes(b'{"name": "caf\xe9"}')
    files["deep nesting"].write_text("[" * 100_000 + "]" * 100_000)
    files["invalid"].write_text("{not json")
    files["top-level list"].write_text("[1, 2]")
    files["directory"].mkdir()
    return files


JSON_CASES = {
    "missing": (FileNotFoundError, r"missing\.json: no such file"),
    "not utf-8": (ValueError, r"latin1\.json: not UTF-8 text \(byte 13: invalid continuation byte\)"),
    "deep nesting": (ValueError, r"deep\.json: JSON nested too deeply"),
    "invalid": (ValueError, r"invalid\.json: invalid JSON"),
    "directory": (ValueError, r"adir\.json: cannot be read"),
}


@pytest.mark.parametrize("case", JSON_CASES, ids=JSON_CASES.keys())
@pytest.mark.parametrize("load, what", [(Config.from_json, "Config file"), (Terrain.load, "Terrain file")],
                         ids=["config", "terrain"])
def test_json_file_errors_name_the_file(tmp_path, case, load, what):
    path = _bad_files(tmp_path)[case]
    exc, pattern = JSON_CASES[case]
    with pytest.raises(exc, match=f"^{what} .*{pattern}"):
        load(path)
    with pytest.raises(exc, match=pattern):
        load(str(path))


def _read_in_a_child(path: str, timeout: float = 60.0):
    """``Config.from_json(path)`` and ``Terrain.load(path)`` in a child process (a blocking read would hang the test
    run, here it times out): their exception lines."""
    import subprocess
    import sys

    code = ("import sys\nfrom covert_env.world.config import Config\nfrom covert_env.world.terrain import Terrain\n"
            "for load in (Config.from_json, Terrain.load):\n"
            "    try:\n        load(sys.argv[1])\n    except (OSError, ValueError) as exc:\n"
            "        print(type(exc).__name__, exc)\n")
    res = subprocess.run([sys.executable, "-c", code, path], capture_output=True, text=True, timeout=timeout,
                         env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    assert res.returncode == 0, res.stderr
    return res.stdout.splitlines()


@pytest.mark.parametrize("path, kind", [("/dev/zero", "a character device"), ("/dev/null", "a character device"),
                                        ("fifo", "a named pipe")])
def test_json_files_that_are_not_regular_files_are_refused_without_reading(tmp_path, path, kind):
    """/dev/zero would be read forever and a named pipe would block until a writer comes: both are refused
    by type before any byte is read."""
    if path == "fifo":
        if not hasattr(os, "mkfifo"):
            pytest.skip("no named pipes on this platform")
        path = str(tmp_path / "fifo")
        os.mkfifo(path)
    elif not Path(path).exists():
        pytest.skip(f"no {path} on this platform")
    lines = _read_in_a_child(path)
    assert lines == [f"ValueError Config file {path}: cannot be read ({kind}, not a regular file)",
                     f"ValueError Terrain file {path}: cannot be read ({kind}, not a regular file)"]


def test_json_files_beyond_the_size_cap_are_refused_before_reading(tmp_path):
    from covert_env.world.config import MAX_JSON_BYTES, read_json

    big = tmp_path / "big.json"
    with open(big, "wb") as f:                               # sparse: no disk space, no time
        f.truncate(MAX_JSON_BYTES + 1)
    for load, what in [(Config.from_json, "Config file"), (Terrain.load, "Terrain file")]:
        with pytest.raises(ValueError, match=rf"^{what} .*big\.json: {MAX_JSON_BYTES + 1} bytes, more than the "
                                             rf"{MAX_JSON_BYTES} a JSON file may have$"):
            load(big)
    small = tmp_path / "small.json"
    small.write_text('{"n_uavs": 2}')
    assert read_json(small, "x", max_bytes=13) == {"n_uavs": 2}         # the cap itself is allowed
    with pytest.raises(ValueError, match=r"small\.json: 13 bytes, more than the 12"):
        read_json(small, "x", max_bytes=12)


@pytest.mark.parametrize("load, pattern", [
    (Config.from_json, r"list\.json: Config must be a JSON object, got list"),
    (Terrain.load, r"list\.json: GeoJSON terrain must be an object with type 'FeatureCollection', got 'list'"),
], ids=["config", "terrain"])
def test_json_wrong_top_level_type_names_the_file(tmp_path, load, pattern):
    with pytest.raises(ValueError, match=pattern):
        load(_bad_files(tmp_path)["top-level list"])


@pytest.mark.parametrize("data, pattern", [
    ({"n_uavs": "3"}, r"cfg\.json: Config\.n_uavs must be an integer .* got '3' \(str\)"),
    ({"n_uavs": 2.5}, r"cfg\.json: Config\.n_uavs must be an integer .* got 2\.5"),
    ({"v_max": None}, r"cfg\.json: Config\.v_max must be a finite number, got None"),
    ({"speed": 3, "mu": 1}, r"cfg\.json: Config: unknown field\(s\) \['speed'\]"),
], ids=["string count", "fractional count", "null number", "unknown field"])
def test_config_file_field_errors_name_file_and_field(tmp_path, data, pattern):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=pattern):
        Config.from_json(path)


@pytest.mark.parametrize("arg, exc, pattern", [
    ("[1, 2]", ValueError, r"Config JSON text: Config must be a JSON object, got list"),
    ("{" * 100_000, ValueError, r"Config JSON text: JSON nested too deeply|Config JSON text: invalid JSON"),
    ('{"n_uavs": 1e999}', ValueError, r"Config JSON text: Config\.n_uavs must be an integer .* got inf"),
    (123, TypeError, r"Config\.from_json takes a JSON string or a path, got int"),
], ids=["list", "deep", "overflow", "not text"])
def test_config_json_text_errors(arg, exc, pattern):
    with pytest.raises(exc, match=pattern):
        Config.from_json(arg)


def test_config_dict_with_non_string_keys_names_them():
    with pytest.raises(ValueError, match=r"unknown field\(s\) \[1, 'x'\]"):
        Config.from_dict({1: 2, "x": 3})


# ----------------------------------------------------------------------------- Scenario
def test_scenario_rejects_a_polytope_above_the_altitude():
    tower = Polytope.prism(SQUARE, 200.0)
    low = Polytope.prism([[20.0, 0.0], [30.0, 0.0], [30.0, 10.0]], 10.0)
    with pytest.raises(ValueError, match=r"Scenario: polytope 1 is 200 m high, not below the flight altitude "
                                         r"config\.altitude = 80 m \(1 such polytope\(s\)\); lower it"):
        _scenario(Terrain((low, tower)))
    with pytest.raises(ValueError, match=r"polytope 0 is 80 m high"):
        _scenario(Terrain((Polytope.prism(SQUARE, 80.0),)))


def test_scenario_accepts_a_top_within_d_safe2_of_the_altitude():
    c = Config(n_slots=10)
    assert c.altitude - c.d_safe2 < 75.0 < c.altitude
    _scenario(Terrain((Polytope.prism(SQUARE, 75.0),)), c)


SCENARIO_CASES = {
    "track delta": (lambda c: _scenario(c=c, track=_track(c, delta=0.5)), ValueError,
                    r"track\.delta = 0\.5 s but config\.delta = 1 s; build the track with delta=config\.delta"),
    "track z": (lambda c: _scenario(c=c, track=_track(c, z=3.0)), ValueError,
                r"track\.z = 3 m but config\.target_height = 1\.5 m"),
    "config type": (lambda c: Scenario(c.to_dict(), Terrain(), _track(c), [[0.0, 0.0]], [0.0]), TypeError,
                    r"Scenario\.config must be a Config, got dict"),
    "terrain type": (lambda c: Scenario(c, [], _track(c), [[0.0, 0.0]], [0.0]), TypeError,
                     r"Scenario\.terrain must be a Terrain, got list"),
    "track type": (lambda c: Scenario(c, Terrain(), _road(), [[0.0, 0.0]], [0.0]), TypeError,
                   r"Scenario\.track must be a TargetTrack, got Road"),
    "starts not numbers": (lambda c: Scenario(c, Terrain(), _track(c), [["a", "b"]], [0.0]), ValueError,
                           r"Scenario: uav_xy must be \(U, 2\)"),
    "team too large": (lambda c: Scenario(c, Terrain(), _track(c), np.zeros((65, 2)), np.zeros(65)), ValueError,
                       r"Scenario: n_uavs must be an integer >= 1 and <= 64, got 65"),
    "random team too large": (lambda c: Scenario.random(0, c, n_uavs=65), ValueError,
                              r"Scenario\.random: n_uavs must be an integer >= 1 and <= 64"),
    "random team fractional": (lambda c: Scenario.random(0, c, n_uavs=2.5), ValueError,
                               r"Scenario\.random: n_uavs must be an integer"),
    "sample more than fit": (lambda c: Scenario.random(0, c.replace(d_safe1=42.0)).sample_starts(
        np.random.default_rng(0), 4), ValueError,
        r"room for only 3 starts d_safe1=42 m apart, asked for n_uavs=4 \(the config's n_uavs=3 fit\)"),
}


@pytest.mark.parametrize("make, exc, pattern", SCENARIO_CASES.values(), ids=SCENARIO_CASES.keys())
def test_scenario_rejects(make, exc, pattern):
    with pytest.raises(exc, match=pattern):
        make(Config(n_slots=10))


# ----------------------------------------------------------------------------- start placement
def _historical_starts(c, terrain, track, rng, u):
    """The sampler of earlier releases, verbatim (it raised where the fallbacks now take over)."""
    q0, phi0 = track.position(0), float(track.heading(0))
    nodes = grid_nodes(q0[:2], phi0, c.grid_step, c.r1, c.r2, c.mu, c.r_u)
    nodes = nodes[line_of_sight(terrain, nodes, c.altitude, q0)]
    picked = []
    for idx in rng.permutation(len(nodes)):
        p = nodes[idx]
        if all(np.hypot(*(p - o)) >= 2 * c.d_safe1 for o in picked):
            picked.append(p)
            if len(picked) == u:
                break
    if len(picked) < u:
        return None
    return np.array(picked), rng.uniform(0, 2 * math.pi, u)


@pytest.mark.parametrize("overrides, seeds", [
    (dict(), range(40)),
    (dict(d_safe1=20.0), range(150)),                       # the case: 239 of 300 resets failed
    (dict(d_safe1=20.0, n_polytopes=30, max_radius=30.0), range(60)),
    (dict(d_safe1=42.0), range(60)),                        # only the lattice-order fallback fits 3 UAVs
])
def test_starts_always_placed_and_unchanged_where_they_were(overrides, seeds):
    c = Config(**overrides)
    old_ok = 0
    for seed in seeds:
        terrain, track, rng = Scenario.random_world(seed, c)
        xy, th = sample_starts_on(c, terrain, track, copy.deepcopy(rng), c.n_uavs, "t")
        old = _historical_starts(c, terrain, track, copy.deepcopy(rng), c.n_uavs)
        if old is not None:                                  # results are compared across releases
            old_ok += 1
            np.testing.assert_array_equal(xy, old[0])
            np.testing.assert_array_equal(th, old[1])
        # The documented invariants: distinct lattice nodes of the eroded zone, d_safe1 apart (eq. 2).
        q0, phi0 = track.position(0), float(track.heading(0))
        nodes = grid_nodes(q0[:2], phi0, c.grid_step, c.r1, c.r2, c.mu, c.r_u)
        assert all(np.any(np.all(nodes == p, axis=1)) for p in xy)
        assert in_feasible_zone(xy, q0[:2], phi0, c.r1, c.r2, c.mu, c.r_u).all()
        d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        assert d.min() >= c.d_safe1
        assert xy.shape == (c.n_uavs, 2) and th.shape == (c.n_uavs,) and np.all((th >= 0) & (th < 2 * math.pi))
    if not overrides:
        assert old_ok == len(seeds)


def test_starts_prefer_visible_nodes_in_the_fallback():
    """Where the historical sampler failed, the fallback's first UAV still starts in clear LoS if any node has it."""
    c = Config(d_safe1=20.0)
    checked = 0
    for seed in range(40):
        terrain, track, rng = Scenario.random_world(seed, c)
        if _historical_starts(c, terrain, track, copy.deepcopy(rng), c.n_uavs) is not None:
            continue
        xy, _ = sample_starts_on(c, terrain, track, copy.deepcopy(rng), c.n_uavs, "t")
        q0, phi0 = track.position(0), float(track.heading(0))
        nodes = grid_nodes(q0[:2], phi0, c.grid_step, c.r1, c.r2, c.mu, c.r_u)
        if line_of_sight(terrain, nodes, c.altitude, q0).any():
            assert line_of_sight(terrain, xy[:1], c.altitude, q0)[0]
            checked += 1
    assert checked > 0


def test_env_resets_never_fail_with_a_tight_config():
    import covert_env

    env = covert_env.parallel_env(config=Config(d_safe1=20.0), max_cycles=5)
    for seed in range(30):
        env.reset(seed=seed)
    env.close()


# ----------------------------------------------------------------------------- Road, TargetTrack
ROAD_CASES = {
    "points strings": (lambda: Road([["a", "b"], ["c", "d"]]),
                       ValueError, r"Road\.points must be a \(K, 2\) array of numbers"),
    "points bools": (lambda: Road([[True, False], [False, True]]),
                     ValueError, r"Road\.points must be a \(K, 2\) array of numbers \(int or float\), got \[\[True"),
    "curvature absurd": (lambda: Road.random(0, max_curvature=1e9), ValueError,
                         r"Road\.random: max_curvature must be <= 1 \(1/m"),
    "point_at NaN": (lambda: _road().point_at(math.nan), ValueError, r"Road\.point_at: arc length s must be finite"),
    "point_at string": (lambda: _road().point_at("10"), TypeError, r"Road\.point_at: arc length s must be numbers"),
    "distance_to 3-D points": (lambda: _road().distance_to([[0.0, 1.0, 2.0]]), ValueError,
                               r"Road\.distance_to: xy must be points \(\.\.\., 2\), got shape \(1, 3\)"),
    "speeds absurd": (lambda: TargetTrack(_road(), [1e300] * 3), ValueError,
                      r"TargetTrack\.speeds must be a non-empty 1-D array of numbers in \[0, 10000\]"),
    "speeds bools": (lambda: TargetTrack(_road(), [True] * 3), ValueError, r"TargetTrack\.speeds must be"),
    "noise bound absurd": (lambda: _track(Config(n_slots=10)).with_speed_noise(1e300, 0), ValueError,
                           r"with_speed_noise: bound must be a number in \[0, max\(speeds\) \* delta = 10\]"),
    "position at a float slot": (lambda: _track(Config(n_slots=10)).position(np.array([1.5])), TypeError,
                                 r"TargetTrack\.position: slot k must be an integer"),
    "heading at NaN": (lambda: _track(Config(n_slots=10)).heading(math.nan), TypeError,
                       r"TargetTrack\.heading: slot k must be an integer"),
    "predict a huge horizon": (lambda: _track(Config(n_slots=10)).predict(0, 10**9), ValueError,
                               r"TargetTrack\.predict: horizon must be an integer in \[0, 1000\], got 1000000000"),
    "predict a negative horizon": (lambda: _track(Config(n_slots=10)).predict(0, -2), ValueError,
                                   r"TargetTrack\.predict: horizon must be an integer in \[0, 1000\], got -2"),
    "predict from a float slot": (lambda: _track(Config(n_slots=10)).predict(1.5, 2), ValueError,
                                  r"TargetTrack\.predict: k must be an integer >= -1, got 1\.5"),
    "fractions outside the slot": (lambda: _track(Config(n_slots=10)).position_between(0, [0.5, 2.0]), ValueError,
                                   r"position_between: fractions must lie in \[0, 1\]"),
    "length negative": (lambda: Road.random(0, length=-5.0),
                        ValueError, r"Road\.random: length must be a finite number > 0, got -5\.0"),
    "length nan": (lambda: Road.random(0, length=math.nan),
                   ValueError, r"Road\.random: length must be a finite number > 0, got nan"),
    "length huge": (lambda: Road.random(0, length=1e12),
                    ValueError, r"length / step = 1e\+12 / 2 would give more than 1000000 points"),
    "step zero": (lambda: Road.random(0, step=0.0),
                  ValueError, r"Road\.random: step must be a finite number > 0, got 0\.0"),
    "curvature negative": (lambda: Road.random(0, max_curvature=-1.0),
                           ValueError, r"max_curvature must be a finite number >= 0"),
    "straight_start string": (lambda: Road.random(0, straight_start="60"),
                              ValueError, r"straight_start must be a finite number >= 0, got '60'"),
    "heading inf": (lambda: Road.random(0, heading=math.inf),
                    ValueError, r"heading must be a finite number \(rad\), got inf"),
    "start wrong shape": (lambda: Road.random(0, start=(1.0, 2.0, 3.0)), ValueError, r"start must be a point \(x, y\)"),
    "start nan": (lambda: Road.random(0, start=(math.nan, 0.0)), ValueError, r"start must be finite"),
    "seed negative": (lambda: Road.random(-1),
                      ValueError, r"Road\.random: seed must be None, an integer >= 0 or a numpy Generator, got -1"),
    "seed float": (lambda: Road.random(1.5), ValueError, r"Road\.random: seed must be .* got 1\.5"),
    "track road type": (lambda: TargetTrack("road", [1.0]), TypeError, r"TargetTrack\.road must be a Road, got str"),
    "track speeds empty": (lambda: TargetTrack(_road(), []),
                           ValueError, r"TargetTrack\.speeds must be a non-empty 1-D array"),
    "track speeds strings": (lambda: TargetTrack(_road(), ["fast"]),
                             ValueError, r"TargetTrack\.speeds .* got \['fast'\]"),
    "track delta zero": (lambda: TargetTrack(_road(), [1.0], delta=0.0),
                         ValueError, r"TargetTrack\.delta must be a finite number > 0 \(s\), got 0\.0"),
    "track delta nan": (lambda: TargetTrack(_road(), [1.0], delta=math.nan),
                        ValueError, r"TargetTrack\.delta must be .* got nan"),
    "track z nan": (lambda: TargetTrack(_road(), [1.0], z=math.nan),
                    ValueError, r"TargetTrack\.z must be a finite number \(m\), got nan"),
    "track s0 string": (lambda: TargetTrack(_road(), [1.0], s0="0"),
                        ValueError, r"TargetTrack\.s0 must be a finite number \(m\), got '0'"),
    "constant n_slots fractional": (lambda: TargetTrack.constant(_road(), 10.0, 2.5), ValueError,
                                    r"TargetTrack\.constant: n_slots must be an integer >= 1 and <= 20000, got 2\.5"),
    "constant speed string": (lambda: TargetTrack.constant(_road(), "10", 5), ValueError,
                              r"TargetTrack\.constant: speed must be a finite number >= 0 \(m/s\), got '10'"),
}


@pytest.mark.parametrize("make, exc, pattern", ROAD_CASES.values(), ids=ROAD_CASES.keys())
def test_road_and_track_reject(make, exc, pattern):
    with pytest.raises(exc, match=pattern):
        make()


def test_constant_track_accepts_numpy_count():
    assert TargetTrack.constant(_road(), 10.0, np.int64(4)).n_slots == 4


# ----------------------------------------------------------------------------- Polytope, Terrain
TERRAIN_CASES = {
    "prism height string": (lambda: Polytope.prism(SQUARE, "30"),
                            ValueError, r"Polytope\.prism: height must be a number > 0 \(m\), got '30'"),
    "prism height nan": (lambda: Polytope.prism(SQUARE, math.nan), ValueError, r"Polytope: top vertex 0 is not finite"),
    "prism base strings": (lambda: Polytope.prism([["a", "b"]] * 3, 30.0),
                           ValueError, r"Polytope: base must be an \(n, 2\) array of numbers"),
    "base inf": (lambda: Polytope.prism([[0.0, 0.0], [math.inf, 0.0], [0.0, 1.0]], 5.0),
                 ValueError, r"base vertex 1 is not finite"),
    "two vertices": (lambda: Polytope.prism([[0.0, 0.0], [1.0, 0.0]], 5.0),
                     ValueError, r"base must have at least 3 vertices, got 2"),
    "terrain not iterable": (lambda: Terrain(5),
                             TypeError, r"Terrain\.polytopes must be an iterable of Polytope, got int"),
    "terrain of arrays": (lambda: Terrain([np.zeros((3, 2))]),
                          TypeError, r"Terrain: polytope 0 must be a Polytope, got ndarray"),
    "random seed negative": (lambda: Terrain.random(seed=-1, road=_road()),
                             ValueError, r"Terrain\.random: seed must be None, an integer >= 0"),
    "random seed string": (lambda: Terrain.random(seed="1", road=_road()),
                           ValueError, r"Terrain\.random: seed must be .* got '1'"),
    "random road type": (lambda: Terrain.random(0, road=[[0, 0], [1, 0]]),
                         TypeError, r"Terrain\.random: road must be a Road or None, got list"),
    "random config type": (lambda: Terrain.random(0, config={"n_polytopes": 3}),
                           TypeError, r"Terrain\.random: config must be a Config, got dict"),
    "random n huge": (lambda: Terrain.random(0, n=10**7),
                      ValueError, r"Terrain\.random: n must be an integer >= 0 and <= 10000"),
    "random no room": (lambda: Terrain.random(0, road=Road([[0.0, 0.0], [60.0, 0.0]]), n=40), ValueError,
                       r"could not place polytope \d+ of 40 .* use fewer polytopes \(n / Config\.n_polytopes\), "
                       r"a smaller max_radius \(22\) or road_clearance \(6\)"),
    "random override bad": (lambda: Terrain.random(0, max_vertices=10**9),
                            ValueError, r"Config\.max_vertices must be an integer >= 3 and <= 64"),
    "validate altitude nan": (lambda: Terrain((Polytope.prism(SQUARE, 30.0),)).validate(math.nan), ValueError,
                              r"altitude must be a positive finite number or None, got nan"),
    "polytope validate altitude string": (lambda: Polytope.prism(SQUARE, 30.0).validate("80"), ValueError,
                                          r"altitude must be a positive finite number or None, got '80'"),
}


@pytest.mark.parametrize("make, exc, pattern", TERRAIN_CASES.values(), ids=TERRAIN_CASES.keys())
def test_terrain_rejects(make, exc, pattern):
    with pytest.raises(exc, match=pattern):
        make()


# ----------------------------------------------------------------------------- large terrains
def _city(n_side: int, pitch: float = 12.0, size: float = 8.0) -> dict:
    feats = []
    for k in range(n_side * n_side):
        x, y = pitch * (k // n_side), pitch * (k % n_side)
        ring = [[x, y], [x + size, y], [x + size, y + size], [x, y + size], [x, y]]
        feats.append({"type": "Feature", "id": k, "properties": {"height": 10.0 + k % 7},
                      "geometry": {"type": "Polygon", "coordinates": [ring]}})
    return {"type": "FeatureCollection", "features": feats}


@pytest.mark.slow
def test_ten_thousand_buildings_load_and_overlaps_are_found(tmp_path):
    """The overlap check is an R-tree query, not an M x M array (which needed 25 GB for 23k buildings)."""
    obj = _city(100)                                        # 10,000 disjoint buildings: the most a Terrain holds
    path = tmp_path / "city.geojson"
    path.write_text(json.dumps(obj))
    t0 = time.perf_counter()
    terrain = Terrain.load(path, altitude=80.0)
    print(f"\nTerrain.load of {len(terrain)} buildings: {time.perf_counter() - t0:.2f} s")
    assert len(terrain) == 100 * 100
    np.testing.assert_array_equal(terrain[101].base, [[12.0, 12.0], [20.0, 12.0], [20.0, 20.0], [12.0, 20.0]])
    assert terrain.z_max[143] == 10.0 + 143 % 7
    # A planted overlap is found and named by both features, wherever it sits in the file.
    i, j = 9_000, 7_001
    x, y = obj["features"][j]["geometry"]["coordinates"][0][0]
    obj["features"][i]["geometry"]["coordinates"] = [[[x + 4, y + 4], [x + 9, y + 4], [x + 9, y + 9], [x + 4, y + 9],
                                                      [x + 4, y + 4]]]
    path.write_text(json.dumps(obj))
    with pytest.raises(ValueError, match=r"city\.geojson: feature 7001 \(id 7001\) and feature 9000 \(id 9000\): "
                                         r"footprints overlap \(intersection area 16 m\^2\)"):
        Terrain.load(path)
    polys = list(terrain.polytopes)
    polys[i] = Polytope.prism([[x + 4, y + 4], [x + 9, y + 4], [x + 9, y + 9], [x + 4, y + 9]], 20.0)
    with pytest.raises(ValueError, match=r"Terrain: polytopes 7001 and 9000: footprints overlap"):
        Terrain(polys)


@pytest.mark.parametrize("text, pattern", [
    ('{"n_uavs": 2, "n_uavs": 3}', r"Config JSON text: invalid JSON \(the key 'n_uavs' appears twice in one object"),
    ('{"n_uavs": ' + "9" * 5001 + "}", r"Config JSON text: Config\.n_uavs must be an integer >= 1 and <= 64, got "
                                       r"<an integer of 5001 digits>"),
])
def test_json_that_python_would_read_loosely_is_refused(text, pattern):
    with pytest.raises(ValueError, match=pattern):
        Config.from_json(text)


def test_a_nul_byte_in_a_path_is_named():
    from pathlib import Path

    with pytest.raises(ValueError, match=r"Config file 'a\\x00b': a path cannot hold a NUL byte"):
        Config.from_json(Path("a\x00b"))
    with pytest.raises(ValueError, match=r"Terrain file 'a\\x00b': a path cannot hold a NUL byte"):
        Terrain.load("a\x00b")


def test_terrain_sizes_are_refused_before_any_geometry_work(tmp_path):
    """A file with too many polytopes or vertices fails at once, naming the count and the bound."""
    from covert_env.world.polytope import MAX_TERRAIN_VERTICES

    path = tmp_path / "huge.geojson"
    path.write_text(json.dumps(_city(101)))                 # 10,201 buildings
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"huge\.geojson: GeoJSON FeatureCollection has 10201 polytopes, more than "
                                         r"10000; split the area"):
        Terrain.load(path)
    assert time.perf_counter() - t0 < 2.0                   # parsing 10,201 features takes several seconds
    ring = np.c_[np.cos(np.linspace(0, 2 * np.pi, 201)[:-1]), np.sin(np.linspace(0, 2 * np.pi, 201)[:-1])]
    feats = [{"type": "Feature", "properties": {"height": 10.0},
              "geometry": {"type": "Polygon", "coordinates": [(3 * ring + [3.0 * k, 0.0]).tolist()
                                                              + [(3 * ring[0] + [3.0 * k, 0.0]).tolist()]]}}
             for k in range(MAX_TERRAIN_VERTICES // 200 + 1)]
    with pytest.raises(ValueError, match=rf"has {200 * (MAX_TERRAIN_VERTICES // 200 + 1)} footprint vertices in all, "
                                         rf"more than {MAX_TERRAIN_VERTICES}; simplify"):
        Terrain.from_geojson({"type": "FeatureCollection", "features": feats})


COORDINATE_CASES = {
    "integer beyond float": (lambda: Polytope.prism([[0, 0], [10**400, 0], [0, 5]], 5.0),
                             r"Polytope: base must be an \(n, 2\) array of numbers \(int too large to convert"),
    "road at 1e308": (lambda: Road([[0.0, 0.0], [1e308, 0.0]]), r"Road\.points\[1, 0\] = 1e\+308 must be a finite "
                                                                 r"coordinate within \+-1e\+06 m"),
    "road just outside": (lambda: Road([[0.0, 0.0], [0.0, -1.5e6]]), r"Road\.points\[1, 1\] = -1500000\.0"),
    "random road start far away": (lambda: Road.random(0, start=(0.0, 2e6)),
                                   r"Road\.random: start\[1\] = 2000000\.0 must be a finite coordinate"),
    "footprint at 1e300": (lambda: Polytope.prism([[0, 0], [1e300, 0], [1e300, 1e300], [0, 1e300]], 10.0),
                           r"Polytope: base\[1, 0\] = 1e\+300 must be a finite coordinate"),
    "top absurdly high": (lambda: Polytope(np.array(SQUARE), np.c_[np.array(SQUARE), [1e7] * 4]),
                          r"Polytope: top\[0, 2\] = 10000000\.0 must be a finite coordinate"),
    "flat starts of 3 UAVs": (lambda: Scenario(Config(n_slots=10), Terrain(), _track(Config(n_slots=10)),
                                               [0.0, 0.0, 1.0, 1.0, 2.0, 2.0], [0.0, 0.0, 0.0]),
                              r"Scenario: uav_xy must be \(U, 2\) and uav_theta \(U,\).*got shapes \(6,\) and \(3,\)"),
    "starts of 3 columns": (lambda: Scenario(Config(n_slots=10), Terrain(), _track(Config(n_slots=10)),
                                             [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], [0.0, 0.0, 0.0]),
                            r"got shapes \(2, 3\) and \(3,\)"),
    "uav start at 1e308": (lambda: Scenario(Config(n_slots=10), Terrain(), _track(Config(n_slots=10)), [[1e308, 0.0]],
                                            [0.0]), r"Scenario\.uav_xy\[0, 0\] = 1e\+308 must be a finite coordinate"),
}


@pytest.mark.parametrize("make, pattern", COORDINATE_CASES.values(), ids=COORDINATE_CASES.keys())
def test_coordinates_are_bounded(make, pattern):
    with pytest.raises(ValueError, match=pattern):
        make()


def test_the_largest_lengths_make_a_working_env():
    """The bounds are not just numbers: a config at MAX_LENGTH's altitude builds its scene and steps, finite."""
    import covert_env

    env = covert_env.parallel_env(config=Config(altitude=1e5, n_slots=3), n_uavs=1)
    env.reset(seed=0)
    _, rewards, *_ , infos = env.step({"uav_0": np.zeros(2, np.float32)})
    assert math.isfinite(rewards["uav_0"]) and math.isfinite(infos["uav_0"]["terrain_clearance"])


def _brute_first_overlap(polys):
    for i in range(len(polys)):
        for j in range(i + 1, len(polys)):
            area = polys[i].footprint.intersection(polys[j].footprint).area
            if area > 1e-6:
                return i, j, area
    return None


@pytest.mark.parametrize("seed", range(8))
def test_rtree_overlap_check_matches_the_pairwise_definition(seed):
    """Same first pair and area as testing every pair; touching (an edge, a corner, 1e-7 m^2) is allowed."""
    rng = np.random.default_rng(seed)
    polys = [Polytope.prism(np.array(SQUARE) + (10.0 * (k % 5), 10.0 * (k // 5)), 5.0) for k in range(25)]
    polys.append(Polytope.prism([[49.9999, 5.0], [60.0, 5.0], [60.0, 5.001]], 5.0))   # overlaps one by ~1e-9 m^2
    for _ in range(int(rng.integers(0, 4))):
        c = rng.uniform(0, 50, 2)
        polys.append(Polytope.prism(np.array(SQUARE) * rng.uniform(0.1, 0.5) + c, 5.0))
    order = rng.permutation(len(polys))
    polys = [polys[k] for k in order]
    assert _first_overlap(polys) == _brute_first_overlap(polys)


# ----------------------------------------------------------------------------- config, scenario, terrain, track, engine
def _engine():
    from covert_env.world.engine import Engine

    return Engine(Scenario.paper(Config(n_slots=10)))


BOUNDARY_CASES = {
    "max_radius larger than the road": (lambda: Config(max_radius=1e4), ValueError,
                                        r"Config\.max_radius must be <= half the scenario road's length \(960 m"),
    "n_polytopes beyond the band's area": (lambda: Config(n_polytopes=300), ValueError,
                                           r"Config\.n_polytopes=300 cannot fit beside the 960 m scenario road"),
    "from_json empty": (lambda: Config.from_json(""), ValueError, r"empty JSON text or path ''"),
    "from_json blank": (lambda: Config.from_json("   "), ValueError, r"empty JSON text or path '   '"),
    "random seed negative": (lambda: Scenario.random(-1), ValueError,
                             r"Scenario\.random: seed must be an integer >= 0, got -1"),
    "random seed string": (lambda: Scenario.random("a"), ValueError, r"Scenario\.random: seed .* got 'a' \(str\)"),
    "random seed float": (lambda: Scenario.random(2.5), ValueError, r"Scenario\.random: seed .* got 2\.5 \(float\)"),
    "random config string": (lambda: Scenario.random(0, "abc"), TypeError,
                             r"Scenario\.random: config must be a Config or None, got 'abc'"),
    "random config dict": (lambda: Scenario.random(0, {"n_uavs": 2}), TypeError,
                           r"config must be a Config or None, got .*\(dict\); build it with Config\.from_dict"),
    "paper n_uavs fractional": (lambda: Scenario.paper(n_uavs=2.5), ValueError,
                                r"Scenario\.paper: n_uavs must be an integer .* got 2\.5"),
    "paper n_uavs string": (lambda: Scenario.paper(n_uavs="2"), ValueError,
                            r"Scenario\.paper: n_uavs must be an integer .* got '2'"),
    "paper config string": (lambda: Scenario.paper("abc"), TypeError,
                            r"Scenario\.paper: config must be a Config or None, got 'abc'"),
    "sample_starts rng string": (lambda: Scenario.paper(Config(n_slots=10)).sample_starts("x"), TypeError,
                                 r"sample_starts: rng must be a numpy Generator .* or an integer seed >= 0, got 'x'"),
    "polytope string coordinates": (lambda: Polytope([["0", "0"], ["10", "0"], ["10", "10"], ["0", "10"]],
                                                     [[0, 0, 20], [10, 0, 20], [10, 10, 20], [0, 10, 20]]),
                                    ValueError, r"Polytope: base must be an array of numbers .* convert them"),
    "polytope bool top": (lambda: Polytope(SQUARE, [[True] * 3] * 4), ValueError,
                          r"Polytope: top must be an array of numbers"),
    "terrain load None": (lambda: Terrain.load(None), TypeError, r"Terrain\.load: path must be a str or pathlib\.Path"),
    "terrain load int": (lambda: Terrain.load(5), TypeError, r"Terrain\.load: path .* got 5 \(int\)"),
    "terrain load empty": (lambda: Terrain.load(""), ValueError, r"Terrain\.load: path is empty"),
    "engine scenario string": (lambda: __import__("covert_env.world.engine").world.engine.Engine("abc"), TypeError,
                               r"Engine: scenario must be a Scenario .* got 'abc' \(str\)"),
    "engine scenario None": (lambda: __import__("covert_env.world.engine").world.engine.Engine(None), TypeError,
                             r"Engine: scenario must be a Scenario"),
    "track n_slots huge": (lambda: TargetTrack.constant(Road.random(0), 10.0, 10**9), ValueError,
                           r"TargetTrack\.constant: n_slots must be an integer >= 1 and <= 20000, got 1000000000"),
    "track route too long": (lambda: TargetTrack.constant(Road.random(0), 1e6, 100), ValueError,
                             r"TargetTrack\.constant: the route .* exceeds 200000 m"),
}


@pytest.mark.parametrize("make, exc, pattern", BOUNDARY_CASES.values(), ids=BOUNDARY_CASES.keys())
def test_boundaries_reject(make, exc, pattern):
    with pytest.raises(exc, match=pattern):
        make()


@pytest.mark.parametrize("value", [2.5, "11", None, 10**9, 1, True])
def test_engine_path_samples_is_an_integer_in_range(value):
    from covert_env.world.engine import Engine

    with pytest.raises(ValueError, match=r"Engine\.path_samples must be an integer in \[2, 1000\], got"):
        Engine(Scenario.paper(Config(n_slots=10)), path_samples=value)


ENGINE_STEP_CASES = {
    "unicycle (2, 2) for 3 UAVs": (dict(unicycle=np.ones((2, 2))), ValueError,
                                   r"unicycle must have shape \(U, 2\) \(U = 3 UAVs\), got shape \(2, 2\)"),
    "unicycle (2, 3)": (dict(unicycle=np.full((2, 3), 10.0)), ValueError, r"unicycle must have shape \(U, 2\)"),
    "unicycle string": (dict(unicycle="fast"), TypeError, r"unicycle must be a \(U, 2\) array of numbers .* 'fast'"),
    "unicycle string numbers": (dict(unicycle=[["10", "0"]] * 3), TypeError, r"unicycle must be a \(U, 2\) array"),
    "waypoints (3,)": (dict(waypoints=np.zeros(3)), ValueError, r"waypoints must have shape \(U, 2\) .* \(3,\)"),
    "waypoints ragged": (dict(waypoints=[[0.0, 1.0], [2.0]]), TypeError, r"waypoints must be a \(U, 2\) array"),
    "decision_time wrong size": (dict(unicycle=np.tile([[10.0, 0.0]], (3, 1)), decision_time=[1.0]), ValueError,
                                 r"decision_time must have shape \(U,\)"),
}


@pytest.mark.parametrize("kwargs, exc, pattern", ENGINE_STEP_CASES.values(), ids=ENGINE_STEP_CASES.keys())
def test_engine_step_rejects(kwargs, exc, pattern):
    e = _engine()
    with pytest.raises(exc, match=pattern):
        e.step(**kwargs)
    assert e.k == 0


@pytest.mark.parametrize("xy, theta, pattern", [
    (np.full((3, 2), np.nan), np.zeros(3), r"uav_xy positions and uav_theta headings must be finite"),
    (np.zeros((3, 2)), [0.0, np.inf, 0.0], r"must be finite"),
    (np.zeros((2, 2)), np.zeros(3), r"2 positions \(uav_xy\) but 3 headings \(uav_theta\)"),
    ("abc", np.zeros(3), r"uav_xy must be a \(U, 2\) array of numbers"),
], ids=["nan positions", "inf heading", "count mismatch", "string"])
def test_engine_reset_rejects(xy, theta, pattern):
    with pytest.raises(ValueError, match=pattern):
        _engine().reset(xy, theta)


def test_engine_accepts_a_flat_single_uav_and_numpy_counts():
    from covert_env.world.engine import Engine

    e = Engine(Scenario.paper(Config(n_slots=10), n_uavs=1), path_samples=np.int64(5))
    e.step(unicycle=[10.0, 0.0])
    assert e.k == 1 and e.path_samples == 5


def test_sample_starts_takes_an_int_seed_like_its_generator():
    p = Scenario.paper(Config(n_slots=10))
    a = p.sample_starts(5)
    b = p.sample_starts(np.random.default_rng(5))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_scenario_team_may_differ_from_the_config_default():
    """Documented rule: a scenario's team is len(uav_xy); config.n_uavs is only the constructors' default."""
    from covert_env.world.engine import Engine

    p = Scenario.paper(Config(n_slots=10))
    sc = Scenario(p.config, p.terrain, p.track, p.uav_xy[:2], p.uav_theta[:2])
    assert sc.n_uavs == 2 and sc.config.n_uavs == 3
    assert Engine(sc).n_uavs == 2


@pytest.mark.parametrize("kwargs", [dict(), dict(n_polytopes=150), dict(max_radius=480.0),
                                    dict(d_safe1=20.0, n_polytopes=30, max_radius=30.0), dict(n_slots=1, horizon=1)])
def test_terrain_feasibility_checks_keep_workable_configs(kwargs):
    Config(**kwargs)


def test_footprint_vertex_bound_fails_fast_in_a_file(tmp_path):
    from covert_env.world.polytope import MAX_FOOTPRINT_VERTICES

    n = 2_000                                          # one footprint: the bound per footprint, not the terrain's
    ring = [[100 * math.cos(2 * math.pi * k / n), 100 * math.sin(2 * math.pi * k / n)] for k in range(n)]
    ring.append(ring[0])
    path = tmp_path / "big.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"height": 20},
        "geometry": {"type": "Polygon", "coordinates": [ring]}}]}))
    with pytest.raises(ValueError, match=rf"{n} vertices, more than {MAX_FOOTPRINT_VERTICES}; simplify"):
        Terrain.load(path, altitude=80.0)
