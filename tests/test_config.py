"""Config: paper defaults, validation messages that name the field, JSON round trip."""

import json
import math

import pytest

from covert_env import Config


def test_paper_defaults():
    c = Config()
    assert (c.v_max, c.w_max, c.altitude, c.horizon, c.delta) == (50, 3, 80, 5, 1)
    assert (c.eta, c.lam, c.d_safe1, c.d_safe2) == (55, 10, 5, 10)
    assert (c.mu, c.r1, c.r2, c.n_polytopes, c.n_slots) == (math.pi / 4, 55, 100, 16, 70)
    assert c.max_polytope_height == 70


def test_json_round_trip(tmp_path):
    c = Config(r_u=3.5, grid_step=5.0, h_min=20.0, n_uavs=1)
    assert Config.from_json(c.to_json()) == c
    c.to_json(tmp_path / "c.json")
    assert Config.from_json(tmp_path / "c.json") == c
    assert json.loads(c.to_json())["r_u"] == 3.5


@pytest.mark.parametrize("field, value, pattern", [
    ("r1", 100.0, r"r1 must be < Config.r2"),
    ("r2", 40.0, r"r1 must be < Config.r2"),
    ("v_max", 0.0, r"v_max must be > 0"),
    ("v_max", -5.0, r"v_max must be > 0"),
    ("w_max", -1.0, r"w_max must be > 0"),
    ("target_speed", 0.0, r"target_speed must be > 0"),
    ("mu", 0.0, r"mu must lie in \(0, 2\*pi\)"),
    ("mu", 7.0, r"mu must lie in \(0, 2\*pi\)"),
    ("altitude", float("nan"), r"altitude must be a finite number"),
    ("eta", float("inf"), r"eta must be a finite number"),
    ("horizon", 0, r"horizon must be an integer >= 1"),
    ("horizon", 2.5, r"horizon must be an integer >= 1"),
    ("n_uavs", 0, r"n_uavs must be an integer >= 1"),
    ("r_u", -1.0, r"r_u must be >= 0"),
    ("r_u", 30.0, r"r_u must be < \(r2 - r1\) / 2"),
    ("grid_step", 0.0, r"grid_step must be > 0"),
    ("h_min", 90.0, r"h_min must be None or in"),
    ("max_height", 85.0, r"max_height must be None or in"),
    ("min_vertices", 9, r"min_vertices must be <= max_vertices"),
    ("target_height", 80.0, r"target_height must be in"),
    ("d_safe1", float("nan"), r"d_safe1 must be a finite number"),
])
def test_validation_names_field(field, value, pattern):
    with pytest.raises(ValueError, match=pattern):
        Config(**{field: value})


def test_unknown_json_field_is_named():
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['speed'\]"):
        Config.from_dict({"speed": 3})
    with pytest.raises(ValueError, match="invalid JSON"):
        Config.from_json("{not json")
