"""The settings of a :mod:`training.mappo` run: ``Args`` (one field per flag, each with its docstring) and their
checks, which name the flag, the value and what is allowed. Importing this module needs no torch."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from covert_env.envs.batch import COSTS
from covert_env.world.tasks import TASKS
from training.pretrained import PRETRAINED_DIR, load_learned, pretrained_names
from training.run_args import TrainingArgs

__all__ = ["Args", "actor_fields", "check_args", "constraint_limits", "init_actor_fits", "task_list"]


@dataclass
class Args(TrainingArgs):
    PROG: ClassVar[str] = "python -m training.mappo"         # the command line's name in --help and errors
    algo: str = "mappo"
    """'mappo' (critic on the centralised state() and the agent's id) or 'ippo' (critic on the agent's obs)"""
    env_id: str = "covert_sensing_vector_v4"
    """name of the env in run names (covert_env.vector_env)"""
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
    gets num_envs / its count copies of one vector env, covert_env.envs.task_mix: the mix acts on the largest
    lattice, which must hold every other task's nodes, as a nominal lattice holds its deviating task's); empty:
    random scenes of the paper family (scene_pool)"""
    total_timesteps: int = 50_000_000
    """env steps (copy-slots) to train for; the time budget usually stops first"""
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
    overlap_update: bool = False
    """collect the next rollout while the PPO update learns from the last one, in a second thread, so that the loop's
    two halves run at once on two cores. The rollout then acts with the weights from before that update, one
    update behind (PPO's ratio is taken against the weights that acted, as in asynchronous PPO); the Lagrange
    multipliers, likewise. Off: rollout and update take turns on one core"""
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
    """waypoint mode: the team's nodes are proposals that fly through the safety filter
    (covert_env.envs.safety_filter), which keeps eqs. 2 and 3 along the flown path; in training and evaluation
    alike. With the separation shield too, the team proposes through the shield (one UAV after another, each
    around its teammates' choices) and the filter guarantees"""
    learn_flown_nodes: bool = False
    """with --safety-filter: where the filter replaced a proposal with a node of the mask (the separation shield's
    mask where the shield is on too), the PPO update learns
    from the node flown (its log-probability under the policy at the rollout) instead of the proposal, so the team
    is credited with the move it made, as under the shield (action projection otherwise: the proposal keeps the
    credit of the replacement's outcome)"""
    filter_scores: bool = False
    """with --safety-filter: the filter orders each UAV's alternatives (the viability rule's and the search's) by
    the policy's logits, the node it prefers first, instead of by the distance to its proposal; in training and
    evaluation alike (the model card's filter_scores)"""
    viability_shield: bool = False
    """waypoint mode, with the separation shield: a UAV also avoids a node from which it could reach no lattice
    node next slot (it would leave the zone): the end of the chosen path is tested with the env's onward_reach and,
    if a dead end, the UAV chooses again among the nodes that are not (training.shield); with the safety filter
    (also): the filter's viability rule (SafetyFilter's min_reach), which replaces a dead-end proposal; in
    training and evaluation alike"""
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
    resume: str = ""
    """a run folder to continue from its newest checkpoint"""
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
    if args.viability_shield and not (args.action_mode == "waypoint" and (args.separation_shield
                                                                         or args.safety_filter)):
        raise ValueError(f"--viability-shield acts inside the separation shield or the safety filter: it needs "
                         f"--action-mode waypoint and one of them, got --action-mode {args.action_mode!r} "
                         f"--separation-shield {str(args.separation_shield).lower()} --safety-filter "
                         f"{str(args.safety_filter).lower()}")
    for flag, on in (("--shield-lookahead", args.shield_lookahead),):
        if on and not (args.separation_shield and args.action_mode == "waypoint"):
            raise ValueError(f"{flag} acts inside the separation shield: it needs --action-mode waypoint and "
                             f"--separation-shield true, got --action-mode {args.action_mode!r} --separation-shield "
                             f"{str(args.separation_shield).lower()}")
    if args.learn_flown_nodes and not args.safety_filter:
        raise ValueError("--learn-flown-nodes needs --safety-filter true (the nodes flown are the filter's)")
    if args.filter_scores and not args.safety_filter:
        raise ValueError("--filter-scores needs --safety-filter true (it orders the filter's alternatives)")
    if args.safety_filter and args.action_mode != "waypoint":
        raise ValueError(f"--safety-filter filters lattice nodes: it needs --action-mode waypoint, got "
                         f"--action-mode {args.action_mode!r}")
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


def actor_fields(args: Args) -> dict:
    """The node head's input switches, as the model card's ``actor`` records them."""
    return dict(node_map=args.node_map, node_manoeuvre=args.node_manoeuvre)


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
