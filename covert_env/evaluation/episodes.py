"""Policies flown through held-out scenes, one row of metrics per episode: the rows every leaderboard is made of.

Every policy has a ``name`` and two methods::

    policy.reset(env, seed=None)            # after env.reset(); seeds the policy's own randomness
    actions = policy.act(observations, env)

``env`` is the PettingZoo :class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv` or a Gymnasium single-UAV
env of covert_env (the parallel env inside is ``env.unwrapped.par``). :func:`run_episode` flies one episode and scores
it with :func:`covert_env.world.metrics.episode_metrics`, the code every policy is scored with; :func:`evaluate` flies
the held-out scenes ``seed_offset + i`` (or a scene set's) and gives one row per episode, with the :data:`COLUMNS` of
the leaderboards; :func:`summarise` their mean and std.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

import numpy as np

from covert_env.envs.covert_sensing import CovertSensingParallelEnv
from covert_env.envs.safety_filter import ShieldedPolicy
from covert_env.world.families import HELD_OUT_SEEDS
from covert_env.world.metrics import episode_metrics
from covert_env.world.scene_set import SceneSet

__all__ = ["COLUMNS", "HELD_OUT_OFFSET", "evaluate", "parallel_env_of", "run_episode", "summarise", "team_row"]

HELD_OUT_OFFSET = HELD_OUT_SEEDS.start
"""The first held-out scene seed (episode i flies scene ``HELD_OUT_OFFSET + i``)."""

#: (key, header, format) of the leaderboard columns; keys are metric names of covert_env.world.metrics or "reward".
COLUMNS = [
    ("reward", "episode reward", "{:.1f}"),
    ("occlusion_rate", "blocked LoS at slots", "{:.3f}"),
    ("occlusion_rate_path", "blocked LoS along path", "{:.3f}"),
    ("blocked_path_share", "share of path with blocked LoS", "{:.3f}"),
    ("zone_violation_rate", "zone violations", "{:.3f}"),
    ("mean_disguise", "disguise kappa", "{:.1f}"),
    ("path_length", "path length (m)", "{:.0f}"),
    ("separation_violations", "separation violations", "{:.2f}"),
    ("min_separation", "min separation (m)", "{:.1f}"),
    ("terrain_violations", "terrain violations", "{:.2f}"),
    ("decision_time_ms", "decision time per slot (ms)", "{:.2f}"),
]


def parallel_env_of(env) -> tuple[Any, str | None]:
    """The parallel env behind ``env`` and, for a Gymnasium single-UAV env, its agent's name (else None)."""
    if hasattr(env, "engine") and hasattr(env, "possible_agents"):
        return env, None
    inner = getattr(env, "unwrapped", env)
    par = getattr(inner, "par", None)
    if par is None:
        raise TypeError(f"{type(env).__name__} is neither a CovertSensingParallelEnv nor a covert_env "
                        "Gymnasium env (no .unwrapped.par)")
    return par, par.possible_agents[0]


def run_episode(policy, env, *, seed: int | None = None, options: dict | None = None) -> dict:
    """Reset ``env``, run ``policy`` to the end of the episode and score it.

    Returns:
        dict with ``trajectory`` (:class:`~covert_env.world.trajectory.Trajectory` recorded by the engine),
        ``metrics`` (one dict per UAV, :func:`covert_env.world.metrics.episode_metrics`, with the measured
        ``decision_time_ms`` of ``act`` split over the UAVs), ``return`` (sum of rewards per agent) and
        ``steps``.
    """
    par, single = parallel_env_of(env)           # first: a wrong env is named before anything runs
    obs, _ = env.reset(seed=seed, options=options)
    policy.reset(env, seed)
    agents = list(par.possible_agents)
    total = {a: 0.0 for a in agents}
    times = []
    steps = 0
    while True:
        t0 = time.perf_counter()
        act = policy.act(obs, env)
        times.append(time.perf_counter() - t0)
        if single is not None:
            obs, r, term, trunc, _ = env.step(act)
            total[single] += float(r)
            done = term or trunc
        else:
            obs, r, term, trunc, _ = env.step(act)
            for a, v in r.items():
                total[a] += float(v)
            done = not par.agents
        steps += 1
        if done:
            break
    traj = par.engine.trajectory()
    metrics = episode_metrics(traj, par.scenario.terrain, par.config)
    per_uav_ms = 1e3 * float(np.mean(times)) / len(agents)
    for m in metrics:
        m["decision_time_ms"] = per_uav_ms
    return {"trajectory": traj, "metrics": metrics, "return": total, "steps": steps}


