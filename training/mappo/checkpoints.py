"""A run's progress, its model card, and its checkpoints: ``.npz`` parameters and Adam moments with a JSON of the
progress and the card (no pickle)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

import covert_env
from training.mappo.agents import RunningNorm, Sizes
from training.mappo.args import Args, actor_fields, task_list

__all__ = ["Progress", "latest_checkpoint", "load_checkpoint", "model_card", "resume", "save_checkpoint",
           "save_final"]


@dataclass
class Progress:
    """How far the run is (saved with every checkpoint): env steps, PPO updates, training wall time, and the
    Lagrange multiplier of each constrained cost."""

    global_step: int = 0
    updates: int = 0
    wall_seconds: float = 0.0
    lam: dict[str, float] = field(default_factory=dict)

    def meta(self, vnorm: RunningNorm, card: dict) -> dict:
        """A checkpoint's JSON (and the final model.json): the progress, the value statistics and the card."""
        return {"global_step": self.global_step, "updates": self.updates, "wall_seconds": self.wall_seconds,
                "lam": self.lam, "vnorm": [vnorm.mean, vnorm.var, vnorm.count], **card}


def model_card(args: Args, s: Sizes, env, env_kwargs: dict, shield) -> dict:
    """What an actor needs besides its weights: its spec, the env it was trained on, the shield it acted under."""
    actor_spec = dict(head=s.head, hidden=args.hidden, node_hidden=args.node_hidden, n_feat=s.feats, obs_dim=s.obs,
                      n_actions=s.actions, agent_id=args.agent_id, **actor_fields(args))
    return {"algorithm": args.algo, "actor": actor_spec, "env_kwargs": env_kwargs, "env_id": env.metadata["name"],
            "separation_shield": None if shield is None else shield.min_distance,
            "shield_end_margin": None if shield is None else shield.end_margin,
            # The viability rule acts in the shield, or in the safety filter (SafetyFilter's min_reach).
            "viability_shield": bool((shield is not None or args.safety_filter) and args.viability_shield),
            "viability_min_reach": (args.viability_min_reach if (shield is not None or args.safety_filter)
                                    and args.viability_shield else None),
            "shield_lookahead": bool(shield is not None and shield.lookahead),
            "safety_filter": bool(args.safety_filter),
            "filter_scores": bool(args.safety_filter and args.filter_scores),
            "train_tasks": task_list(args) or None,
            "covert_env_version": covert_env.__version__ if hasattr(covert_env, "__version__") else None}


def save_checkpoint(path: Path, actor, critic, optim, extra: dict) -> None:
    """``path`` (.npz): parameters (``actor.*``, ``critic.*``) and Adam's moments (``optim.<i>.*``); ``path``
    with .json: steps, value statistics, lambda and the actor's spec. No pickle."""
    arrays = {f"actor.{k}": v.detach().numpy() for k, v in actor.state_dict().items()}
    arrays.update({f"critic.{k}": v.detach().numpy() for k, v in critic.state_dict().items()})
    for i, st in optim.state_dict()["state"].items():
        for k, v in st.items():
            arrays[f"optim.{i}.{k}"] = np.asarray(v.detach().numpy() if hasattr(v, "detach") else v)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    path.with_suffix(".json").write_text(json.dumps(extra, indent=2))


def load_checkpoint(path: Path, actor, critic, optim) -> dict:
    with np.load(path, allow_pickle=False) as data:
        actor.load_state_dict({k[6:]: torch.from_numpy(data[k]) for k in data.files if k.startswith("actor.")})
        critic.load_state_dict({k[7:]: torch.from_numpy(data[k]) for k in data.files if k.startswith("critic.")})
        sd = optim.state_dict()
        for k in data.files:
            if k.startswith("optim."):
                _, i, name = k.split(".", 2)
                sd["state"].setdefault(int(i), {})[name] = torch.from_numpy(data[k].copy())
        optim.load_state_dict(sd)
    return json.loads(path.with_suffix(".json").read_text())


def latest_checkpoint(run_dir: Path) -> Path | None:
    found = sorted((run_dir / "checkpoints").glob("step_*.npz"), key=lambda p: int(p.stem.split("_")[1]))
    return found[-1] if found else None


def resume(run_dir: Path, actor, critic, optim, vnorm: RunningNorm) -> Progress:
    """The newest checkpoint of ``run_dir`` loaded into the networks, Adam and the value statistics; its progress
    (a fresh one where the run has no checkpoint)."""
    ckpt = latest_checkpoint(run_dir)
    if ckpt is None:
        return Progress()
    meta = load_checkpoint(ckpt, actor, critic, optim)
    vnorm.mean, vnorm.var, vnorm.count = meta["vnorm"]
    print(f"resumed from {ckpt} at {meta['global_step']} env steps", flush=True)
    lam = meta["lam"]
    if not isinstance(lam, dict):                 # runs before per-constraint multipliers: separation's
        lam = {"separation": float(lam)} if lam else {}
    return Progress(global_step=meta["global_step"], updates=meta["updates"], wall_seconds=meta["wall_seconds"],
                    lam=lam)


def save_final(run_dir: Path, actor, critic, optim, meta: dict) -> None:
    """The last checkpoint, and the actor alone in the format training.pretrained loads (``mappo:RUN`` and the
    shipped weights) with its card."""
    save_checkpoint(run_dir / "checkpoints" / f"step_{meta['global_step']}.npz", actor, critic, optim, meta)
    np.savez(run_dir / "model.npz", **{f"actor.{k}": v.detach().numpy() for k, v in actor.state_dict().items()})
    (run_dir / "model.json").write_text(json.dumps(meta, indent=2))
