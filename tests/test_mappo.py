"""training.mappo: smoke runs of MAPPO/IPPO in both action modes (a few hundred agent-steps each), checkpoints
and resume, the Lagrangian flag, and the numpy actor of training.pretrained against the torch one."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from _extras import needs

torch = needs("torch")

from covert_env.envs.observation import field_slices  # noqa: E402
from training import mappo  # noqa: E402
from training.mappo.networks import Actor  # noqa: E402
from training.pretrained import (  # noqa: E402
    N_MAP_FEATURES,
    N_OWN_FEATURES,
    NumpyActor,
    load_learned,
    node_features,
    pretrained_names,
)

TINY = ["--num-envs", "2", "--num-steps", "8", "--num-minibatches", "2", "--update-epochs", "1", "--hidden", "16",
        "--node-hidden", "8", "--max-cycles", "5", "--checkpoint-every", "16", "--progress-bar", "false"]


@pytest.fixture
def train_extra():
    """What training.mappo.train imports besides torch and the core dependencies."""
    needs("tensorboard")


def _curve(run):
    return [json.loads(line) for line in (run / "curve.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("head", ["node", "flat", "gaussian"])
def test_numpy_actor_equals_torch_actor(head):
    torch.manual_seed(0)
    u, d, lat = 3, 143, np.random.default_rng(0).uniform(-100, 30, (40, 2))
    n_act = len(lat) if head != "gaussian" else 2
    actor = Actor(d, n_act, head=head, hidden=16, node_hidden=8, n_feat=N_OWN_FEATURES + u - 1, log_std_init=-0.5)
    for p in actor.parameters():                     # away from the tiny initial output layer
        torch.nn.init.normal_(p, std=0.5)
    obs = np.random.default_rng(1).normal(size=(5, d)).astype(np.float32)
    feats = node_features(obs, lat, u, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0)
    assert feats.shape == (5, len(lat), N_OWN_FEATURES + u - 1) and np.isfinite(feats).all()
    mask = np.ones((5, n_act), bool)
    mask[:, ::3] = False
    with torch.no_grad():
        dist = actor.dist(torch.from_numpy(obs), torch.from_numpy(feats), torch.from_numpy(mask))
    np_actor = NumpyActor({k: v.numpy() for k, v in actor.state_dict().items()}, {"head": head})
    if head == "gaussian":
        np.testing.assert_allclose(np_actor.mean(obs), dist.mean.numpy(), rtol=1e-5, atol=1e-5)
    else:
        logits = np_actor.logits(obs, feats if head == "node" else None)
        ref = torch.log_softmax(torch.from_numpy(np.where(mask, logits, -np.inf)), -1).numpy()
        np.testing.assert_allclose(ref[mask], dist.logits.numpy()[mask], rtol=1e-4, atol=1e-4)
        assert (dist.probs.numpy()[~mask] == 0).all()            # masked nodes are never sampled


@pytest.mark.parametrize("algo,mode", [("mappo", "waypoint"), ("ippo", "waypoint"), ("mappo", "unicycle"),
                                       ("ippo", "unicycle")])
def test_smoke_run_checkpoint_resume(tmp_path, algo, mode, train_extra):
    run = mappo.main([*TINY, "--algo", algo, "--action-mode", mode, "--total-timesteps", "48",
                      "--runs-dir", str(tmp_path), "--run-name", "r"])
    rows = _curve(run)
    assert len(rows) >= 2 and rows[-1]["env_steps"] == 48                # 3 updates of 2 copies x 8 steps
    for r in rows:
        for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "reward"):
            assert math.isfinite(r[k]), (k, r)
    assert sum(r["episodes"] for r in rows) >= 4                        # 5-slot episodes ended (autoreset)
    steps = sorted(int(p.stem.split("_")[1]) for p in (run / "checkpoints").glob("step_*.npz"))
    assert steps[0] == 16 and steps[-1] == 48
    first = np.load(run / "checkpoints" / "step_16.npz")
    final = np.load(run / "model.npz")
    assert any(not np.array_equal(first[k], final[k]) for k in final.files)      # the updates changed the actor
    pol = load_learned(run)
    assert pol.env_settings == {"n_uavs": 3, "action_mode": mode, "map_size": 8,
                                **({"mask_mode": "visible"} if mode == "waypoint" else {})}
    # Resume: continues at 48 steps with the saved settings, not the command line's (except the budget).
    mappo.main(["--resume", str(run), "--total-timesteps", "80", "--progress-bar", "false", "--hidden", "64"])
    meta = json.loads((run / "model.json").read_text())
    assert meta["global_step"] == 80 and meta["updates"] == 5 and meta["actor"]["hidden"] == 16


def test_lagrangian_raises_lambda_and_harness_scores_the_run(tmp_path, train_extra):
    from covert_env.evaluation.evaluate import evaluate, load_policy

    run = mappo.main([*TINY, "--lagrangian", "true", "--cost-limit", "0", "--lagrange-lr", "1", "--n-uavs", "2",
                      "--agent-id", "true", "--separation-shield", "false",
                      "--total-timesteps", "32", "--runs-dir", str(tmp_path), "--run-name", "lag"])
    rows = _curve(run)
    # With a zero limit, lambda rises by the rollout's violation rate: never falls, and the random start collides.
    lams = [r["lambda"]["separation"] for r in rows]
    assert all(set(r["lambda"]) == {"separation"} for r in rows)
    assert lams == sorted(lams) and lams[-1] > 0
    pol, settings = load_policy(f"mappo:{run}", 2)
    assert settings["action_mode"] == "waypoint" and settings["n_uavs"] == 2 and pol.actor.spec["agent_id"]
    assert pol.shield_distance is None
    assert pol.actor.p["trunk.0.weight"].shape[1] == 143 - 2 + 2             # obs (one teammate) + one-hot of 2
    res = evaluate(pol, settings, 1, progress=False)
    assert len(res) == 1 and math.isfinite(res[0]["reward"]) and res[0]["scene_seed"] == 1_000_000


def test_bad_choices_are_one_line_errors(capsys):
    with pytest.raises(SystemExit) as exc:
        mappo.main(["--algo", "qmix"])
    assert exc.value.code == 2 and "--algo" in capsys.readouterr().err


def test_the_recipes_are_valid_and_the_shield_recipes_keep_their_settings():
    """Every recipe passes the settings' checks. ``3uav-suite`` is the shield recipe with the safety filter in place
    of the shield; ``-path`` and ``-manoeuvre`` are the shield recipe with one setting more (so their documented runs
    still reproduce)."""
    from training.common import parse_args
    from training.recipes import MAPPO_RECIPES

    for name in MAPPO_RECIPES:
        mappo.check_args(parse_args(mappo.Args, ["--recipe", name], description="", presets=MAPPO_RECIPES))
    shield = MAPPO_RECIPES["3uav-suite-shield"]
    assert MAPPO_RECIPES["3uav-suite-path"] == {**shield, "target_path": 5}
    assert MAPPO_RECIPES["3uav-suite-manoeuvre"] == {**shield, "node_manoeuvre": True}
    suite = MAPPO_RECIPES["3uav-suite"]
    changed = {k: v for k, v in suite.items() if shield.get(k) != v}
    assert changed == {"num_envs": 256, "num_steps": 16, "time_budget_minutes": 40.0, "separation_shield": False,
                       "shield_lookahead": False, "safety_filter": True, "filter_scores": True,
                       "learn_flown_nodes": True, "map_size": 24}
    assert suite["viability_shield"] and suite["viability_min_reach"] == 10
    six = MAPPO_RECIPES["6uav-suite"]
    assert {k: v for k, v in six.items() if suite.get(k) != v} == {
        "n_uavs": 6, "num_envs": 128, "tasks": suite["tasks"].replace("3uav", "6uav")}


def test_shielded_run_records_the_shield_and_evaluates_with_it(tmp_path, train_extra):
    """The recipe's shield: on by default in the waypoint mode, written to the card, used by the harness (a
    separation violation only in a slot where it found no separated nodes: its fallbacks); off in the unicycle
    mode."""
    from covert_env.evaluation.evaluate import evaluate, load_policy
    from training.recipes import MAPPO_RECIPES

    assert MAPPO_RECIPES["3uav-mappo"]["separation_shield"] is True
    run = mappo.main([*TINY, "--total-timesteps", "32", "--runs-dir", str(tmp_path), "--run-name", "sh"])
    assert json.loads((run / "model.json").read_text())["separation_shield"] == 5.0        # d_safe1 + margin 0
    pol, settings = load_policy(f"mappo:{run}", 3)
    assert pol.shield_distance == 5.0
    row = evaluate(pol, settings, 1, progress=False)[0]
    assert pol.shield.choices > 0 and math.isfinite(row["reward"])
    # Violating UAV-slots (the row's per-UAV mean times 3 UAVs) <= 3 UAVs x team slots with a fallback.
    assert row["separation_violations"] <= pol.shield.fallbacks
    flat = mappo.main([*TINY, "--head", "flat", "--total-timesteps", "16", "--runs-dir", str(tmp_path),
                       "--run-name", "flat"])                          # the flat head under the shield too
    assert load_policy(f"mappo:{flat}", 3)[0].shield_distance == 5.0
    uni = mappo.main([*TINY, "--action-mode", "unicycle", "--total-timesteps", "16", "--runs-dir", str(tmp_path),
                      "--run-name", "uni"])
    assert json.loads((uni / "model.json").read_text())["separation_shield"] is None


def test_safety_filter_run_flies_through_the_filter_and_evaluates_with_it(tmp_path, train_extra, capsys):
    """--safety-filter: the env flies the filter's nodes (a task mix too), the card says so, and the harness flies
    the team through the same filter: no separation or terrain violation on the flown path."""
    from covert_env.envs.safety_filter import ShieldedPolicy
    from covert_env.evaluation.evaluate import evaluate, load_policy

    with pytest.raises(SystemExit):
        mappo.main([*TINY, "--safety-filter", "true", "--action-mode", "unicycle", "--total-timesteps", "16"])
    assert "--safety-filter filters lattice nodes: it needs --action-mode waypoint" in capsys.readouterr().err
    run = mappo.main([*TINY, "--safety-filter", "true", "--separation-shield", "false", "--mask-mode", "kinematic",
                      "--tasks", "paper-3uav,towers-3uav", "--total-timesteps", "32", "--runs-dir", str(tmp_path),
                      "--run-name", "filt"])
    card = json.loads((run / "model.json").read_text())
    assert card["safety_filter"] is True and card["separation_shield"] is None
    pol, settings = load_policy(f"mappo:{run}", 3, trust_checkpoint=False)
    assert isinstance(pol, ShieldedPolicy) and settings["mask_mode"] == "kinematic"
    assert pol.use_scores is False                        # alternatives ordered as in training, not by the logits
    assert load_policy(f"mappo:{run}+shield", 3)[0].__class__ is ShieldedPolicy          # not wrapped twice
    row = evaluate(pol, settings, 1, progress=False, env_kwargs={"task": "towers-3uav"})[0]
    assert row["separation_violations"] == 0 and row["terrain_violations"] == 0 and row["filter_team_slots"] > 0
    tb = list((run / "tb").glob("events.*"))
    assert tb, "no TensorBoard log"
    assert card["viability_shield"] is False and card["viability_min_reach"] is None
    assert load_policy(f"mappo:{run}", 3)[0].filter_kw["min_reach"] == 0
    # With the viability rule: the filter replaces dead-end proposals, in training and in the harness alike.
    run = mappo.main([*TINY, "--safety-filter", "true", "--separation-shield", "false", "--viability-shield", "true",
                      "--viability-min-reach", "7", "--mask-mode", "kinematic", "--total-timesteps", "16",
                      "--runs-dir", str(tmp_path), "--run-name", "filt_viable"])
    card = json.loads((run / "model.json").read_text())
    assert card["viability_shield"] is True and card["viability_min_reach"] == 7
    pol, settings = load_policy(f"mappo:{run}", 3)
    assert pol.filter_kw["min_reach"] == 7
    row = evaluate(pol, settings, 2, progress=False, env_kwargs={"task": "towers-3uav"})[0]      # flown with it
    assert row["separation_violations"] == 0 and row["terrain_violations"] == 0
    card["viability_min_reach"] = None                   # a hand-made card: the shield's default bar, 1
    (run / "model.json").write_text(json.dumps(card))
    assert load_policy(f"mappo:{run}", 3)[0].filter_kw["min_reach"] == 1


def test_a_shielded_team_can_train_and_fly_through_the_filter(tmp_path, train_extra):
    """--separation-shield true --safety-filter true: the team proposes through its shield (one UAV after another)
    and flies through the filter, in training and in the harness; the card keeps both."""
    from covert_env.envs.safety_filter import ShieldedPolicy
    from covert_env.evaluation.evaluate import evaluate, load_policy

    run = mappo.main([*TINY, "--safety-filter", "true", "--viability-shield", "true", "--viability-min-reach", "10",
                      "--mask-mode", "kinematic", "--total-timesteps", "32", "--runs-dir", str(tmp_path),
                      "--run-name", "both"])
    card = json.loads((run / "model.json").read_text())
    assert card["safety_filter"] is True and card["separation_shield"] == 5.0 and card["viability_min_reach"] == 10
    pol, settings = load_policy(f"mappo:{run}", 3)
    assert isinstance(pol, ShieldedPolicy) and pol.filter_kw["min_reach"] == 10
    assert pol.policy.shield is not None and pol.policy.viability
    row = evaluate(pol, settings, 1, progress=False, env_kwargs={"task": "towers-3uav"})[0]
    assert pol.policy.shield.choices > 0 and row["filter_team_slots"] > 0
    assert row["separation_violations"] == 0 and row["terrain_violations"] == 0


def test_learn_flown_nodes_credits_the_team_with_the_nodes_the_filter_flew(tmp_path, train_extra, capsys):
    """--learn-flown-nodes: a proposal the filter replaced with a node of the mask is stored as that node, with its
    log-probability under the rollout's policy; one replaced with a node outside the mask (no probability) and the
    kept ones stay as proposed. The option needs the filter."""
    from types import SimpleNamespace

    from training.mappo.rollout import _learn_flown

    mask = np.zeros((1, 2, 3, 5), bool)
    mask[0, :, :, :3] = True                                            # nodes 0-2 allowed
    buf = SimpleNamespace(mask=mask, act=np.array([[[0, 1, 2], [2, 2, 0]]]),
                          logp=np.full((1, 2, 3), -9.0, np.float32))
    log_probs = np.log(np.arange(1, 31, dtype=np.float32).reshape(2, 3, 5) / 100)
    flown = np.array([[1, 1, 4], [2, 0, 0]])           # copy 0: UAV 0 replaced, UAV 2 widened; copy 1: UAV 1
    _learn_flown(buf, 0, flown, log_probs)
    np.testing.assert_array_equal(buf.act[0], [[1, 1, 2], [2, 0, 0]])
    np.testing.assert_array_equal(buf.logp[0], [[log_probs[0, 0, 1], -9.0, -9.0], [-9.0, log_probs[1, 1, 0], -9.0]])
    with pytest.raises(SystemExit):
        mappo.main([*TINY, "--learn-flown-nodes", "true", "--total-timesteps", "16"])
    assert "--learn-flown-nodes needs --safety-filter true" in capsys.readouterr().err
    run = mappo.main([*TINY, "--safety-filter", "true", "--separation-shield", "false", "--learn-flown-nodes", "true",
                      "--mask-mode", "kinematic", "--total-timesteps", "32", "--runs-dir", str(tmp_path),
                      "--run-name", "flown"])
    assert json.loads((run / "args.json").read_text())["learn_flown_nodes"] is True
    assert json.loads((run / "train_summary.json").read_text())["env_steps"] == 32



def test_filter_scores_orders_the_filters_alternatives_by_the_policy(tmp_path, train_extra, capsys, monkeypatch):
    """--filter-scores: every training step gives the filter the policy's node logits, the masked nodes' at
    MASKED_LOGIT; the card says ``filter_scores`` and the harness flies the team through the filter with its
    alternatives ordered by the same scores; without it, by the distance to the proposal. The option needs the
    filter."""
    import covert_env
    from covert_env.envs.safety_filter import SafetyFilteredVectorEnv
    from covert_env.evaluation.specs import load_policy
    from training.pretrained import MASKED_LOGIT

    with pytest.raises(SystemExit):
        mappo.main([*TINY, "--filter-scores", "true", "--total-timesteps", "16", "--runs-dir", str(tmp_path)])
    assert "--filter-scores needs --safety-filter true" in capsys.readouterr().err
    given, step = [], SafetyFilteredVectorEnv.step

    def recording_step(self, actions, scores=None):
        given.append((self.action_masks().astype(bool), scores))
        return step(self, actions, scores=scores)

    monkeypatch.setattr(SafetyFilteredVectorEnv, "step", recording_step)
    run = mappo.main([*TINY, "--safety-filter", "true", "--separation-shield", "false", "--filter-scores", "true",
                      "--mask-mode", "kinematic", "--total-timesteps", "32", "--runs-dir", str(tmp_path),
                      "--run-name", "scores"])
    assert len(given) == 16
    for mask, scores in given:
        assert scores is not None and scores.shape == mask.shape == (2, 3, mask.shape[2]) and (~mask).any()
        assert (scores[~mask] == MASKED_LOGIT).all() and (scores[mask] > MASKED_LOGIT / 2).all()
    card = json.loads((run / "model.json").read_text())
    assert card["filter_scores"] is True and card["safety_filter"] is True
    pol = load_policy(f"mappo:{run}", 3)[0]
    assert pol.use_scores is True
    par = covert_env.parallel_env(**card["env_kwargs"])
    obs, _ = par.reset(seed=3)
    pol.reset(par, seed=3)
    pol.act(obs, par)
    mask = np.stack([par.action_mask(a) for a in par.possible_agents]).astype(bool)
    logits = pol.policy.last_logits
    assert (~mask).any() and (logits[~mask] == MASKED_LOGIT).all() and (logits[mask] > MASKED_LOGIT / 2).all()
    # The exported card keeps it, so pretrained:NAME flies as mappo:RUN does.
    from training.pretrained.export import export
    shipped = export(run, "tiny_scores", episodes=1, out_dir=tmp_path / "shipped", progress=False)
    assert json.loads(shipped.read_text())["filter_scores"] is True
    assert load_policy(f"mappo:{shipped.with_suffix('.npz')}", 3)[0].use_scores is True
    card["filter_scores"] = False
    (run / "model.json").write_text(json.dumps(card))
    assert load_policy(f"mappo:{run}", 3)[0].use_scores is False
    for bad, message in (({"filter_scores": "yes"}, "filter_scores must be true or false, got 'yes'"),
                         ({"filter_scores": True, "safety_filter": False},
                          "filter_scores orders the safety filter's alternatives, but safety_filter is false")):
        (run / "model.json").write_text(json.dumps({**card, **bad}))
        with pytest.raises(ValueError, match=message):
            load_policy(f"mappo:{run}", 3)


def test_training_throughput_benchmark_measures_every_guard(train_extra, capsys):
    """benchmarks/training_throughput.py: a row per B for the raw env and per guard (and with --overlap, the guard's
    loop with --overlap-update), with the sequential loop's time by part adding up to 100 %."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "training_throughput.py"
    spec = importlib.util.spec_from_file_location("training_throughput", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    with pytest.raises(SystemExit):
        mod.main(["--sizes", "12"])
    assert "--sizes must be positive multiples of the recipe's 8 tasks" in capsys.readouterr().err
    assert mod.main(["--sizes", "8", "--updates", "1", "--num-steps", "2", "--seconds", "0.05",
                     "--guards", "shield", "filter", "none", "--overlap"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 8 |")]
    assert [r.split(" | ")[1] for r in rows] == ["raw env", "shield", "shield, overlapped", "filter",
                                                 "filter, overlapped", "none", "none, overlapped"]
    for r in rows:
        rates = [float(x.replace(",", "")) for x in r.split(" | ")[2:5]]
        assert all(x > 0 for x in rates), r
    for r in rows[1::2]:
        shares = [float(x.strip(" %|")) for x in r.split(" | ")[5:]]
        assert len(shares) == 6 and abs(sum(shares) - 100) <= 3, r
    assert rows[5].split(" | ")[6].strip() == "0 %"                                  # no guard, no guard time


@pytest.mark.slow
def test_seed_group_is_one_leaderboard_row(tmp_path, train_extra):
    """``mappo:RUN1,RUN2``: both runs on the same scenes, one row, its IQM interval over seeds x scenes."""
    from covert_env.evaluation.evaluate import _reward_matrix, main, split_seeds

    runs = [mappo.main([*TINY, "--seed", str(s), "--total-timesteps", "16", "--runs-dir", str(tmp_path),
                        "--run-name", f"s{s}"]) for s in (0, 1)]
    spec = f"mappo:{runs[0]},{runs[1]}"
    assert split_seeds(spec) == [f"mappo:{runs[0]}", f"mappo:{runs[1]}"]
    assert split_seeds(spec + "@waypoint") == [f"mappo:{runs[0]}@waypoint", f"mappo:{runs[1]}@waypoint"]
    assert split_seeds("dp") == ["dp"]
    out = tmp_path / "lb"
    assert main(["--policies", spec, "--episodes", "2", "--out", str(out), "--no-progress"]) == 0
    md = (out / "leaderboard.md").read_text()
    assert "| mappo (2 seeds) | 2 |" in md
    rows = [line for line in (out / "episodes.csv").read_text().splitlines()[1:]]
    assert len(rows) == 4                                                   # 2 seeds x 2 scenes
    m = _reward_matrix({"rows": [{"scene_seed": s, "reward": float(10 * r + s), "run": r}
                                 for r in (0, 1) for s in (5, 6)], "runs": 2})
    np.testing.assert_array_equal(m, [[5, 6], [15, 16]])


def test_expected_steps_is_the_binding_budget():
    from training.budget import expected_steps

    assert expected_steps(50_000_000, 0, 0.0, 2.0, 0.0) == 50_000_000              # no rate yet
    assert expected_steps(50_000_000, 1000, 10.0, 0.0, 100.0) == 50_000_000        # no time budget
    assert expected_steps(50_000_000, 1000, 10.0, 2.0, 100.0) == 1000 + 100 * 110   # 110 s left at 100 steps/s
    assert expected_steps(5_000, 1000, 10.0, 2.0, 100.0) == 5_000                   # the step budget ends it first
    assert expected_steps(50_000_000, 9000, 130.0, 2.0, 100.0) == 9000              # past the budget


@pytest.mark.parametrize("budget, total, binding", [("0.03", "10000000", "time"), ("10", "48", "steps")])
def test_progress_bar_ends_where_the_run_stops(tmp_path, monkeypatch, train_extra, budget, total, binding):
    """Under a time budget the bar's total is the projected end of the budget, not total_timesteps, so its ETA is
    the budget's (a 2-minute run shows about 2 minutes); under a step budget that ends first, total_timesteps."""
    import tqdm.auto

    seen, closed = [], []

    class Recording(tqdm.auto.tqdm):
        def update(self, n=1):
            out = super().update(n)
            d = self.format_dict
            rate = d["rate"] or (d["n"] - d["initial"]) / d["elapsed"]     # what the bar's ETA divides by
            seen.append((d["total"], d["elapsed"] + (d["total"] - d["n"]) / rate))   # total, predicted end (s)
            return out

        def close(self):
            closed.append((self.n, self.total))
            return super().close()

    monkeypatch.setattr(tqdm.auto, "tqdm", Recording)
    args = [a if a != "false" else "true" for a in TINY]           # the progress bar on
    run = mappo.main([*args, "--action-mode", "unicycle", "--n-uavs", "1", "--checkpoint-every", "0",
                      "--time-budget-minutes", budget, "--total-timesteps", total, "--runs-dir", str(tmp_path),
                      "--run-name", "bar"])
    summary = json.loads((run / "train_summary.json").read_text())
    steps = summary["env_steps"]
    assert summary["stopped_by_time_budget"] == (binding == "time")
    assert closed[0] == (steps, steps)                              # the bar ends full, at the last step
    if binding == "steps":
        assert steps == 48 and {t for t, _ in seen} == {48}
    else:
        budget_s = 60 * float(budget)
        assert seen and all(t < 10_000_000 for t, _ in seen), seen
        assert all(0.3 * budget_s <= end <= 3 * budget_s for _, end in seen), (budget_s, seen)


def test_kinematic_mask_run_records_its_mask(tmp_path, train_extra):
    """--mask-mode kinematic trains on the reachable-only mask and the run's card says so: the loaded policy
    evaluates with the mask it was trained with; the unicycle mode has no mask to choose."""
    run = mappo.main([*TINY, "--mask-mode", "kinematic", "--total-timesteps", "16", "--runs-dir", str(tmp_path),
                      "--run-name", "k"])
    assert json.loads((run / "model.json").read_text())["env_kwargs"]["mask_mode"] == "kinematic"
    assert load_learned(run).env_settings["mask_mode"] == "kinematic"
    with pytest.raises(SystemExit) as exc:                  # one error line, before anything is set up
        mappo.main([*TINY, "--mask-mode", "kinematic", "--action-mode", "unicycle", "--total-timesteps", "16",
                    "--runs-dir", str(tmp_path), "--run-name", "u"])
    assert exc.value.code == 2 and not (tmp_path / "u").exists()
    with pytest.raises(ValueError, match=r"--mask-mode 'nope': must be one of \('visible', 'kinematic'\)"):
        mappo.check_args(mappo.Args(mask_mode="nope"))


def test_constraints_parse_and_their_errors_name_the_item():
    args = mappo.Args(constraints=" zone=0.01, los_path=0 ", lagrangian=True, cost_limit=0.007)
    assert mappo.constraint_limits(args) == {"los_path": 0.0, "zone": 0.01, "separation": 0.007}   # COSTS order
    assert mappo.constraint_limits(mappo.Args()) == {}
    for bad, pattern in (("zone", r"'zone' must be NAME=LIMIT"), ("speed=0.1", r"'speed=0.1' must be NAME=LIMIT"),
                         ("zone=2", r"limit of zone must be a number in \[0, 1\].*got '2'"),
                         ("zone=nan", r"limit of zone must be a number"), ("zone=x", r"got 'x'"),
                         ("zone=0.1,zone=0.2", r"zone is given twice")):
        with pytest.raises(ValueError, match=pattern):
            mappo.check_args(mappo.Args(constraints=bad))
    with pytest.raises(ValueError, match=r"--lagrangian constrains separation"):
        mappo.check_args(mappo.Args(constraints="separation=0.1", lagrangian=True))


def test_constraint_multipliers_rise_with_their_costs_and_resume(tmp_path, train_extra):
    """Each constrained cost gets its own multiplier: with limits of 0, a random team's zone and LoS-path costs are
    above them, so dual ascent raises both; the multipliers are saved with the checkpoints and resumed, and a
    checkpoint of the single-multiplier format (a float: separation's) still resumes."""
    run = mappo.main([*TINY, "--constraints", "zone=0,los_path=0", "--total-timesteps", "48", "--lagrange-lr", "1.0",
                      "--runs-dir", str(tmp_path), "--run-name", "c", "--checkpoint-every", "16"])
    rows = _curve(run)
    assert set(rows[-1]["lambda"]) == {"los_path", "zone"}
    assert rows[-1]["lambda"]["zone"] > 0 and rows[-1]["lambda"]["los_path"] > 0
    meta = json.loads((run / "model.json").read_text())
    assert meta["lam"] == rows[-1]["lambda"]
    ckpt = sorted((run / "checkpoints").glob("step_*.json"))[-1]
    old = json.loads(ckpt.read_text())
    old["lam"] = 0.25
    ckpt.write_text(json.dumps(old))
    mappo.main(["--resume", str(run), "--total-timesteps", "64", "--progress-bar", "false"])
    assert set(_curve(run)[-1]["lambda"]) == {"los_path", "zone"}


def test_numpy_actor_with_the_map_features_equals_torch_actor():
    """The node head with ``node_map``: two more features per node, the same outputs in numpy and torch."""
    torch.manual_seed(0)
    u, s = 3, 6
    lat = np.random.default_rng(0).uniform(-100, 30, (40, 2))
    cells = np.array([(x, y) for y in np.linspace(50, -50, s) for x in np.linspace(-110, 40, s)])
    d = field_slices(u, s)["map_next"].stop
    n_feat = N_OWN_FEATURES + u - 1 + N_MAP_FEATURES
    actor = Actor(d, len(lat), head="node", hidden=16, node_hidden=8, n_feat=n_feat, log_std_init=-0.5)
    for p in actor.parameters():
        torch.nn.init.normal_(p, std=0.5)
    obs = np.random.default_rng(1).integers(0, 2, (5, d)).astype(np.float32)
    feats = node_features(obs, lat, u, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0, map_offsets=cells)
    assert feats.shape == (5, len(lat), n_feat) and set(np.unique(feats[..., -2:])) <= {0.0, 1.0}
    np.testing.assert_array_equal(feats[..., :-2], node_features(obs, lat, u, r2=100.0, v_max=50.0, delta=1.0,
                                                                 d_safe1=5.0))
    mask = np.ones((5, len(lat)), bool)
    with torch.no_grad():
        dist = actor.dist(torch.from_numpy(obs), torch.from_numpy(feats), torch.from_numpy(mask))
    np_actor = NumpyActor({k: v.numpy() for k, v in actor.state_dict().items()}, {"head": "node", "node_map": True})
    ref = torch.log_softmax(torch.from_numpy(np_actor.logits(obs, feats)), -1).numpy()
    np.testing.assert_allclose(ref, dist.logits.numpy(), rtol=1e-4, atol=1e-4)


def test_task_mix_and_map_features_run_and_card(tmp_path, train_extra):
    """--tasks trains on several tasks' scenes at once (a nominal and a deviating one: two lattices) and --node-map
    adds the map features; the card records both and the loaded policy acts with them; bad values are errors that
    name them."""
    run = mappo.main([*TINY, "--tasks", "downtown-3uav,paper-3uav-deviating", "--node-map", "--map-size", "6",
                      "--mask-mode", "kinematic", "--total-timesteps", "16", "--runs-dir", str(tmp_path),
                      "--run-name", "t"])
    card = json.loads((run / "model.json").read_text())
    assert card["train_tasks"] == ["downtown-3uav", "paper-3uav-deviating"]
    assert card["actor"]["node_map"] is True and card["actor"]["n_feat"] == N_OWN_FEATURES + 2 + N_MAP_FEATURES
    assert card["env_kwargs"]["map_size"] == 6
    pol = load_learned(run)
    assert pol.env_settings == {"n_uavs": 3, "action_mode": "waypoint", "map_size": 6, "mask_mode": "kinematic"}
    for value, pattern in (("yes", r"actor.node_map must be true or false, got 'yes'"),
                           (False, r"node_feat.weight has shape \(8, 13\), expected \(8, 11\)")):
        card["actor"]["node_map"] = value
        (run / "model.json").write_text(json.dumps(card))
        with pytest.raises(ValueError, match=pattern):
            load_learned(run)
    for bad, pattern in ((dict(tasks="paper-3uav,nope"), r"unknown task 'nope'"),
                         (dict(tasks="paper-1uav"), r"paper-1uav has 1 UAVs, --n-uavs is 3"),
                         (dict(tasks="paper-3uav,paper-3uav"), r"named twice"),
                         (dict(tasks="paper-3uav,dense-3uav,towers-3uav", num_envs=16), r"multiple of the 3"),
                         (dict(node_map=True, head="flat"), r"--node-map needs --action-mode waypoint and --head "
                                                            r"node, got --action-mode 'waypoint' --head 'flat'"),
                         (dict(node_map=True, action_mode="unicycle"), r"got --action-mode 'unicycle'"),
                         (dict(tasks="paper-3uav", scene_pool=50), r"--scene-pool 50 does not go with --tasks")):
        with pytest.raises(ValueError, match=pattern):
            mappo.check_args(mappo.Args(**bad))


def test_init_actor_starts_as_the_loaded_team_and_warmup_keeps_it(tmp_path, train_extra):
    """--init-actor pretrained:mappo into an actor with --node-map: the map's columns start at zero, so every node
    scores as under the shipped weights; during --actor-warmup-updates only the critic learns (the actor saved
    after two warm-up updates is the shipped one); after them the actor moves. --lambda-max bounds every
    multiplier."""
    shipped = load_learned("training/pretrained/mappo.npz")
    common = [*TINY, "--hidden", "128", "--node-hidden", "32", "--init-actor", "pretrained:mappo", "--node-map",
              "--mask-mode", "kinematic", "--constraints", "zone=0,los=0", "--lagrange-lr", "5", "--lambda-max",
              "0.3", "--runs-dir", str(tmp_path)]
    run = mappo.main([*common, "--actor-warmup-updates", "2", "--total-timesteps", "32", "--run-name", "w"])
    saved = np.load(run / "model.npz")
    for k, v in shipped.actor.p.items():
        got = saved[f"actor.{k}"]
        if k == "node_feat.weight":
            assert got.shape == (v.shape[0], v.shape[1] + N_MAP_FEATURES) and not got[:, v.shape[1]:].any()
            got = got[:, :v.shape[1]]
        np.testing.assert_array_equal(got, v.astype(np.float32), err_msg=k)
    lam = _curve(run)[-1]["lambda"]
    assert set(lam) == {"los", "zone"} and max(lam.values()) <= 0.3
    moved = mappo.main([*common, "--actor-warmup-updates", "1", "--total-timesteps", "32", "--run-name", "m"])
    assert not np.array_equal(np.load(moved / "model.npz")["actor.node_out.weight"],
                              shipped.actor.p["node_out.weight"].astype(np.float32))
    # The loaded policy with zero map columns acts as the shipped one on the same observations.
    obs = np.random.default_rng(0).normal(size=(4, 143)).astype(np.float32)
    lat = np.random.default_rng(1).uniform(-100, 30, (30, 2))
    feats = node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0)
    cells = np.array([(x, y) for y in np.linspace(50, -50, 8) for x in np.linspace(-110, 40, 8)])
    feats_map = node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0, map_offsets=cells)
    np.testing.assert_allclose(load_learned(run).actor.logits(obs, feats_map), shipped.actor.logits(obs, feats),
                               rtol=1e-5, atol=1e-5)


def test_init_actor_and_lambda_max_errors_name_the_value(tmp_path, train_extra, capsys):
    for bad, pattern in ((dict(init_actor="pretrained:nope"), r"--init-actor pretrained:nope: no shipped weights "
                                                               r"'nope'; the shipped are "
                                                               + re.escape(str(pretrained_names()))),
                         (dict(init_actor=str(tmp_path / "none.npz")), r"no such file or folder"),
                         (dict(actor_warmup_updates=3), r"--actor-warmup-updates 3: needs --init-actor"),
                         (dict(lambda_max=2.0), r"--lambda-max 2: bounds the Lagrange multipliers, but no "
                                                r"constraint is set")):
        with pytest.raises(ValueError, match=pattern):
            mappo.check_args(mappo.Args(**bad))
    # A card that contradicts the flags is found before any env is built, naming the field and both values.
    with pytest.raises(SystemExit) as exc:
        mappo.main([*TINY, "--init-actor", "pretrained:mappo", "--total-timesteps", "16", "--runs-dir",
                    str(tmp_path), "--run-name", "x"])
    assert exc.value.code == 2
    for flags, pattern in ((dict(hidden=16), r"its card has actor.hidden = 128, this run's --hidden is 16"),
                           (dict(n_uavs=4), r"env_kwargs.n_uavs = 3, this run's --n-uavs is 4"),
                           (dict(map_size=16), r"env_kwargs.map_size = 8, this run's --map-size is 16"),
                           (dict(node_hidden=8), r"actor.node_hidden = 32, this run's --node-hidden is 8")):
        with pytest.raises(ValueError, match=pattern):
            mappo.check_args(mappo.Args(action_mode="waypoint", init_actor="pretrained:mappo", **flags))
    card = json.loads((mappo.PRETRAINED_DIR / "mappo.json").read_text())
    card["actor"]["node_map"] = True
    (tmp_path / "m.npz").write_bytes((mappo.PRETRAINED_DIR / "mappo.npz").read_bytes())
    (tmp_path / "m.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"actor.node_map = True, this run's --node-map is False"):
        mappo.check_args(mappo.Args(action_mode="waypoint", init_actor=str(tmp_path / "m.npz")))
    (tmp_path / "w.npz").write_bytes((mappo.PRETRAINED_DIR / "mappo.npz").read_bytes())
    with pytest.raises(ValueError, match=r"no readable model card at .*w.json"):
        mappo.check_args(mappo.Args(action_mode="waypoint", init_actor=str(tmp_path / "w.npz")))
    # The weights themselves are checked with the flags, before anything is set up: a card that fits the flags but
    # not its weights, and a weights file that is no zip, end in one error line and no run folder.
    card = json.loads((mappo.PRETRAINED_DIR / "mappo.json").read_text())
    card["actor"].update(hidden=16, node_hidden=8)
    (tmp_path / "w.json").write_text(json.dumps(card))
    (tmp_path / "g.npz").write_text("not weights")
    (tmp_path / "g.json").write_text(json.dumps(card))
    for weights, pattern in (("w.npz", r"--init-actor .*w.npz: .*actor.trunk.0.weight has 128 outputs, but the card's "
                                       r"actor.hidden is 16"),
                             ("g.npz", r"--init-actor .*g.npz: .*g.npz: not a weights file")):
        with pytest.raises(SystemExit) as exc:
            mappo.main([*TINY, "--init-actor", str(tmp_path / weights), "--total-timesteps", "16", "--runs-dir",
                        str(tmp_path), "--run-name", "y"])
        assert exc.value.code == 2 and not (tmp_path / "y").exists()
        err = capsys.readouterr().err
        assert re.search(r"python -m training.mappo: error: " + pattern, err) and "Traceback" not in err, err
    for bad, pattern in ((dict(mask_mode="kinematic", action_mode="unicycle"),
                          r"--mask-mode 'kinematic' needs --action-mode waypoint"),
                         (dict(constraints=" , ,"), r"--constraints ' , ,' names no constraint")):
        with pytest.raises(ValueError, match=pattern):
            mappo.check_args(mappo.Args(**bad))
    with pytest.raises(SystemExit):
        mappo.main(["--lambda-max", "-1"])


def test_viability_shield_run_records_it_and_the_policy_uses_it(tmp_path, train_extra):
    """--viability-shield: the card says so, the loaded policy acts through it (its shield tests the chosen nodes
    with the env's onward_reach), and it needs the separation shield in the waypoint mode."""
    run = mappo.main([*TINY, "--viability-shield", "--mask-mode", "kinematic", "--total-timesteps", "16",
                      "--runs-dir", str(tmp_path), "--run-name", "v"])
    card = json.loads((run / "model.json").read_text())
    assert card["viability_shield"] is True
    pol = load_learned(run)
    assert pol.viability
    import covert_env
    par = covert_env.parallel_env(n_uavs=3, action_mode="waypoint", mask_mode="kinematic")
    obs, _ = par.reset(seed=0)
    calls = []
    real = par.onward_reach
    par.onward_reach = lambda xy, theta: calls.append(1) or real(xy, theta)
    pol.act(obs, par)
    assert calls
    card["separation_shield"] = None
    (run / "model.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"viability_shield is a rule of the separation shield or the safety "
                                         r"filter, but separation_shield is null and safety_filter false"):
        load_learned(run)
    card["viability_shield"] = "yes"
    (run / "model.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match=r"viability_shield must be true or false, got 'yes'"):
        load_learned(run)
    for bad in (dict(viability_shield=True, separation_shield=False),
                dict(viability_shield=True, action_mode="unicycle")):
        with pytest.raises(ValueError, match=r"--viability-shield acts inside the separation shield or the safety "
                                             r"filter"):
            mappo.check_args(mappo.Args(**bad))


def test_init_temperature_flattens_the_loaded_policy_but_keeps_its_ranking():
    """--init-temperature T divides the loaded node logits by T: the greedy choice is the shipped one, the
    distribution is flatter (higher entropy); it needs --init-actor in the waypoint mode."""
    shipped = load_learned("training/pretrained/mappo.npz")
    spec = shipped.actor.spec
    actors = []
    for t in (1.0, 4.0):
        a = Actor(spec["obs_dim"], spec["n_actions"], head="node", hidden=spec["hidden"],
                  node_hidden=spec["node_hidden"], n_feat=spec["n_feat"], log_std_init=-0.5)
        mappo.load_initial_actor(a, "pretrained:mappo", node_map=False, temperature=t)
        actors.append(a)
    obs = np.random.default_rng(0).normal(size=(6, spec["obs_dim"])).astype(np.float32)
    lat = np.random.default_rng(1).uniform(-100, 30, (40, 2))
    feats = torch.from_numpy(node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0))
    with torch.no_grad():
        l1, l4 = (a.logits(torch.from_numpy(obs), feats) for a in actors)
    np.testing.assert_allclose(l4.numpy(), l1.numpy() / 4.0, rtol=1e-5, atol=1e-6)
    assert (l4.argmax(1) == l1.argmax(1)).all()
    ent = [torch.distributions.Categorical(logits=x).entropy().mean().item() for x in (l1, l4)]
    assert ent[1] > ent[0]
    with pytest.raises(ValueError, match=r"--init-temperature 4: needs --init-actor"):
        mappo.check_args(mappo.Args(init_temperature=4.0))


def test_shield_lookahead_and_viability_bar_are_recorded_checked_and_used(tmp_path, train_extra):
    """--shield-lookahead and --viability-min-reach: the card records them, the loaded policy's shield has them,
    a card with bad values or without the rule they belong to fails at load, and the flags need their rules."""
    run = mappo.main([*TINY, "--viability-shield", "--viability-min-reach", "7", "--shield-lookahead",
                      "--mask-mode", "kinematic", "--total-timesteps", "16", "--runs-dir", str(tmp_path),
                      "--run-name", "la"])
    card = json.loads((run / "model.json").read_text())
    assert card["shield_lookahead"] is True and card["viability_min_reach"] == 7
    pol = load_learned(run)
    assert pol.shield.lookahead and pol.shield.min_reach == 7 and pol.viability
    for key, value, pattern in (
            ("shield_lookahead", 1, r"shield_lookahead must be true or false, got 1"),
            ("viability_min_reach", 0, r"viability_min_reach must be null or an integer in \[1, 100000\], got 0"),
            ("viability_min_reach", 2.5, r"viability_min_reach must be null or an integer in \[1, 100000\], got 2.5"),
            ("viability_shield", False, r"viability_min_reach is a bar of the viability rule, but viability_shield "
                                        r"is false")):
        bad = {**card, key: value}
        (run / "model.json").write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=pattern):
            load_learned(run)
    (run / "model.json").write_text(json.dumps({**card, "separation_shield": None, "viability_shield": False,
                                                "viability_min_reach": None}))
    with pytest.raises(ValueError, match=r"shield_lookahead is a rule of the separation shield, but "
                                         r"separation_shield is null"):
        load_learned(run)
    old = {k: v for k, v in card.items() if k not in ("shield_lookahead", "viability_min_reach")}
    (run / "model.json").write_text(json.dumps(old))                  # cards before these fields: both off
    pol = load_learned(run)
    assert not pol.shield.lookahead and pol.shield.min_reach == 1
    with pytest.raises(ValueError, match=r"--viability-min-reach 3: a bar of the viability rule, it needs "
                                         r"--viability-shield true"):
        mappo.check_args(mappo.Args(viability_min_reach=3))
    with pytest.raises(ValueError, match=r"--shield-lookahead acts inside the separation shield"):
        mappo.check_args(mappo.Args(shield_lookahead=True, separation_shield=False))
    with pytest.raises(SystemExit):
        mappo.main(["--viability-min-reach", "0"])


def test_target_path_run_card_harness_and_widening(tmp_path, train_extra):
    """--target-path P: the env's observation carries the target's path, the card records it, the harness builds the
    same env; --init-actor from weights without the path puts zeros in the path's trunk columns (so the new actor
    scores every node as the loaded one), and a card with another path length is an error naming both."""
    run = mappo.main([*TINY, "--action-mode", "waypoint", "--target-path", "3", "--total-timesteps", "16",
                      "--runs-dir", str(tmp_path), "--run-name", "p"])
    card = json.loads((run / "model.json").read_text())
    assert card["env_kwargs"]["target_path"] == 3
    pol = load_learned(run)
    assert pol.env_settings["target_path"] == 3
    from covert_env.evaluation.evaluate import evaluate

    rows = evaluate(pol, pol.env_settings, 1, env_kwargs={"max_cycles": 3}, progress=False)
    assert len(rows) == 1 and np.isfinite(rows[0]["reward"])
    shipped = load_learned("training/pretrained/mappo.npz")
    wide = mappo.main([*TINY, "--hidden", "128", "--node-hidden", "32", "--action-mode", "waypoint",
                       "--init-actor", "pretrained:mappo", "--actor-warmup-updates", "2", "--target-path", "5",
                       "--total-timesteps", "32", "--runs-dir", str(tmp_path), "--run-name", "w"])
    w = np.load(wide / "model.npz")["actor.trunk.0.weight"]
    old = shipped.actor.p["trunk.0.weight"]
    assert w.shape == (old.shape[0], old.shape[1] + 20) and not w[:, old.shape[1]:].any()
    np.testing.assert_array_equal(w[:, :old.shape[1]], old.astype(np.float32))
    obs = np.random.default_rng(0).normal(size=(4, old.shape[1])).astype(np.float32)
    path_obs = np.concatenate([obs, np.random.default_rng(1).normal(size=(4, 20)).astype(np.float32)], axis=1)
    lat = np.random.default_rng(2).uniform(-100, 30, (30, 2))
    feats = node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0)
    np.testing.assert_allclose(load_learned(wide).actor.logits(path_obs, feats), shipped.actor.logits(obs, feats),
                               rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match=r"its card has env_kwargs.target_path = 3, this run's --target-path is 5"):
        mappo.check_args(mappo.Args(action_mode="waypoint", hidden=16, node_hidden=8, init_actor=str(run),
                                    target_path=5))
    with pytest.raises(SystemExit):
        mappo.main(["--target-path", "9"])


