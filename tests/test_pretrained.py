"""Shipped weights reproduce their model card; export -> card -> loader round trip (numpy only, no torch)."""

import json

import numpy as np
import pytest

from training.evaluate import evaluate, load_policy, main
from training.pretrained import N_OWN_FEATURES, pretrained_names
from training.pretrained.export import export

N_SCENES = 3        # scenes replayed per shipped card (a few seconds each in waypoint mode)


@pytest.mark.parametrize("name", pretrained_names() or [pytest.param(None, marks=pytest.mark.skip("none shipped"))])
def test_shipped_weights_reproduce_their_card(name):
    pol, settings = load_policy(f"pretrained:{name}", 3)
    card = pol.card
    assert card["commit"] and card["env_id"] == "covert_sensing_vector_v1" and card["training"]["env_steps"] > 0
    lo, hi = card["scores"]["reward_iqm_ci95_over_scenes"]
    assert lo <= card["scores"]["reward_iqm"] <= hi
    rows = evaluate(pol, settings, N_SCENES, progress=False)
    for r in rows:
        # Deterministic acting in numpy: the same scene gives the same episode, up to float summation order.
        assert r["reward"] == pytest.approx(card["scores"]["per_scene_reward"][str(r["scene_seed"])], abs=1e-6)


def _tiny_run(tmp_path, head="node", mode="waypoint", u=2):
    """A run folder of training.mappo with a small randomly initialised actor (what the trainer writes)."""
    rng = np.random.default_rng(0)
    d, h, nh, n_act = 11 + 2 * (u - 1) + 2 * 64, 8, 4, (577 if head != "gaussian" else 2)
    params = {"trunk.0.weight": rng.normal(0, 0.3, (h, d)), "trunk.0.bias": np.zeros(h),
              "trunk.2.weight": rng.normal(0, 0.3, (h, h)), "trunk.2.bias": np.zeros(h)}
    if head == "node":
        params.update({"node_obs.weight": rng.normal(0, 0.5, (nh, h)), "node_obs.bias": np.zeros(nh),
                       "node_feat.weight": rng.normal(0, 0.5, (nh, N_OWN_FEATURES + u - 1)),
                       "node_out.weight": rng.normal(0, 1.0, (1, nh)), "node_out.bias": np.zeros(1)})
    else:
        params.update({"mean.weight": rng.normal(0, 0.5, (n_act, h)), "mean.bias": np.zeros(n_act),
                       "log_std": np.zeros(n_act)})
    run = tmp_path / "run"
    run.mkdir()
    np.savez(run / "model.npz", **{f"actor.{k}": v.astype(np.float32) for k, v in params.items()})
    meta = {"algorithm": "mappo", "env_id": "covert_sensing_vector_v1", "global_step": 16,
            "actor": {"head": head, "hidden": h, "node_hidden": nh, "n_feat": N_OWN_FEATURES + u - 1,
                      "obs_dim": d, "n_actions": n_act},
            "env_kwargs": {"n_uavs": u, "action_mode": mode, "max_cycles": 70, "scene_pool": 10000},
            "separation_shield": 5.0 if mode == "waypoint" else None}
    (run / "model.json").write_text(json.dumps(meta))
    (run / "args.json").write_text(json.dumps({"algo": "mappo", "seed": 0}))
    (run / "train_summary.json").write_text(json.dumps({"env_steps": 16}))
    return run


@pytest.mark.parametrize("head,mode", [("node", "waypoint"), ("gaussian", "unicycle")])
def test_export_card_round_trip(tmp_path, head, mode):
    run = _tiny_run(tmp_path, head, mode)
    card_path = export(run, "tiny", episodes=2, out_dir=tmp_path / "shipped", progress=False)
    card = json.loads(card_path.read_text())
    assert card["algorithm"] == "mappo" and card["training"]["env_steps"] == 16
    assert card_path.with_suffix(".npz").stat().st_size < 1_000_000
    with np.load(card_path.with_suffix(".npz"), allow_pickle=False) as data:
        assert all(data[k].dtype == np.float32 for k in data.files)
    s = card["scores"]
    assert s["reward_iqm_ci95_over_scenes"][0] <= s["reward_iqm"] <= s["reward_iqm_ci95_over_scenes"][1]
    # The harness's mappo:PATH spec reloads the shipped file and replays the card's scenes exactly.
    pol, settings = load_policy(f"mappo:{card_path.with_suffix('.npz')}", 2)
    assert settings["action_mode"] == mode
    assert card["separation_shield"] == pol.shield_distance == (5.0 if mode == "waypoint" else None)
    rows = evaluate(pol, settings, 2, progress=False)
    assert [r["reward"] for r in rows] == pytest.approx([s["per_scene_reward"][str(r["scene_seed"])] for r in rows])
    assert len(set(s["per_scene_reward"].values())) == 2          # two scenes, two episodes: not a constant


def test_bad_learned_specs_are_one_line_errors(tmp_path, capsys):
    from training.pretrained import NumpyActor

    (tmp_path / "w.npz").write_bytes(b"not a zip")
    (tmp_path / "w.json").write_text("{}")
    for spec, msg in [(f"mappo:{tmp_path / 'none'}", "no learned actor"),
                      (f"mappo:{tmp_path / 'w.npz'}", "not a model card"),
                      ("pretrained:nope", "no pretrained weights 'nope'")]:
        with pytest.raises(SystemExit) as exc:
            main(["--policies", spec, "--episodes", "1", "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and msg in err and "Traceback" not in err, err
    with pytest.raises(ValueError, match="node_obs.weight"):
        NumpyActor({}, {"head": "node"})
