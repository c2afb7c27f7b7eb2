"""MAPPO and IPPO on the batched vector env (``covert_env.vector_env``), one CleanRL-style file.

    OMP_NUM_THREADS=1 python -m training.mappo --recipe 3uav-mappo --seed 0        # the documented recipe
    OMP_NUM_THREADS=1 python -m training.mappo --algo mappo --action-mode waypoint --time-budget-minutes 55
    OMP_NUM_THREADS=1 python -m training.mappo --algo ippo --action-mode unicycle
    python -m training.mappo --resume runs/<run>                  # continue from the newest checkpoint
    python -m training.evaluate --policies dp random@waypoint mappo:runs/<run>
    tensorboard --logdir runs

Read top to bottom: arguments, networks, the rollout (same-step autoreset, truncation bootstrap, episode
statistics), GAE, the PPO update, checkpoints. Nothing here is pickled: checkpoints are ``.npz`` + JSON.

* **Actor** (parameter-shared, every UAV of every copy): an MLP on the agent's own observation. Waypoint mode:
  a masked categorical over the lattice nodes (masked nodes get -inf), by default scoring each node from its
  geometry relative to the UAV and teammates (``--head node``, :func:`training.pretrained.node_features`;
  ``--head flat`` is one logit per node). Unicycle mode: a Gaussian with a state-independent std; actions are
  **clipped** to [-1, 1] by the env (no tanh squashing; the log-probability is that of the unclipped sample,
  as in CleanRL's continuous PPO).
* **Separation shield** (waypoint mode, ``--separation-shield``, on by default): the UAVs of a copy choose one
  after another, and a UAV may not choose a node whose path comes closer than d_safe1 to a teammate's chosen
  path (:mod:`training.shield`; the env's ``waypoint_paths`` flies the candidates). The shielded masks are
  stored with the actions, so PPO's ratios use the masks the actions were sampled under, and the harness runs
  the same shield (the model card's ``separation_shield``).
* **Critic**: MAPPO (``--algo mappo``) sees the centralised ``state()`` of the copy plus a one-hot of the agent
  (the rewards are per agent, so one state value would not do); IPPO (``--algo ippo``) sees the agent's own
  observation. Value targets are normalised by running statistics (``--value-norm``, MAPPO's ValueNorm).
* **Autoreset**: the vector env resets an ended copy within ``step()`` and hands back its last observation and
  state in ``infos["final_obs"/"final_state"]``. A step that ended a copy is a done for GAE (no bootstrap across
  episodes). Truncated before the route's end (``--max-cycles`` < the track's ``n_slots``), the value of the
  final observation/state is added as ``gamma V(final)`` to the last reward (the time limit is not part of the
  task). At the route's end (the default 70 slots) there are no more slots: the episode truly ends, V = 0.
* **Reward**: the env's default reward (eq. 18 / reward_scale plus unit penalties); the constraint costs
  ``cost_*`` of the infos are logged per episode. ``--lagrangian`` subtracts ``lambda * cost_separation``
  (eq. 2) from the training reward, lambda >= 0 raised by dual ascent while the rollout's separation-violation
  rate exceeds ``--cost-limit`` (slots per UAV and slot).

Env steps count copy-slots (one step of one env copy, all its UAVs); agent-steps are ``n_uavs`` times more.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from covert_env.envs.batch import COSTS
from training.budget import expected_steps
from training.common import parse_args, resumed_args, run_name, save_run, setup_torch
from training.pretrained import N_OWN_FEATURES, node_features
from training.recipes import MAPPO_RECIPES
from training.shield import SeparationShield


@dataclass
class Args:
    algo: str = "mappo"
    """'mappo' (critic on the centralised state() and the agent's id) or 'ippo' (critic on the agent's obs)"""
    env_id: str = "covert_sensing_vector_v1"
    """name of the env in run names (covert_env.vector_env)"""
    seed: int = 0
    """seed of numpy, torch and the env copies (their scenes, starts and the action sampling)"""
    n_uavs: int = 3
    """UAVs per env copy (one shared actor)"""
    num_envs: int = 16
    """env copies stepped as one batch"""
    action_mode: str = "waypoint"
    """'waypoint' (masked categorical over the lattice) or 'unicycle' (Gaussian, clipped)"""
    head: str = "node"
    """waypoint actor head: 'node' (score each node from its geometry) or 'flat' (one logit per node)"""
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
    """subtract lambda * cost_separation from the training reward, lambda by dual ascent"""
    separation_shield: bool = True
    """waypoint mode: the UAVs choose one after another and none may choose a node whose path comes closer than
    d_safe1 + shield_margin to a teammate's chosen path (training.shield); in training and evaluation alike.
    The unicycle mode has no shield"""
    shield_margin: float = 0.0
    """extra distance (m) the shield keeps beyond d_safe1 along the paths"""
    shield_end_margin: float = 10.0
    """where possible, the shield also keeps the UAVs' slot ends d_safe1 + this (m) apart (room for the next slot)"""
    cost_limit: float = 0.007
    """allowed separation-violation rate per UAV and slot (0.5 of 70 slots) for --lagrangian"""
    lagrange_lr: float = 1.0
    """dual ascent step of lambda per update (times the rollout's violation rate minus cost_limit)"""
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
                          ("head", ("node", "flat"))):
        if getattr(args, name) not in allowed:
            raise ValueError(f"--{name.replace('_', '-')} {getattr(args, name)!r}: must be one of {allowed}")
    rows = args.num_envs * args.num_steps * args.n_uavs
    if rows < 2 * args.num_minibatches:
        # A minibatch of one row has no advantage spread to normalise by: its update would be NaN.
        raise ValueError(f"--num-minibatches {args.num_minibatches}: a batch of num_envs * num_steps * n_uavs = "
                         f"{rows} rows gives minibatches of fewer than 2 rows; use at most {max(rows // 2, 1)} "
                         f"minibatches or a larger batch")