def test_init_actor_widening_puts_the_path_before_the_agent_id(tmp_path, train_extra):
    """With --agent-id the actor's input is the observation then the agent's one-hot: the path's zero columns go
    between them, so the widened actor scores every node as the loaded one for every agent."""
    base = mappo.main([*TINY, "--action-mode", "waypoint", "--agent-id", "--total-timesteps", "16", "--runs-dir",
                       str(tmp_path), "--run-name", "a"])
    wide = mappo.main([*TINY, "--action-mode", "waypoint", "--agent-id", "--init-actor", str(base),
                       "--actor-warmup-updates", "2", "--target-path", "2", "--total-timesteps", "32", "--runs-dir",
                       str(tmp_path), "--run-name", "b"])
    old, new = load_learned(base), load_learned(wide)
    w_old, w_new = old.actor.p["trunk.0.weight"], new.actor.p["trunk.0.weight"]
    d = w_old.shape[1] - 3                                          # observation width without the path
    assert w_new.shape[1] == w_old.shape[1] + 8 and not w_new[:, d:d + 8].any()
    np.testing.assert_array_equal(w_new[:, :d], w_old[:, :d])
    np.testing.assert_array_equal(w_new[:, d + 8:], w_old[:, d:])
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(3, d)).astype(np.float32)
    onehot = np.eye(3, dtype=np.float32)
    lat = rng.uniform(-100, 30, (20, 2))
    feats = node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0)
    path = rng.normal(size=(3, 8)).astype(np.float32)
    np.testing.assert_allclose(new.actor.logits(np.concatenate([obs, path, onehot], 1), feats),
                               old.actor.logits(np.concatenate([obs, onehot], 1), feats), rtol=1e-5, atol=1e-5)


