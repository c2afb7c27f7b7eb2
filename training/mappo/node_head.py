"""The node head's scores of the allowed nodes, forward and backward compiled, a chunk of pairs at a time.

The waypoint actor's node head (:class:`training.mappo.networks.Actor`) scores node ``n`` of row ``r`` as

    logit[r, n] = w . relu(a[r] + W f[r, n]) + b,

with ``a[r]`` the trunk's projection of the row's observation (``node_obs``), ``f[r, n]`` the node's features
(:func:`training.pretrained.node_features`), ``W`` the ``node_feat`` weights and ``w``, ``b`` the ``node_out``
layer. :func:`node_scores` gives the logits themselves: the rollout samples its nodes from them (no gradient),
and behaviour cloning (:mod:`training.imitation`) trains on them. Written with torch, a few thousand rows with
some 250 allowed nodes each make several tensors of (rows x nodes x hidden) floats (the gathered features, the
pre-activations, their gradients): memory traffic, not arithmetic, bounds it. Here the same arithmetic runs a
chunk of :data:`CHUNK` pairs at a time: the chunk's features gathered into one block (compiled), ``W f`` of the
whole block as one torch matrix product (on torch's threads: one in the training scripts, so a run's numbers do
not depend on the number of cores), the rest pair by pair (compiled); the backward pass recomputes the products
instead of storing them. The PPO update needs only each row's log-probability and entropy, which
:mod:`training.mappo.node_categorical` computes without the logits.

The features stay where they are, ``(samples, L, F)``; each row names its sample (``sample_of``), so rows read
them without copying.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["check_head", "node_scores"]


#: Pairs per chunk: their features are gathered into one (CHUNK, F) block, and W f of them all is one matrix
#: product (a few hundred kB of float32: the block, its products and their gradients stay in cache).
CHUNK = 2048


@numba.njit(cache=True, nogil=True)
def _gather(feats, sample_of, rows, nodes, start, m, block):
    """``block[i]`` = the features of pair ``start + i``, for ``i < m``."""
    for i in range(m):
        p = start + i
        block[i] = feats[sample_of[rows[p]], nodes[p]]


@numba.njit(cache=True, nogil=True)
def _hidden(z, a, rows, start):
    """``z[i]`` = relu(``z[i]`` + ``a[rows[start + i]]``): the hidden units of the chunk's pairs, in place."""
    zero = np.float32(0.0)
    for i in range(z.shape[0]):
        r = rows[start + i]
        for j in range(z.shape[1]):
            z[i, j] = max(z[i, j] + a[r, j], zero)


@numba.njit(cache=True, nogil=True)
def _hidden_grad(z, a, rows, start, grad, w, dz, da, dw):
    """From the chunk's products ``z`` = W f: ``dz`` (the gradient at the pre-activations), added up into ``da``
    per row, and ``dw`` (float32, the chunk's sum)."""
    zero = np.float32(0.0)
    for j in range(z.shape[1]):
        dw[j] = 0.0
    for i in range(z.shape[0]):
        p = start + i
        r = rows[p]
        g = grad[p]
        for j in range(z.shape[1]):
            pre = z[i, j] + a[r, j]
            on = pre > 0.0
            d = g * w[j] if on else zero
            dz[i, j] = d
            da[r, j] += d
            dw[j] += g * pre if on else zero


def _forward(a, feats, sample_of, rows, nodes, weight, w, b) -> np.ndarray:
    """The scores of the pairs ``(rows[p], nodes[p])`` (module docstring): a chunk at a time, its ``W f`` one torch
    matrix product (on torch's threads, one in the training scripts)."""
    out = np.empty(len(rows), np.float32)
    block = np.empty((CHUNK, feats.shape[2]), np.float32)
    wt = weight.t()
    for start in range(0, len(rows), CHUNK):
        m = min(CHUNK, len(rows) - start)
        _gather(feats, sample_of, rows, nodes, start, m, block)
        z = torch.mm(torch.from_numpy(block[:m]), wt)
        _hidden(z.numpy(), a, rows, start)
        out[start:start + m] = torch.mv(z, w).numpy() + b
    return out


def _backward(a, feats, sample_of, rows, nodes, weight, w, grad):
    """The gradients of ``sum_p grad[p] * out[p]`` with respect to ``a``, ``W`` and ``w``. The products ``W f`` are
    recomputed, not stored; a chunk's parameter gradients add up in float32 (``W``'s as one matrix product), the
    totals over chunks in float64."""
    n_feat, hidden = feats.shape[2], weight.shape[0]
    block = np.empty((CHUNK, n_feat), np.float32)
    dz = np.empty((CHUNK, hidden), np.float32)
    chunk_dw = np.empty(hidden, np.float32)
    da = np.zeros(a.shape, np.float32)
    dweight, dw = np.zeros((hidden, n_feat)), np.zeros(hidden)
    wt, w_np = weight.t(), w.numpy()
    for start in range(0, len(rows), CHUNK):
        m = min(CHUNK, len(rows) - start)
        _gather(feats, sample_of, rows, nodes, start, m, block)
        z = torch.mm(torch.from_numpy(block[:m]), wt).numpy()
        _hidden_grad(z, a, rows, start, grad, w_np, dz, da, chunk_dw)
        dweight += torch.mm(torch.from_numpy(dz[:m]).t(), torch.from_numpy(block[:m])).numpy()   # (H, F)
        dw += chunk_dw
    return da, dweight, dw


class _NodeScores(torch.autograd.Function):
    """:func:`node_scores` with its gradient (the features get none: they are inputs, not parameters)."""

    @staticmethod
    def forward(ctx, a, weight, w, b, feats, sample_of, rows, nodes):
        weight, w = weight.detach().contiguous(), w.detach().reshape(-1).contiguous()
        out = _forward(a.detach().numpy(), feats, sample_of, rows, nodes, weight, w,
                       np.float32(b.detach().reshape(-1)[0].item()))
        ctx.save_for_backward(a, weight, w, b)
        ctx.inputs = (feats, sample_of, rows, nodes)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        a, weight, w, b = ctx.saved_tensors
        feats, sample_of, rows, nodes = ctx.inputs
        g = np.ascontiguousarray(grad.detach().numpy(), np.float32)
        da, dweight, dw = _backward(a.detach().numpy(), feats, sample_of, rows, nodes, weight, w, g)
        db = np.full(b.shape, g.sum(dtype=np.float64), np.float32)
        return (torch.from_numpy(da), torch.from_numpy(dweight.astype(np.float32)),
                torch.from_numpy(dw.astype(np.float32).reshape(1, -1)), torch.from_numpy(db),
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
    check_head("node_scores", a, node_feat, node_out)
    if feats.dtype != np.float32 or not feats.flags.c_contiguous or feats.ndim != 3:
        raise ValueError(f"node_scores: feats must be a C-contiguous (S, L, F) float32 array, got {feats.dtype} "
                         f"{feats.shape}")
    return _NodeScores.apply(a, node_feat.weight, node_out.weight, node_out.bias, feats, sample_of, rows, nodes)


def check_head(name: str, a, node_feat, node_out) -> None:
    """What the compiled node head needs of the layers: a bias-free ``node_feat``, float32 throughout."""
    if node_feat.bias is not None:
        raise ValueError(f"{name}: node_feat must have no bias (the node head's F -> H layer)")
    dtypes = {str(t.dtype) for t in (a, node_feat.weight, node_out.weight, node_out.bias)}
    if dtypes != {"torch.float32"}:
        raise ValueError(f"{name}: the node head runs in float32 (a and both layers' parameters), got "
                         f"{sorted(dtypes)}")
