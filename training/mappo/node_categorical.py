"""The PPO update's view of the node head: the masked categorical's log-probability of each row's action and its
entropy, fused with the head's scores, in two compiled passes (forward and backward) over the allowed pairs.

The node head (:mod:`training.mappo.node_head`) scores node ``n`` of row ``r`` as
``logit[r, n] = w . relu(a[r] + W f[r, n]) + b``; the actor's distribution is the categorical over those logits,
the nodes outside the row's mask at MASKED_LOGIT. What an update needs of it per row is two numbers:
``log pi(action)`` and the entropy. Written with torch, a minibatch of a few thousand rows makes (rows x 577)
logits, masks, probabilities and their gradients, and (pairs x hidden) pre-activations: memory traffic, not
arithmetic, bounds it. Here:

* :class:`NodePairs` lays the allowed pairs' features out once per update, feature-major (``ft[k, p]``), each
  sample's pairs next to each other: a minibatch row reads its pairs' features as F contiguous runs.
* The forward pass computes every pair's logit a hidden unit at a time over the row's pairs (loops that
  vectorise), then the row's log-normaliser, ``log pi(action)`` and entropy in float64. The pairs' logits are
  kept for the backward pass; the pre-activations are recomputed there, not stored.
* The masked nodes enter the normaliser and the entropy as the dense categorical's do: their probability
  ``exp(MASKED_LOGIT - lse)`` vanishes unless a row allows no node, and such a row is uniform over every node
  (torch's float32 categorical rounds -1e8 - lse there and gives a log-probability of -8, not -log L; the env's
  masks never leave a row empty).

The compiled loops may reassociate sums (``fastmath`` without ``nnan``/``ninf``), so the last bits of a
gradient depend on the CPU's vector width: like torch's own matrix products, the update is reproducible on one
machine, not bit for bit across machines. Nothing the env or a shipped card computes goes through here.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from training.mappo.node_head import check_head
from training.pretrained import MASKED_LOGIT

__all__ = ["NodePairs", "node_log_prob_entropy"]

#: Sums may be reassociated and products contracted; NaN and inf keep their meaning.
_FAST = {"reassoc", "contract", "nsz"}


#: Each sample's pairs are padded to a multiple of this many (features 0, node -1): the compiled loops then run
#: whole vectors, with no scalar remainder (the remainder cost a quarter of the time at some 250 pairs a row).
PAD = 16


@numba.njit(cache=True, nogil=True)
def _lay_out(feats, mask):
    """``(start, count, nodes, ft)``: sample ``q``'s allowed nodes are ``nodes[start[q]:start[q] + count[q]]``
    (ascending), their features ``ft[:, start[q]:start[q] + count[q]]``; its run is padded to a multiple of PAD."""
    samples, n_nodes, n_feat = feats.shape
    start = np.zeros(samples + 1, np.int64)
    count = np.zeros(samples, np.int64)
    for q in range(samples):
        c = 0
        for j in range(n_nodes):
            c += mask[q, j]
        count[q] = c
        start[q + 1] = start[q] + (c + PAD - 1) // PAD * PAD
    nodes = np.full(start[samples], -1, np.int64)
    ft = np.zeros((n_feat, start[samples]), np.float32)
    for q in range(samples):
        p = start[q]
        for j in range(n_nodes):
            if mask[q, j]:
                nodes[p] = j
                for k in range(n_feat):
                    ft[k, p] = feats[q, j, k]
                p += 1
    return start, count, nodes, ft


class NodePairs:
    """The allowed (sample, node) pairs of a rollout and their features, laid out for :func:`node_log_prob_entropy`.

    Args:
        feats: ``(S, L, F)`` float32, the node features of every sample (the rollout's store).
        mask: ``(S, L)`` bool, the nodes each sample's categorical allows.
    """

    def __init__(self, feats: np.ndarray, mask: np.ndarray):
        feats = np.ascontiguousarray(feats, np.float32)
        mask = np.ascontiguousarray(mask, bool)
        if feats.ndim != 3 or mask.shape != feats.shape[:2]:
            raise ValueError(f"NodePairs: feats must be (S, L, F) and mask (S, L), got {feats.shape} and {mask.shape}")
        self.n_nodes = feats.shape[1]
        self.start, self.count, self.nodes, self.ft = _lay_out(feats, mask)


@numba.njit(cache=True, nogil=True, fastmath=_FAST)
def _row_pre(a, wt, ft, r, j, p0, n, acc):
    """``acc[:n]`` = the pre-activations of hidden unit ``j`` over row ``r``'s pairs ``p0 .. p0 + n``."""
    aj = a[r, j]
    for i in range(n):
        acc[i] = aj
    for k in range(wt.shape[0]):
        c = wt[k, j]
        fk = ft[k, p0:p0 + n]           # indices from range() only: no wraparound test, so the loop vectorises
        for i in range(n):
            acc[i] += c * fk[i]


@numba.njit(cache=True, nogil=True, fastmath=_FAST)
def _forward(a, wt, w, b, ft, start, count, nodes, rows, act, n_nodes, masked_logit):
    """Per row its log-normaliser, the action's log-probability and the entropy (float64), and the rows' pairs'
    logits (row ``r``'s at ``logits[at[r]:at[r + 1]]``, this call's own: the backward pass reads them)."""
    rows_n, hidden = a.shape
    most = 0
    at = np.zeros(rows_n + 1, np.int64)            # row r's logits are logits[at[r]:at[r] + count[rows[r]]]
    for r in range(rows_n):
        most = max(most, start[rows[r] + 1] - start[rows[r]])
        at[r + 1] = at[r] + count[rows[r]]
    logits = np.empty(at[rows_n], np.float32)
    acc = np.empty(most, np.float32)
    out = np.empty(most, np.float32)
    lse, logp, ent = np.empty(rows_n), np.empty(rows_n), np.empty(rows_n)
    for r in range(rows_n):
        p0, n = start[rows[r]], count[rows[r]]
        padded = start[rows[r] + 1] - p0
        for i in range(padded):
            out[i] = b
        for j in range(hidden):
            _row_pre(a, wt, ft, r, j, p0, padded, acc)
            wj = w[j]
            for i in range(padded):
                out[i] += wj * max(acc[i], np.float32(0.0))
        n_masked = n_nodes - n
        top = masked_logit if n_masked > 0 else -np.inf
        for i in range(n):
            logits[at[r] + i] = out[i]
            top = max(top, np.float64(out[i]))
        z = n_masked * np.exp(masked_logit - top)
        for i in range(n):
            z += np.exp(out[i] - top)
        lse[r] = top + np.log(z)
        h = -n_masked * np.exp(masked_logit - lse[r]) * (masked_logit - lse[r]) if n_masked > 0 else 0.0
        chosen = masked_logit
        for i in range(n):
            d = out[i] - lse[r]
            h -= np.exp(d) * d
            if nodes[p0 + i] == act[r]:
                chosen = np.float64(out[i])
        logp[r] = chosen - lse[r]
        ent[r] = h
    return lse, logp, ent, logits, at


@numba.njit(cache=True, nogil=True, fastmath=_FAST)
def _backward(a, wt, w, ft, start, count, nodes, rows, act, logits, at, lse, ent, g_logp, g_ent):
    """The gradients of ``sum_r g_logp[r] logp[r] + g_ent[r] ent[r]`` in ``a``, ``W`` (as ``wt``), ``w`` and ``b``:
    float32 within a row, float64 over rows."""
    rows_n, hidden = a.shape
    n_feat = wt.shape[0]
    most = 0
    for r in range(rows_n):
        most = max(most, start[rows[r] + 1] - start[rows[r]])
    acc, ds, dz = np.empty(most, np.float32), np.empty(most, np.float32), np.empty(most, np.float32)
    da = np.zeros(a.shape, np.float32)
    dwt, dw, db = np.zeros(wt.shape), np.zeros(hidden), 0.0
    for r in range(rows_n):
        p0, n = start[rows[r]], count[rows[r]]
        padded = start[rows[r] + 1] - p0
        for i in range(n, padded):
            ds[i] = 0.0
        for i in range(n):
            # d log pi(act) / d s = [node = act] - pi; d H / d s = -pi (log pi + H)
            d = logits[at[r] + i] - lse[r]
            pi = np.exp(d)
            g = -g_logp[r] * pi - g_ent[r] * pi * (d + ent[r])
            if nodes[p0 + i] == act[r]:
                g += g_logp[r]
            ds[i] = g
            db += g
        for j in range(hidden):
            _row_pre(a, wt, ft, r, j, p0, padded, acc)
            wj = w[j]
            sum_dz, sum_dw = np.float32(0.0), np.float32(0.0)
            for i in range(padded):
                on = acc[i] > 0.0
                dz[i] = ds[i] * wj if on else np.float32(0.0)
                sum_dz += dz[i]
                sum_dw += ds[i] * acc[i] if on else np.float32(0.0)
            da[r, j] = sum_dz
            dw[j] += sum_dw
            for k in range(n_feat):
                fk = ft[k, p0:p0 + padded]
                t = np.float32(0.0)
                for i in range(padded):
                    t += dz[i] * fk[i]
                dwt[k, j] += t
    return da, dwt, dw, db


class _NodeCategorical(torch.autograd.Function):
    """:func:`node_log_prob_entropy` with its gradient."""

    @staticmethod
    def forward(ctx, a, weight, w, b, pairs, rows, act):
        a_np = a.detach().numpy()
        wt = np.ascontiguousarray(weight.detach().numpy().T)
        w_np = np.ascontiguousarray(w.detach().numpy().reshape(-1))
        lse, logp, ent, logits, at = _forward(a_np, wt, w_np, np.float32(b.detach().reshape(-1)[0].item()),
                                              pairs.ft, pairs.start, pairs.count, pairs.nodes, rows, act,
                                              pairs.n_nodes, float(MASKED_LOGIT))
        # Numpy views of a and w, not saved tensors: nothing changes them in place between the passes of an update.
        ctx.kept = (a_np, wt, w_np, pairs, rows, act, lse, ent, logits, at)
        ctx.shapes = (weight.shape, w.shape, b.shape)
        return torch.from_numpy(logp.astype(np.float32)), torch.from_numpy(ent.astype(np.float32))

    @staticmethod
    def backward(ctx, g_logp, g_ent):
        a_np, wt, w_np, pairs, rows, act, lse, ent, logits, at = ctx.kept
        zero = np.zeros(len(a_np))
        g_lp = zero if g_logp is None else g_logp.detach().numpy().astype(np.float64)
        g_h = zero if g_ent is None else g_ent.detach().numpy().astype(np.float64)
        da, dwt, dw, db = _backward(a_np, wt, w_np, pairs.ft, pairs.start, pairs.count, pairs.nodes, rows, act,
                                    logits, at, lse, ent, g_lp, g_h)
        _, w_shape, b_shape = ctx.shapes
        return (torch.from_numpy(da), torch.from_numpy(np.ascontiguousarray(dwt.T, np.float32)),
                torch.from_numpy(dw.astype(np.float32).reshape(w_shape)),
                torch.full(b_shape, db, dtype=torch.float32), None, None, None)


def node_log_prob_entropy(a: torch.Tensor, node_feat: torch.nn.Linear, node_out: torch.nn.Linear, pairs: NodePairs,
                          rows: np.ndarray, actions: np.ndarray):
    """The masked categorical over the node head's scores, for some samples' actions: ``(log_prob, entropy)``,
    each ``(R,)`` float32 and differentiable in ``a`` and the two layers' parameters. The numbers of
    :func:`~training.mappo.networks.masked_categorical` over :func:`~training.mappo.node_head.node_scores`' logits,
    to float32 rounding (module docstring).

    Args:
        a: the rows' projections ``node_obs(trunk(obs))``, ``(R, H)`` float32.
        node_feat: the bias-free ``F -> H`` layer of the node features.
        node_out: the ``H -> 1`` output layer.
        pairs: the samples' allowed pairs and features.
        rows: ``(R,)`` int, the sample of ``pairs`` each row is.
        actions: ``(R,)`` int, each row's node (one outside the row's mask has the logit MASKED_LOGIT).
    """
    check_head("node_log_prob_entropy", a, node_feat, node_out)
    rows = np.ascontiguousarray(rows, np.int64)
    actions = np.ascontiguousarray(actions, np.int64)
    if rows.shape != (len(a),) or actions.shape != (len(a),) or node_feat.weight.shape[1] != len(pairs.ft):
        raise ValueError(f"node_log_prob_entropy: rows and actions must be ({len(a)},) and the pairs' features "
                         f"{node_feat.weight.shape[1]} wide, got {rows.shape}, {actions.shape} and {len(pairs.ft)}")
    if a.shape[1] != node_feat.weight.shape[0]:
        raise ValueError(f"node_log_prob_entropy: a is {a.shape[1]} wide, node_feat has {node_feat.weight.shape[0]} "
                         "outputs")
    samples = len(pairs.count)
    if len(rows) and (rows.min() < 0 or rows.max() >= samples):
        raise ValueError(f"node_log_prob_entropy: rows must be samples in [0, {samples}), got {rows.min()} .. "
                         f"{rows.max()}")
    if len(actions) and (actions.min() < 0 or actions.max() >= pairs.n_nodes):
        raise ValueError(f"node_log_prob_entropy: actions must be nodes in [0, {pairs.n_nodes}), got "
                         f"{actions.min()} .. {actions.max()}")
    return _NodeCategorical.apply(a, node_feat.weight, node_out.weight, node_out.bias, pairs, rows, actions)
