"""MAPPO and IPPO on the batched vector env (``covert_env.vector_env``), one CleanRL-style file.

    OMP_NUM_THREADS=1 python -m training.mappo --recipe 3uav-mappo --seed 0        # the documented recipe
    OMP_NUM_THREADS=1 python -m training.mappo --algo mappo --action-mode waypoint --time-budget-minutes 55
    OMP_NUM_THREADS=1 python -m training.mappo --algo ippo --action-mode unicycle
    python -m training.mappo --resume runs/<run>                  # continue from the newest checkpoint
    python -m training.evaluate --policies dp random@waypoint mappo:runs/<run>
    tensorboard --logdir runs

Read top to bottom: arguments; the agents (the networks of :mod:`training.mappo_networks` read and written as numpy
rows); the rollout (same-step autoreset, truncation bootstrap, episode statistics); GAE; the PPO update; logs and
checkpoints; ``train``, which runs them in that order. Nothing here is pickled: checkpoints are ``.npz`` + JSON.

* **Actor** (parameter-shared, every UAV of every copy): an MLP on the agent's own observation. Waypoint mode:
  a masked categorical over the lattice nodes (masked nodes get -inf), by default scoring each node from its
  geometry relative to the UAV and teammates (``--head node``, :func:`training.pretrained.node_features`;
  ``--head flat`` is one logit per node). Unicycle mode: a Gaussian with a state-independent std; actions are
  **clipped** to [-1, 1] by the env (no tanh squashing; the log-probability is that of the unclipped sample,
  as in CleanRL's continuous PPO).
* **Map under each node** (``--node-map``): the node head also reads the observation's ``map_next`` under each
  node and the move's midpoint, so that a team acting with ``--mask-mode kinematic`` sees the shadows where it
  scores the nodes (docs/decisions/learning.md, "Learned teams across the suite").
* **Tasks** (``--tasks a,b,...``): the copies are split evenly over suite tasks and draw from each task's training
  scenes (:mod:`training.task_mix`); without it, random scenes of the paper family.
* **Separation shield** (waypoint mode, ``--separation-shield``, on by default): the UAVs of a copy choose one
  after another, and a UAV may not choose a node whose path comes closer than d_safe1 to a teammate's chosen
  path (:mod:`training.shield`; the env's ``waypoint_paths`` flies the candidates). The shielded masks are
  stored with the actions, so PPO's ratios use the masks the actions were sampled under, and the harness runs
  the same shield (the model card's ``separation_shield``).
* **Safety filter** (waypoint mode, ``--safety-filter``, with ``--separation-shield false``): the team's sampled
  nodes are proposals, and the env flies the nodes of :class:`covert_env.envs.safety_filter.SafetyFilteredVectorEnv`,
  which keeps eqs. 2 and 3 along the flown path and certifies each move by a backup plan (action projection: PPO
  keeps the probabilities of the proposals, the rewards and costs are those of the moves flown). The harness
  flies a team trained so through the same filter (the model card's ``safety_filter``).
* **Critic**: MAPPO (``--algo mappo``) sees the centralised ``state()`` of the copy plus a one-hot of the agent
  (the rewards are per agent, so one state value would not do); IPPO (``--algo ippo``) sees the agent's own
  observation. Value targets are normalised by running statistics (``--value-norm``, MAPPO's ValueNorm).
* **Autoreset**: the vector env resets an ended copy within ``step()`` and hands back its last observation and
  state in ``infos["final_obs"/"final_state"]``. A step that ended a copy is a done for GAE (no bootstrap across
  episodes). Truncated before the route's end (``--max-cycles`` < the track's ``n_slots``), the value of the
  final observation/state is added as ``gamma V(final)`` to the last reward (the time limit is not part of the
  task). At the route's end (the default 70 slots) there are no more slots: the episode truly ends, V = 0.
* **Reward**: the env's default reward (eq. 18 / reward_scale plus unit penalties); the constraint costs
  ``cost_*`` of the infos are logged per episode. Constrained RL, one Lagrange multiplier per constraint:
  ``--constraints zone=0.01,los_path=0.005`` subtracts ``lambda_c * cost_c`` from the training reward for each
  named env cost c (``covert_env.envs.batch.COSTS``), lambda_c >= 0 raised by dual ascent while the rollout's mean
  cost per UAV and slot exceeds its limit; ``--lagrangian`` adds ``separation=--cost-limit`` (eq. 2);
  ``--lambda-max`` bounds every multiplier.
* **Warm start** (``--init-actor pretrained:NAME``): the actor starts from trained weights (with ``--node-map``
  added, its map inputs start at zero), and ``--actor-warmup-updates`` lets the fresh critic learn first.

Env steps count copy-slots (one step of one env copy, all its UAVs); agent-steps are ``n_uavs`` times more.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import covert_env
from covert_env.envs.batch import COSTS
from covert_env.envs.safety_filter import SafetyFilteredVectorEnv
from covert_env.tasks import TASKS
from training.budget import expected_steps
from training.common import parse_args, resumed_args, run_name, save_run, setup_torch
from training.pretrained import (
    N_MAP_FEATURES,
    PRETRAINED_DIR,
    load_learned,
    n_node_features,
    node_features,
    pretrained_names,
)
from training.recipes import MAPPO_RECIPES
from training.shield import SeparationShield
from training.task_mix import make_training_env

try:                            # importing this file (--help, its arguments and recipes) needs no torch; train() does
    import torch
except ModuleNotFoundError:
    torch = None
else:
    from training.mappo_networks import Actor, Critic, masked_categorical


@dataclass
class Args:
    algo: str = "mappo"
    """'mappo' (critic on the centralised state() and the agent's id) or 'ippo' (critic on the agent's obs)"""
    env_id: str = "covert_sensing_vector_v4"
    """name of the env in run names (covert_env.vector_env)"""
    seed: int = 0
    """seed of numpy, torch and the env copies (their scenes, starts and the action sampling)"""
    n_uavs: int = 3
    """UAVs per env copy (one shared actor)"""
    num_envs: int = 16
    """env copies stepped as one batch"""
    action_mode: str = "waypoint"
    """'waypoint' (masked categorical over the lattice) or 'unicycle' (Gaussian, clipped)"""
    mask_mode: str = "visible"
    """waypoint action mask: 'visible' (reachable nodes of the visible zone) or 'kinematic' (reachable nodes only:
    the team must learn the shadows from its observations and the LoS costs)"""
    head: str = "node"
    """waypoint actor head: 'node' (score each node from its geometry) or 'flat' (one logit per node)"""
    node_map: bool = False
    """node head: also read the observation's map_next under each node and under the move's midpoint
    (training.pretrained.node_features), so that the head sees the shadows where it scores the nodes"""
    node_manoeuvre: bool = False
    """node head: also read the manoeuvre to each node (whether one exists, its length, the heading the UAV arrives
    with; training.pretrained.manoeuvre_features), so that the head tells nodes apart by what the next slot reaches"""
    map_size: int = 8
    """side S of the observation's two S x S visibility maps (the env's map_size, 2..64)"""
    target_path: int = 0
    """predicted slots of the target's path in the observation (the env's target_path, 0..config.horizon; 0: the
    default observation, which shows the next slot only)"""
    tasks: str = ""
    """train on these suite tasks' training scenes at once (comma-separated, e.g. 'sparse-3uav,paper-3uav'; each
    gets num_envs / its count copies; training.task_mix: the mix acts on the largest lattice, which must hold every
    other task's nodes, as a nominal lattice holds its deviating task's); empty: random scenes of the paper family
    (scene_pool)"""
    max_cycles: int = 70
    """episode length in slots (70 = the whole route)"""
    scene_pool: int = 10_000
    """training scene seeds are drawn from range(scene_pool); evaluation uses seeds >= 1_000_000"""
    total_timesteps: int = 50_000_000
    """env steps (copy-slots) to train for; the time budget usually stops first"""
    time_budget_minutes: float = 0.0
    """stop gracefully after this much wall-clock training time and save (0: no budget)"""
    learning_rate: float = 3e-4
    """Adam learning rate of actor and critic"""
    anneal_lr: bool = False
    """decay the learning rate linearly to 0 over total_timesteps"""
    num_steps: int = 64
    """rollout length per copy (steps between updates)"""
    gamma: float = 0.97
    """discount factor (a ~33-slot horizon inside the 70-slot route)"""
    gae_lambda: float = 0.95
    """GAE lambda"""
    num_minibatches: int = 4
    """minibatches per epoch (over num_steps * num_envs * n_uavs agent-samples)"""
    update_epochs: int = 4
    """PPO epochs per rollout"""
    clip_coef: float = 0.2
    """PPO clip range of the probability ratio"""
    ent_coef: float = 0.003
    """entropy bonus"""
    vf_coef: float = 0.5
    """value loss weight"""
    max_grad_norm: float = 0.5
    """gradient clipping (global norm)"""
    value_norm: bool = True
    """normalise value targets with running mean/std (MAPPO's ValueNorm)"""
    hidden: int = 128
    """width of the two hidden layers of actor trunk and critic"""
    node_hidden: int = 32
    """hidden width of the node head (per lattice node and agent)"""
    log_std_init: float = -0.5
    """initial log std of the unicycle Gaussian"""
    agent_id: bool = False
    """append a one-hot of the agent's index to the actor's input: with one shared actor, two UAVs at the same spot
    see the same observation and pick the same move, so they can never part"""
    lagrangian: bool = False
    """subtract lambda * cost_separation from the training reward, lambda by dual ascent (--constraints
    separation=--cost-limit)"""
    constraints: str = ""
    """constrained RL on the env's costs: comma-separated NAME=LIMIT (NAME in los, los_path, zone, separation,
    terrain; LIMIT the allowed mean cost per UAV and slot, in [0, 1]), e.g. 'zone=0.01,los_path=0.005'; each gets
    its own Lagrange multiplier"""
    separation_shield: bool = True
    """waypoint mode: the UAVs choose one after another and none may choose a node whose path comes closer than
    d_safe1 + shield_margin to a teammate's chosen path (training.shield); in training and evaluation alike.
    The unicycle mode has no shield"""
    safety_filter: bool = False
    """waypoint mode, with --separation-shield false: the team's nodes are proposals that fly through the safety
    filter (covert_env.envs.safety_filter), which keeps eqs. 2 and 3 along the flown path; in training and
    evaluation alike"""
    viability_shield: bool = False
    """waypoint mode, with the separation shield: a UAV also avoids a node from which it could reach no lattice
    node next slot (it would leave the zone): the end of the chosen path is tested with the env's onward_reach and,
    if a dead end, the UAV chooses again among the nodes that are not (training.shield); in training and
    evaluation alike"""
    viability_min_reach: int = 1
    """with --viability-shield: a node counts as a dead end if fewer lattice nodes than this are reachable from its
    path's end next slot, where the UAV has a node that reaches this many (1: only nodes that reach none)"""
    shield_lookahead: bool = False
    """with the separation shield: a team choice that no UAV order settles is tried once more, each UAV keeping
    only nodes that leave its later teammates a separated node (training.shield)"""
    shield_margin: float = 0.0
    """extra distance (m) the shield keeps beyond d_safe1 along the paths"""
    shield_end_margin: float = 10.0
    """where possible, the shield also keeps the UAVs' slot ends d_safe1 + this (m) apart (room for the next slot)"""
    cost_limit: float = 0.007
    """allowed separation-violation rate per UAV and slot (0.5 of 70 slots) for --lagrangian"""
    lagrange_lr: float = 1.0
    """dual ascent step of every lambda per update (times the rollout's mean cost minus its limit)"""
    lambda_max: float = 0.0
    """upper bound of every Lagrange multiplier (0: none). A limit the team does not reach raises its multiplier
    without end, until the costs drown the reward and the team learns to keep still; a bound makes such a
    constraint a fixed penalty instead (OmniSafe's lagrangian_upper_bound)"""
    init_actor: str = ""
    """start the actor from these weights: pretrained:NAME, a training.mappo run folder or a weights .npz with
    its card (training.pretrained.load_learned); the architecture must match. Loaded into an actor with
    --node-map from weights without it, the map inputs start at zero: the team starts as the loaded one"""
    init_temperature: float = 1.0
    """with --init-actor (waypoint heads): divide the loaded actor's logits by this. Its greedy choices stay the
    same and its samples spread: a near-greedy policy gives policy gradients almost nothing to move (the gradient
    of log pi(a) vanishes as pi(a) nears 1)"""
    actor_warmup_updates: int = 0
    """the first this many PPO updates train the critic only (with --init-actor: a fresh critic's advantages would
    otherwise move the loaded actor at random)"""
    checkpoint_every: int = 200_000
    """save a checkpoint every this many env steps (0: only at the end)"""
    runs_dir: str = "runs"
    """folder of the runs (git-ignored)"""
    run_name: str = ""
    """run folder name; empty: {env}__{algo}__{seed}__{time}"""
    resume: str = ""
    """a run folder to continue from its newest checkpoint"""
    torch_threads: int = 1
    """torch threads (1: 2 threads on 2 busy cores can be 50x slower)"""
    progress_bar: bool = True
    """show a tqdm progress bar over env steps; its total and ETA are where the run is expected to stop (the time
    budget's end at the rate so far, or total_timesteps, whichever comes first)"""


def check_args(args: Args) -> None:
    """The choice fields (the numeric ones are range-checked by the CLI)."""
    for name, allowed in (("algo", ("mappo", "ippo")), ("action_mode", ("waypoint", "unicycle")),
                          ("head", ("node", "flat")), ("mask_mode", ("visible", "kinematic"))):
        if getattr(args, name) not in allowed:
            raise ValueError(f"--{name.replace('_', '-')} {getattr(args, name)!r}: must be one of {allowed}")
    constraint_limits(args)
    tasks = task_list(args)
    if tasks and args.num_envs % len(tasks):
        raise ValueError(f"--num-envs {args.num_envs}: must be a multiple of the {len(tasks)} --tasks (each task gets "
                         "as many copies)")
    for flag in ("node_map", "node_manoeuvre"):
        if getattr(args, flag) and (args.head != "node" or args.action_mode != "waypoint"):
            raise ValueError(f"--{flag.replace('_', '-')} needs --action-mode waypoint and --head node, got "
                             f"--action-mode {args.action_mode!r} --head {args.head!r}")
    if args.init_actor.startswith("pretrained:"):
        name = args.init_actor.removeprefix("pretrained:")
        if name not in pretrained_names():                  # a name, never a path (no ../)
            raise ValueError(f"--init-actor {args.init_actor}: no shipped weights {name!r}; the shipped are "
                             f"{pretrained_names()}")
    elif args.init_actor and not Path(args.init_actor).exists():
        raise ValueError(f"--init-actor {args.init_actor}: no such file or folder (pretrained:NAME, a run folder "
                         "or a weights .npz)")
    if args.init_actor:
        init_actor_fits(args)
        # The weights themselves, before any env is built (a malformed file fails here with its field named).
        spec = args.init_actor
        try:
            load_learned(PRETRAINED_DIR / f"{spec.removeprefix('pretrained:')}.npz" if spec.startswith("pretrained:")
                         else spec)
        except Exception as exc:        # the loader's UsageError/ValueError name the file and field
            raise ValueError(f"--init-actor {spec}: {exc}") from None
    if args.mask_mode != "visible" and args.action_mode != "waypoint":
        raise ValueError(f"--mask-mode {args.mask_mode!r} needs --action-mode waypoint (the unicycle mode has no "
                         "action mask)")
    for flag, on in (("--viability-shield", args.viability_shield), ("--shield-lookahead", args.shield_lookahead)):
        if on and not (args.separation_shield and args.action_mode == "waypoint"):
            raise ValueError(f"{flag} acts inside the separation shield: it needs --action-mode waypoint and "
                             f"--separation-shield true, got --action-mode {args.action_mode!r} --separation-shield "
                             f"{str(args.separation_shield).lower()}")
    if args.safety_filter and (args.action_mode != "waypoint" or args.separation_shield):
        raise ValueError(f"--safety-filter replaces the separation shield: it needs --action-mode waypoint and "
                         f"--separation-shield false, got --action-mode {args.action_mode!r} --separation-shield "
                         f"{str(args.separation_shield).lower()}")
    if args.viability_min_reach != 1 and not args.viability_shield:
        raise ValueError(f"--viability-min-reach {args.viability_min_reach}: a bar of the viability rule, it needs "
                         "--viability-shield true")
    if args.init_temperature != 1.0 and not (args.init_actor and args.action_mode == "waypoint"):
        raise ValueError(f"--init-temperature {args.init_temperature:g}: needs --init-actor and --action-mode "
                         "waypoint (it scales the loaded actor's node logits)")
    if args.actor_warmup_updates and not args.init_actor:
        raise ValueError(f"--actor-warmup-updates {args.actor_warmup_updates}: needs --init-actor (a fresh actor "
                         "has nothing to keep)")
    if args.lambda_max and not constraint_limits(args):
        raise ValueError(f"--lambda-max {args.lambda_max:g}: bounds the Lagrange multipliers, but no constraint is "
                         "set (--constraints or --lagrangian)")
    if tasks and args.scene_pool != Args.scene_pool:
        raise ValueError(f"--scene-pool {args.scene_pool} does not go with --tasks: each task draws its own "
                         "training scenes")
    rows = args.num_envs * args.num_steps * args.n_uavs
    if rows < 2 * args.num_minibatches:
        # A minibatch of one row has no advantage spread to normalise by: its update would be NaN.
        raise ValueError(f"--num-minibatches {args.num_minibatches}: a batch of num_envs * num_steps * n_uavs = "
                         f"{rows} rows gives minibatches of fewer than 2 rows; use at most {max(rows // 2, 1)} "
                         f"minibatches or a larger batch")


def init_actor_fits(args: Args) -> None:
    """``--init-actor``: a ValueError naming the card field whose value this run's flags contradict (the actor's
    shape and the env it reads), found from the card alone before any env is built. The weights themselves are
    checked when they are loaded (:func:`load_initial_actor`)."""
    spec = args.init_actor
    if spec.startswith("pretrained:"):
        card_path = PRETRAINED_DIR / f"{spec.removeprefix('pretrained:')}.json"
    else:
        path = Path(spec)
        card_path = path / "model.json" if path.is_dir() else path.with_suffix(".json")
    try:
        card = json.loads(card_path.read_text())
        if isinstance(card, dict) and card.get("kind") == "dp-cost":
            actor = ekw = None
        else:
            actor, ekw = dict(card["actor"]), dict(card["env_kwargs"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"--init-actor {spec}: no readable model card at {card_path} ({type(exc).__name__}: "
                         f"{exc})") from None
    if actor is None:
        raise ValueError(f"--init-actor {spec}: {card_path} is a planner with a learned cost (training.dp_cost), "
                         "not an actor; give a MAPPO actor (pretrained:mappo, a run folder)")
    waypoint = args.action_mode == "waypoint"
    wanted = [("env_kwargs.action_mode", ekw.get("action_mode"), args.action_mode, "--action-mode"),
              ("env_kwargs.n_uavs", ekw.get("n_uavs"), args.n_uavs, "--n-uavs"),
              ("env_kwargs.map_size", ekw.get("map_size", 8), args.map_size, "--map-size"),
              ("actor.head", actor.get("head"), args.head if waypoint else "gaussian", "--head"),
              ("actor.hidden", actor.get("hidden"), args.hidden, "--hidden"),
              ("actor.agent_id", actor.get("agent_id", False), args.agent_id, "--agent-id")]
    if waypoint and args.head == "node":
        wanted.append(("actor.node_hidden", actor.get("node_hidden"), args.node_hidden, "--node-hidden"))
        wanted.append(("actor.node_manoeuvre", actor.get("node_manoeuvre", False), args.node_manoeuvre,
                       "--node-manoeuvre"))
    if ekw.get("target_path", 0) not in (0, args.target_path):
        # From 0 load_initial_actor widens the trunk; between two path lengths the columns would not line up.
        wanted.append(("env_kwargs.target_path", ekw["target_path"], args.target_path, "--target-path"))
    if actor.get("node_map", False) and not args.node_map:
        # The other way round is fine: load_initial_actor widens an actor without the map inputs.
        wanted.append(("actor.node_map", True, args.node_map, "--node-map"))
    for field_name, theirs, ours, flag in wanted:
        if theirs != ours:
            raise ValueError(f"--init-actor {spec}: its card has {field_name} = {theirs!r}, this run's {flag} is "
                             f"{ours!r}; the actor must match ({card_path})")


def task_list(args: Args) -> list[str]:
    """The ``--tasks`` names, checked against the suite (a ValueError names an unknown one or a team size that
    differs from --n-uavs)."""
    names = [t.strip() for t in args.tasks.split(",") if t.strip()]
    for t in names:
        if t not in TASKS:
            raise ValueError(f"--tasks {args.tasks!r}: unknown task {t!r}; the suite's are {sorted(TASKS)}")
        if TASKS[t].n_uavs != args.n_uavs:
            raise ValueError(f"--tasks {args.tasks!r}: {t} has {TASKS[t].n_uavs} UAVs, --n-uavs is {args.n_uavs}")
    if len(set(names)) != len(names):
        raise ValueError(f"--tasks {args.tasks!r}: a task is named twice")
    return names


class RunningNorm:
    """Running mean and variance of value targets (parallel-variance merge of batches), for ``--value-norm``."""

    def __init__(self):
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    def update(self, x: np.ndarray) -> None:
        m, v, n = float(x.mean()), float(x.var()), x.size
        d, tot = m - self.mean, self.count + n
        self.var = (self.var * self.count + v * n + d * d * self.count * n / tot) / tot
        self.mean, self.count = self.mean + d * n / tot, tot

    @property
    def std(self) -> float:
        return float(np.sqrt(self.var) + 1e-8)


# ---------------------------------------------------------------------------------------------- agents
@dataclass(frozen=True)
class Sizes:
    """The shapes of a run."""

    B: int                    # env copies
    U: int                    # UAVs per copy
    T: int                    # rollout steps per copy and update
    obs: int                  # observation width
    state: int                # centralised state width
    critic_in: int            # the critic's input width (state + agent one-hot, or the observation)
    actions: int              # lattice nodes (waypoint mode) or the unicycle's 2 controls
    feats: int                # the node head's features per node
    waypoint: bool            # the action mode
    head: str                 # "node", "flat" or "gaussian" (the unicycle mode)
    constrained: dict         # {cost name: limit} of the Lagrangian constraints, in the env's COSTS order


def actor_fields(args: Args) -> dict:
    """The node head's input switches, as the model card's ``actor`` records them."""
    return dict(node_map=args.node_map, node_manoeuvre=args.node_manoeuvre)


def sizes_of(args: Args, env) -> Sizes:
    waypoint = args.action_mode == "waypoint"
    obs, state, u = env.single_observation_space.shape[0], env.single_state_space.shape[0], args.n_uavs
    return Sizes(B=args.num_envs, U=u, T=args.num_steps, obs=obs, state=state,
                 critic_in=state + u if args.algo == "mappo" else obs, actions=len(env.lattice) if waypoint else 2,
                 feats=n_node_features(u, actor_fields(args)), waypoint=waypoint,
                 head=args.head if waypoint else "gaussian",
                 constrained=constraint_limits(args))


def make_networks(args: Args, s: Sizes):
    """The shared actor, the critic and one Adam over both (created in this order: torch's seeded draws)."""
    actor = Actor(s.obs + (s.U if args.agent_id else 0), s.actions, head=s.head, hidden=args.hidden,
                  node_hidden=args.node_hidden, n_feat=s.feats, log_std_init=args.log_std_init)
    critic = Critic(s.critic_in, args.hidden)
    optim = torch.optim.Adam([*actor.parameters(), *critic.parameters()], lr=args.learning_rate, eps=1e-5)
    return actor, critic, optim


def load_initial_actor(actor, spec: str, node_map: bool, temperature: float = 1.0, target_path: int = 0) -> None:
    """``--init-actor``: copy the weights of ``spec`` (``pretrained:NAME``, a run folder or a weights ``.npz``,
    checked by :func:`training.pretrained.load_learned`) into ``actor``. Every parameter must have the loaded
    one's shape, except that an actor with ``node_map`` takes weights without it: the map's columns of
    ``node_feat.weight`` (the last :data:`~training.pretrained.N_MAP_FEATURES` features) start at zero, so the
    new actor scores every node as the loaded one does; and an actor reading the target's path over
    ``target_path`` slots takes weights without it (the card's ``env_kwargs.target_path`` 0): the path's 4 P
    columns of ``trunk.0.weight`` (after the observation's other fields) start at zero, likewise. The output layer
    (``node_out`` or ``flat``) is divided by ``temperature``: the same ranking of the nodes, a flatter
    distribution. A ``ValueError`` names the parameter and both shapes."""
    path = PRETRAINED_DIR / f"{spec.removeprefix('pretrained:')}.npz" if spec.startswith("pretrained:") else spec
    try:
        loaded = load_learned(path)
    except Exception as exc:        # the loader's UsageError/ValueError name the file and field
        raise ValueError(f"--init-actor {spec}: {exc}") from None
    params = loaded.actor.p
    own = actor.state_dict()
    if set(params) != set(own):
        raise ValueError(f"--init-actor {spec}: its parameters {sorted(params)} are not this actor's {sorted(own)} "
                         "(--head, --action-mode and the trunk's depth must match)")
    widen = node_map and not loaded.actor.spec.get("node_map", False)
    path_columns = 4 * target_path if not loaded.card["env_kwargs"].get("target_path", 0) else 0
    new = {}
    for key, target in own.items():
        value = torch.from_numpy(params[key].astype(np.float32))
        if widen and key == "node_feat.weight" and value.shape[1] + N_MAP_FEATURES == target.shape[1] \
                and value.shape[0] == target.shape[0]:
            value = torch.cat([value, torch.zeros(value.shape[0], N_MAP_FEATURES)], dim=1)
        if path_columns and key == "trunk.0.weight" and value.shape[1] + path_columns == target.shape[1]:
            # The path's fields come after every other field of the row and before the agent id's one-hot.
            at = value.shape[1] - (loaded.env_settings["n_uavs"] if loaded.actor.spec.get("agent_id") else 0)
            value = torch.cat([value[:, :at], torch.zeros(value.shape[0], path_columns), value[:, at:]], dim=1)
        if tuple(value.shape) != tuple(target.shape):
            raise ValueError(f"--init-actor {spec}: actor.{key} has shape {tuple(params[key].shape)}, this actor's "
                             f"is {tuple(target.shape)} (--hidden, --node-hidden, --agent-id, --n-uavs, "
                             "--map-size and --target-path must match the loaded card's)")
        if key.split(".")[0] in ("node_out", "flat"):
            value = value / temperature
        new[key] = value
    actor.load_state_dict(new)


def gumbel_pick(logits: np.ndarray):
    """The shield's ``pick(k, mask)`` in training: the node of UAV ``k[b]`` of each copy b, sampled from its
    ``logits`` (B, U, L) under ``mask`` by the Gumbel-max trick (numpy's global generator, seeded by --seed)."""
    copies = np.arange(len(logits))

    def pick(k, m):
        g = -np.log(-np.log(np.random.random(m.shape)))
        return np.argmax(np.where(m, logits[copies, k] + g, -np.inf), axis=1)

    return pick


class Agents:
    """The team as the rollout and the update see it: numpy observations in, the actor's and the critic's input
    rows, sampled actions (through the shield) and values (in return units) out."""

    def __init__(self, args: Args, sizes: Sizes, env, actor, critic, vnorm: RunningNorm, shield):
        self.args, self.sizes, self.env = args, sizes, env
        self.actor, self.critic, self.vnorm, self.shield = actor, critic, vnorm, shield
        self.eye = np.eye(sizes.U, dtype=np.float32)

    def node_feats(self, flat_obs: np.ndarray):
        """The node head's inputs (rows, L, feats); None for the other heads."""
        if self.sizes.head != "node":
            return None
        c = self.env.config
        return torch.from_numpy(node_features(flat_obs, self.env.lattice, self.sizes.U, r2=c.r2, v_max=c.v_max,
                                              delta=c.delta, d_safe1=c.d_safe1,
                                              map_offsets=self.env.map_offsets if self.args.node_map else None,
                                              w_max=c.w_max if self.args.node_manoeuvre else None))

    def actor_in(self, flat_obs: np.ndarray):
        """The actor's input rows: observations (agent-minor rows, as (..., U, D) flattened) and, with
        --agent-id, the one-hot of each row's agent."""
        if self.args.agent_id:
            flat_obs = np.concatenate([flat_obs, self.eye[np.arange(len(flat_obs)) % self.sizes.U]], 1)
        return torch.from_numpy(np.ascontiguousarray(flat_obs, dtype=np.float32))

    def critic_in(self, obs: np.ndarray, state: np.ndarray) -> np.ndarray:
        """(..., U, critic_in) from observations (..., U, D) and states (..., S)."""
        if self.args.algo == "ippo":
            return obs
        u, lead = self.sizes.U, state.shape[:-1]
        st = np.broadcast_to(state[..., None, :], (*lead, u, self.sizes.state))
        return np.concatenate([st, np.broadcast_to(self.eye, (*lead, u, u))], axis=-1)

    def value(self, obs: np.ndarray, state: np.ndarray) -> np.ndarray:
        """V (..., U) of every agent, de-normalised with --value-norm."""
        with torch.no_grad():
            v = self.critic(torch.from_numpy(self.critic_in(obs, state).astype(np.float32))).numpy()
        return v * self.vnorm.std + self.vnorm.mean if self.args.value_norm else v

    def act(self, obs: np.ndarray, masks: np.ndarray):
        """Every agent's action from observations (B, U, D) under the env's masks (B, U, L).

        Returns ``(actions, log_probs, masks, feats)``: actions and their log-probabilities per row (B * U), the
        masks they were sampled under (the shield's, PPO's ratios need them) and the node features (or None).
        """
        s = self.sizes
        rows = s.B * s.U
        flat_obs = obs.reshape(rows, s.obs)
        with torch.no_grad():
            feats = self.node_feats(flat_obs)
            if self.shield is not None:
                # The team chooses one UAV after another (training.shield), sampling each UAV's node by the
                # Gumbel-max trick under its shielded mask.
                logits = self.actor.logits(self.actor_in(flat_obs), feats, torch.from_numpy(masks.reshape(rows, -1)))
                a_np, masks = self.shield.choose(masks, self.env.waypoint_paths,
                                                 gumbel_pick(logits.numpy().reshape(s.B, s.U, -1)),
                                                 self.env.onward_reach if self.args.viability_shield else None)
                d = masked_categorical(logits, torch.from_numpy(masks.reshape(rows, -1)))
                a = torch.from_numpy(a_np.reshape(rows))
            else:
                d = self.actor.dist(self.actor_in(flat_obs), feats,
                                    torch.from_numpy(masks.reshape(rows, -1)) if s.waypoint else None)
                a = d.sample()
            logp = d.log_prob(a) if s.waypoint else d.log_prob(a).sum(-1)
        return a, logp, masks, feats


def constraint_limits(args: Args) -> dict[str, float]:
    """The constrained costs and their limits, {name: limit} in the env's COSTS order: ``--constraints``, and
    separation at ``--cost-limit`` with ``--lagrangian`` (a ValueError names a bad item)."""
    limits: dict[str, float] = {}
    items = [x.strip() for x in args.constraints.split(",") if x.strip()]
    if args.constraints.strip() and not items:
        raise ValueError(f"--constraints {args.constraints!r} names no constraint; give NAME=LIMIT[,NAME=LIMIT...] "
                         f"with NAME one of {COSTS}, or leave it out")
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in COSTS:
            raise ValueError(f"--constraints {args.constraints!r}: {item!r} must be NAME=LIMIT with NAME one of "
                             f"{COSTS}")
        try:
            limit = float(value)
        except ValueError:
            limit = math.nan
        if not 0.0 <= limit <= 1.0:
            raise ValueError(f"--constraints {args.constraints!r}: the limit of {name} must be a number in [0, 1] "
                             f"(mean cost per UAV and slot), got {value.strip()!r}")
        if name in limits:
            raise ValueError(f"--constraints {args.constraints!r}: {name} is given twice")
        limits[name] = limit
    if args.lagrangian:
        if "separation" in limits:
            raise ValueError("--lagrangian constrains separation at --cost-limit; --constraints names it too")
        limits["separation"] = args.cost_limit
    return {name: limits[name] for name in COSTS if name in limits}


# ---------------------------------------------------------------------------------------------- rollout
COST_KEYS = tuple(f"cost_{name}" for name in COSTS)      # the env's constraint costs, by name


class Rollout:
    """Rollout storage: (T, B, U, ...) numpy arrays, flattened to agent-samples for the update."""

    def __init__(self, s: Sizes):
        T, B, U = s.T, s.B, s.U
        self.obs = np.zeros((T, B, U, s.obs), np.float32)
        self.state = np.zeros((T, B, s.state), np.float32)
        self.mask = np.ones((T, B, U, s.actions if s.waypoint else 1), bool)
        self.act = np.zeros((T, B, U) if s.waypoint else (T, B, U, 2), np.int64 if s.waypoint else np.float32)
        self.logp, self.value = np.zeros((T, B, U), np.float32), np.zeros((T, B, U), np.float32)
        self.reward, self.done = np.zeros((T, B, U), np.float32), np.zeros((T, B), np.float32)
        self.costs = np.zeros((T, len(s.constrained), B, U), np.float32)     # the constrained costs, in order
        # The node head's inputs, kept from the rollout for the update (they do not depend on the parameters).
        self.feats = torch.zeros((T, B * U, s.actions, s.feats) if s.head == "node" else (T, 0))


class Episodes:
    """Running sums of every copy's episode (reward, disguise, constraint costs) and the finished episodes' means
    since they were last taken."""

    def __init__(self, s: Sizes):
        self.ret, self.kappa = np.zeros((s.B, s.U)), np.zeros((s.B, s.U))
        self.cost = np.zeros((len(COST_KEYS), s.B, s.U))
        self.recent: list[dict] = []

    def add(self, rew: np.ndarray, costs: np.ndarray, kappa: np.ndarray, done: np.ndarray, infos: dict) -> None:
        """One step's rewards, costs (C, B, U) and disguise (B, U); ``done`` (B,) copies end their episodes."""
        self.ret += rew
        self.cost += costs
        self.kappa += kappa
        for b in np.flatnonzero(done):
            slots = max(infos["final_info"]["slot"][b, 0], 1)
            self.recent.append({"reward": float(self.ret[b].mean()), "kappa": float(self.kappa[b].mean() / slots),
                                **{k: float(self.cost[i, b].mean()) for i, k in enumerate(COST_KEYS)}})
        self.ret[done], self.kappa[done], self.cost[:, done] = 0.0, 0.0, 0.0

    def take_means(self) -> dict:
        """The means over the episodes finished since the last call (at least one)."""
        means = {k: float(np.mean([e[k] for e in self.recent])) for k in self.recent[0]}
        self.recent = []
        return means


def collect_rollout(agents: Agents, buf: Rollout, episodes: Episodes, obs, state, *, lam: dict[str, float]):
    """T steps of every copy into ``buf`` (the training reward minus ``lam[c] * cost_c`` of each constrained cost);
    returns the observation and state to continue from."""
    args, s, env = agents.args, agents.sizes, agents.env
    which = [COSTS.index(c) for c in s.constrained]
    weights = np.array([lam[c] for c in s.constrained], np.float64)[:, None, None]
    for t in range(s.T):
        buf.obs[t], buf.state[t] = obs, state
        if s.waypoint:
            buf.mask[t] = env.action_masks().astype(bool)
        a, logp, buf.mask[t], feats = agents.act(obs, buf.mask[t])
        if s.head == "node":
            buf.feats[t] = feats
        buf.value[t] = agents.value(obs, state)
        buf.act[t] = a.numpy().reshape(buf.act.shape[1:])
        buf.logp[t] = logp.numpy().reshape(s.B, s.U)
        obs, rew, term, trunc, infos = env.step(buf.act[t])
        state = env.state()
        done = term[:, 0] | trunc[:, 0]
        # An ended copy's infos are its next episode's first ones; its last slot's are in final_info.
        last = infos["final_info"] if done.any() else infos
        step_costs = np.stack([np.where(done[:, None], last[k], infos[k]) for k in COST_KEYS])
        episodes.add(rew, step_costs, np.where(done[:, None], last["kappa"], infos["kappa"]), done, infos)
        kept = step_costs[which]
        r = rew - (weights * kept).sum(axis=0) if which else rew.copy()
        cut = trunc[:, 0] & ~term[:, 0]
        if cut.any() and env.episode_length < env.config.n_slots:
            ended = np.flatnonzero(cut)        # time limit before the route's end: bootstrap V(final)
            r[ended] += args.gamma * agents.value(infos["final_obs"][ended], infos["final_state"][ended])
        buf.reward[t], buf.done[t], buf.costs[t] = r, done, kept
    return obs, state


# ---------------------------------------------------------------------------------------------- GAE
def advantages(buf: Rollout, next_value: np.ndarray, gamma: float, gae_lambda: float):
    """GAE(gamma, lambda) of the rollout, with no bootstrap across a done: ``(advantages, returns)`` (T, B, U)."""
    T = len(buf.reward)
    adv = np.zeros(buf.reward.shape, np.float32)
    last_gae = np.zeros(buf.reward.shape[1:], np.float32)
    for t in reversed(range(T)):
        nv = next_value if t == T - 1 else buf.value[t + 1]
        nonterminal = 1.0 - buf.done[t][:, None]
        delta = buf.reward[t] + gamma * nv * nonterminal - buf.value[t]
        last_gae = delta + gamma * gae_lambda * nonterminal * last_gae
        adv[t] = last_gae
    return adv, adv + buf.value


# ---------------------------------------------------------------------------------------------- PPO update
def ppo_update(agents: Agents, optim, buf: Rollout, adv: np.ndarray, returns: np.ndarray, train_actor: bool = True):
    """``update_epochs`` epochs of clipped PPO over minibatches of agent-samples (the critic's loss alone without
    ``train_actor``).

    Returns the last minibatch's losses (``policy_loss``, ``value_loss``, ``entropy``, ``approx_kl``) and every
    minibatch's clip fraction.
    """
    args, s, actor, critic, vnorm = agents.args, agents.sizes, agents.actor, agents.critic, agents.vnorm
    N = s.T * s.B * s.U
    f_x = agents.actor_in(buf.obs.reshape(N, s.obs))
    f_feats = buf.feats.reshape(N, s.actions, s.feats) if s.head == "node" else None
    f_cin = agents.critic_in(buf.obs, buf.state).reshape(N, s.critic_in).astype(np.float32)
    f_mask = buf.mask.reshape(N, -1)
    f_act = buf.act.reshape(N, *buf.act.shape[3:])
    f_logp, f_adv, f_ret = buf.logp.reshape(N), adv.reshape(N), returns.reshape(N)
    f_ret_n = (f_ret - vnorm.mean) / vnorm.std if args.value_norm else f_ret
    mb = max(N // args.num_minibatches, 1)
    clipfracs, losses = [], {}
    for _ in range(args.update_epochs):
        perm = np.random.permutation(N)
        for start in range(0, N, mb):
            idx = perm[start:start + mb]
            d = actor.dist(f_x[idx], f_feats, torch.from_numpy(f_mask[idx]) if s.waypoint else None,
                           None if f_feats is None else idx)         # the rows read the rollout's features
            a = torch.from_numpy(f_act[idx])
            new_logp = d.log_prob(a) if s.waypoint else d.log_prob(a).sum(-1)
            entropy = d.entropy() if s.waypoint else d.entropy().sum(-1)
            ratio = (new_logp - torch.from_numpy(f_logp[idx])).exp()
            mb_adv = torch.from_numpy(f_adv[idx])
            mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
            pg_loss = torch.max(-mb_adv * ratio, -mb_adv * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)).mean()
            v = critic(torch.from_numpy(f_cin[idx]))
            v_loss = 0.5 * ((v - torch.from_numpy(f_ret_n[idx].astype(np.float32))) ** 2).mean()
            loss = (pg_loss - args.ent_coef * entropy.mean() if train_actor else 0.0) + args.vf_coef * v_loss
            optim.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_([*actor.parameters(), *critic.parameters()], args.max_grad_norm)
            optim.step()
            clipfracs.append(float(((ratio - 1.0).abs() > args.clip_coef).float().mean()))
            losses = {"policy_loss": pg_loss.item(), "value_loss": v_loss.item(), "entropy": entropy.mean().item(),
                      "approx_kl": ((ratio - 1) - ratio.log()).mean().item()}
    return losses, clipfracs


# ---------------------------------------------------------------------------------------------- progress and logs
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
            "viability_shield": bool(shield is not None and args.viability_shield),
            "viability_min_reach": shield.min_reach if shield is not None and args.viability_shield else None,
            "shield_lookahead": bool(shield is not None and shield.lookahead),
            "safety_filter": bool(args.safety_filter),
            "train_tasks": task_list(args) or None,
            "covert_env_version": covert_env.__version__ if hasattr(covert_env, "__version__") else None}


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


# ---------------------------------------------------------------------------------------------- checkpoints
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


# ---------------------------------------------------------------------------------------------- training
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
        env = SafetyFilteredVectorEnv(env)
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
    t_start, stopped = time.monotonic() - prog.wall_seconds, False
    t_run, step_run = time.monotonic(), prog.global_step     # this process's rate projects the time budget's end
    last_ckpt = prog.global_step
    while prog.global_step < args.total_timesteps:
        if args.anneal_lr:
            optim.param_groups[0]["lr"] = args.learning_rate * max(1.0 - prog.global_step / args.total_timesteps, 0.0)
        obs, state = collect_rollout(agents, buf, episodes, obs, state, lam=prog.lam)
        prog.global_step += s.B * s.T
        now = time.monotonic()
        bar.total = expected_steps(args.total_timesteps, prog.global_step, now - t_start, args.time_budget_minutes,
                                   (prog.global_step - step_run) / max(now - t_run, 1e-9))
        bar.update(s.B * s.T)

        adv, returns = advantages(buf, agents.value(obs, state), args.gamma, args.gae_lambda)
        if args.value_norm:
            vnorm.update(returns)
        losses, clipfracs = ppo_update(agents, optim, buf, adv, returns,
                                       train_actor=prog.updates >= args.actor_warmup_updates)
        if not all(np.isfinite(v) for v in losses.values()):
            raise FloatingPointError(f"non-finite losses at update {prog.updates}: {losses}")
        for j, (name, limit) in enumerate(s.constrained.items()):       # dual ascent, one multiplier each
            prog.lam[name] = max(0.0, prog.lam[name] + args.lagrange_lr * (float(buf.costs[:, j].mean()) - limit))
            if args.lambda_max:
                prog.lam[name] = min(prog.lam[name], args.lambda_max)
        prog.updates += 1

        prog.wall_seconds = time.monotonic() - t_start
        log_update(writer, curve, bar, prog, losses=losses, clipfracs=clipfracs, shield=shield, episodes=episodes,
                   agents_env=env)
        if args.time_budget_minutes > 0 and prog.wall_seconds > 60 * args.time_budget_minutes:
            print(f"time budget of {args.time_budget_minutes:g} min reached at {prog.global_step} env steps: "
                  "stopping", flush=True)
            stopped = True
        if args.checkpoint_every and prog.global_step - last_ckpt >= args.checkpoint_every:
            save_checkpoint(run_dir / "checkpoints" / f"step_{prog.global_step}.npz", actor, critic, optim,
                            prog.meta(vnorm, card))
            last_ckpt = prog.global_step
        if stopped:
            break
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


def save_final(run_dir: Path, actor, critic, optim, meta: dict) -> None:
    """The last checkpoint, and the actor alone in the format training.pretrained loads (``mappo:RUN`` and the
    shipped weights) with its card."""
    save_checkpoint(run_dir / "checkpoints" / f"step_{meta['global_step']}.npz", actor, critic, optim, meta)
    np.savez(run_dir / "model.npz", **{f"actor.{k}": v.detach().numpy() for k, v in actor.state_dict().items()})
    (run_dir / "model.json").write_text(json.dumps(meta, indent=2))


def main(argv: list[str] | None = None) -> Path:
    args = parse_args(Args, argv, description=__doc__.split("\n")[0], presets=MAPPO_RECIPES)
    try:
        check_args(args)
    except ValueError as exc:
        print(f"python -m training.mappo: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return train(args)


if __name__ == "__main__":
    main()