def test_overlap_update_acts_one_update_behind_and_is_deterministic(tmp_path, train_extra, monkeypatch):
    """--overlap-update: rollout r acts with the learner's weights from before update r - 1 (the update runs while
    the rollout collects), each update learns from the rollout before it, every rollout is learned from, and the
    thread timing cannot change a run: two runs with one seed end with the same weights."""
    import training.mappo.train as train_mod

    acted, collected, learned = [], [], []

    def weights(agents):
        return np.concatenate([v.numpy().ravel() for v in agents.actor.state_dict().values()])

    def collect(agents, buf, *a, **k):
        acted.append(weights(agents))
        out = mappo.collect_rollout(agents, buf, *a, **k)
        collected.append(buf.obs.copy())
        return out

    def update(agents, optim, buf, *a, **k):
        learned.append((weights(agents), buf.obs.copy()))
        return mappo.ppo_update(agents, optim, buf, *a, **k)

    monkeypatch.setattr(train_mod, "collect_rollout", collect)
    monkeypatch.setattr(train_mod, "ppo_update", update)
    flags = [*TINY, "--overlap-update", "true", "--total-timesteps", "64", "--runs-dir", str(tmp_path)]
    run = mappo.main([*flags, "--run-name", "a"])
    summary = json.loads((run / "train_summary.json").read_text())
    assert summary["env_steps"] == 64 and summary["updates"] == 4          # 4 rollouts of 2 copies x 8 steps
    assert len(acted) == 4 and len(learned) == 4
    assert np.array_equal(acted[0], acted[1])                            # rollouts 0 and 1 act before any update
    for r in (2, 3):                                 # rollout r acts with the weights update r - 1 began with
        assert np.array_equal(acted[r], learned[r - 1][0]) and not np.array_equal(acted[r], learned[r][0])
    # The rollouts alternate between two buffers; update u learns from what rollout u collected.
    assert all(np.array_equal(learned[u][1], collected[u]) for u in range(4))
    assert not np.array_equal(collected[1], collected[2])
    first = np.load(run / "model.npz")
    again = np.load(mappo.main([*flags, "--run-name", "b"]) / "model.npz")
    assert all(np.array_equal(first[k], again[k]) for k in first.files)
    card = json.loads((run / "model.json").read_text())
    assert card["global_step"] == 64 and card["updates"] == 4
    # A checkpoint and a curve row name the env-steps learned from, not those collected ahead (16 per update).
    for step in (16, 32, 48, 64):
        assert json.loads((run / "checkpoints" / f"step_{step}.json").read_text())["updates"] == step // 16


@pytest.mark.parametrize("overlap", ["false", "true"])
def test_anneal_lr_decays_the_rate_by_the_steps_before_each_update(tmp_path, train_extra, monkeypatch, overlap):
    import training.mappo.train as train_mod

    rates = []

    def update(agents, optim, *a, **k):
        rates.append(optim.param_groups[0]["lr"])
        return mappo.ppo_update(agents, optim, *a, **k)

    monkeypatch.setattr(train_mod, "ppo_update", update)
    mappo.main([*TINY, "--anneal-lr", "true", "--learning-rate", "0.001", "--total-timesteps", "48",
                "--overlap-update", overlap, "--runs-dir", str(tmp_path), "--run-name", "anneal"])
    np.testing.assert_allclose(rates, [1e-3, 1e-3 * 32 / 48, 1e-3 * 16 / 48])      # 3 updates of 16 env-steps
