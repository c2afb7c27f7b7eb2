"""training.imitation: the planner's recorded slots, the filter of labels outside the mask, the flags' errors, a
smoke run with a DAgger round whose actor the harness loads, and that cloning fits the planner's choices."""

import json

import numpy as np
import pytest
from _extras import needs

torch = needs("torch")

import covert_env  # noqa: E402
from baselines.policies import make_policy  # noqa: E402
from training import imitation  # noqa: E402
from training.pretrained import load_learned  # noqa: E402

SETTINGS = {"action_mode": "waypoint", "mask_mode": "kinematic", "map_size": 16, "max_cycles": 4}
SMOKE = ["--recipe", "3uav-mappo", "--episodes-per-task", "2", "--val-episodes", "1", "--dagger-rounds", "1",
         "--dagger-episodes-per-task", "2", "--epochs", "1", "--max-cycles", "3", "--jobs", "1",
         "--progress-bar", "false"]


def test_teacher_episode_records_the_planners_nodes():
    ep = imitation.teacher_episode("paper-3uav", 5, "dp", SETTINGS)
    assert ep["obs"].shape == (12, 527) and ep["mask"].shape == (12, 577) and ep["mask"].dtype == bool
    assert ep["agent"].tolist() == [0, 1, 2] * 4
    # The same scene flown by the planner directly: the same nodes, slot by slot.
    env = covert_env.parallel_env(task="paper-3uav", **SETTINGS)
    pol = make_policy("dp")
    obs, _ = env.reset(seed=5, options={"scene_seed": 5})
    assert np.array_equal(ep["obs"][:3], np.stack([obs[a] for a in env.possible_agents]))   # before the step
    pol.reset(env, 5)
    nodes = []
    while env.agents:
        act = pol.act(obs, env)
        nodes += [act[a] for a in env.agents]
        obs, *_ = env.step(act)
    env.close()
    assert ep["label"].tolist() == nodes
    assert ep["mask"][np.arange(12), ep["label"]].all()


def test_dagger_episode_flies_the_student_and_labels_with_the_planner():
    """With a student the learned team flies: its states differ from the planner's after the first slot, and every
    label is the planner's node from the student's state."""
    from training.pretrained import PRETRAINED_DIR

    settings = {"action_mode": "waypoint", "mask_mode": "visible", "map_size": 8, "max_cycles": 4}
    own = imitation.teacher_episode("paper-3uav", 5, "dp", settings)
    flown = imitation.teacher_episode("paper-3uav", 5, "dp", settings, student=str(PRETRAINED_DIR / "mappo.npz"))
    assert np.array_equal(own["obs"][:3], flown["obs"][:3])
    assert not np.array_equal(own["obs"][3:], flown["obs"][3:])
    assert flown["mask"][np.arange(12), flown["label"]].all()


def test_join_holds_out_the_last_episodes_and_drops_labels_outside_the_mask():
    def ep(v, ok):
        mask = np.zeros((2, 4), bool)
        mask[:, 1] = True
        return {"obs": np.full((2, 3), v, np.float32), "mask": mask, "label": np.array([1, 1 if ok else 2]),
                "agent": np.array([0, 1])}
    train, val = imitation.join([ep(0, True), ep(1, False), ep(2, True)], 1)
    assert train["obs"][:, 0].tolist() == [0, 0, 1] and train["label"].tolist() == [1, 1, 1]
    assert val["obs"][:, 0].tolist() == [2, 2]
    assert imitation.join([ep(0, True)], 0)[1] is None


