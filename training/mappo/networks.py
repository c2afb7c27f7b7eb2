"""The torch networks of :mod:`training.mappo`: the shared actor, the critic, the masked categorical.

They live apart from the training script so that importing :mod:`training.mappo` (its ``--help``, its
arguments and recipes) needs no torch. Learned teams run without torch, in
:class:`~training.pretrained.NumpyActor`: the same parameter names, the same outputs.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from training.mappo.node_categorical import node_log_prob_entropy
from training.mappo.node_head import node_scores
from training.pretrained import MASKED_LOGIT

__all__ = ["Actor", "Critic", "layer", "masked_categorical"]


def layer(i: int, o: int, std: float = 2 ** 0.5, bias: bool = True) -> nn.Linear:
    """A linear layer with orthogonal weights of gain ``std`` and zero bias (CleanRL's ``layer_init``)."""
    lin = nn.Linear(i, o, bias=bias)
    nn.init.orthogonal_(lin.weight, std)
    if bias:
        nn.init.zeros_(lin.bias)
    return lin


def masked_categorical(logits: torch.Tensor, mask: torch.Tensor) -> torch.distributions.Categorical:
    """A categorical over the allowed nodes: the masked ones get MASKED_LOGIT (never sampled, a finite
    log-probability)."""
    return torch.distributions.Categorical(logits=torch.where(mask, logits, torch.tensor(MASKED_LOGIT)))


class Actor(nn.Module):
    """The parameter-shared actor: an MLP trunk on the agent's observation and one of three heads.

    ``head="node"`` scores each lattice node from the trunk's output and the node's features
    (:func:`training.pretrained.node_features`); ``"flat"`` is one logit per node; ``"gaussian"`` is the unicycle
    mode's Gaussian with a state-independent std. Parameter names match :class:`training.pretrained.NumpyActor`.
    """

    def __init__(self, obs_dim: int, n_actions: int, *, head: str, hidden: int, node_hidden: int, n_feat: int,
                 log_std_init: float):
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

    def logits(self, obs, feats=None, mask=None, sample_of=None):
        """Node logits (waypoint heads). ``feats`` are the node features, one sample per row, or with
        ``sample_of`` (an int array, one per row) a store of samples that the rows name. With ``mask``, the node
        head scores only the allowed nodes (:func:`training.mappo.node_head.node_scores`) and the others get
        MASKED_LOGIT."""
        h = self.trunk(obs)
        if self.head != "node":
            return self.flat(h)
        if mask is None:
            f = feats if sample_of is None else feats[torch.as_tensor(sample_of)]
            z = torch.relu(self.node_obs(h)[:, None, :] + self.node_feat(f))
            return self.node_out(z)[..., 0]
        rows, nodes = mask.nonzero(as_tuple=True)
        store = feats.numpy() if isinstance(feats, torch.Tensor) else feats
        sample_of = np.arange(len(mask)) if sample_of is None else np.asarray(sample_of, np.int64)
        scores = node_scores(self.node_obs(h), self.node_feat, self.node_out, np.ascontiguousarray(store, np.float32),
                             sample_of, rows.numpy(), nodes.numpy())
        return torch.full(mask.shape, MASKED_LOGIT).index_put((rows, nodes), scores)

    def log_prob_entropy(self, obs, actions: np.ndarray, mask=None, pairs=None, sample_of=None):
        """``(log_prob, entropy)`` of the rows' node ``actions`` under the masked categorical (waypoint heads): what
        the PPO update asks. The node head reads ``pairs`` (a :class:`~training.mappo.node_categorical.NodePairs`
        of the samples) and ``sample_of``, the sample of each row, in one compiled pass over the allowed pairs
        (:func:`~training.mappo.node_categorical.node_log_prob_entropy`); the flat head reads ``mask`` (R, L)."""
        if self.head == "node":
            return node_log_prob_entropy(self.node_obs(self.trunk(obs)), self.node_feat, self.node_out, pairs,
                                         sample_of, actions)
        d = self.dist(obs, None, torch.from_numpy(mask))
        return d.log_prob(torch.from_numpy(actions)), d.entropy()

    def dist(self, obs, feats=None, mask=None, sample_of=None):
        """The action distribution: a masked categorical over the nodes, or the unicycle's Gaussian."""
        if self.head == "gaussian":
            mean = self.mean(self.trunk(obs))
            return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))
        return masked_categorical(self.logits(obs, feats, mask, sample_of), mask)


class Critic(nn.Module):
    """A value per input row: an MLP on the centralised state and agent one-hot (MAPPO) or the observation (IPPO)."""

    def __init__(self, in_dim: int, hidden: int):
        super().__init__()
        self.net = nn.Sequential(layer(in_dim, hidden), nn.Tanh(), layer(hidden, hidden), nn.Tanh(),
                                 layer(hidden, 1, std=1.0))

    def forward(self, x):
        return self.net(x)[..., 0]
