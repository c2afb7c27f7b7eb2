"""The node head's scores of the allowed nodes, forward and backward in one compiled pass each.

The waypoint actor's node head (:class:`training.mappo.networks.Actor`) scores node ``n`` of row ``r`` as

    logit[r, n] = w . relu(a[r] + W f[r, n]) + b,

with ``a[r]`` the trunk's projection of the row's observation (``node_obs``), ``f[r, n]`` the node's features
(:func:`training.pretrained.node_features`), ``W`` the ``node_feat`` weights and ``w``, ``b`` the ``node_out``
layer. Written with torch, one PPO minibatch of a few thousand rows with some 250 allowed nodes each makes
several tensors of (rows x nodes x hidden) floats (the gathered features, the pre-activations, their gradients):
memory traffic, not arithmetic, bounds it. :func:`node_scores` does the same arithmetic pair by pair in a compiled
loop that holds one pair's hidden vector at a time, and recomputes it in the backward pass instead of storing it.

The features stay where the rollout stored them, ``(samples, L, F)``; each row names its sample (``sample_of``),
so a minibatch reads them without copying.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["node_scores"]


@numba.njit(cache=True, nogil=True, inline="always")
def _hidden(a, r, f, wt, pre):
    """``pre`` = ``a[r] + W f``, the hidden pre-activations of one pair."""
    n_feat, hidden = wt.shape
    for j in range(hidden):
        pre[j] = 0.0
    for k in range(n_feat):
        fk = f[k]
        for j in range(hidden):
            pre[j] += wt[k, j] * fk
    for j in range(hidden):
        pre[j] += a[r, j]


@numba.njit(cache=True, nogil=True, inline="always")
def _tree_sum(x):
    """The sum of ``x`` (its length a power of two) by halves: a fixed order that vectorises."""
    n = len(x) // 2
    while n >= 1:
        for j in range(n):
            x[j] += x[j + n]
        n //= 2
    return x[0]


@numba.njit(cache=True, nogil=True)
def _forward(a, feats, sample_of, rows, nodes, wt, w, b, out):
    """``out[p]`` = the score of node ``nodes[p]`` of row ``rows[p]`` (module docstring); ``wt`` is ``W``
    transposed, ``(F, H)``, so that the inner loops run over the hidden units (``H`` a power of two)."""
    hidden = wt.shape[1]
    pre = np.empty(hidden, np.float32)
    for p in range(len(rows)):
        r = rows[p]
        _hidden(a, r, feats[sample_of[r], nodes[p]], wt, pre)
        for j in range(hidden):
            pre[j] = w[j] * max(pre[j], np.float32(0.0))
        out[p] = _tree_sum(pre) + b


@numba.njit(cache=True, nogil=True)
def _backward(a, feats, sample_of, rows, nodes, wt, w, grad, da, dwt, dw):
    """The gradients of ``sum_p grad[p] * out[p]`` with respect to ``a`` (added to ``da``), ``W`` transposed
    (``dwt``) and ``w`` (``dw``). A row's pairs (next to each other in ``rows``) add up in float32; the parameters'
    gradients, sums over every row, in float64."""
    n_feat, hidden = wt.shape
    pre = np.empty(hidden, np.float32)
    dz = np.empty(hidden, np.float32)
    row_dwt = np.zeros((n_feat, hidden), np.float32)
    row_dw = np.zeros(hidden, np.float32)
    n = len(rows)
    for p in range(n):
        r = rows[p]
        g = grad[p]
        f = feats[sample_of[r], nodes[p]]
        _hidden(a, r, f, wt, pre)
        for j in range(hidden):
            on = pre[j] > 0.0
            dz[j] = g * w[j] if on else np.float32(0.0)
            row_dw[j] += g * pre[j] if on else np.float32(0.0)
            da[r, j] += dz[j]
        for k in range(n_feat):
            fk = f[k]
            for j in range(hidden):
                row_dwt[k, j] += fk * dz[j]
        if p == n - 1 or rows[p + 1] != r:                 # the row's last pair: its sums join the totals
            for k in range(n_feat):
                for j in range(hidden):
                    dwt[k, j] += row_dwt[k, j]
                    row_dwt[k, j] = 0.0
            for j in range(hidden):
                dw[j] += row_dw[j]
                row_dw[j] = 0.0


class _NodeScores(torch.autograd.Function):
    """:func:`node_scores` with its gradient (the features get none: they are inputs, not parameters)."""

    @staticmethod
    def forward(ctx, a, weight, w, b, feats, sample_of, rows, nodes):
        wt = np.ascontiguousarray(weight.detach().numpy().T)
        out = np.empty(len(rows), np.float32)
        _forward(a.detach().numpy(), feats, sample_of, rows, nodes, wt, w.detach().numpy().reshape(-1),
                 np.float32(b.detach().reshape(-1)[0].item()), out)
        ctx.save_for_backward(a, weight, w, b)
        ctx.inputs = (feats, sample_of, rows, nodes, wt)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        a, weight, w, b = ctx.saved_tensors
        feats, sample_of, rows, nodes, wt = ctx.inputs
        g = np.ascontiguousarray(grad.detach().numpy(), np.float32)
        da = np.zeros(a.shape, np.float32)
        dwt, dw = np.zeros(wt.shape), np.zeros(wt.shape[1])
        _backward(a.detach().numpy(), feats, sample_of, rows, nodes, wt, w.detach().numpy().reshape(-1), g, da,
                  dwt, dw)
        db = np.full(b.shape, g.sum(dtype=np.float64), np.float32)
        return (torch.from_numpy(da), torch.from_numpy(np.ascontiguousarray(dwt.T, np.float32)),
                torch.from_numpy(dw.astype(np.float32).reshape(w.shape)), torch.from_numpy(db),
                None, None, None, None)


def node_scores(a: torch.Tensor, node_feat: torch.nn.Linear, node_out: torch.nn.Linear, feats: np.ndarray,
                sample_of: np.ndarray, rows: np.ndarray, nodes: np.ndarray) -> torch.Tensor:
    """The node head's scores of the pairs ``(rows[p], nodes[p])``, ``(P,)`` float32, differentiable in ``a``
    ``(R, H)`` and the two layers' parameters.

    Args:
        a: the rows' projections ``node_obs(trunk(obs))``, ``(R, H)`` float32.
        node_feat: the bias-free ``F -> H`` layer of the node features.
        node_out: the ``H -> 1`` output layer.
        feats: node features ``(S, L, F)`` float32, C-contiguous (the rollout's store, or one row each).
        sample_of: ``(R,)`` int64, the sample of ``feats`` each row reads.
        rows, nodes: ``(P,)`` int64, the pairs to score (a row's pairs next to each other keep ``a[r]`` in cache).
    """
    hidden = node_feat.weight.shape[0]
    if hidden & (hidden - 1):
        raise ValueError(f"node_scores: the node head's hidden width must be a power of two, got {hidden}")
    if node_feat.bias is not None:
        raise ValueError("node_scores: node_feat must have no bias (the node head's F -> H layer)")
    if feats.dtype != np.float32 or not feats.flags.c_contiguous or feats.ndim != 3:
        raise ValueError(f"node_scores: feats must be a C-contiguous (S, L, F) float32 array, got {feats.dtype} "
                         f"{feats.shape}")
    return _NodeScores.apply(a, node_feat.weight, node_out.weight, node_out.bias, feats, sample_of, rows, nodes)
