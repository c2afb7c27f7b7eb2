"""One SB3 training run, shared by every SB3 script around the two things that differ: its envs and its model.

Run layout (git-ignored ``runs/``)::

    runs/{env}__{algo}__{seed}__{time}/
        args.json            # the exact arguments (the harness reads env settings from here)
        model.zip            # final model
        vecnormalize.json    # VecNormalize statistics of the final model (if used)
        checkpoints/         # {algo}_{steps}_steps.zip + {algo}_vecnormalize_{steps}_steps.json
        tb/                  # TensorBoard logs
        train_summary.json   # steps, minutes, whether the time budget stopped it

The callbacks (:mod:`training.sb3.callbacks`): a tqdm progress bar (``mininterval`` 30 s when stdout is not a
terminal, so logs stay small); a wall-clock time budget that stops ``learn()`` gracefully (the model is then
saved); SB3's checkpoints every ``checkpoint_freq`` steps with the VecNormalize statistics beside the model as JSON
(:func:`training.sb3.vec_env.save_vecnormalize`: nothing we write is a pickle, but SB3's ``model.zip`` itself holds
pickled parts, so ``--resume`` loads it only with ``--trust-checkpoint``: :mod:`training.trust`).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from training.common import resume_checkpoint, resumed_args, run_name, save_run, setup_torch

if TYPE_CHECKING:
    from training.sb3.callbacks import TimeBudgetCallback

__all__ = ["make_callbacks", "save_final_vecnormalize", "train_sb3", "train_single"]


def make_callbacks(run_dir: Path, algo: str, total_timesteps: int, num_envs: int, checkpoint_freq: int,
                   time_budget_minutes: float, progress_bar: bool = True) -> tuple[list, TimeBudgetCallback]:
    """Checkpoints every ``checkpoint_freq`` steps (with VecNormalize stats), a time budget and a progress bar."""
    from training.sb3.callbacks import JsonCheckpointCallback, TimeBudgetCallback, TqdmCallback

    budget = TimeBudgetCallback(time_budget_minutes)
    cbs: list = [budget]
    if checkpoint_freq > 0:
        cbs.append(JsonCheckpointCallback(save_freq=max(checkpoint_freq // num_envs, 1),
                                          save_path=str(Path(run_dir) / "checkpoints"), name_prefix=algo))
    if progress_bar:
        cbs.append(TqdmCallback(total_timesteps, time_budget_minutes))
    return cbs, budget


def save_final_vecnormalize(model, run_dir: Path) -> Path | None:
    """``run_dir/vecnormalize.json`` with the statistics of the model's VecNormalize (if it has one)."""
    from training.sb3.vec_env import save_vecnormalize

    vn = model.get_vec_normalize_env()
    return save_vecnormalize(vn, Path(run_dir) / "vecnormalize.json") if vn is not None else None


def train_sb3(args: Any, algo: str, sb3_class: str, meta: Callable[[Any], dict], make_venv: Callable[[Any], Any],
              build: Callable[[Any, Any, str], Any], callbacks: Callable[[Any], Sequence] | None = None) -> Path:
    """An SB3 script's whole run; returns the run folder.

    The run folder (or ``--resume``: the saved settings, the newest checkpoint, which needs
    ``args.trust_checkpoint``, and its VecNormalize statistics), ``args.json`` with ``meta(args)`` (the env settings
    the harness reads), ``make_venv(args)`` (the seeded envs), VecNormalize (``norm_obs``/``norm_reward``, SB3's
    clips), ``build(args, venv, tensorboard_log)`` (the new model with the script's hyper-parameters), ``learn``
    with :func:`make_callbacks` and ``callbacks(args)``, then ``model.zip``, ``vecnormalize.json`` and
    ``train_summary.json``.
    ``sb3_class`` is ``"PPO"``, ``"SAC"`` (stable_baselines3) or ``"MaskablePPO"`` (sb3_contrib). The functions
    of ``args`` are called with the run's settings (a resumed run's saved ones).
    """
    setup_torch(args.torch_threads)
    if sb3_class == "MaskablePPO":
        from sb3_contrib import MaskablePPO as cls
    else:
        import stable_baselines3

        cls = getattr(stable_baselines3, sb3_class)
    from stable_baselines3.common.vec_env import VecNormalize

    from training.sb3.vec_env import load_vecnormalize

    ckpt = None
    if args.resume:
        run_dir = Path(args.resume)
        ckpt = resume_checkpoint(run_dir, trust_checkpoint=args.trust_checkpoint)
        args = resumed_args(args, run_dir)
    else:
        run_dir = Path(args.runs_dir) / (args.run_name or run_name(args.env_id, algo, args.seed))
    save_run(run_dir, args, {"algo": algo, "sb3_class": sb3_class, **meta(args)})
    venv = make_venv(args)
    if ckpt is not None:
        venv = load_vecnormalize(ckpt[1], venv) if ckpt[1] else venv
        model = cls.load(str(ckpt[0]), env=venv, device="cpu")
        print(f"resumed from {ckpt[0]} at {model.num_timesteps} steps", flush=True)
    else:
        if args.norm_obs or args.norm_reward:
            venv = VecNormalize(venv, norm_obs=args.norm_obs, norm_reward=args.norm_reward, gamma=args.gamma)
        model = build(args, venv, str(run_dir / "tb"))
    cbs, budget = make_callbacks(run_dir, algo, args.total_timesteps, venv.num_envs, args.checkpoint_freq,
                                 args.time_budget_minutes, args.progress_bar)
    t0 = time.monotonic()
    extra = list(callbacks(args)) if callbacks is not None else []
    model.learn(max(args.total_timesteps - model.num_timesteps, 0), callback=[*cbs, *extra], tb_log_name=algo,
                reset_num_timesteps=ckpt is None)
    model.save(run_dir / "model.zip")
    save_final_vecnormalize(model, run_dir)
    info = {"timesteps": int(model.num_timesteps), "train_minutes": round((time.monotonic() - t0) / 60, 2),
            "stopped_by_time_budget": budget.stopped}
    (run_dir / "train_summary.json").write_text(json.dumps(info, indent=2))
    print(f"saved {run_dir / 'model.zip'}: {info}", flush=True)
    venv.close()
    return run_dir


def train_single(args: Any, algo: str, sb3_class: str, action_mode: str,
                 build: Callable[[Any, Any, str], Any]) -> Path:
    """:func:`train_sb3` of a single-UAV script: ``args.n_envs`` seeded copies of the Gymnasium env ``args.env_id``
    (SB3's ``make_vec_env``), one UAV in ``action_mode``."""
    def env_kwargs(args) -> dict:
        return dict(max_cycles=args.max_cycles, scene_pool=args.scene_pool)

    def make_venv(args):
        from stable_baselines3.common.env_util import make_vec_env

        import covert_env  # noqa: F401  (registers the Gymnasium ids)

        return make_vec_env(args.env_id, n_envs=args.n_envs, seed=args.seed, env_kwargs=env_kwargs(args))

    def meta(args) -> dict:
        return {"multi_agent": False, "env_kwargs": {**env_kwargs(args), "n_uavs": 1, "action_mode": action_mode}}

    return train_sb3(args, algo, sb3_class, meta, make_venv, build)