@pytest.mark.parametrize("flags, match", [
    (["--teacher", "dp-blind"], "argument --teacher: invalid choice: 'dp-blind'"),
    (["--recipe", "3uav-ppo"], "--recipe '3uav-ppo'"),
    (["--recipe", "3uav-suite"], "--recipe '3uav-suite': trains through the safety filter"),
    (["--val-episodes", "24"], "--val-episodes 24: must be below"),
    (["--epochs", "0"], "argument --epochs: must be an integer in [1, 100000], got 0"),
    (["--max-cycles", "0"], "argument --max-cycles: must be an integer >= 1, got 0"),
    (["--learning-rate", "nan"], "argument --learning-rate"),
    (["--seed", "1000"], "--seed 1000: must be below 1000"),
    (["--episodes-per-task", "900", "--dagger-episodes-per-task", "200"], "at most 1000 scenes per task"),
    (["--dagger-episodes-per-task", "2"], "--val-episodes 2: must be below --dagger-episodes-per-task (2)"),
])
def test_bad_flags_name_the_flag(flags, match, capsys):
    with pytest.raises(SystemExit) as exc:
        imitation.main(flags)
    assert exc.value.code == 2
    assert match in capsys.readouterr().err


def test_smoke_run_with_a_dagger_round_saves_a_loadable_team(tmp_path):
    needs("tensorboard")
    run = imitation.main([*SMOKE, "--runs-dir", str(tmp_path), "--run-name", "bc"])
    card = json.loads((run / "model.json").read_text())
    assert card["algorithm"] == "bc-dp" and card["imitation"]["dagger_rounds"] == 1
    assert card["train_tasks"] == ["paper-3uav"]
    assert card["separation_shield"] == 5.0 and card["env_kwargs"]["action_mode"] == "waypoint"
    curve = [json.loads(line) for line in (run / "curve.jsonl").read_text().splitlines()]
    assert [c["epoch"] for c in curve] == [1, 2]                    # one epoch per collection
    summary = json.loads((run / "train_summary.json").read_text())
    # 2 + 2 episodes of 3 slots and 3 UAVs, one episode per collection held out.
    assert summary["uav_slots"] == 18 and summary["held_out_uav_slots"] == 18
    with np.load(run / "data.npz", allow_pickle=False) as data:
        assert data["train.paper-3uav.label"].shape == (18,) and data["val.paper-3uav.obs"].shape[0] == 18
    assert summary["dropped_outside_mask"] >= 0 and 0 <= curve[-1]["val_agreement"] <= 1
    team = load_learned(run)
    env = covert_env.parallel_env(task="paper-3uav", **team.env_settings, max_cycles=2)
    obs, _ = env.reset(seed=1)
    act = team.act(obs, env)
    assert all(env.action_mask(a)[v] for a, v in act.items())
    env.close()


def test_cloning_fits_the_planners_choices():
    """Four hundred steps on 36 recorded UAV-slots: the cross-entropy falls by half and the actor ranks the planner's
    node first on at least 40 % of them (the node head scores nodes from smooth features, so it separates a node
    from its neighbours slowly; docs/decisions/learning.md, "Cloning the planner")."""
    margs = imitation.mappo_args("3uav-suite-shield")
    settings = imitation.env_settings(margs, 6)
    train, _ = imitation.join([imitation.teacher_episode("downtown-3uav", s, "dp", settings) for s in (0, 1)], 0)
    from training.mappo import make_networks, sizes_of
    from training.task_mix import make_training_env

    torch.manual_seed(0)
    mix = make_training_env(["downtown-3uav"], 1, **{k: v for k, v in settings.items() if k != "max_cycles"})
    actor, _, _ = make_networks(margs, sizes_of(margs, mix))
    mix.close()
    cloner = imitation.Cloner(margs, ["downtown-3uav"], settings, actor)
    optim = torch.optim.Adam(actor.parameters(), lr=3e-3)
    idx = np.arange(len(train["label"]))
    first, hits0 = cloner.loss("downtown-3uav", train, idx)
    for _ in range(400):
        ce, _ = cloner.loss("downtown-3uav", train, idx)
        optim.zero_grad()
        ce.backward()
        optim.step()
    last, hits = cloner.loss("downtown-3uav", train, idx)
    assert last.item() < 0.55 * first.item()
    assert hits >= 0.4 * len(idx) > hits0 + 5
