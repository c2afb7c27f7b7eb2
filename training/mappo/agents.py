"""The team as the training loop sees it: the networks' sizes and construction, the value statistics, a warm start
from trained weights, and :class:`Agents`, which turns numpy observations into sampled actions and values."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from training.mappo.args import Args, actor_fields, constraint_limits
from training.mappo.networks import Actor, Critic, masked_categorical
from training.pretrained import N_MAP_FEATURES, PRETRAINED_DIR, load_learned, n_node_features, node_features

__all__ = ["Agents", "RunningNorm", "Sizes", "behaviour_copy", "copy_weights", "gumbel_pick", "load_initial_actor",
           "make_networks", "sizes_of"]


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
        #: The last ``act``'s log-probabilities of every node (rows, L) in waypoint mode (None otherwise): what the
        #: rollout reads for a node other than the one sampled (--learn-flown-nodes).
        self.log_probs = None

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
            elif s.waypoint:
                mask = torch.from_numpy(masks.reshape(rows, -1))
                logits = self.actor.logits(self.actor_in(flat_obs), feats, mask)
                d = masked_categorical(logits, mask)
                a = d.sample()
            else:
                logits = None
                d = self.actor.dist(self.actor_in(flat_obs), feats, None)
                a = d.sample()
            #: The node logits of this step (B * U, L), the masked nodes' at MASKED_LOGIT (what --filter-scores
            #: gives the filter, as a team's card makes the harness give it), and their log-probabilities.
            self.scores = logits
            self.log_probs = d.logits if s.waypoint else None
            logp = d.log_prob(a) if s.waypoint else d.log_prob(a).sum(-1)
        return a, logp, masks, feats


def behaviour_copy(agents: Agents) -> Agents:
    """The team of ``agents`` with its own copies of the actor, the critic and the value statistics (the env and the
    shield shared): the team that acts while the learner's weights change (``--overlap-update``)."""
    return Agents(agents.args, agents.sizes, agents.env, copy.deepcopy(agents.actor), copy.deepcopy(agents.critic),
                  copy.deepcopy(agents.vnorm), agents.shield)


def copy_weights(source: Agents, into: Agents) -> None:
    """``into`` acts as ``source`` from now on: the actor's and the critic's weights and the value statistics."""
    into.actor.load_state_dict(source.actor.state_dict())
    into.critic.load_state_dict(source.critic.state_dict())
    into.vnorm.mean, into.vnorm.var, into.vnorm.count = source.vnorm.mean, source.vnorm.var, source.vnorm.count
