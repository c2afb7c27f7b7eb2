"""Scene sets as data (covert_env.world.scene_set): a family's scenes saved and loaded bit for bit, bad files named, and
the harness flying a set exactly as it flies the family's held-out seeds."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import covert_env
from covert_env.cli import main as cli_main
from covert_env.world.scene_set import SceneSet


@pytest.fixture(scope="module")
def towers():
    return SceneSet.generate("towers", 2)


def test_a_saved_set_loads_bit_for_bit(tmp_path, towers):
    path = tmp_path / "towers.json"
    towers.save(path)
    back = SceneSet.load(path)
    assert back.family == "towers" and back.seeds == [1_000_000, 1_000_001] and back.config == towers.config
    for a, b in zip(towers, back, strict=True):
        assert a.name == b.name and np.array_equal(a.uav_xy, b.uav_xy) and np.array_equal(a.uav_theta, b.uav_theta)
        assert np.array_equal(a.track.positions, b.track.positions) and np.array_equal(a.track.road.points,
                                                                                      b.track.road.points)
        assert all(np.array_equal(p.vertices, q.vertices) for p, q in zip(a.terrain, b.terrain, strict=True))
    assert SceneSet.load(path).to_json() == back.to_json()                 # two loads, two labs: the same data


def test_a_loaded_scene_flies_as_the_generated_one(tmp_path, towers):
    """Seeded waypoint rollouts on a generated and on a loaded scene: the same rewards and observations."""
    towers.save(tmp_path / "t.json")
    loaded = SceneSet.load(tmp_path / "t.json")
    sums = []
    for sc in (towers[0], loaded[0]):
        env = covert_env.parallel_env(scenario=sc, action_mode="waypoint")
        obs, _ = env.reset(seed=0)
        rng, total = np.random.default_rng(0), []
        while env.agents:
            obs, rew, *_ = env.step({a: int(rng.choice(np.flatnonzero(env.action_mask(a)))) for a in env.agents})
            total.append((sum(rew.values()), sum(float(o.sum()) for o in obs.values())))
        sums.append(total)
    assert sums[0] == sums[1] and len(sums[0]) == towers.config.n_slots


@pytest.mark.parametrize("mutate, match", [
    (lambda o: o.update(format="x"), "not a scene set"),
    (lambda o: o.update(version=2), "version 2"),
    (lambda o: o["config"].update(n_uavs=0), "scene set config"),
    (lambda o: o.update(family="nope"), "family must be one of"),
    (lambda o: o.update(scenes=[]), "list of 1 to"),
    (lambda o: o["scenes"][1].pop("road"), r"scene 1: KeyError'road'"),
    (lambda o: o["scenes"][0]["starts"].update(xy=[[0.0, 0.0, 0.0]] * 3), "scene 0: "),
    (lambda o: o["scenes"][0]["track"].update(speeds=[-1.0]), "scene 0: TargetTrack.speeds"),
    (lambda o: o["scenes"][1]["terrain"]["features"][0]["properties"].update(top=[[0, 0, 1e9]]), "scene 1: "),
])
def test_bad_files_are_named_errors(tmp_path, towers, mutate, match):
    obj = json.loads(json.dumps(towers.to_json()))
    mutate(obj)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(obj))
    with pytest.raises(ValueError, match=match) as exc:
        SceneSet.load(path)
    assert str(path) in str(exc.value)


def test_generate_checks_its_arguments():
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="n must be an integer"):
            SceneSet.generate("paper", bad)
    with pytest.raises(ValueError, match="family must be one of"):
        SceneSet.generate("nope", 1)
    assert SceneSet.generate("sparse", seeds=[7]).seeds == [7]


def test_the_cli_writes_a_set_the_harness_flies_as_the_family(tmp_path, capsys):
    from covert_env.evaluation.evaluate import main

    path = tmp_path / "sets" / "dense1.json"
    assert cli_main(["scene-set", "--family", "dense", "--scenes", "1", "--out", str(path)]) == 0
    assert SceneSet.load(path).family == "dense"
    common = ["--policies", "random@waypoint", "--episodes", "1", "--no-progress"]
    assert main([*common, "--scene-set", str(path), "--out", str(tmp_path / "a")]) == 0
    assert main([*common, "--family", "dense", "--out", str(tmp_path / "b")]) == 0
    rows = [[{k: v for k, v in row.items() if k != "decision_time_ms"}               # a timing: not the same
             for row in csv.DictReader(open(tmp_path / d / "episodes.csv"))] for d in ("a", "b")]
    assert rows[0] == rows[1] and len(rows[0]) == 1
    assert "scene set" in (tmp_path / "a" / "leaderboard.md").read_text()
    for argv, message in (([*common, "--scene-set", str(path), "--family", "dense"], "do not go with it"),
                          (["--scene-set", str(path), "--episodes", "2"], "has 1 scenes"),
                          (["--scene-set", str(tmp_path / "none.json")], "--scene-set")):
        with pytest.raises(SystemExit):
            main([*argv, "--out", str(tmp_path / "c")])
        assert message in capsys.readouterr().err


# ---------------------------------------------------------------------- a set is checked against itself
def _edited(tmp_path, towers, edit):
    obj = towers.to_json()
    edit(obj)
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(obj))
    return path


def _move_polytope_onto_road(obj):
    scene = obj["scenes"][0]
    road = np.asarray(scene["road"]["points"])
    mid = road[len(road) // 2]
    feat = scene["terrain"]["features"][0]
    ring = np.asarray(feat["geometry"]["coordinates"][0])
    shift = mid - ring[:-1, :2].mean(axis=0)
    feat["geometry"]["coordinates"][0] = [[x + shift[0], y + shift[1], *rest] for x, y, *rest in ring.tolist()]
    for key in ("top",):
        if key in feat["properties"]:
            feat["properties"][key] = [[x + shift[0], y + shift[1], *rest] for x, y, *rest in feat["properties"][key]]


@pytest.mark.parametrize("edit, message", [
    (lambda o: o.update(family="downtown"), r"family 'downtown' draws with .* the family label and the config "
                                            r"disagree"),
    (lambda o: o["scenes"][1]["starts"].update(xy=o["scenes"][1]["starts"]["xy"][:2],
                                               theta=o["scenes"][1]["starts"]["theta"][:2]),
     r"scene 1 has 2 UAV starts, but the config's n_uavs is 3"),
    (lambda o: o["scenes"].__setitem__(1, o["scenes"][0]), r"scene 1 repeats scene 0"),
    (_move_polytope_onto_road, r"scene 0: polytope 0 stands on the road"),
    (lambda o: o["scenes"][0]["starts"].update(theta=[t + 1e-3 for t in o["scenes"][0]["starts"]["theta"]]),
     r"scene 0 \(seed 1000000\) is not what family 'towers' draws .*\(first difference: UAV starts\).*edited"),
    (lambda o: o["scenes"][1].update(seed=1_000_007), r"scene 1 \(seed 1000007\) is not what family 'towers' "
                                                      r"draws.*first difference: terrain"),
    (lambda o: o["scenes"][0].update(seed=1_000_000.5), r"scene 0: seed must be an integer in \[0, 2\^63 - 1\], "
                                                        r"got 1000000\.5"),
    (lambda o: o["scenes"][0].update(seed=2 ** 64), r"scene 0: seed must be an integer in \[0, 2\^63 - 1\]"),
    (lambda o: o["scenes"][0].update(seed=None), r"scene 0 has no seed but others have one"),
    (lambda o: o["scenes"][1]["track"].update(delta="1.0"), r"scene 1: track.delta must be a number, got '1.0'"),
])
def test_a_set_that_contradicts_itself_is_refused_naming_the_scene(tmp_path, towers, edit, message):
    path = _edited(tmp_path, towers, edit)
    with pytest.raises(ValueError, match=message) as exc:
        SceneSet.load(path)
    assert str(path) in str(exc.value)


def test_a_hand_made_set_without_family_or_seeds_is_not_drawn_again(tmp_path, towers):
    """Without a family or seeds there is nothing to draw from: edited starts load (the other checks still hold)."""
    def edit(o):
        o["family"] = None
        o["scenes"][0]["starts"]["theta"] = [t + 1e-3 for t in o["scenes"][0]["starts"]["theta"]]

    back = SceneSet.load(_edited(tmp_path, towers, edit))
    assert back.family is None and back.seeds == [1_000_000, 1_000_001]
    with pytest.raises(ValueError, match="no family or no seeds"):
        back.check_against_seeds()