# ---------------------------------------------------------------------------------------------- networks
def _nets():
    """The torch modules (defined on first use so that importing this file does not need torch)."""
    import torch
    from torch import nn

    def layer(i, o, std=2 ** 0.5, bias=True):
        lin = nn.Linear(i, o, bias=bias)
        nn.init.orthogonal_(lin.weight, std)
        if bias:
            nn.init.zeros_(lin.bias)
        return lin

    class Actor(nn.Module):
        """Parameter names match :class:`training.pretrained.NumpyActor`."""

        def __init__(self, obs_dim, n_actions, head, hidden, node_hidden, n_feat, log_std_init):
            super().__init__()
            self.head = head
            self.trunk = nn.Sequential(layer(obs_dim, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh())
            if head == "node":
                self.node_obs = layer(hidden, node_hidden)
                self.node_feat = layer(n_feat, node_hidden, bias=False)
                self.node_out = layer(node_hidden, 1, std=0.01)
            elif head == "flat":
                self.flat = layer(hidden, n_actions, std=0.01)
            else:
                self.mean = layer(hidden, n_actions, std=0.01)
                self.log_std = nn.Parameter(torch.full((n_actions,), float(log_std_init)))

        def logits(self, obs, feats=None, mask=None):
            """Node logits (waypoint heads); with ``mask``, the node head scores only the allowed nodes (about
            two in five: the same values at a fraction of the cost) and the others get -1e8."""
            h = self.trunk(obs)
            if self.head != "node":
                return self.flat(h)
            if mask is None:
                z = torch.relu(self.node_obs(h)[:, None, :] + self.node_feat(feats))
                return self.node_out(z)[..., 0]
            rows, nodes = mask.nonzero(as_tuple=True)
            z = torch.relu(self.node_obs(h)[rows] + self.node_feat(feats[rows, nodes]))
            return torch.full(mask.shape, -1e8).index_put((rows, nodes), self.node_out(z)[:, 0])

        def dist(self, obs, feats=None, mask=None):
            if self.head == "gaussian":
                mean = self.mean(self.trunk(obs))
                return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))
            return masked_categorical(self.logits(obs, feats, mask), mask)

    def masked_categorical(logits, mask):
        return torch.distributions.Categorical(logits=torch.where(mask, logits, torch.tensor(-1e8)))

    Actor.masked_categorical = staticmethod(masked_categorical)

    class Critic(nn.Module):
        def __init__(self, in_dim, hidden):
            super().__init__()
            self.net = nn.Sequential(layer(in_dim, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh(),
                                     layer(hidden, 1, std=1.0))

        def forward(self, x):
            return self.net(x)[..., 0]

    return Actor, Critic


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
    import torch

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


# ---------------------------------------------------------------------------------------------- training
def train(args: Args) -> Path:
    check_args(args)
    setup_torch(args.torch_threads)
    import torch
    from torch.utils.tensorboard import SummaryWriter
    from tqdm.auto import tqdm

    import covert_env

    if args.resume:
        run_dir = Path(args.resume)
        args = resumed_args(args, run_dir)
    else:
        run_dir = Path(args.runs_dir) / (args.run_name or run_name(args.env_id, args.algo, args.seed))
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    ekw = dict(n_uavs=args.n_uavs, action_mode=args.action_mode, max_cycles=args.max_cycles,
               scene_pool=args.scene_pool)
    env = covert_env.vector_env(num_envs=args.num_envs, **ekw)
    B, U, T, c = args.num_envs, args.n_uavs, args.num_steps, env.config
    waypoint = args.action_mode == "waypoint"
    obs_dim = env.single_observation_space.shape[0]
    state_dim = env.single_state_space.shape[0]
    n_act = len(env.lattice) if waypoint else 2
    head = (args.head if waypoint else "gaussian")
    n_feat = N_OWN_FEATURES + U - 1
    actor_spec = dict(head=head, hidden=args.hidden, node_hidden=args.node_hidden, n_feat=n_feat, obs_dim=obs_dim,
                      n_actions=n_act, agent_id=args.agent_id)
    shield = (SeparationShield(c.d_safe1 + args.shield_margin, args.shield_end_margin)
              if waypoint and args.separation_shield else None)
    Actor, Critic = _nets()
    actor = Actor(obs_dim + (U if args.agent_id else 0), n_act, head, args.hidden, args.node_hidden, n_feat,
                  args.log_std_init)
    critic_in = state_dim + U if args.algo == "mappo" else obs_dim
    critic = Critic(critic_in, args.hidden)
    optim = torch.optim.Adam([*actor.parameters(), *critic.parameters()], lr=args.learning_rate, eps=1e-5)
    vnorm, lam = RunningNorm(), 0.0
    global_step, updates, wall0 = 0, 0, 0.0
    ckpt = latest_checkpoint(run_dir) if args.resume else None
    if ckpt is not None:
        meta = load_checkpoint(ckpt, actor, critic, optim)
        global_step, updates, wall0, lam = meta["global_step"], meta["updates"], meta["wall_seconds"], meta["lam"]
        vnorm.mean, vnorm.var, vnorm.count = meta["vnorm"]
        print(f"resumed from {ckpt} at {global_step} env steps", flush=True)
    card = {"algorithm": args.algo, "actor": actor_spec, "env_kwargs": ekw, "env_id": env.metadata["name"],
            "separation_shield": None if shield is None else shield.min_distance,
            "shield_end_margin": None if shield is None else shield.end_margin,
            "covert_env_version": covert_env.__version__ if hasattr(covert_env, "__version__") else None}
    save_run(run_dir, args, {"card": card})
    writer = SummaryWriter(str(run_dir / "tb"))
    curve = open(run_dir / "curve.jsonl", "a")

    def feats_of(obs_np):
        return torch.from_numpy(node_features(obs_np, env.lattice, U, c.r2, c.v_max, c.delta, c.d_safe1)) \
            if head == "node" else None

    eye = np.eye(U, dtype=np.float32)
    copies = np.arange(B)

    def actor_in(flat_obs):
        """The actor's input rows: observations (agent-minor rows, as (..., U, D) flattened) and, with
        --agent-id, the one-hot of each row's agent."""
        x = np.concatenate([flat_obs, eye[np.arange(len(flat_obs)) % U]], 1) if args.agent_id else flat_obs
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))

    def critic_input(obs_np, state_np):
        """(..., U, critic_in) from observations (..., U, D) and states (..., S)."""
        if args.algo == "ippo":
            return obs_np
        st = np.broadcast_to(state_np[..., None, :], (*state_np.shape[:-1], U, state_dim))
        return np.concatenate([st, np.broadcast_to(eye, (*state_np.shape[:-1], U, U))], axis=-1)

    def value_of(obs_np, state_np):
        with torch.no_grad():
            v = critic(torch.from_numpy(critic_input(obs_np, state_np).astype(np.float32))).numpy()
        return v * vnorm.std + vnorm.mean if args.value_norm else v

    # Rollout storage: (T, B, U, ...) numpy arrays, flattened to agent-samples for the update.
    obs_buf = np.zeros((T, B, U, obs_dim), np.float32)
    state_buf = np.zeros((T, B, state_dim), np.float32)
    mask_buf = np.ones((T, B, U, n_act if waypoint else 1), bool)
    act_buf = np.zeros((T, B, U) if waypoint else (T, B, U, 2), np.int64 if waypoint else np.float32)
    logp_buf, val_buf = np.zeros((T, B, U), np.float32), np.zeros((T, B, U), np.float32)
    rew_buf, done_buf = np.zeros((T, B, U), np.float32), np.zeros((T, B), np.float32)
    sep_buf = np.zeros((T, B, U), np.float32)
    # The node head's inputs, kept from the rollout for the update (they do not depend on the parameters).
    feats_buf = torch.zeros((T, B * U, n_act, n_feat) if head == "node" else (T, 0))
    cost_keys = tuple(f"cost_{name}" for name in COSTS)              # the env's constraint costs, by name
    separation = COSTS.index("separation")
    ep_ret, ep_kappa = np.zeros((B, U)), np.zeros((B, U))
    ep_cost = np.zeros((len(cost_keys), B, U))
    recent: list[dict] = []

    obs, _ = env.reset(seed=args.seed + 7919 * updates)      # a resumed run draws fresh episodes
    state = env.state()
    bar = tqdm(total=args.total_timesteps, initial=global_step, unit="step", disable=not args.progress_bar,
               mininterval=0.5 if os.isatty(2) else 30.0, smoothing=0.05)
    t_start, stopped = time.monotonic() - wall0, False
    t_run, step_run = time.monotonic(), global_step          # this process's rate projects the time budget's end
    last_ckpt = global_step
    while global_step < args.total_timesteps:
        if args.anneal_lr:
            optim.param_groups[0]["lr"] = args.learning_rate * max(1.0 - global_step / args.total_timesteps, 0.0)
        # ------------------------------------------------------------------ rollout
        for t in range(T):
            obs_buf[t], state_buf[t] = obs, state
            if waypoint:
                mask_buf[t] = env.action_masks().astype(bool)
            with torch.no_grad():
                flat_obs = obs.reshape(B * U, obs_dim)
                feats = feats_of(flat_obs)
                if head == "node":
                    feats_buf[t] = feats
                if shield is not None:
                    # The team chooses one UAV after another (training.shield), sampling each UAV's node by the
                    # Gumbel-max trick under its shielded mask; those masks are stored for the update.
                    logits = actor.logits(actor_in(flat_obs), feats, torch.from_numpy(mask_buf[t].reshape(B * U, -1)))
                    lg = logits.numpy().reshape(B, U, -1)

                    def pick(k, m, lg=lg):
                        g = -np.log(-np.log(np.random.random(m.shape)))
                        return np.argmax(np.where(m, lg[copies, k] + g, -np.inf), axis=1)

                    a_np, mask_buf[t] = shield.choose(mask_buf[t], env.waypoint_paths, pick)
                    d = Actor.masked_categorical(logits, torch.from_numpy(mask_buf[t].reshape(B * U, -1)))
                    a = torch.from_numpy(a_np.reshape(B * U))
                else:
                    d = actor.dist(actor_in(flat_obs), feats,
                                   torch.from_numpy(mask_buf[t].reshape(B * U, -1)) if waypoint else None)
                    a = d.sample()
                logp = d.log_prob(a) if waypoint else d.log_prob(a).sum(-1)
            val_buf[t] = value_of(obs, state)
            act_buf[t] = a.numpy().reshape(act_buf.shape[1:])
            logp_buf[t] = logp.numpy().reshape(B, U)
            obs, rew, term, trunc, infos = env.step(act_buf[t])
            state = env.state()
            done = term[:, 0] | trunc[:, 0]
            # An ended copy's infos are its next episode's first ones; its last slot's are in final_info.
            last = infos["final_info"] if done.any() else infos
            step_costs = np.stack([np.where(done[:, None], last[k], infos[k]) for k in cost_keys])
            kappa = np.where(done[:, None], last["kappa"], infos["kappa"])
            ep_ret += rew
            ep_cost += step_costs
            ep_kappa += kappa
            r = rew - lam * step_costs[separation] if args.lagrangian else rew.copy()
            cut = trunc[:, 0] & ~term[:, 0]
            if cut.any() and env.episode_length < c.n_slots:
                ended = np.flatnonzero(cut)        # time limit before the route's end: bootstrap V(final)
                r[ended] += args.gamma * value_of(infos["final_obs"][ended], infos["final_state"][ended])
            rew_buf[t], done_buf[t], sep_buf[t] = r, done, step_costs[separation]
            for b in np.flatnonzero(done):
                recent.append({"reward": float(ep_ret[b].mean()), "kappa": float(ep_kappa[b].mean() / max(
                    infos["final_info"]["slot"][b, 0], 1)), **{k: float(ep_cost[i, b].mean())
                                                               for i, k in enumerate(cost_keys)}})
            ep_ret[done], ep_kappa[done], ep_cost[:, done] = 0.0, 0.0, 0.0
            global_step += B
        now = time.monotonic()
        bar.total = expected_steps(args.total_timesteps, global_step, now - t_start, args.time_budget_minutes,
                                   (global_step - step_run) / max(now - t_run, 1e-9))
        bar.update(B * T)
        # ------------------------------------------------------------------ GAE
        next_val = value_of(obs, state)
        adv = np.zeros((T, B, U), np.float32)
        last_gae = np.zeros((B, U), np.float32)
        for t in reversed(range(T)):
            nv = next_val if t == T - 1 else val_buf[t + 1]
            nonterminal = 1.0 - done_buf[t][:, None]
            delta = rew_buf[t] + args.gamma * nv * nonterminal - val_buf[t]
            last_gae = delta + args.gamma * args.gae_lambda * nonterminal * last_gae
            adv[t] = last_gae
        returns = adv + val_buf
        if args.value_norm:
            vnorm.update(returns)
        # ------------------------------------------------------------------ PPO update
        N = T * B * U
        f_obs = obs_buf.reshape(N, obs_dim)
        f_x = actor_in(f_obs)
        f_feats = feats_buf.reshape(N, n_act, n_feat) if head == "node" else None
        f_cin = critic_input(obs_buf, state_buf).reshape(N, critic_in).astype(np.float32)
        f_mask = mask_buf.reshape(N, -1)
        f_act = act_buf.reshape(N, *act_buf.shape[3:])
        f_logp, f_adv, f_ret = logp_buf.reshape(N), adv.reshape(N), returns.reshape(N)
        f_ret_n = (f_ret - vnorm.mean) / vnorm.std if args.value_norm else f_ret
        mb = max(N // args.num_minibatches, 1)
        clipfracs, stats = [], {}
        for _ in range(args.update_epochs):
            perm = np.random.permutation(N)
            for s in range(0, N, mb):
                idx = perm[s:s + mb]
                d = actor.dist(f_x[idx], None if f_feats is None else f_feats[idx],
                               torch.from_numpy(f_mask[idx]) if waypoint else None)
                a = torch.from_numpy(f_act[idx])
                new_logp = d.log_prob(a) if waypoint else d.log_prob(a).sum(-1)
                entropy = d.entropy() if waypoint else d.entropy().sum(-1)
                ratio = (new_logp - torch.from_numpy(f_logp[idx])).exp()
                mb_adv = torch.from_numpy(f_adv[idx])
                mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                pg_loss = torch.max(-mb_adv * ratio,
                                    -mb_adv * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)).mean()
                v = critic(torch.from_numpy(f_cin[idx]))
                v_loss = 0.5 * ((v - torch.from_numpy(f_ret_n[idx].astype(np.float32))) ** 2).mean()
                loss = pg_loss - args.ent_coef * entropy.mean() + args.vf_coef * v_loss
                optim.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_([*actor.parameters(), *critic.parameters()], args.max_grad_norm)
                optim.step()
                clipfracs.append(float(((ratio - 1.0).abs() > args.clip_coef).float().mean()))
                stats = {"policy_loss": pg_loss.item(), "value_loss": v_loss.item(), "entropy": entropy.mean().item(),
                         "approx_kl": ((ratio - 1) - ratio.log()).mean().item()}
        if not all(np.isfinite(v) for v in stats.values()):
            raise FloatingPointError(f"non-finite losses at update {updates}: {stats}")
        if args.lagrangian:                        # dual ascent on the separation constraint (eq. 2)
            lam = max(0.0, lam + args.lagrange_lr * (float(sep_buf.mean()) - args.cost_limit))
        updates += 1
        # ------------------------------------------------------------------ logging and checkpoints
        wall = time.monotonic() - t_start
        for k, v in stats.items():
            writer.add_scalar(f"losses/{k}", v, global_step)
        writer.add_scalar("losses/clipfrac", float(np.mean(clipfracs)), global_step)
        writer.add_scalar("charts/sps", global_step / max(wall, 1e-9), global_step)
        writer.add_scalar("charts/lambda_separation", lam, global_step)
        if shield is not None:
            writer.add_scalar("charts/shield_fallbacks", shield.fallbacks / max(shield.choices, 1), global_step)
        if recent:
            means = {k: float(np.mean([e[k] for e in recent])) for k in recent[0]}
            for k, v in means.items():
                writer.add_scalar(f"episode/{k}", v, global_step)
            curve.write(json.dumps({"env_steps": global_step, "wall_seconds": round(wall, 1), "episodes": len(recent),
                                    **means, **stats, "lambda": lam}) + "\n")
            curve.flush()
            bar.set_postfix(reward=f"{means['reward']:.1f}", sep=f"{means['cost_separation']:.1f}", refresh=False)
            recent = []
        if args.time_budget_minutes > 0 and wall > 60 * args.time_budget_minutes:
            print(f"time budget of {args.time_budget_minutes:g} min reached at {global_step} env steps: stopping",
                  flush=True)
            stopped = True
        meta = {"global_step": global_step, "updates": updates, "wall_seconds": wall, "lam": lam,
                "vnorm": [vnorm.mean, vnorm.var, vnorm.count], **card}
        if args.checkpoint_every and global_step - last_ckpt >= args.checkpoint_every:
            save_checkpoint(run_dir / "checkpoints" / f"step_{global_step}.npz", actor, critic, optim, meta)
            last_ckpt = global_step
        if stopped:
            break
    if stopped:
        bar.total = bar.n                       # the time budget ended the run here
    bar.close()
    save_checkpoint(run_dir / "checkpoints" / f"step_{global_step}.npz", actor, critic, optim, meta)
    # The final actor alone, in the format training.pretrained loads (mappo:RUN and the shipped weights).
    np.savez(run_dir / "model.npz", **{f"actor.{k}": v.detach().numpy() for k, v in actor.state_dict().items()})
    (run_dir / "model.json").write_text(json.dumps(meta, indent=2))
    summary = {"env_steps": global_step, "agent_steps": global_step * U, "updates": updates,
               "train_minutes": round((time.monotonic() - t_start) / 60, 2), "stopped_by_time_budget": stopped}
    (run_dir / "train_summary.json").write_text(json.dumps(summary, indent=2))
    print(f"saved {run_dir / 'model.npz'}: {summary}", flush=True)
    writer.close()
    curve.close()
    env.close()
    return run_dir


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
