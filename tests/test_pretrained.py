"""Shipped weights reproduce their model card; export -> card -> loader round trip (numpy only, no torch)."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from covert_env.command_line import UsageError
from covert_env.evaluation.evaluate import evaluate, load_policy, main
from covert_env.evaluation.provenance import numpy_cpu_dispatch, platform_key, platform_record
from covert_env.evaluation.stats import iqm
from training.pretrained import N_OWN_FEATURES, pretrained_names
from training.pretrained import PRETRAINED_DIR as PRETRAINED
from training.pretrained.export import export

N_SCENES = 3        # scenes replayed per shipped card in the slow test (a few seconds each in waypoint mode)
#: Largest relative difference of a replayed scene's reward from its card's on another platform (another CPU
#: dispatch of numpy or other library versions: covert_env.evaluation.provenance). On the card's own platform: none.
REPLAY_RTOL = 1e-6
#: The fast subset's replay: the cheapest card, one scene.
FAST_CARD = "mappo-suite"

_REPLAY = """
import json, sys
from covert_env.evaluation.evaluate import evaluate, load_policy
from covert_env.evaluation.provenance import platform_record
pol, settings = load_policy("pretrained:" + sys.argv[1], int(sys.argv[3]))
rows = evaluate(pol, settings, int(sys.argv[2]), progress=False)
print(json.dumps({"platform": platform_record(), "rewards": {str(r["scene_seed"]): r["reward"] for r in rows}}))
"""


def _team(name: str) -> int:
    """The team size a shipped card acts for: its env's ``n_uavs`` (3 for the learned-cost planners, which plan for
    any team)."""
    card = json.loads((PRETRAINED / f"{name}.json").read_text())
    return int(card.get("env_kwargs", {}).get("n_uavs", 3))


def _replay(name: str, n: int) -> tuple[dict, dict]:
    pol, settings = load_policy(f"pretrained:{name}", _team(name))
    rows = evaluate(pol, settings, n, progress=False)
    return pol.card, {str(r["scene_seed"]): r["reward"] for r in rows}


def _assert_replays(card: dict, rewards: dict, record: dict) -> None:
    """Bit for bit on the card's platform, within REPLAY_RTOL per scene elsewhere."""
    want = card["scores"]["per_scene_reward"]
    same = platform_key(card["platform"]) == platform_key(record)
    for seed, r in rewards.items():
        if same:
            assert r == want[seed], f"{card['name']} scene {seed}: {r!r} != {want[seed]!r} on the card's platform"
        else:
            assert r == pytest.approx(want[seed], rel=REPLAY_RTOL), f"{card['name']} scene {seed} on another platform"


def test_every_card_records_its_platform_and_is_scored_on_this_env():
    from covert_env.envs.vector import CovertSensingVectorEnv

    for name in pretrained_names():
        card = load_policy(f"pretrained:{name}", _team(name))[0].card
        # Scored on the env as it is now (export --rescore after every env version).
        assert card["env_id"] == CovertSensingVectorEnv.metadata["name"], name
        assert card["commit"] and card["training"]["env_steps"] > 0
        lo, hi = card["scores"]["reward_iqm_ci95_over_scenes"]
        assert lo <= card["scores"]["reward_iqm"] <= hi
        assert set(card["platform"]) >= {"machine", "numpy", "numpy_cpu_dispatch", "shapely", "geos"}, name
        assert not card["commit"].endswith("-dirty"), f"{name} was scored on uncommitted code"


def test_a_shipped_card_replays():
    """The fast subset's replay: the cheapest card's first scene."""
    card, rewards = _replay(FAST_CARD, 1)
    _assert_replays(card, rewards, platform_record())


@pytest.mark.slow
@pytest.mark.parametrize("name", pretrained_names() or [pytest.param(None, marks=pytest.mark.skip("none shipped"))])
def test_shipped_weights_reproduce_their_card(name):
    card, rewards = _replay(name, N_SCENES)
    _assert_replays(card, rewards, platform_record())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mappo", "mappo-suite"])
def test_a_card_replays_every_scene_within_its_interval(name):
    """All of a card's scenes, and the IQM of the replay inside the card's interval (the aggregate check)."""
    pol, _ = load_policy(f"pretrained:{name}", _team(name))
    first, last = pol.card["scores"]["scenes"]
    card, rewards = _replay(name, last - first + 1)
    _assert_replays(card, rewards, platform_record())
    lo, hi = card["scores"]["reward_iqm_ci95_over_scenes"]
    assert lo <= iqm(np.array(list(rewards.values()))[:, None]) <= hi


