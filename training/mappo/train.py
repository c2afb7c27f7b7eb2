"""The training loop of :mod:`training.mappo`: rollout, GAE, the PPO update and the dual ascent, with TensorBoard,
``curve.jsonl``, checkpoints and a time budget."""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

from covert_env.envs.safety_filter import SafetyFilteredVectorEnv
from training.budget import expected_steps
from training.common import resumed_args, run_name, save_run, setup_torch
from training.mappo.agents import (
    Agents,
    RunningNorm,
    behaviour_copy,
    copy_weights,
    load_initial_actor,
    make_networks,
    sizes_of,
)
from training.mappo.args import Args, check_args, task_list
from training.mappo.checkpoints import Progress, model_card, resume, save_checkpoint, save_final
from training.mappo.ppo import advantages, ppo_update
from training.mappo.rollout import Episodes, Rollout, collect_rollout
from training.shield import SeparationShield
from training.task_mix import make_training_env

__all__ = ["log_update", "train"]


def log_update(writer, curve, bar, prog: Progress, *, losses: dict, clipfracs: list, shield,
               episodes: Episodes, agents_env=None) -> None:
    """The update's losses and charts to TensorBoard (with the safety filter's counts where ``agents_env`` has
    one); the finished episodes' means to TensorBoard, curve.jsonl and the progress bar."""
    step = prog.global_step
    for k, v in losses.items():
        writer.add_scalar(f"losses/{k}", v, step)
    writer.add_scalar("losses/clipfrac", float(np.mean(clipfracs)), step)
    writer.add_scalar("charts/sps", step / max(prog.wall_seconds, 1e-9), step)
    for name, value in prog.lam.items():
        writer.add_scalar(f"charts/lambda_{name}", value, step)
    safety = getattr(agents_env, "safety", None)
    if safety is not None:                   # the safety filter: what it did, since the run (re)started
        st = safety.stats
        for key in ("changed", "backups", "uncertified", "infeasible"):
            writer.add_scalar(f"charts/filter_{key}", getattr(st, key) / max(st.team_slots, 1), step)
    if shield is not None:
        writer.add_scalar("charts/shield_fallbacks", shield.fallbacks / max(shield.choices, 1), step)
        writer.add_scalar("charts/shield_dead_ends", shield.dead_ends / max(shield.choices, 1), step)
        writer.add_scalar("charts/shield_rescued", shield.rescued / max(shield.choices, 1), step)
    if episodes.recent:
        n_episodes, means = len(episodes.recent), episodes.take_means()
        for k, v in means.items():
            writer.add_scalar(f"episode/{k}", v, step)
        curve.write(json.dumps({"env_steps": step, "wall_seconds": round(prog.wall_seconds, 1),
                                "episodes": n_episodes, **means, **losses, "lambda": prog.lam}) + "\n")
        curve.flush()
        bar.set_postfix(reward=f"{means['reward']:.1f}", sep=f"{means['cost_separation']:.1f}", refresh=False)


