"""Scene families (covert_env.world.families): valid presets whose scenes keep the generator's documented invariants,
selectable by name in every env kind and in the harness, reproducible across processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import shapely

import covert_env
from covert_env import Config, Scenario
from covert_env.envs.settings import MAX_SCENE_POOL
from covert_env.geometry.separation import team_separation
from covert_env.geometry.zone import in_feasible_zone, to_world, zone_lattice
from covert_env.world.families import FAMILIES, HELD_OUT_SEEDS, TRAIN_SEEDS, family_config, scene_family
from covert_env.world.metrics import terrain_clearance

#: Scenes checked per family: the first and last training seeds and the first held-out one.
SEEDS = (TRAIN_SEEDS.start, TRAIN_SEEDS.stop - 1, HELD_OUT_SEEDS.start)


def _max_curvature(road) -> float:
    """Largest heading change per metre between consecutive road segments."""
    d = np.diff(road.points, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return float((np.abs(np.diff(heading)) / np.hypot(d[1:, 0], d[1:, 1])).max())


def test_seed_ranges_are_disjoint_and_the_envs_and_harness_use_them():
    from baselines.reproduce import HELDOUT_SEED_BASE
    from covert_env.evaluation.evaluate import HELD_OUT_OFFSET

    assert TRAIN_SEEDS.stop <= HELD_OUT_SEEDS.start
    assert MAX_SCENE_POOL == len(TRAIN_SEEDS) and HELD_OUT_OFFSET == HELDOUT_SEED_BASE == HELD_OUT_SEEDS.start


@pytest.mark.parametrize("name", list(FAMILIES))
def test_family_scenes_keep_the_generators_invariants(name):
    """Footprints 2 m apart, road_clearance from the road, tops within [min_height, max_polytope_height], as many
    polytopes as asked; starts in the eroded zone, d_safe1 apart, d_safe2 from every top; the road as curved as
    the family says at most."""
    c = family_config(name)
    assert {k: getattr(c, k) for k in FAMILIES[name].fields} == dict(FAMILIES[name].fields)
    for seed in SEEDS:
        sc = Scenario.random(seed, c)
        polys = list(sc.terrain)
        assert len(polys) == c.n_polytopes
        fps = np.array([p.footprint for p in polys], dtype=object)
        gaps = shapely.distance(fps[:, None], fps[None, :])
        np.fill_diagonal(gaps, np.inf)
        assert gaps.min() >= 2.0 - 1e-9
        road = sc.track.road.linestring
        assert min(road.distance(fp) for fp in fps) >= c.road_clearance - 1e-9
        tops = np.array([p.vertices[:, 2].max() for p in polys])
        assert tops.min() >= c.min_height - 1e-9 and tops.max() <= c.max_polytope_height + 1e-9
        q0, phi0 = sc.track.position(0), sc.track.heading(0)
        assert in_feasible_zone(sc.uav_xy, q0[:2], phi0, c.r1, c.r2, c.mu, c.r_u).all()
        assert team_separation(sc.uav_xy[:, None, :]).min() >= c.d_safe1 - 1e-9
        assert terrain_clearance(sc.uav_xy, c.altitude, sc.terrain).min() >= c.d_safe2
        assert _max_curvature(sc.track.road) <= c.road_max_curvature * (1 + 1e-6) + 1e-12


def test_the_families_differ_as_documented():
    """sparse's road is straight; towers' tops come within d_safe2 of the flight altitude, so eq. 3 removes
    lattice nodes (no other family's do); downtown's zone is more shadowed than paper's."""
    sparse = Scenario.random(1_000_000, family_config("sparse"))
    assert _max_curvature(sparse.track.road) < 1e-12
    assert _max_curvature(Scenario.random(1_000_000, family_config("winding")).track.road) > 1 / 60
    for name in FAMILIES:
        c = family_config(name)
        sc = Scenario.random(1_000_000, c)
        q, phi = sc.track.positions[:c.n_slots], sc.track.headings[:c.n_slots]
        near = terrain_clearance(to_world(zone_lattice(c), q[:, :2], phi), c.altitude, sc.terrain) < c.d_safe2
        assert near.any() == (name == "towers"), name


def test_families_are_selected_by_name_in_every_env_kind():
    penv = covert_env.parallel_env(family="dense", n_uavs=2)
    penv.reset(seed=3)
    assert penv.family == "dense" and penv.config.n_polytopes == 48
    venv = covert_env.vector_env(num_envs=2, family="towers")
    venv.reset(seed=0)
    assert venv.family == "towers" and all(len(venv.scene(i).terrain) == 24 for i in range(2))
    genv = gym.make("covert_env/CovertSensing-v4", family="winding")
    assert genv.unwrapped.par.config.road_max_curvature == pytest.approx(1 / 30)
    aec = covert_env.env(family="sparse", n_uavs=2)
    aec.reset(seed=0)
    assert aec.unwrapped.config.n_polytopes == 8
    for env in (penv, venv, genv, aec):
        env.close()


@pytest.mark.parametrize("kwargs, match", [
    (dict(family="nope"), r"family must be one of \['sparse', 'paper'"),
    (dict(family=3), "family must be one of"),
    (dict(family="dense", scenario="paper"), "needs scenario='random'"),
    (dict(family="dense", config=Config(n_polytopes=20)), r"sets \{'n_polytopes': 48\}.*n_polytopes': 20"),
])
def test_bad_family_arguments_are_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        covert_env.parallel_env(**kwargs)


def test_a_family_keeps_the_callers_other_fields():
    c = family_config("dense", Config(n_uavs=5, altitude=90.0))
    assert (c.n_polytopes, c.n_uavs, c.altitude) == (48, 5, 90.0)
    assert family_config("dense", Config(n_polytopes=48)).n_polytopes == 48       # the same value: no clash
    assert scene_family("paper").config() == Config()
    with pytest.raises(TypeError):
        FAMILIES["dense"].fields["n_polytopes"] = 3                                  # read-only


def test_family_scenes_are_reproducible_across_processes():
    """A family's scene from a seed is the same in another interpreter with another hash seed."""
    code = ("import json, numpy as np; from covert_env import Scenario; from covert_env.world.families import "
            "family_config; sc = Scenario.random(1_000_001, family_config('downtown')); "
            "print(json.dumps([np.round(p.vertices, 9).tolist() for p in sc.terrain] + [sc.uav_xy.tolist()]))")
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={**os.environ, "PYTHONHASHSEED": str(h)}).stdout for h in (1, 2)]
    assert runs[0] == runs[1] and len(json.loads(runs[0])) == 57


def test_the_harness_takes_a_family(tmp_path):
    from covert_env.evaluation.evaluate import main

    assert main(["--policies", "random@waypoint", "--episodes", "1", "--family", "towers", "--no-progress",
                 "--out", str(tmp_path / "lb")]) == 0
    assert "family towers" in (tmp_path / "lb" / "leaderboard.md").read_text()
    with pytest.raises(SystemExit) as exc:
        main(["--family", "nope", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