def _avx512_targets() -> list[str]:
    return [t for t in numpy_cpu_dispatch() if "512" in t or t == "X86_V4"]


@pytest.mark.parametrize("name", [FAST_CARD, pytest.param("dp-cost", marks=pytest.mark.slow)])
def test_cards_replay_without_avx512(name):
    """The replay on this machine with numpy's AVX-512 dispatch disabled (where the CPU has it): numpy then
    rounds its float64 arctan2, exp and arccos as on a CPU without AVX-512, and the card still replays."""
    off = _avx512_targets()
    if not off:
        pytest.skip("this CPU has no AVX-512 dispatch in numpy: nothing to disable")
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(off)}
    out = subprocess.run([sys.executable, "-c", _REPLAY, name, "2", str(_team(name))], env=env, capture_output=True,
                         text=True, check=True, cwd=Path(__file__).resolve().parents[1])
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert not set(off) & set(got["platform"]["numpy_cpu_dispatch"])          # the child ran without AVX-512
    card = load_policy(f"pretrained:{name}", _team(name))[0].card
    _assert_replays(card, got["rewards"], got["platform"])


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
    meta = {"algorithm": "mappo", "env_id": "covert_sensing_vector_v4", "global_step": 16,
            "actor": {"head": head, "hidden": h, "node_hidden": nh, "n_feat": N_OWN_FEATURES + u - 1,
                      "obs_dim": d, "n_actions": n_act},
            "env_kwargs": {"n_uavs": u, "action_mode": mode, "max_cycles": 70, "scene_pool": 10000},
            "separation_shield": 5.0 if mode == "waypoint" else None, "viability_shield": mode == "waypoint"}
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
    assert card["viability_shield"] is pol.viability is (mode == "waypoint")
    rows = evaluate(pol, settings, 2, progress=False)
    assert [r["reward"] for r in rows] == pytest.approx([s["per_scene_reward"][str(r["scene_seed"])] for r in rows])
    assert len(set(s["per_scene_reward"].values())) == 2          # two scenes, two episodes: not a constant


def test_rescore_scores_shipped_weights_on_the_current_env(tmp_path, capsys):
    """After an env version bump the shipped weights are scored again: the card names the env it was scored on
    (the recipe keeps the one it was trained on; the suite rows the one they were measured on), its scenes' rewards
    are the harness's and its platform is this one."""
    import shutil

    import covert_env
    from covert_env.envs.vector import CovertSensingVectorEnv
    from training.pretrained import PRETRAINED_DIR
    from training.pretrained.export import main as export_main
    from training.pretrained.export import rescore

    name = FAST_CARD
    for ext in (".npz", ".json"):
        shutil.copy(PRETRAINED_DIR / f"{name}{ext}", tmp_path / f"{name}{ext}")
    old = json.loads((tmp_path / f"{name}.json").read_text())
    suite = {"env_id": "covert_sensing_vector_v1", "cells": "c.csv", "policy": "p", "run": 0, "tasks": {}}
    now = CovertSensingVectorEnv.metadata["name"]
    old.update(env_id=now, suite=suite)                          # the suite keeps the env id it names
    (tmp_path / f"{name}.json").write_text(json.dumps(old))
    assert json.loads(rescore(name, 1, tmp_path, progress=False).read_text())["suite"] == suite
    del suite["env_id"]
    old.update(env_id="covert_sensing_vector_v0", covert_env_version="0.0.1", commit="0" * 40, suite=suite)
    (tmp_path / f"{name}.json").write_text(json.dumps(old))
    card = json.loads(rescore(name, 1, tmp_path, progress=False).read_text())
    # A suite without an env id was measured with the card's old scores: it is labelled with that env.
    assert card["suite"] == {"env_id": "covert_sensing_vector_v0", **suite}
    assert card["platform"] == platform_record()
    assert card["env_id"] == now and card["recipe"] == old["recipe"]
    assert card["covert_env_version"] == covert_env.__version__ and card["commit"] != "0" * 40
    assert card["scores"]["scenes"] == [1_000_000, 1_000_000]
    pol, settings = load_policy(f"pretrained:{name}", 3)
    assert card["scores"]["per_scene_reward"]["1000000"] == pytest.approx(evaluate(pol, settings, 1,
                                                                                   progress=False)[0]["reward"])
    for argv, message in ((["--rescore", "nope"], "no nope.npz with its card"),
                          ([str(tmp_path), "--rescore", name], "not both"),
                          (["--rescore", name, "--note", "x"], "--note does not go with --rescore")):
        with pytest.raises(SystemExit):
            export_main([*argv, "--out-dir", str(tmp_path)])
        assert message in capsys.readouterr().err
    (tmp_path / f"{name}.json").write_text(json.dumps({"name": name}))
    with pytest.raises(SystemExit):
        export_main(["--rescore", name, "--out-dir", str(tmp_path)])
    assert "no scores.scenes" in capsys.readouterr().err


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