def train(args: Args) -> Path:
    """Train a team (module docstring) and save its run folder; returns the folder."""
    check_args(args)
    setup_torch(args.torch_threads)
    from torch.utils.tensorboard import SummaryWriter
    from tqdm.auto import tqdm

    if args.resume:
        run_dir = Path(args.resume)
        args = resumed_args(args, run_dir)
    else:
        run_dir = Path(args.runs_dir) / (args.run_name or run_name(args.env_id, args.algo, args.seed))
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    env_kwargs = dict(n_uavs=args.n_uavs, action_mode=args.action_mode, max_cycles=args.max_cycles,
                      scene_pool=args.scene_pool)
    if args.map_size != 8:
        env_kwargs["map_size"] = args.map_size
    if args.target_path:
        env_kwargs["target_path"] = args.target_path
    if args.mask_mode != "visible":
        env_kwargs["mask_mode"] = args.mask_mode
    tasks = task_list(args)
    env = make_training_env(tasks, args.num_envs, **({k: v for k, v in env_kwargs.items()
                                                       if k not in ("n_uavs", "scene_pool")} if tasks else env_kwargs))
    if args.safety_filter:
        env = SafetyFilteredVectorEnv(env, min_reach=args.viability_min_reach if args.viability_shield else 0)
    s = sizes_of(args, env)
    shield = (SeparationShield(env.config.d_safe1 + args.shield_margin, args.shield_end_margin,
                               lookahead=args.shield_lookahead, min_reach=args.viability_min_reach)
              if s.waypoint and args.separation_shield else None)
    actor, critic, optim = make_networks(args, s)
    vnorm, prog = RunningNorm(), Progress()
    if args.resume:
        prog = resume(run_dir, actor, critic, optim, vnorm)
    elif args.init_actor:
        load_initial_actor(actor, args.init_actor, args.node_map, args.init_temperature, args.target_path)
    prog.lam = {name: prog.lam.get(name, 0.0) for name in s.constrained}
    card = model_card(args, s, env, env_kwargs, shield)
    save_run(run_dir, args, {"card": card})
    writer = SummaryWriter(str(run_dir / "tb"))
    curve = open(run_dir / "curve.jsonl", "a")
    agents = Agents(args, s, env, actor, critic, vnorm, shield)
    buf, episodes = Rollout(s), Episodes(s)

    obs, _ = env.reset(seed=args.seed + 7919 * prog.updates)      # a resumed run draws fresh episodes
    state = env.state()
    bar = tqdm(total=args.total_timesteps, initial=prog.global_step, unit="step", disable=not args.progress_bar,
               mininterval=0.5 if os.isatty(2) else 30.0, smoothing=0.05)
    t_start = time.monotonic() - prog.wall_seconds
    t_run, step_run = time.monotonic(), prog.global_step     # this process's rate projects the time budget's end
    last_ckpt = prog.global_step
    # prog.global_step counts the env-steps learned from; ``collected`` those stepped, one rollout more while an
    # overlapped update runs.
    collected = prog.global_step
    # The team that acts: the learner itself, or with --overlap-update a copy one update behind it.
    behaviour = behaviour_copy(agents) if args.overlap_update else agents
    update_rng = np.random.default_rng(args.seed + 7919 * prog.updates) if args.overlap_update else None

    def collect(into: Rollout) -> tuple[np.ndarray, list]:
        """A rollout into ``into`` with the behaviour team; returns the values to bootstrap it from and the episodes
        it finished."""
        nonlocal obs, state, collected
        obs, state = collect_rollout(behaviour, into, episodes, obs, state, lam=dict(prog.lam))
        collected += s.B * s.T
        now = time.monotonic()
        bar.total = expected_steps(args.total_timesteps, collected, now - t_start, args.time_budget_minutes,
                                   (collected - step_run) / max(now - t_run, 1e-9))
        bar.update(s.B * s.T)
        return behaviour.value(obs, state), episodes.take_recent()

    def anneal() -> None:
        """--anneal-lr: the learning rate of the next update, by the env-steps learned from before it."""
        if args.anneal_lr:
            optim.param_groups[0]["lr"] = args.learning_rate * max(1.0 - prog.global_step / args.total_timesteps,
                                                                   0.0)

    def learn(rollout: Rollout, next_value: np.ndarray):
        """GAE and the PPO update of the learner from ``rollout``."""
        adv, returns = advantages(rollout, next_value, args.gamma, args.gae_lambda)
        if args.value_norm:
            vnorm.update(returns)
        losses, clipfracs = ppo_update(agents, optim, rollout, adv, returns,
                                       train_actor=prog.updates >= args.actor_warmup_updates, rng=update_rng)
        if not all(np.isfinite(v) for v in losses.values()):
            raise FloatingPointError(f"non-finite losses at update {prog.updates}: {losses}")
        return losses, clipfracs

    def finish(rollout: Rollout, finished: list, losses: dict, clipfracs: list) -> bool:
        """The dual ascent on ``rollout``'s costs, the logs (with the episodes it ``finished``) and the checkpoint of
        the update that learned from it; True if the run's time budget is spent."""
        nonlocal last_ckpt
        prog.global_step += s.B * s.T
        for j, (name, limit) in enumerate(s.constrained.items()):       # dual ascent, one multiplier each
            prog.lam[name] = max(0.0, prog.lam[name] + args.lagrange_lr * (float(rollout.costs[:, j].mean()) - limit))
            if args.lambda_max:
                prog.lam[name] = min(prog.lam[name], args.lambda_max)
        prog.updates += 1
        prog.wall_seconds = time.monotonic() - t_start
        episodes.recent = finished
        log_update(writer, curve, bar, prog, losses=losses, clipfracs=clipfracs, shield=shield, episodes=episodes,
                   agents_env=env)
        spent = args.time_budget_minutes > 0 and prog.wall_seconds > 60 * args.time_budget_minutes
        if spent and not stopped:
            print(f"time budget of {args.time_budget_minutes:g} min reached at {prog.global_step} env steps: "
                  "stopping", flush=True)
        if args.checkpoint_every and prog.global_step - last_ckpt >= args.checkpoint_every:
            save_checkpoint(run_dir / "checkpoints" / f"step_{prog.global_step}.npz", actor, critic, optim,
                            prog.meta(vnorm, card))
            last_ckpt = prog.global_step
        return spent

    stopped = False
    if not args.overlap_update:
        while prog.global_step < args.total_timesteps:
            next_value, finished = collect(buf)
            anneal()
            stopped = finish(buf, finished, *learn(buf, next_value))
            if stopped:
                break
    elif prog.global_step < args.total_timesteps:
        # Two rollouts take turns: the update learns from one while the behaviour team fills the other (the numpy
        # and compiled parts of both release the GIL). Each rollout's ratios and GAE are against the behaviour
        # team that acted; it takes the learner's weights when both halves are done.
        rollouts, i = (buf, Rollout(s)), 0
        next_value, finished = collect(rollouts[0])
        with ThreadPoolExecutor(1, thread_name_prefix="ppo-update") as pool:
            while True:
                last = stopped or collected >= args.total_timesteps
                anneal()
                update = pool.submit(learn, rollouts[i], next_value)
                learned_finished = finished
                if not last:
                    next_value, finished = collect(rollouts[1 - i])
                stopped = finish(rollouts[i], learned_finished, *update.result()) or stopped
                if last:
                    break
                copy_weights(agents, behaviour)
                i = 1 - i
    if stopped:
        bar.total = bar.n                       # the time budget ended the run here
    bar.close()
    save_final(run_dir, actor, critic, optim, prog.meta(vnorm, card))
    summary = {"env_steps": prog.global_step, "agent_steps": prog.global_step * s.U, "updates": prog.updates,
               "train_minutes": round((time.monotonic() - t_start) / 60, 2), "stopped_by_time_budget": stopped}
    (run_dir / "train_summary.json").write_text(json.dumps(summary, indent=2))
    print(f"saved {run_dir / 'model.npz'}: {summary}", flush=True)
    writer.close()
    curve.close()
    env.close()
    return run_dir
