"""The task suite (covert_env.world.tasks): names, configs, fixed scenes, and every env kind built from a task."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import covert_env
from covert_env import Config
from covert_env.world.families import FAMILIES, HELD_OUT_SEEDS, TRAIN_SEEDS, family_config
from covert_env.world.tasks import DEFAULT_TASKS, DEVIATION, TASKS, TEAM_SIZES, TEST_SCENES, get_task, resolve_tasks


def test_every_family_team_size_and_target_is_a_task_with_its_config():
    assert len(TASKS) == len(FAMILIES) * len(TEAM_SIZES) * 2
    for name, t in TASKS.items():
        c = t.config()
        assert name == f"{t.family}-{t.n_uavs}uav" + ("-deviating" if t.target == "deviating" else "")
        assert c.n_uavs == t.n_uavs
        fam = family_config(t.family)
        assert all(getattr(c, k) == getattr(fam, k) for k in FAMILIES[t.family].fields)
        want = (DEVIATION, DEVIATION) if t.target == "deviating" else (0.0, Config().r_u)
        assert (c.prediction_error, c.r_u) == want
        assert t.test_seeds == range(HELD_OUT_SEEDS.start, HELD_OUT_SEEDS.start + TEST_SCENES)
        assert t.train_seeds == TRAIN_SEEDS and not set(t.test_seeds) & set(range(0, 10_000))
    assert set(DEFAULT_TASKS) <= set(TASKS)


@pytest.mark.parametrize("name", list(TASKS))
def test_every_task_resets_on_its_first_test_scene_and_a_training_scene(name):
    """Each task's team fits its scenes (starts placed) on a held-out and a training scene, in both action modes."""
    t = get_task(name)
    venv = covert_env.vector_env(num_envs=2, task=name, action_mode="waypoint")
    obs, _ = venv.reset(seed=0, options={"scene_seed": [t.test_seeds[0], t.train_seeds[5]]})
    assert obs.shape[:2] == (2, t.n_uavs) and np.isfinite(obs).all()
    assert venv.config == t.config() and venv.task == name and venv.family == t.family


def test_a_task_is_its_family_team_and_target_bit_for_bit():
    """task="downtown-3uav-deviating" flies exactly the env built from its parts."""
    t = get_task("downtown-3uav-deviating")
    a = covert_env.parallel_env(task=t.name)
    b = covert_env.parallel_env(family="downtown", n_uavs=3, config=Config(prediction_error=DEVIATION, r_u=DEVIATION))
    for env in (a, b):
        env.reset(seed=3, options={"scene_seed": 1_000_004})
    rng = np.random.default_rng(0)
    for _ in range(10):
        act = {u: rng.uniform(-1, 1, 2).astype(np.float32) for u in a.agents}
        oa, ra = a.step(act)[:2]
        ob, rb = b.step(act)[:2]
        for u in act:
            np.testing.assert_array_equal(oa[u], ob[u])
            assert ra[u] == rb[u]


def test_task_conflicts_and_bad_names_are_clear_errors():
    with pytest.raises(ValueError, match="flies 3 UAV"):
        covert_env.parallel_env(task="paper-3uav", n_uavs=1)
    with pytest.raises(ValueError, match="'paper' family, got family='dense'"):
        covert_env.parallel_env(task="paper-3uav", family="dense")
    with pytest.raises(ValueError, match="needs scenario='random'"):
        covert_env.parallel_env(task="paper-1uav", scenario="paper")
    with pytest.raises(ValueError, match="config sets"):
        covert_env.parallel_env(task="paper-3uav-deviating", config=Config(prediction_error=1.0, r_u=1.0))
    for bad in ("paper", "paper-2uav", "Paper-3uav", 3, None):
        with pytest.raises(ValueError, match=r"task must be a task name .* got"):
            get_task(bad)
    with pytest.raises(ValueError, match="flies 3 UAV"):
        gym.make("covert_env/CovertSensing-v4", task="towers-3uav")
    assert gym.make("covert_env/CovertSensing-v4", task="towers-1uav").reset(seed=0)[0].shape == (139,)


def test_resolve_tasks_expands_groups_in_order_without_repeats():
    assert [t.name for t in resolve_tasks(["core"])] == list(DEFAULT_TASKS)
    assert [t.name for t in resolve_tasks(["towers-1uav", "core", "paper-3uav"])] == ["towers-1uav",
                                                                                          *DEFAULT_TASKS]
    assert len(resolve_tasks(["all", "core"])) == len(TASKS)


def test_the_harness_flies_a_task_on_its_held_out_scenes(tmp_path, capsys):
    """covert-env evaluate --task: the task's family, team and target on its test scenes; conflicting flags are one
    usage error each."""
    from covert_env.evaluation.evaluate import main

    out = tmp_path / "lb"
    assert main(["--task", "towers-1uav-deviating", "--policies", "hold-centre", "--episodes", "2", "--out", str(out),
                 "--no-progress"]) == 0
    text = (out / "leaderboard.md").read_text()
    assert "task towers-1uav-deviating" in text and "1 UAV(s)" in text
    rows = (out / "episodes.csv").read_text().splitlines()
    assert [r.split(",")[1] for r in rows[1:]] == ["1000000", "1000001"]
    for argv, msg in ((["--task", "paper-3uav", "--family", "dense"], "leave out --family"),
                      (["--task", "paper-1uav", "--n-uavs", "6"], "flies 1 UAV"),
                      (["--task", "paper-9uav"], "--task: task must be")):
        with pytest.raises(SystemExit) as e:
            main(argv + ["--out", str(out)])
        assert e.value.code == 2 and msg in capsys.readouterr().err


def test_a_config_that_changes_the_tasks_target_is_refused():
    """A nominal task's target drives its prediction exactly: a config with a prediction error contradicts it."""
    with pytest.raises(ValueError, match=r"task='paper-3uav' sets .*'prediction_error': 0\.0.*the config sets "
                                         r"\{'prediction_error': 2\.0\}"):
        covert_env.parallel_env(task="paper-3uav", config=Config(prediction_error=2.0, r_u=2.0))
    with pytest.raises(ValueError, match=r"the config sets \{'prediction_error': 1\.0\}"):
        covert_env.vector_env(num_envs=1, task="paper-3uav-deviating", config=Config(prediction_error=1.0))
    assert covert_env.parallel_env(task="paper-3uav-deviating").config.prediction_error == 4.0


@pytest.mark.parametrize("make", [lambda: covert_env.parallel_env(task="paper-3uav", action_mode="waypoint"),
                                  lambda: covert_env.vector_env(num_envs=2, task="paper-3uav", action_mode="waypoint")])
def test_construction_settings_are_read_only_after_construction(make):
    """Assigning a construction setting would change nothing the env built: it raises, naming the value it keeps."""
    from covert_env.envs.arguments import CONSTRUCTION_SETTINGS

    env = make()
    for name in CONSTRUCTION_SETTINGS:
        before = getattr(env, name)
        with pytest.raises(AttributeError, match=rf"\.{name} is a construction setting.*make a new env with {name}="):
            setattr(env, name, "other")
        assert getattr(env, name) is before
    env.max_cycles = 10                                  # a live setting: assignable
    assert env.max_cycles == 10
