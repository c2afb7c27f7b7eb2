"""Behaviour cloning of the DP planner: a learned team's actor that starts where the paper's planner is.

    OMP_NUM_THREADS=1 python -m training.imitation --recipe 3uav-suite-shield --seed 0   # time: docs/training.md
    covert-env benchmark --policies dp mappo:runs/<run>                           # score it on the suite
    OMP_NUM_THREADS=1 python -m training.mappo --recipe 3uav-suite-shield --init-actor runs/<run>  # fine-tune (RL)

The planner (``--teacher``, :mod:`baselines.policies`) flies training scenes of the recipe's tasks (run ``--seed s``
takes scenes ``s * 1000 + i`` of ``covert_env.world.tasks.Task.train_seeds``, never a held-out one). Every slot, each
UAV's observation, its action mask and the planner's node are recorded. The actor of the MAPPO recipe
(:mod:`training.mappo.networks`, the same architecture, node features and card) is then trained to pick the
planner's node under the mask: cross-entropy of the masked categorical, Adam, minibatches from one task at a time,
since the node features depend on the task's lattice. The mask is the recipe's (``kinematic`` for the suite's:
every reachable node), so whatever shadow the actor avoids it read from its observation; the planner never picks a
shadowed node at a slot time.

**DAgger** (``--dagger-rounds N``, Ross et al. 2011): a cloned actor meets states the planner never visits. Each
round flies the current actor (through its shield, as the harness does) on fresh training scenes, labels every
slot with the planner's node from that state, adds the slots to the data and trains again from the union.

The run folder (``runs/<run>``) holds the actor as :mod:`training.mappo` saves it, ``model.npz`` and ``model.json``
(the card: ``algorithm = "bc-dp"``, the recipe's shield, the tasks), and ``args.json``; ``curve.jsonl`` (per
epoch: the training loss, the held-out loss and how often the actor ranks the planner's node first on the held-out
slots, overall and per task), TensorBoard logs, ``train_summary.json`` (slots recorded, held out and dropped, the
last epoch's figures) and ``data.npz``, the recorded slots (``train.<task>.<field>`` and ``val.<task>.<field>``;
numpy arrays, no pickle). Held out: the last ``--val-episodes`` episodes of every task in every collection, so after
a DAgger round the held-out slots mix states the planner flew with states the clone flew. Slots where the planner's
node is outside the mask are dropped and counted.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import covert_env
from covert_env.command_line import ordered_results
from covert_env.world.families import TRAIN_SEEDS
from covert_env.world.tasks import get_task
from training.common import _ranges, checked_main, run_name, save_run, setup_torch
from training.run_args import RunArgs

__all__ = ["Args", "teacher_episode", "collect", "train"]

#: Scenes per run seed: run ``--seed s`` records on training scenes ``s * SCENES_PER_SEED + i``.
SCENES_PER_SEED = 1000


@dataclass
class Args(RunArgs):
    recipe: str = "3uav-suite-shield"
    """the training.mappo recipe (one with the separation shield, which the DAgger rounds fly) whose actor, tasks,
    env settings and shield the clone takes"""
    teacher: str = "dp"
    """the planner cloned: dp (the paper's), dp-binned or dp-path (baselines.policies)"""
    episodes_per_task: int = 24
    """planner episodes recorded per task (70 slots each)"""
    val_episodes: int = 2
    """of those, per task and round, held out to measure the agreement with the planner"""
    max_cycles: int = 70
    """slots per recorded episode (the route's 70; fewer only for smoke tests)"""
    dagger_rounds: int = 1
    """rounds in which the cloned team flies and the planner labels its states (0: plain behaviour cloning)"""
    dagger_episodes_per_task: int = 12
    """episodes per task and DAgger round"""
    epochs: int = 12
    """passes over the data after each collection"""
    batch_size: int = 256
    """UAV-slots per minibatch"""
    learning_rate: float = 1e-3
    """Adam's step size"""
    seed: int = 0
    """seeds torch, the minibatch order, and picks the scenes (seed * 1000 + i of the training scenes, seed < 1000)"""
    run_name: str = ""
    """run folder name (default {env}__bc-dp__{seed}__{time})"""
    jobs: int = 2
    """processes flying the planner"""
    torch_threads: int = 1
    """torch threads"""


def _recipes() -> list[str]:
    from training.recipes import MAPPO_RECIPES

    return list(MAPPO_RECIPES)


def mappo_args(recipe: str):
    """The :class:`training.mappo.Args` of a MAPPO recipe: the actor, env and shield the cloned team takes."""
    from training.mappo import Args as MappoArgs
    from training.recipes import MAPPO_RECIPES

    if recipe not in MAPPO_RECIPES:
        raise ValueError(f"--recipe {recipe!r}: not a training.mappo recipe; choose from {sorted(MAPPO_RECIPES)}")
    return dataclasses.replace(MappoArgs(), **MAPPO_RECIPES[recipe])


def env_settings(margs, max_cycles: int = 70) -> dict:
    """The parallel env's keyword arguments matching the recipe's vector env (what the harness builds)."""
    return {"action_mode": margs.action_mode, "mask_mode": margs.mask_mode, "map_size": margs.map_size,
            "target_path": margs.target_path, "max_cycles": max_cycles}


def teacher_episode(task: str, seed: int, teacher: str, settings: dict, student: str | None = None) -> dict:
    """One episode of ``task`` on training scene ``seed``: every live UAV's observation ``obs`` (n, D), action mask
    ``mask`` (n, L), the planner's node ``label`` (n,) and the UAV's index ``agent`` (n,). The planner flies, or
    the learned team at ``student`` (a run folder or weights) flies and the planner labels its states."""
    from baselines.policies import make_policy
    from training.pretrained import load_learned

    env = covert_env.parallel_env(task=task, **settings)
    planner = make_policy(teacher)
    pilot = load_learned(student) if student else planner
    obs, _ = env.reset(seed=seed, options={"scene_seed": seed})
    planner.reset(env, seed)
    rows = {"obs": [], "mask": [], "label": [], "agent": []}
    while env.agents:
        label = planner.act(obs, env)
        acts = label if student is None else pilot.act(obs, env)
        live = list(env.agents)
        rows["obs"].append(np.stack([obs[a] for a in live]).astype(np.float32))
        rows["mask"].append(np.stack([env.action_mask(a) for a in live]).astype(bool))
        rows["label"].append(np.array([label[a] for a in live], np.int64))
        rows["agent"].append(np.array([env.possible_agents.index(a) for a in live], np.int64))
        obs, *_ = env.step(acts)
    env.close()
    return {k: np.concatenate(v) for k, v in rows.items()}


def collect(tasks: list[str], seeds: list[int], args: Args, settings: dict, student: str | None = None,
            label: str = "planner") -> list[list[dict]]:
    """:func:`teacher_episode` for every task and seed, on ``args.jobs`` processes; ``[task][episode]``."""
    from tqdm.auto import tqdm

    work = [(t, s) for t in tasks for s in seeds]
    bar = tqdm(total=len(work), desc=label, unit="episode", disable=not args.progress_bar, file=sys.stderr,
               mininterval=1.0 if sys.stderr.isatty() else 30.0)
    out = ordered_results(teacher_episode, [(t, s, args.teacher, settings, student) for t, s in work], args.jobs,
                          bar.update)
    bar.close()
    return [out[i * len(seeds):(i + 1) * len(seeds)] for i in range(len(tasks))]


def join(episodes: list[dict], val: int) -> tuple[dict, dict]:
    """Training and held-out arrays of one task's episodes (the last ``val`` episodes held out), without the slots
    whose label is outside the mask (``None`` for no episodes)."""
    cut = len(episodes) - val

    def cat(eps):
        if not eps:
            return None
        d = {k: np.concatenate([e[k] for e in eps]) for k in episodes[0]}
        # The planner's best effort when no node qualifies may lie outside the mask (docs/decisions/flight.md,
        # "Unreachable waypoint best effort"): no masked categorical can pick it, so it teaches nothing.
        keep = d["mask"][np.arange(len(d["label"])), d["label"]]
        return {k: v[keep] for k, v in d.items()}
    return cat(episodes[:cut]), cat(episodes[cut:])


class Cloner:
    """The actor and what it needs to score a task's recorded slots: its lattice, its map cells, the config."""

    def __init__(self, margs, tasks: list[str], settings: dict, actor):
        from training.pretrained import node_features

        self.margs, self.actor, self.node_features = margs, actor, node_features
        self.geometry = {}
        for t in tasks:
            env = covert_env.parallel_env(task=t, **settings)
            self.geometry[t] = (env.lattice.copy(), env.map_offsets.copy(), env.config, len(env.possible_agents))
            env.close()

    def logits(self, task: str, d: dict, idx):
        import torch

        lattice, offsets, c, u = self.geometry[task]
        obs = d["obs"][idx]
        feats = self.node_features(obs, lattice, u, r2=c.r2, v_max=c.v_max, delta=c.delta, d_safe1=c.d_safe1,
                                   map_offsets=offsets if self.margs.node_map else None,
                                   w_max=c.w_max if self.margs.node_manoeuvre else None)
        x = np.concatenate([obs, np.eye(u, dtype=np.float32)[d["agent"][idx]]], 1) if self.margs.agent_id else obs
        mask = torch.from_numpy(d["mask"][idx])
        return self.actor.logits(torch.from_numpy(x), torch.from_numpy(feats), mask), mask

    def loss(self, task: str, d: dict, idx):
        """Mean cross-entropy of the masked categorical at the planner's nodes, and how many it ranks first."""
        import torch

        logits, _ = self.logits(task, d, idx)
        target = torch.from_numpy(d["label"][idx])
        ce = torch.nn.functional.cross_entropy(logits, target)
        return ce, int((logits.argmax(-1) == target).sum())


def fit(cloner: Cloner, optim, train_sets: dict, val_sets: dict, args: Args, rng, log) -> dict:
    """``args.epochs`` passes of minibatches, each from one task, in a shuffled order; the held-out agreement."""
    import torch

    stats = {}
    for _ in range(args.epochs):
        batches = [(t, p[i:i + args.batch_size]) for t, d in train_sets.items()
                   for p in [rng.permutation(len(d["label"]))] for i in range(0, len(p), args.batch_size)]
        order = rng.permutation(len(batches))
        total, n = 0.0, 0
        for j in order:
            t, idx = batches[j]
            ce, _ = cloner.loss(t, train_sets[t], idx)
            optim.zero_grad()
            ce.backward()
            optim.step()
            total, n = total + ce.item() * len(idx), n + len(idx)
        with torch.no_grad():
            hits, seen, vloss = 0, 0, 0.0
            per_task = {}
            for t, d in val_sets.items():
                t_hits = 0
                for i in range(0, len(d["label"]), args.batch_size):
                    idx = np.arange(i, min(i + args.batch_size, len(d["label"])))
                    ce, h = cloner.loss(t, d, idx)
                    t_hits, vloss = t_hits + h, vloss + ce.item() * len(idx)
                per_task[t] = t_hits / len(d["label"])
                hits, seen = hits + t_hits, seen + len(d["label"])
        # Without held-out slots (--val-episodes 0) there is nothing to report: None, not a measured 0.
        stats = {"train_loss": total / max(n, 1), "val_loss": vloss / seen if seen else None,
                 "val_agreement": hits / seen if seen else None, "val_agreement_per_task": per_task}
        log(stats)
    return stats


def train(args: Args) -> Path:
    """Record the planner, clone it (and run the DAgger rounds); save and return the run folder."""
    import torch
    from torch.utils.tensorboard import SummaryWriter

    from training.mappo import make_networks, model_card, sizes_of, task_list
    from training.shield import SeparationShield
    from training.task_mix import make_training_env

    check_args(args)
    setup_torch(args.torch_threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    margs = dataclasses.replace(mappo_args(args.recipe), seed=args.seed)
    tasks = task_list(margs) or [get_task("paper-3uav").name]
    settings = env_settings(margs, args.max_cycles)
    run_dir = Path(args.runs_dir) / (args.run_name or run_name(margs.env_id, f"bc-{args.teacher}", args.seed))
    t0 = time.monotonic()

    env_kwargs = dict(n_uavs=margs.n_uavs, action_mode=margs.action_mode, max_cycles=margs.max_cycles,
                      scene_pool=margs.scene_pool, map_size=margs.map_size, mask_mode=margs.mask_mode,
                      target_path=margs.target_path)
    mix = make_training_env(tasks, len(tasks), **{k: v for k, v in env_kwargs.items()
                                                 if k not in ("n_uavs", "scene_pool")})
    s = sizes_of(margs, mix)
    shield = SeparationShield(mix.config.d_safe1 + margs.shield_margin, margs.shield_end_margin,
                              lookahead=margs.shield_lookahead, min_reach=margs.viability_min_reach) \
        if margs.separation_shield else None
    card = model_card(margs, s, mix, env_kwargs, shield)
    mix.close()
    card["algorithm"] = f"bc-{args.teacher}"
    card["imitation"] = {"teacher": args.teacher, "recipe": args.recipe, "dagger_rounds": args.dagger_rounds}
    card["train_tasks"] = tasks
    actor, _, _ = make_networks(margs, s)
    optim = torch.optim.Adam(actor.parameters(), lr=args.learning_rate)
    cloner = Cloner(margs, tasks, settings, actor)
    save_run(run_dir, args, {"card": card})
    writer = SummaryWriter(str(run_dir / "tb"))
    curve = open(run_dir / "curve.jsonl", "w")
    epoch = 0

    def log(stats):
        nonlocal epoch
        epoch += 1
        for k, v in stats.items():
            if v is not None and not isinstance(v, dict):
                writer.add_scalar(f"imitation/{k}", v, epoch)
        curve.write(json.dumps({"epoch": epoch, "minutes": round((time.monotonic() - t0) / 60, 2), **stats}) + "\n")
        curve.flush()
        if args.progress_bar:
            held = "no held-out slots" if stats["val_loss"] is None else \
                f"held-out loss {stats['val_loss']:.3f}, agreement {stats['val_agreement']:.3f}"
            print(f"epoch {epoch}: loss {stats['train_loss']:.3f}, {held}", file=sys.stderr, flush=True)

    next_scene = args.seed * SCENES_PER_SEED                     # an index into TRAIN_SEEDS (check_args bounds it)

    def scenes(n: int) -> list[int]:
        nonlocal next_scene
        next_scene += n
        return [TRAIN_SEEDS[i] for i in range(next_scene - n, next_scene)]

    collection = collect(tasks, scenes(args.episodes_per_task), args, settings)
    train_sets, val_sets, stats, dropped = {}, {}, {}, 0
    for r in range(args.dagger_rounds + 1):
        for t, eps in zip(tasks, collection, strict=True):
            tr, va = join(eps, args.val_episodes)
            dropped += sum(len(e["label"]) for e in eps) - len(tr["label"]) - (0 if va is None else len(va["label"]))
            train_sets[t] = tr if t not in train_sets else {k: np.concatenate([train_sets[t][k], tr[k]]) for k in tr}
            if va is not None:
                val_sets[t] = va if t not in val_sets else {k: np.concatenate([val_sets[t][k], va[k]]) for k in va}
        stats = fit(cloner, optim, train_sets, val_sets, args, rng, log)
        save_actor(run_dir, actor, card, stats)
        if r < args.dagger_rounds:
            collection = collect(tasks, scenes(args.dagger_episodes_per_task), args, settings, student=str(run_dir),
                                 label=f"DAgger {r + 1}")
    np.savez_compressed(run_dir / "data.npz", **{f"{part}.{t}.{k}": v for part, sets in (("train", train_sets),
                                                                                        ("val", val_sets))
                                                 for t, d in sets.items() for k, v in d.items()})
    summary = {"uav_slots": int(sum(len(d["label"]) for d in train_sets.values())),
               "held_out_uav_slots": int(sum(len(d["label"]) for d in val_sets.values())),
               "dropped_outside_mask": int(dropped), "minutes": round((time.monotonic() - t0) / 60, 2), **stats}
    (run_dir / "train_summary.json").write_text(json.dumps(summary, indent=2))
    print(f"saved {run_dir / 'model.npz'}: {json.dumps(summary)}", flush=True)
    writer.close()
    curve.close()
    return run_dir


def save_actor(run_dir: Path, actor, card: dict, stats: dict) -> None:
    """The actor in the format :mod:`training.pretrained` loads (``mappo:RUN``, ``--init-actor RUN``), its card."""
    np.savez(run_dir / "model.npz", **{f"actor.{k}": v.detach().numpy() for k, v in actor.state_dict().items()})
    (run_dir / "model.json").write_text(json.dumps({**card, "imitation_stats": stats}, indent=2))


def check_args(args: Args) -> None:
    """The recipe, the teacher and the flags that bound each other: a ValueError naming the flag, its value and what
    is allowed (each numeric flag's own range is checked by the CLI, :func:`training.common.parse_args`)."""
    if mappo_args(args.recipe).safety_filter:
        shield_recipes = sorted(r for r in _recipes() if not mappo_args(r).safety_filter)
        raise ValueError(f"--recipe {args.recipe!r}: trains through the safety filter, which the DAgger rounds do not "
                         f"fly; choose a recipe with the separation shield: {', '.join(shield_recipes)}")
    teachers = _ranges()["teacher"][1]
    if args.teacher not in teachers:
        raise ValueError(f"--teacher {args.teacher!r}: choose from {', '.join(teachers)}")
    if args.val_episodes >= args.episodes_per_task:
        raise ValueError(f"--val-episodes {args.val_episodes}: must be below --episodes-per-task "
                         f"({args.episodes_per_task})")
    if args.dagger_rounds and args.val_episodes >= args.dagger_episodes_per_task:
        raise ValueError(f"--val-episodes {args.val_episodes}: must be below --dagger-episodes-per-task "
                         f"({args.dagger_episodes_per_task}) with --dagger-rounds {args.dagger_rounds}")
    per_seed = args.episodes_per_task + args.dagger_rounds * args.dagger_episodes_per_task
    if per_seed > SCENES_PER_SEED:
        raise ValueError(f"--episodes-per-task + --dagger-rounds x --dagger-episodes-per-task = {per_seed}: a run may "
                         f"record at most {SCENES_PER_SEED} scenes per task (runs with other seeds take the next)")
    if (args.seed + 1) * SCENES_PER_SEED > len(TRAIN_SEEDS):
        raise ValueError(f"--seed {args.seed}: must be below {len(TRAIN_SEEDS) // SCENES_PER_SEED} (its scenes are "
                         f"training scenes seed * {SCENES_PER_SEED} + i, and the held-out scenes start at "
                         f"{TRAIN_SEEDS.stop})")


def main(argv: list[str] | None = None) -> Path:
    return checked_main(Args, argv, description=__doc__.split("\n")[0], check=check_args, run=train)


if __name__ == "__main__":
    main()