def team_row(result: dict) -> dict:
    """Team mean of the per-UAV metrics of one episode (``min_separation``: the team's smallest, a minimum as the
    name says), plus the mean episode reward over UAVs."""
    ms = result["metrics"]
    row = {k: float(np.mean([m[k] for m in ms])) for k in ms[0]}
    row["min_separation"] = float(min(m["min_separation"] for m in ms))
    row["reward"] = float(np.mean(list(result["return"].values())))
    return row


def _filter_counts(policy) -> dict:
    """A ``+shield`` policy's safety-filter counts of the episode just flown (``filter_changed``,
    ``filter_infeasible``, ...: the episodes' CSV columns); {} for other policies."""
    if not isinstance(policy, ShieldedPolicy):
        return {}
    return {f"filter_{k}": v for k, v in policy.episode_counts().items()}


def evaluate(policy, settings: dict, episodes: int, seed_offset: int = HELD_OUT_OFFSET,
             env_kwargs: dict | None = None, progress: bool = True, label: str | None = None,
             scenes: SceneSet | None = None) -> list[dict]:
    """Run ``policy`` on held-out scenes ``seed_offset + i`` (or on the first ``episodes`` scenes of ``scenes``, each
    reset with its seed, or its index for a hand-made set) and return one metrics row per episode."""
    kw = dict(env_kwargs or {})
    kw.update(n_uavs=settings["n_uavs"], action_mode=settings["action_mode"])
    for key in ("map_size", "mask_mode", "target_path"):
        if key in settings:
            kw[key] = settings[key]
    if scenes is not None:
        return _evaluate_set(policy, kw, scenes, episodes, progress, label)
    env = CovertSensingParallelEnv(**kw)
    rows = []
    for i in _episodes(episodes, progress, label or getattr(policy, "name", "policy")):
        s = seed_offset + i
        res = run_episode(policy, env, seed=s, options={"scene_seed": s})
        row = team_row(res) | _filter_counts(policy)
        row["scene_seed"] = s
        rows.append(row)
    env.close()
    return rows


def _episodes(episodes: int, progress: bool, label: str):
    """``range(episodes)``, with a progress bar on stderr named ``label`` if asked."""
    if not progress:
        return range(episodes)
    from tqdm.auto import tqdm

    return tqdm(range(episodes), desc=label, leave=False, file=sys.stderr,
                mininterval=1.0 if sys.stderr.isatty() else 30.0)


def _evaluate_set(policy, kw: dict, scenes: SceneSet, episodes: int, progress: bool, label: str | None) -> list[dict]:
    """:func:`evaluate` on a scene set: one env per scene (a scene is the env's fixed scenario)."""
    kw.pop("family", None)
    rows = []
    for i in _episodes(episodes, progress, label or getattr(policy, "name", "policy")):
        s = scenes.seeds[i] if scenes.seeds is not None else i
        env = CovertSensingParallelEnv(scenario=scenes[i], **kw)
        row = team_row(run_episode(policy, env, seed=s)) | _filter_counts(policy)
        row["scene_seed"] = s
        rows.append(row)
        env.close()
    return rows


def summarise(rows: list[dict]) -> dict:
    """Mean and std over the rows of every :data:`COLUMNS` key (NaN and inf left out; NaN if none is finite)."""
    out = {}
    for key, _, _ in COLUMNS:
        v = np.array([r[key] for r in rows], float)
        v = v[np.isfinite(v)]
        out[key] = (float(v.mean()) if len(v) else math.nan, float(v.std()) if len(v) else math.nan)
    return out