def _rewrite(run, params=None, card=None):
    """Change a run's weights (``params``: name -> array, None to drop) or card fields (``card``: dotted key ->
    value)."""
    if params:
        with np.load(run / "model.npz", allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        for k, v in params.items():
            if v is None:
                arrays.pop(f"actor.{k}")
            else:
                arrays[f"actor.{k}"] = v
        np.savez(run / "model.npz", **arrays)
    if card:
        meta = json.loads((run / "model.json").read_text())
        for key, v in card.items():
            d = meta
            *head, last = key.split(".")
            for h in head:
                d = d[h]
            d[last] = v
        (run / "model.json").write_text(json.dumps(meta))


BAD_LEARNED = {
    # name: (head, mode, params, card, regex after "<file>: ")
    "trunk input one too wide": ("node", "waypoint", {"trunk.0.weight": np.zeros((8, 142), np.float32)}, None,
                                 r"actor\.trunk\.0\.weight has shape \(8, 142\), expected \(\*, 141\) "
                                 r"\(observations of 141 values\)"),
    "trunk layers do not chain": ("node", "waypoint", {"trunk.2.weight": np.zeros((8, 5), np.float32)}, None,
                                  r"actor\.trunk\.2\.weight has shape \(8, 5\), expected \(\*, 8\) "
                                  r"\(trunk\.0 has 8 outputs\)"),
    "bias of the wrong length": ("node", "waypoint", {"trunk.0.bias": np.zeros(7, np.float32)}, None,
                                 r"actor\.trunk\.0\.bias has shape \(7,\), expected \(8,\)"),
    "node features for another team": ("node", "waypoint", {"node_feat.weight": np.zeros((4, 12), np.float32)}, None,
                                       r"actor\.node_feat\.weight has shape \(4, 12\), expected \(4, 10\) "
                                       r"\(10 node features for 2 UAVs"),
    "missing head weight": ("node", "waypoint", {"node_out.weight": None}, None,
                            r"actor\.node_out\.weight is missing \(node head\)"),
    "gaussian head of 3 actions": ("gaussian", "unicycle", {"mean.weight": np.zeros((3, 8), np.float32)}, None,
                                   r"actor\.mean\.weight has shape \(3, 8\), expected \(2, 8\) "
                                   r"\(2 action components"),
    "non-finite weight": ("node", "waypoint", {"trunk.0.bias": np.full(8, np.nan, np.float32)}, None,
                          r"actor\.trunk\.0\.bias holds non-finite values"),
    "card n_uavs three": ("node", "waypoint", None, {"env_kwargs.n_uavs": "three"},
                          r"env_kwargs: n_uavs must be an integer, got str 'three'"),
    "card shield text": ("node", "waypoint", None, {"separation_shield": "far"},
                         r"separation_shield must be null or a number > 0, got 'far'"),
}


@pytest.mark.parametrize("case", list(BAD_LEARNED))
def test_learned_weights_that_do_not_fit_name_the_file_and_parameter(tmp_path, capsys, case):
    head, mode, params, card, pattern = BAD_LEARNED[case]
    run = _tiny_run(tmp_path, head, mode)
    load_policy(f"mappo:{run}", 2)                                  # the untouched run loads
    _rewrite(run, params, card)
    bad = run / ("model.npz" if params else "model.json")
    with pytest.raises(ValueError, match=rf"^mappo:{re.escape(str(run))}: {re.escape(str(bad))}: {pattern}"):
        load_policy(f"mappo:{run}", 2)
    with pytest.raises(SystemExit) as exc:
        main(["--policies", f"mappo:{run}", "--n-uavs", "2", "--episodes", "1", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err, err
    assert len([ln for ln in err.splitlines() if "error:" in ln]) == 1


def test_weights_beyond_the_size_cap_are_refused_before_unpacking(tmp_path, monkeypatch):
    import training.pretrained

    run = _tiny_run(tmp_path)
    monkeypatch.setattr(training.pretrained, "MAX_WEIGHTS_BYTES", 1000)
    calls = []
    monkeypatch.setattr(np, "load", lambda *a, **k: calls.append(a))
    with pytest.raises(ValueError, match=rf"{re.escape(str(run / 'model.npz'))}: \d+ bytes of arrays, more than the "
                                         r"1000 a weights file may hold"):
        load_policy(f"mappo:{run}", 2)
    assert calls == []


def test_card_states_the_constraint_rates_and_the_suite_rows(tmp_path, capsys):
    """The card's ``constraints`` are its scored scenes' mean rates; ``--suite`` adds the weights' rows of a suite's
    cells.csv per task (its run of a seed group), with the smallest separation of any scene."""
    from training.pretrained.export import main as export_main
    from training.pretrained.export import suite_rows

    cells = tmp_path / "cells.csv"
    head = ("task,policy,run,action_mode,mask_mode,scene_seed,score,reward,occlusion_rate,occlusion_rate_path,"
            "blocked_path_share,zone_violation_rate,mean_disguise,path_length,separation_violations,min_separation,"
            "terrain_violations,decision_time_ms")
    lines = [head]
    for run, (a, b) in enumerate(((0.5, 0.7), (0.9, 0.1))):
        for scene, x in ((1_000_000, a), (1_000_001, b)):
            lines.append(f"paper-2uav,mappo:x,{run},waypoint,kinematic,{scene},{x},{100 * x},0.1,0.2,0.05,{x / 10},"
                         f"30,2000,0.5,{5 + 10 * x},0,1")
    lines.append("paper-2uav,dp,0,waypoint,,1000000,1,200,0,0,0,0,38,2900,0,6,0,20")
    cells.write_text("\n".join(lines) + "\n")
    got = suite_rows(cells, "mappo:x", 1)["tasks"]["paper-2uav"]
    assert got["scenes"] == [1_000_000, 1_000_001] and got["mask_mode"] == "kinematic"
    assert got["score"] == pytest.approx(0.5) and got["zone_violation_rate"] == pytest.approx(0.05)
    assert got["min_separation"] == pytest.approx(6.0)                       # the smaller of 14 and 6
    with pytest.raises(ValueError, match="no rows of policy 'mappo:y'"):
        suite_rows(cells, "mappo:y")
    run = _tiny_run(tmp_path)
    export_main([str(run), "--name", "tiny", "--episodes", "1", "--out-dir", str(tmp_path / "shipped"),
                 "--suite", str(cells), "--suite-policy", "mappo:x", "--suite-run", "0"])
    card = json.loads((tmp_path / "shipped" / "tiny.json").read_text())
    m = card["scores"]["metrics_mean_std"]
    assert card["constraints"]["zone_violation_rate"] == m["zone_violation_rate"][0]
    assert card["constraints"]["blocked_los_rate_along_path"] == m["occlusion_rate_path"][0]
    assert card["constraints"]["min_separation_m"] == card["scores"]["min_separation"]     # the smallest, no mean
    assert card["constraints"]["measured_on"].startswith("held-out paper-family scenes 1000000..1000000, 2 UAVs")
    assert card["suite"]["tasks"]["paper-2uav"]["score"] == pytest.approx(0.6)
    with pytest.raises(SystemExit):
        export_main([str(run), "--out-dir", str(tmp_path / "shipped"), "--suite", str(cells)])
    assert "--suite needs --suite-policy" in capsys.readouterr().err
    assert card["env_id"] == "covert_sensing_vector_v4" and card["train_tasks"] is None
    for argv, message in (([str(run), "--suite-policy", "mappo:x"], "--suite-policy and --suite-run need --suite"),
                          (["--rescore", "tiny", "--suite", str(cells)], "--suite does not go with --rescore")):
        with pytest.raises(SystemExit):
            export_main([*argv, "--out-dir", str(tmp_path / "shipped")])
        assert message in capsys.readouterr().err


@pytest.mark.parametrize("name", ["dp-cost", "dp-cost-binned", "dp-cost-kinematic", "dp-cost-kinematic-binned"])
def test_shipped_planners_fly_with_both_separation_rules_and_keep_d_safe1(name):
    """The learned-cost cards turn on the look-ahead and the escape, and state a smallest separation (the smallest of
    any scored scene, on the held-out paper scenes and per suite task) of at least d_safe1."""
    from covert_env import Config

    pol, _ = load_policy(f"pretrained:{name}", 3)
    assert pol.team_kw["separated_continuation"] is True and pol.team_kw["best_effort_escape"] is True
    d_safe1 = Config().d_safe1
    assert pol.card["constraints"]["min_separation_m"] >= d_safe1
    assert pol.card["constraints"]["separation_violation_slots_per_uav"] == 0.0
    assert min(t["min_separation"] for t in pol.card["suite"]["tasks"].values()) >= d_safe1


@pytest.mark.parametrize("name,heading", [("dp-cost-kinematic", "inherited"), ("dp-cost-kinematic-binned", "binned")])
def test_the_kinematic_mask_planners_plan_over_shadowed_nodes_and_say_so(name, heading):
    """The kinematic-mask cards are shadow-blind (their nodes are the kinematic mask's) and fly, score and report
    their suite rows with the kinematic mask; the binned one flies the same learned cost with heading bins."""
    pol, settings = load_policy(f"pretrained:{name}", 3)
    assert pol.kw["shadow_aware"] is False and settings["mask_mode"] == "kinematic"
    assert pol.kw["heading"] == heading
    assert pol.card["path_cost"] == load_policy("pretrained:dp-cost-kinematic", 3)[0].card["path_cost"]
    assert {t["mask_mode"] for t in pol.card["suite"]["tasks"].values()} == {"kinematic"}


# ---------------------------------------------------------------------- cards are checked against one schema at load
def _card_copy(tmp_path, name, edit, weights=None):
    card = json.loads((PRETRAINED / f"{name}.json").read_text())
    edit(card)
    (tmp_path / "c.json").write_text(json.dumps(card))
    if weights is None:
        (tmp_path / "c.npz").write_bytes((PRETRAINED / f"{name}.npz").read_bytes())
    else:
        np.savez(tmp_path / "c.npz", **weights)
    return tmp_path / "c.npz"


@pytest.mark.parametrize("name, edit, weights, message", [
    ("mappo-suite", lambda c: c["env_kwargs"].update(frame_skip=2), None,
     r"env_kwargs has unknown fields \['frame_skip'\]"),
    ("mappo-suite", lambda c: c["env_kwargs"].update(n_uavs="3"), None, r"env_kwargs: n_uavs must be an integer"),
    ("mappo-suite", lambda c: c["env_kwargs"].update(max_cycles=0), None, r"env_kwargs: max_cycles"),
    ("mappo-suite", lambda c: c["actor"].update(hidden="128"), None, r"actor.hidden must be an integer"),
    ("mappo-suite", lambda c: c["env_kwargs"].update(map_size=8), None,
     r"actor.obs_dim is 1167, but env_kwargs .* give observations of 143 values"),
    ("mappo-suite", lambda c: c["actor"].update(dropout=0.1), None, r"actor has unknown fields \['dropout'\]"),
    ("dp-cost", lambda c: c["planner"].update(horizon=7), None, r"planner has unknown fields \['horizon'\]"),
    ("dp-cost", lambda c: c["env_kwargs"].update(map_size=4), None, r"env_kwargs has unknown fields \['map_size'\]"),
    ("dp-cost", lambda c: c["env_kwargs"].update(action_mode="unicycle"), None,
     r"env_kwargs.action_mode must be 'waypoint'"),
    ("dp-cost", lambda c: c.pop("path_cost"), {"path_cost": np.ones(3)},
     r"path_cost must be 5 numbers .* \(config\.horizon = 5\)"),
    ("dp-cost", lambda c: c.pop("path_cost"), {"path_cost": np.array(["1", "2", "3", "4", "5"])},
     r"path_cost must hold numbers"),
    ("dp-cost", lambda c: c.update(path_cost=[1.0] * 5), None, r"path_cost \[1\.0, .*\] is not the weights'"),
])
def test_a_card_that_breaks_the_schema_fails_at_load(tmp_path, name, edit, weights, message):
    """Unknown fields, wrong types (no string read as a number) and a learned cost of the wrong length or not its
    weights' are refused when the card is loaded, naming the card and the field, not at the first act."""
    npz = _card_copy(tmp_path, name, edit, weights)
    with pytest.raises(UsageError, match=message):
        load_policy(f"mappo:{npz}", 3)


def test_pretrained_names_are_names_not_paths(tmp_path, capsys):
    from training import mappo
    from training.pretrained import pretrained_path
    from training.pretrained.export import main as export_main

    for bad in ("../mappo", "../pretrained/mappo", "/etc/passwd"):
        with pytest.raises(ValueError, match="no pretrained weights"):
            pretrained_path(bad)
        with pytest.raises(UsageError, match="no pretrained weights"):
            load_policy(f"pretrained:{bad}", 3)
        with pytest.raises(ValueError, match="no shipped weights"):
            mappo.check_args(mappo.Args(action_mode="waypoint", init_actor=f"pretrained:{bad}"))
    with pytest.raises(SystemExit):
        export_main(["--rescore", "../pretrained/mappo", "--out-dir", str(tmp_path)])
    assert "a file stem in --out-dir" in capsys.readouterr().err
    assert pretrained_path("mappo") == PRETRAINED / "mappo.npz"
