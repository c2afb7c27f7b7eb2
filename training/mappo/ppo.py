"""GAE and the clipped PPO update over agent-samples."""

from __future__ import annotations

import numpy as np
import torch

from training.mappo.agents import Agents
from training.mappo.node_categorical import NodePairs
from training.mappo.rollout import Rollout

__all__ = ["advantages", "ppo_update"]


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


def ppo_update(agents: Agents, optim, buf: Rollout, adv: np.ndarray, returns: np.ndarray, train_actor: bool = True,
               rng: np.random.Generator | None = None):
    """``update_epochs`` epochs of clipped PPO over minibatches of agent-samples (the critic's loss alone without
    ``train_actor``). The minibatches are drawn with ``rng`` (numpy's global generator if None).

    Returns the last minibatch's losses (``policy_loss``, ``value_loss``, ``entropy``, ``approx_kl``) and every
    minibatch's clip fraction.
    """
    args, s, actor, critic, vnorm = agents.args, agents.sizes, agents.actor, agents.critic, agents.vnorm
    N = s.T * s.B * s.U
    f_x = agents.actor_in(buf.obs.reshape(N, s.obs))
    f_mask = buf.mask.reshape(N, -1)
    # The node head reads each sample's allowed nodes and their features, laid out once for every minibatch.
    pairs = NodePairs(buf.feats.reshape(N, s.actions, s.feats).numpy(), f_mask) if s.head == "node" else None
    f_cin = agents.critic_in(buf.obs, buf.state).reshape(N, s.critic_in).astype(np.float32)
    f_act = buf.act.reshape(N, *buf.act.shape[3:])
    f_logp, f_adv, f_ret = buf.logp.reshape(N), adv.reshape(N), returns.reshape(N)
    f_ret_n = (f_ret - vnorm.mean) / vnorm.std if args.value_norm else f_ret
    mb = max(N // args.num_minibatches, 1)
    clipfracs, losses = [], {}
    for _ in range(args.update_epochs):
        perm = (np.random if rng is None else rng).permutation(N)
        for start in range(0, N, mb):
            idx = perm[start:start + mb]
            if s.waypoint:
                new_logp, entropy = actor.log_prob_entropy(f_x[idx], f_act[idx],
                                                           None if pairs is not None else f_mask[idx],
                                                           pairs, idx)
            else:
                d = actor.dist(f_x[idx])
                a = torch.from_numpy(f_act[idx])
                new_logp, entropy = d.log_prob(a).sum(-1), d.entropy().sum(-1)
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
