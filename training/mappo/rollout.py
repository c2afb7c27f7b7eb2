"""The rollout: storage of T steps of every copy, the episodes' running sums, and the loop that fills them
(same-step autoreset, the truncation bootstrap, the Lagrangian's training reward)."""

from __future__ import annotations

import numpy as np
import torch

from covert_env.envs.batch import COSTS
from training.mappo.agents import Agents, Sizes

__all__ = ["COST_KEYS", "Episodes", "Rollout", "collect_rollout"]

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

    def take_recent(self) -> list[dict]:
        """The episodes finished since the last call (or :meth:`take_means`), removed from ``recent``."""
        out, self.recent = self.recent, []
        return out

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
        if args.filter_scores:         # the filter orders its alternatives by the policy's logits
            obs, rew, term, trunc, infos = env.step(buf.act[t], scores=agents.scores.numpy().reshape(s.B, s.U, -1))
        else:
            obs, rew, term, trunc, infos = env.step(buf.act[t])
        if args.learn_flown_nodes:
            _learn_flown(buf, t, infos["shield_node"], agents.log_probs.numpy().reshape(s.B, s.U, -1))
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


def _learn_flown(buf: Rollout, t: int, flown: np.ndarray, log_probs: np.ndarray) -> None:
    """Step ``t``'s actions become the nodes ``flown`` (B, U) where the filter replaced a proposal with a node of the
    mask, their log-probabilities read from ``log_probs`` (B, U, L), the policy's at the rollout."""
    in_mask = np.take_along_axis(buf.mask[t], flown[..., None], axis=-1)[..., 0]
    swap = (flown != buf.act[t]) & in_mask
    if swap.any():
        c, i = np.nonzero(swap)
        buf.act[t, c, i] = flown[c, i]
        buf.logp[t, c, i] = log_probs[c, i, flown[c, i]]
