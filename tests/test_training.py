"""CI smoke tests of training/ (small budgets): the SB3 VecEnv adapter, every SB3 script (train a few thousand
steps, save, reload, evaluate through the harness), RLlib (one iteration, skipped without ray) and the harness."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _extras import needs

needs("stable_baselines3")
needs("sb3_contrib")

import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize  # noqa: E402

from covert_env.envs.covert_sensing import CovertSensingParallelEnv  # noqa: E402
from training.sb3.vec_env import ParallelEnvVecAdapter, make_vec_env  # noqa: E402

torch.set_num_threads(1)

SMALL = dict(n_uavs=3, max_cycles=8)


# ---------------------------------------------------------------------- adapter
def _params(model) -> np.ndarray:
    return torch.nn.utils.parameters_to_vector(model.policy.parameters()).detach().numpy().copy()


def _ppo(seed: int) -> PPO:
    venv = VecNormalize(VecMonitor(make_vec_env(2, SMALL)))
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=48, n_epochs=2, seed=seed, device="cpu")
    model.learn(2 * 16 * venv.num_envs)
    return model


def test_adapter_shapes_and_rows():
    venv = make_vec_env(2, SMALL)
    assert venv.num_envs == 6 and venv.n_agents == 3 and venv.n_copies == 2
    venv.seed(3)
    obs = venv.reset()
    assert obs.shape == (6, *venv.observation_space.shape) and obs.dtype == np.float32
    # row j*U + i is agent i of copy j: copy j is seeded with seed + j * U (the first of its rows)
    one = CovertSensingParallelEnv(**SMALL)
    rows, _ = one.reset(seed=3 + 1 * 3)
    np.testing.assert_array_equal(obs[4], rows["uav_1"])
    venv.close()


def test_seeded_ppo_runs_are_identical():
    a, b = _ppo(0), _ppo(0)
    np.testing.assert_array_equal(_params(a), _params(b))
    c = _ppo(1)
    assert not np.array_equal(_params(a), _params(c))


def test_seed_reproduces_scenes():
    def first_obs(seed):
        v = make_vec_env(2, SMALL)
        v.seed(seed)
        return v.reset()

    np.testing.assert_array_equal(first_obs(3), first_obs(3))
    assert not np.array_equal(first_obs(3), first_obs(4))


def test_truncation_flags_and_terminal_observation():
    venv = make_vec_env(2, SMALL)
    venv.seed(0)
    obs = venv.reset()
    acts = np.zeros((venv.num_envs, 2), np.float32)
    for t in range(SMALL["max_cycles"]):
        prev = obs
        obs, rew, dones, infos = venv.step(acts)
        assert rew.shape == (6,) and np.isfinite(rew).all()
        if t < SMALL["max_cycles"] - 1:
            assert not dones.any()
            assert all("terminal_observation" not in i for i in infos)
            assert all(not i.get("TimeLimit.truncated", False) for i in infos)
    assert dones.all()
    for r, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True
        term = info["terminal_observation"]
        assert term.shape == venv.observation_space.shape
        # the terminal observation is the last one of the episode (time remaining 0), the returned one is fresh
        assert term[10] == pytest.approx(0.0)
        assert obs[r, 10] == pytest.approx(1.0)
        assert not np.array_equal(term, prev[r])
    venv.close()


class _EndsEarly:
    """A minimal ParallelEnv whose two agents are terminated (not truncated) at step 3."""

    possible_agents = ["a", "b"]
    render_mode = None

    def __init__(self):
        from gymnasium import spaces

        self._obs, self._act = spaces.Box(-1, 1, (3,), np.float32), spaces.Box(-1, 1, (2,), np.float32)
        self.agents, self.t = [], 0

    def observation_space(self, agent):
        return self._obs

    def action_space(self, agent):
        return self._act

    def _o(self):
        return {a: np.full(3, self.t / 10, np.float32) for a in self.possible_agents}

    def reset(self, seed=None, options=None):
        self.agents, self.t = list(self.possible_agents), 0
        return self._o(), {a: {} for a in self.agents}

    def step(self, actions):
        self.t += 1
        end = self.t >= 3
        agents = list(self.agents)
        if end:
            self.agents = []
        return (self._o(), {a: 1.0 for a in agents}, {a: end for a in agents}, {a: False for a in agents},
                {a: {} for a in agents})

    def close(self):
        pass


def test_termination_is_not_truncation():
    venv = ParallelEnvVecAdapter([_EndsEarly, _EndsEarly])
    venv.reset()
    for _ in range(3):
        obs, _, dones, infos = venv.step(np.zeros((4, 2), np.float32))
    assert dones.all()
    for r, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is False
        assert info["terminal_observation"] == pytest.approx(np.full(3, 0.3))
        assert obs[r] == pytest.approx(np.zeros(3))           # auto-reset


@pytest.mark.parametrize("mode", ["unicycle", "waypoint"])
def test_batched_adapter_equals_stepping_copy_by_copy(mode):
    """make_vec_env (one vector env, every copy in one batch) gives exactly what the generic adapter gives by stepping
    each parallel env copy through env.step, over episode ends and resets: observations, rewards, dones, infos."""
    kw = dict(n_uavs=3, max_cycles=6, action_mode=mode)
    fast = make_vec_env(3, kw)
    slow = ParallelEnvVecAdapter([lambda: CovertSensingParallelEnv(**kw) for _ in range(3)])
    for v in (fast, slow):
        v.seed(5)
    np.testing.assert_array_equal(fast.reset(), slow.reset())
    rng = np.random.default_rng(0)
    for _ in range(12):                                   # two episode ends
        if mode == "unicycle":
            acts = rng.uniform(-1.5, 1.5, (fast.num_envs, 2)).astype(np.float32)   # out of range: clipped
        else:
            acts = np.array([rng.choice(np.flatnonzero(m)) for m in fast.env_method("action_masks")])
            np.testing.assert_array_equal(np.stack(fast.env_method("action_masks")),
                                          np.stack(slow.env_method("action_masks")))
        a, b = fast.step(acts), slow.step(acts)
        for x, y in zip(a[:3], b[:3], strict=True):
            np.testing.assert_array_equal(x, y)
        for ia, ib in zip(a[3], b[3], strict=True):
            ib = {k: v for k, v in ib.items() if k != "action_mask"}    # the batched adapter serves masks apart
            assert ia.keys() == ib.keys()
            for key in ia:
                np.testing.assert_array_equal(ia[key], ib[key], err_msg=key)
    assert a[2].all()                                     # the last step ended every copy


def test_generic_adapter_copies_with_their_own_rewards_and_lengths():
    """The generic adapter's copies may differ in reward scale, penalties, max_cycles and terminate_on_collision,
    also when set after construction (set_attr on one copy's rows): each copy gives what its env alone gives.
    reward_fn gets the env's float64 reward."""
    kws = [dict(max_cycles=5), dict(max_cycles=7, reward_scale=3.0, los_penalty=0.5, terminate_on_collision=True)]
    seen = []

    def shaping(reward, info):
        seen.append((reward, info["env_reward"]))
        return 2.0 * reward

    venv = ParallelEnvVecAdapter([lambda kw=kw: CovertSensingParallelEnv(n_uavs=3, **kw) for kw in kws],
                                 reward_fn=shaping)
    alone = [CovertSensingParallelEnv(n_uavs=3, **kw) for kw in kws]
    venv.seed(1)
    venv.reset()
    for j, env in enumerate(alone):
        env.reset(seed=1 + 3 * j)
    venv.set_attr("reward_scale", 6.0, indices=[3])       # copy 1 only, after construction: read live
    alone[1].reward_scale = 6.0
    assert venv.get_attr("reward_scale") == [100.0] * 3 + [6.0] * 3
    rng = np.random.default_rng(2)
    for _ in range(9):
        acts = rng.uniform(-1, 1, (6, 2)).astype(np.float32)
        _, rew, dones, infos = venv.step(acts)
        for j, env in enumerate(alone):
            _, r, te, tr, _ = env.step(dict(zip(env.possible_agents, acts[3 * j:3 * j + 3], strict=True)))
            np.testing.assert_array_equal(rew[3 * j:3 * j + 3], 2.0 * np.array(list(r.values()), np.float32))
            assert dones[3 * j] == (te["uav_0"] or tr["uav_0"])
            if not env.agents:
                env.reset()
    assert all(type(r) is float and r == e for r, e in seen)


def test_batched_adapter_bad_actions_raise_naming_the_copy_and_agent():
    venv = make_vec_env(2, dict(n_uavs=3, max_cycles=4))
    venv.reset()
    acts = np.zeros((6, 2), np.float32)
    acts[4, 1] = np.inf
    with pytest.raises(ValueError, match=r"copy 1, agent uav_1 must be finite"):
        venv.step(acts)
    with pytest.raises(ValueError, match=r"actions must have shape \(6, 2\)"):
        venv.step(np.zeros((6, 3), np.float32))
    wp = make_vec_env(1, dict(n_uavs=2, max_cycles=4, action_mode="waypoint"))
    wp.reset()
    n = wp.action_space.n
    with pytest.raises(ValueError, match=rf"copy 0, agent uav_1 must be an integer in \[0, {n - 1}\], got {n}$"):
        wp.step(np.array([0, n]))


def test_vecmonitor_and_vecnormalize():
    venv = VecNormalize(VecMonitor(make_vec_env(1, SMALL)), gamma=0.97)
    venv.seed(0)
    obs = venv.reset()
    assert np.abs(obs).max() <= 10.0
    episodes = []
    for _ in range(SMALL["max_cycles"]):
        obs, rew, dones, infos = venv.step(np.zeros((3, 2), np.float32))
    episodes = [i["episode"] for i in infos if "episode" in i]
    assert len(episodes) == 3 and all(e["l"] == SMALL["max_cycles"] for e in episodes)
    # VecNormalize normalises the terminal observation too, and the raw reward is recoverable
    assert all("terminal_observation" in i for i in infos)
    assert venv.get_original_reward().shape == (3,)
    assert venv.obs_rms.count > 1


def test_action_masks_through_env_method():
    venv = make_vec_env(1, dict(n_uavs=2, max_cycles=5, action_mode="waypoint"))
    venv.reset()
    masks = np.stack(venv.env_method("action_masks"))
    assert masks.shape == (2, venv.action_space.n) and masks.dtype == bool and masks.any(axis=1).all()


def test_reward_fn_shaping():
    from training.sb3.ppo_multi import shaped_reward

    venv = make_vec_env(1, SMALL, reward_fn=shaped_reward(True))
    venv.reset()
    _, rew, _, infos = venv.step(np.ones((3, 2), np.float32))
    for r, info in zip(rew, infos, strict=True):
        t = {k: v for k, v in info.items() if k.startswith("reward_")}
        assert len(t) == 7
        expect = sum(t.values()) - (0.0 if info["in_zone"] else t["reward_disguise"])
        assert r == pytest.approx(expect, abs=1e-5) and "env_reward" in info


# ---------------------------------------------------------------------- scripts + harness
def _evaluate(tmp_path, spec, n_uavs, extra=()):
    from covert_env.evaluation.evaluate import main as evaluate_main

    out = tmp_path / "lb"
    assert evaluate_main(["--policies", "random", spec, *extra, "--episodes", "1", "--n-uavs", str(n_uavs),
                          "--out", str(out), "--no-progress", "--trust-checkpoint"]) == 0
    md = (out / "leaderboard.md").read_text()
    csv_text = (out / "leaderboard.csv").read_text()
    assert (out / "comparison.png").exists()
    assert csv_text.count("\n") == 3 + len(extra)   # header, random, spec, extras
    return md


def _common(tmp_path):
    return ["--runs-dir", str(tmp_path / "runs"), "--run-name", "r", "--progress-bar", "false",
            "--max-cycles", "16"]


@pytest.mark.slow
def test_ppo_multi_train_resume_evaluate(tmp_path):
    from training.sb3 import ppo_multi

    run = ppo_multi.main(["--recipe", "smoke", *_common(tmp_path)])
    assert (run / "model.zip").exists() and (run / "vecnormalize.json").exists()
    assert json.loads((run / "train_summary.json").read_text())["timesteps"] >= 3000
    assert list((run / "checkpoints").glob("ppo_multi_*_steps.zip"))
    assert list((run / "checkpoints").glob("ppo_multi_vecnormalize_*_steps.json"))
    assert not list(run.rglob("*.pkl"))                          # nothing we write is a pickle
    assert list((run / "tb").iterdir())
    run2 = ppo_multi.main(["--recipe", "smoke", "--resume", str(run), "--trust-checkpoint", "--total-timesteps",
                           "4500", "--progress-bar", "false"])
    assert run2 == run and json.loads((run / "train_summary.json").read_text())["timesteps"] >= 4500
    ckpt = sorted((run / "checkpoints").glob("ppo_multi_*_steps.zip"))[0]
    md = _evaluate(tmp_path, f"sb3:{run}", 3, extra=(f"sb3:{ckpt}",))
    assert "ppo_multi" in md


@pytest.mark.slow
def test_ppo_single_train_evaluate(tmp_path):
    from training.sb3 import ppo_single

    run = ppo_single.main(["--total-timesteps", "2048", "--n-envs", "2", "--n-steps", "512", "--checkpoint-freq",
                           "1024", *_common(tmp_path)])
    assert (run / "model.zip").exists() and (run / "vecnormalize.json").exists()
    assert "ppo_single" in _evaluate(tmp_path, f"sb3:{run}", 1)


@pytest.mark.slow
def test_sac_single_train_evaluate(tmp_path):
    from training.sb3 import sac_single

    run = sac_single.main(["--total-timesteps", "1000", "--learning-starts", "500", "--batch-size", "64",
                           "--net-arch", "64", "64", "--checkpoint-freq", "500", *_common(tmp_path)])
    assert (run / "model.zip").exists() and (run / "vecnormalize.json").exists()
    assert "sac_single" in _evaluate(tmp_path, f"sb3:{run}", 1)


@pytest.mark.slow
def test_maskable_ppo_single_train_evaluate(tmp_path):
    from training.sb3 import maskable_ppo_single

    run = maskable_ppo_single.main(["--total-timesteps", "2048", "--n-envs", "2", "--n-steps", "512",
                                    "--checkpoint-freq", "1024", *_common(tmp_path)])
    assert (run / "model.zip").exists()
    md = _evaluate(tmp_path, f"sb3:{run}", 1)
    assert "maskable_ppo_single" in md and "| waypoint |" in md


def test_harness_rejects_team_size_mismatch(tmp_path):
    from covert_env.evaluation.evaluate import load_policy
    from training.sb3 import ppo_single

    run = ppo_single.main(["--total-timesteps", "256", "--n-envs", "1", "--n-steps", "256", "--batch-size", "64",
                           "--checkpoint-freq", "0", *_common(tmp_path)])
    with pytest.raises(ValueError, match="--n-uavs 1"):
        load_policy(f"sb3:{run}", 3, trust_checkpoint=True)
    with pytest.raises(ValueError, match="action mode"):
        load_policy("random@hover", 3)
    with pytest.raises(ValueError, match="unknown policy 'nonsense'"):
        load_policy("nonsense", 3)
    with pytest.raises(ValueError, match="no SB3 model"):
        load_policy(f"sb3:{run / 'missing'}", 1)


def test_rllib_one_iteration_and_harness(tmp_path):
    needs("ray.rllib")
    from training import rllib_ppo

    ckpt = rllib_ppo.main(["--iterations", "1", "--num-env-runners", "0", "--train-batch-size", "256",
                           "--minibatch-size", "128", "--num-epochs", "1", "--max-cycles", "16",
                           "--runs-dir", str(tmp_path / "runs"), "--run-name", "r"])
    assert ckpt.exists()
    assert "rllib" in _evaluate(tmp_path, f"rllib:{ckpt}", 3)


def test_time_budget_stops_and_saves(tmp_path):
    from training.sb3 import ppo_multi

    run = ppo_multi.main(["--recipe", "smoke", *_common(tmp_path), "--total-timesteps", "1000000",
                          "--time-budget-minutes", "0.001", "--checkpoint-freq", "0"])
    summary = json.loads((run / "train_summary.json").read_text())
    assert summary["stopped_by_time_budget"] is True and summary["timesteps"] < 1_000_000
    assert (run / "model.zip").exists() and (run / "vecnormalize.json").exists()


def test_progress_bar_ends_with_the_time_budget(tmp_path, monkeypatch):
    """The SB3 bar's total is the projected end of the time budget, not total_timesteps, so its ETA is the
    budget's; it ends full at the step where the budget stopped the run."""
    import tqdm.auto

    from training.sb3 import ppo_multi

    seen, closed = [], []

    class Recording(tqdm.auto.tqdm):
        def update(self, n=1):
            out = super().update(n)
            d = self.format_dict
            if d["n"] > d["initial"]:
                rate = d["rate"] or (d["n"] - d["initial"]) / d["elapsed"]
                seen.append((d["total"], d["elapsed"] + (d["total"] - d["n"]) / rate))
            return out

        def close(self):
            closed.append((self.n, self.total))
            return super().close()

    monkeypatch.setattr(tqdm.auto, "tqdm", Recording)
    run = ppo_multi.main(["--recipe", "smoke", *_common(tmp_path), "--progress-bar", "true",
                          "--total-timesteps", "10000000", "--time-budget-minutes", "0.03", "--checkpoint-freq", "0"])
    summary = json.loads((run / "train_summary.json").read_text())
    assert summary["stopped_by_time_budget"] is True
    assert closed[0] == (summary["timesteps"], summary["timesteps"])
    late = seen[len(seen) // 2:]                       # the second half of the run: the rate is measured
    assert late and all(t < 10_000_000 and 0.3 * 1.8 <= end <= 3 * 1.8 for t, end in late), seen


# ---------------------------------------------------------------------- VecNormalize statistics as JSON, no pickle
def _trained_vecnormalize(norm_reward: bool = True) -> VecNormalize:
    """A VecNormalize whose statistics moved away from their initial values."""
    vn = VecNormalize(VecMonitor(make_vec_env(2, SMALL)), gamma=0.97, clip_obs=5.0, norm_reward=norm_reward)
    vn.seed(0)
    vn.reset()
    rng = np.random.default_rng(0)
    for _ in range(12):
        vn.step(rng.uniform(-1, 1, (vn.num_envs, 2)).astype(np.float32))
    return vn


def _raw_observations(n: int = 6) -> np.ndarray:
    venv = make_vec_env(2, SMALL)
    venv.seed(7)
    obs = [venv.reset()]
    for _ in range(n):
        obs.append(venv.step(np.ones((venv.num_envs, 2), np.float32))[0])
    return np.concatenate(obs)


def test_vecnormalize_json_round_trip_is_exact(tmp_path):
    from training.sb3.vec_env import load_vecnormalize, read_vecnormalize, save_vecnormalize

    vn = _trained_vecnormalize()
    path = save_vecnormalize(vn, tmp_path / "vecnormalize.json")
    data = json.loads(path.read_text())                      # plain JSON
    assert data["format"] == "covert_env.vecnormalize" and data["clip_obs"] == 5.0 and data["gamma"] == 0.97
    obs = _raw_observations()
    expected = vn.normalize_obs(obs)
    assert not np.allclose(expected, np.clip(obs, -5, 5))   # the statistics matter
    stats = read_vecnormalize(path)
    got = stats.normalize_obs(obs)
    assert got.dtype == expected.dtype and np.array_equal(got, expected)
    vn2 = load_vecnormalize(path, VecMonitor(make_vec_env(2, SMALL)))
    assert np.array_equal(vn2.obs_rms.mean, vn.obs_rms.mean) and np.array_equal(vn2.obs_rms.var, vn.obs_rms.var)
    assert vn2.obs_rms.count == vn.obs_rms.count
    assert (vn2.ret_rms.mean, vn2.ret_rms.var, vn2.ret_rms.count) == (vn.ret_rms.mean, vn.ret_rms.var,
                                                                       vn.ret_rms.count)
    assert (vn2.clip_obs, vn2.clip_reward, vn2.gamma, vn2.epsilon, vn2.norm_obs, vn2.norm_reward) == (
        vn.clip_obs, vn.clip_reward, vn.gamma, vn.epsilon, vn.norm_obs, vn.norm_reward)
    assert np.array_equal(vn2.normalize_obs(obs), expected)
    rew = np.linspace(-3, 3, vn.num_envs)
    assert np.array_equal(vn2.normalize_reward(rew), vn.normalize_reward(rew))


def test_vecnormalize_json_rejects_bad_files(tmp_path):
    from training.sb3.vec_env import load_vecnormalize, read_vecnormalize, save_vecnormalize

    vn = _trained_vecnormalize()
    good = json.loads(save_vecnormalize(vn, tmp_path / "ok.json").read_text())
    cases = {"not json": "{", "other format": json.dumps({"format": "x"}),
             "wrong version": json.dumps({**good, "version": 99}),
             "negative var": json.dumps({**good, "obs_rms": {**good["obs_rms"], "var": [-1.0] * len(
                 good["obs_rms"]["var"])}}),
             "short mean": json.dumps({**good, "obs_rms": {**good["obs_rms"], "mean": [0.0]}}),
             "clip": json.dumps({**good, "clip_obs": "big"})}
    for name, text in cases.items():
        p = tmp_path / f"{name}.json"
        p.write_text(text)
        with pytest.raises(ValueError, match=str(p).replace("\\", "\\\\")):
            read_vecnormalize(p)
    # statistics of another observation size are refused when wrapping an env
    with pytest.raises(ValueError, match="shape"):
        load_vecnormalize(tmp_path / "ok.json", VecMonitor(make_vec_env(1, dict(n_uavs=1, max_cycles=4,
                                                                             map_size=4))))


def _sb3_run(tmp_path, name="run"):
    """A tiny trained PPO run folder as the scripts write it: model.zip, vecnormalize.json, args.json."""
    from training.common import save_run
    from training.sb3.run import save_final_vecnormalize

    run = tmp_path / name
    vn = _trained_vecnormalize()
    model = PPO("MlpPolicy", vn, n_steps=16, batch_size=48, n_epochs=1, seed=0, device="cpu")
    model.learn(32)
    save_run(run, {"seed": 0}, {"algo": "tiny", "sb3_class": "PPO", "env_kwargs": {"n_uavs": 3}})
    model.save(run / "model.zip")
    save_final_vecnormalize(model, run)
    return run, model


def test_evaluation_normalises_like_the_training_vecnormalize(tmp_path, monkeypatch):
    import pickle

    from training.learned_policies import load_sb3

    run, model = _sb3_run(tmp_path)
    in_memory = model.get_vec_normalize_env()
    assert (run / "vecnormalize.json").exists() and not list(run.glob("*.pkl"))

    def no_pickle(*a, **k):
        raise AssertionError("pickle used for VecNormalize statistics")

    monkeypatch.setattr(pickle, "load", no_pickle)               # SB3's model.zip is not read with pickle.load
    pol = load_sb3(run, trust_checkpoint=True)
    obs = _raw_observations()
    assert np.array_equal(pol.norm.normalize_obs(obs), in_memory.normalize_obs(obs))
    # and the policy acts on exactly those observations
    from covert_env.envs.covert_sensing import CovertSensingParallelEnv

    env = CovertSensingParallelEnv(**SMALL)
    o, _ = env.reset(seed=3)
    acts = pol.act(o, env)
    expect, _ = model.predict(in_memory.normalize_obs(np.stack([o[a] for a in env.agents])), deterministic=True)
    assert np.array_equal(np.stack([acts[a] for a in env.agents]), expect)


def test_pickled_statistics_are_refused_with_the_conversion_command(tmp_path, monkeypatch):
    import pickle

    from covert_env.cli import UsageError
    from training.learned_policies import load_sb3
    from training.sb3.convert_vecnormalize import main as convert_main
    from training.sb3.vec_env import load_vecnormalize, read_vecnormalize

    run, model = _sb3_run(tmp_path)
    in_memory = model.get_vec_normalize_env()
    (run / "vecnormalize.json").unlink()
    in_memory.save(str(run / "vecnormalize.pkl"))                # as older versions wrote it (SB3's pickle)
    calls = []
    real_load = pickle.load
    monkeypatch.setattr(pickle, "load", lambda *a, **k: calls.append(a) or real_load(*a, **k))
    with pytest.raises(UsageError, match="convert_vecnormalize") as exc:
        load_sb3(run, trust_checkpoint=True)
    assert "older covert_env" in str(exc.value) and str(run / "vecnormalize.pkl") in str(exc.value)
    with pytest.raises(ValueError, match="convert_vecnormalize"):
        load_vecnormalize(run / "vecnormalize.pkl", VecMonitor(make_vec_env(2, SMALL)))   # resume path
    assert calls == []                                           # refused without unpickling
    # the explicit one-off conversion of a trusted file, then evaluation works and normalises the same
    assert convert_main(["--trust-checkpoint", str(run)]) == 0
    assert calls                                                 # (that one does unpickle, on request)
    obs = _raw_observations()
    assert np.array_equal(read_vecnormalize(run / "vecnormalize.json").normalize_obs(obs),
                          in_memory.normalize_obs(obs))
    assert np.array_equal(load_sb3(run, trust_checkpoint=True).norm.normalize_obs(obs), in_memory.normalize_obs(obs))


def test_no_pickle_on_the_statistics_path():
    """Nothing in training/ but the explicit converter imports pickle or calls SB3's pickle-based load/save."""
    import pathlib

    import training

    root = pathlib.Path(training.__file__).parent
    for f in root.glob("*.py"):
        src = f.read_text()
        if f.name == "convert_vecnormalize.py":
            continue
        assert "import pickle" not in src and "VecNormalize.load" not in src, f.name
        assert "save_vecnormalize=True" not in src and "get_env().save(" not in src, f.name


# ---------------------------------------------------------------------- pickled checkpoints load only on request
def _payload_model(tmp_path, marker):
    """A real SB3 run folder whose model.zip ``data`` entry also carries a cloudpickle payload that creates
    ``marker`` when unpickled (as a hostile file would run its code)."""
    import base64
    import pathlib
    import pickle
    import zipfile

    run, _ = _sb3_run(tmp_path)
    payload = base64.b64encode(pickle.dumps(_Touch(str(marker)))).decode()
    src = run / "model.zip"
    entries = {}
    with zipfile.ZipFile(src) as z:
        for name in z.namelist():
            entries[name] = z.read(name)
    data = json.loads(entries["data"])
    data["payload"] = {":type:": "<class 'pathlib.Path'>", ":serialized:": payload}
    entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(src, "w") as z:
        for name, blob in entries.items():
            z.writestr(name, blob)
    assert pathlib.Path(marker).exists() is False
    return run


class _Touch:
    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        import pathlib

        return pathlib.Path.touch, (pathlib.Path(self.path),)


TRUST_RE = (r"is an SB3 model, which holds pickled Python objects: loading it runs any code they carry\. "
            r"Pass --trust-checkpoint \(trust_checkpoint=True in Python\) only if it comes from a source you trust$")


@pytest.mark.parametrize("which", ["run folder", "zip path"])
def test_evaluate_refuses_a_pickled_model_without_trust_checkpoint(tmp_path, capsys, which):
    import re

    from covert_env.cli import main

    marker = tmp_path / "payload_ran"
    run = _payload_model(tmp_path, marker)
    spec = f"sb3:{run if which == 'run folder' else run / 'model.zip'}"
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--policies", "random", spec, "--episodes", "1", "--n-uavs", "3", "--no-progress",
              "--out", str(tmp_path / "lb")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert re.fullmatch(rf"covert-env evaluate: error: --policies: {re.escape(str(run / 'model.zip'))} {TRUST_RE}",
                        lines[0]), lines[0]
    assert not marker.exists()                                   # the payload never ran
    assert not (tmp_path / "lb").exists()                        # and nothing was evaluated or written


def test_load_policy_trust_checkpoint_is_the_only_way_in(tmp_path, monkeypatch):
    import stable_baselines3

    from covert_env.cli import UsageError
    from covert_env.evaluation.evaluate import load_policy

    marker = tmp_path / "payload_ran"
    run = _payload_model(tmp_path, marker)
    calls = []
    real_load = stable_baselines3.PPO.load
    monkeypatch.setattr(stable_baselines3.PPO, "load", classmethod(
        lambda cls, *a, **k: calls.append(a) or real_load.__func__(cls, *a, **k)))
    for kw in ({}, {"trust_checkpoint": False}):
        with pytest.raises(UsageError, match=TRUST_RE):
            load_policy(f"sb3:{run}", 3, **kw)
    with pytest.raises(TypeError, match="trust_checkpoint must be True or False, got 'yes'"):
        load_policy(f"sb3:{run}", 3, trust_checkpoint="yes")
    assert calls == [] and not marker.exists()
    pol, settings = load_policy(f"sb3:{run}", 3, trust_checkpoint=True)     # the opt-in loads it
    assert len(calls) == 1 and settings["n_uavs"] == 3 and pol.model.policy is not None
    assert marker.exists()                     # the payload was real: only the refusal kept it from running


def test_rllib_checkpoints_are_refused_without_trust_before_ray_loads(tmp_path, capsys):
    from covert_env.cli import UsageError, main
    from training import rllib_ppo

    ckpt = tmp_path / "run" / "checkpoint"
    (ckpt / "learner_group").mkdir(parents=True)
    (tmp_path / "run" / "args.json").write_text("{}")
    with pytest.raises(UsageError, match=r"checkpoint is an RLlib checkpoint, which holds pickled Python objects.*"
                                         r"--trust-checkpoint"):
        rllib_ppo.load_policy(ckpt)
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--policies", f"rllib:{ckpt}", "--out", str(tmp_path / "lb")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    assert f"--policies: {ckpt} is an RLlib checkpoint" in err and "--trust-checkpoint" in err
    with pytest.raises(SystemExit) as exc:
        rllib_ppo.main(["--resume", str(ckpt)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    assert f"error: --resume {ckpt}: {ckpt} is an RLlib checkpoint" in err and "--trust-checkpoint" in err
    with pytest.raises(UsageError, match="--trust-checkpoint"):
        rllib_ppo.train(rllib_ppo.Args(resume=str(ckpt)))


def test_resume_of_an_sb3_run_needs_trust_checkpoint(tmp_path, capsys, monkeypatch):
    import stable_baselines3

    from covert_env.cli import UsageError
    from training.sb3 import ppo_single
    from training.sb3.run import train_single

    run = ppo_single.main(["--total-timesteps", "256", "--n-envs", "1", "--n-steps", "256", "--batch-size", "64",
                           "--checkpoint-freq", "0", *_common(tmp_path)])
    args_before = (run / "args.json").read_text()

    def never(*a, **k):
        raise AssertionError("the pickled model was loaded")

    monkeypatch.setattr(stable_baselines3.PPO, "load", never)
    with pytest.raises(SystemExit) as exc:
        ppo_single.main(["--resume", str(run), "--total-timesteps", "512", "--progress-bar", "false"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    assert f"error: --resume {run}: {run / 'model.zip'} is an SB3 model, which holds pickled" in err, err
    assert "--trust-checkpoint" in err
    with pytest.raises(UsageError, match=TRUST_RE):
        train_single(ppo_single.Args(resume=str(run)), "ppo_single", "PPO", "unicycle", None)
    assert (run / "args.json").read_text() == args_before             # refused before anything was written
    monkeypatch.undo()
    assert ppo_single.main(["--resume", str(run), "--trust-checkpoint", "--total-timesteps", "512",
                            "--progress-bar", "false"]) == run
    assert json.loads((run / "train_summary.json").read_text())["timesteps"] >= 512


def test_convert_vecnormalize_needs_trust_checkpoint(tmp_path, capsys, monkeypatch):
    import pickle

    from training.sb3.convert_vecnormalize import convert
    from training.sb3.convert_vecnormalize import main as convert_main

    run, model = _sb3_run(tmp_path)
    model.get_vec_normalize_env().save(str(run / "vecnormalize.pkl"))
    calls = []
    monkeypatch.setattr(pickle, "load", lambda *a, **k: calls.append(a))
    with pytest.raises(SystemExit) as exc:
        convert_main([str(run)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--trust-checkpoint" in err and "Traceback" not in err
    with pytest.raises(ValueError, match="a pickled VecNormalize file.*--trust-checkpoint"):
        convert(run / "vecnormalize.pkl")
    assert calls == []


@pytest.mark.parametrize("env_kwargs, pattern", [
    ({"n_uavs": 2}, r"takes observations as a Box of shape \(143,\), but the env of its settings \(.*args\.json: "
                    r"n_uavs=2, action_mode=unicycle, map_size=8\) has a Box of shape \(141,\)"),
    ({"n_uavs": 3, "action_mode": "waypoint"}, r"takes actions as a Box of shape \(2,\), but .* has Discrete\(577\)"),
])
def test_sb3_model_that_does_not_fit_its_args_json_is_named(tmp_path, env_kwargs, pattern):
    from covert_env.cli import UsageError
    from covert_env.evaluation.evaluate import load_policy

    run, _ = _sb3_run(tmp_path)
    meta = json.loads((run / "args.json").read_text())
    (run / "args.json").write_text(json.dumps({**meta, "env_kwargs": env_kwargs}))
    with pytest.raises(UsageError, match=rf"^sb3:.*run: .*model\.zip {pattern}$"):
        load_policy(f"sb3:{run}", env_kwargs["n_uavs"], trust_checkpoint=True)
