"""The node head's compiled scores (training.mappo.node_head): the torch arithmetic they replace, values and
gradients."""

from __future__ import annotations

import numpy as np
import pytest
from _extras import needs

torch = needs("torch")

from training.mappo.networks import Actor, masked_categorical  # noqa: E402
from training.mappo.node_categorical import NodePairs, node_log_prob_entropy  # noqa: E402
from training.mappo.node_head import CHUNK, node_scores  # noqa: E402


def _reference(actor, obs, store, sample_of, mask):
    """The node head written with torch ops (every allowed pair's relu(a + W f), then the output layer)."""
    rows, nodes = mask.nonzero(as_tuple=True)
    f = store[torch.as_tensor(sample_of)][rows, nodes]
    z = torch.relu(actor.node_obs(actor.trunk(obs))[rows] + actor.node_feat(f))
    return torch.full(mask.shape, -1e8).index_put((rows, nodes), actor.node_out(z)[:, 0])


def _grads(actor, fn, weight):
    actor.zero_grad()
    logits = fn()
    (torch.where(weight != 0, logits, 0.0) * weight).sum().backward()
    return logits.detach(), {k: p.grad.clone() for k, p in actor.named_parameters()}


@pytest.mark.parametrize(("seed", "rows", "node_hidden"), [(0, 40, 32), (1, 40, 32), (2, 130, 6)])
def test_scores_and_gradients_are_the_torch_head(seed, rows, node_hidden):
    """Also with more pairs than a chunk (130 rows: some 3,000 pairs, rows cut between chunks) and a width that is
    not a power of two."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    n_nodes, n_feat, width = 57, 13, 21
    actor = Actor(width, n_nodes, head="node", hidden=16, node_hidden=node_hidden, n_feat=n_feat, log_std_init=-0.5)
    for p in actor.node_out.parameters():             # a trained-size output layer: every hidden unit matters
        torch.nn.init.normal_(p, std=0.5)
    obs = torch.randn(rows, width)
    store = torch.randn(3 * rows, n_nodes, n_feat)
    sample_of = rng.permutation(3 * rows)[:rows]      # rows read samples of a larger store, as a minibatch does
    mask = torch.from_numpy(rng.random((rows, n_nodes)) < 0.4)
    mask[3] = False                                   # a row with no allowed node
    assert rows < 100 or int(mask.sum()) > CHUNK      # the large case spans chunks
    weight = torch.randn(rows, n_nodes) * mask
    want, want_g = _grads(actor, lambda: _reference(actor, obs, store, sample_of, mask), weight)
    got, got_g = _grads(actor, lambda: actor.logits(obs, store, mask, sample_of), weight)
    np.testing.assert_array_equal(got[~mask].numpy(), -1e8)
    np.testing.assert_allclose(got[mask].numpy(), want[mask].numpy(), rtol=1e-5, atol=1e-5)
    for name, g in want_g.items():
        scale = float(g.abs().max()) + 1e-6
        np.testing.assert_allclose(got_g[name].numpy() / scale, g.numpy() / scale, atol=2e-5, err_msg=name)
    assert float(want_g["node_feat.weight"].abs().sum()) > 0       # the comparison is not of zeros


def test_the_dense_path_reads_the_rows_samples():
    torch.manual_seed(0)
    actor = Actor(5, 7, head="node", hidden=8, node_hidden=4, n_feat=3, log_std_init=-0.5)
    obs, store = torch.randn(4, 5), torch.randn(6, 7, 3)
    sample_of = np.array([5, 0, 2, 2])
    full = actor.logits(obs, store, torch.ones(4, 7, dtype=torch.bool), sample_of)
    dense = actor.logits(obs, store, None, sample_of)
    np.testing.assert_allclose(full.detach().numpy(), dense.detach().numpy(), rtol=1e-5, atol=1e-6)


def test_bad_inputs_are_refused_with_what_was_given():
    torch.manual_seed(0)
    actor = Actor(5, 7, head="node", hidden=8, node_hidden=6, n_feat=3, log_std_init=-0.5)
    one = np.zeros(1, np.int64)
    actor = Actor(5, 7, head="node", hidden=8, node_hidden=4, n_feat=3, log_std_init=-0.5)
    with pytest.raises(ValueError, match=r"runs in float32 .* got \['torch.float64'\]"):
        node_scores(torch.zeros(2, 4, dtype=torch.float64), actor.node_feat.double(), actor.node_out.double(),
                    np.zeros((2, 7, 3), np.float32), one, one, one)
    actor = Actor(5, 7, head="node", hidden=8, node_hidden=4, n_feat=3, log_std_init=-0.5)
    with pytest.raises(ValueError, match=r"float32 array, got float64 \(2, 7, 3\)"):
        node_scores(torch.zeros(2, 4), actor.node_feat, actor.node_out, np.zeros((2, 7, 3)), one, one, one)


@pytest.mark.parametrize(("seed", "rows", "node_hidden"), [(0, 40, 32), (1, 130, 6), (2, 25, 13)])
def test_fused_categorical_is_the_dense_one(seed, rows, node_hidden):
    """``node_log_prob_entropy`` against the masked categorical over the torch head's logits: log-probabilities,
    entropies and the gradients of a loss of both, with a row that allows no node, a row that allows one, and an
    action outside its row's mask."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    n_nodes, n_feat, width = 57, 13, 21
    actor = Actor(width, n_nodes, head="node", hidden=16, node_hidden=node_hidden, n_feat=n_feat, log_std_init=-0.5)
    for p in actor.node_out.parameters():
        torch.nn.init.normal_(p, std=0.5)
    obs = torch.randn(rows, width)
    store = torch.randn(3 * rows, n_nodes, n_feat)
    sample_of = rng.permutation(3 * rows)[:rows]
    mask = torch.from_numpy(rng.random((rows, n_nodes)) < 0.4)
    mask[3] = False
    mask[4] = False
    mask[4, 7] = True
    probs = np.where(mask.numpy(), 1.0, 0.0) + 1e-9
    actions = np.array([rng.choice(n_nodes, p=q / q.sum()) for q in probs])
    actions[5] = int(np.flatnonzero(~mask[5].numpy())[0])        # a node the row's mask leaves out
    sample_of[7], mask[7] = sample_of[6], mask[6]                 # two rows of one sample (other observations)
    g_lp, g_ent = torch.randn(rows), torch.randn(rows)

    def run(fn):
        actor.zero_grad()
        logp, ent = fn()
        ((logp * g_lp).sum() + (ent * g_ent).sum()).backward()
        return logp.detach().numpy(), ent.detach().numpy(), {k: p.grad.clone() for k, p in actor.named_parameters()}

    def dense():
        d = masked_categorical(_reference(actor, obs, store, sample_of, mask), mask)
        return d.log_prob(torch.from_numpy(actions)), d.entropy()

    full_mask = np.zeros((3 * rows, n_nodes), bool)          # the store's samples, each under its row's mask
    full_mask[sample_of] = mask.numpy()
    pairs = NodePairs(store.numpy(), full_mask)

    def fused():
        return actor.log_prob_entropy(obs, actions, pairs=pairs, sample_of=sample_of)

    want_lp, want_ent, want_g = run(dense)
    got_lp, got_ent, got_g = run(fused)
    keep = np.ones(rows, bool)
    keep[[3, 5]] = False                # float32 holds -1e8 - lse to 8 units (torch's row 3 gives -8, not -4.04)
    np.testing.assert_allclose(got_lp[keep], want_lp[keep], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(got_lp[5], want_lp[5], rtol=1e-6)
    assert got_lp[3] == pytest.approx(-np.log(n_nodes), rel=1e-6)      # uniform over every node, as it should be
    np.testing.assert_allclose(got_ent[keep], want_ent[keep], rtol=1e-5, atol=1e-5)
    assert got_ent[3] == pytest.approx(np.log(n_nodes), rel=1e-6) and got_ent[4] == pytest.approx(0.0, abs=1e-6)
    for name, g in want_g.items():
        scale = float(g.abs().max()) + 1e-6
        np.testing.assert_allclose(got_g[name].numpy() / scale, g.numpy() / scale, atol=2e-5, err_msg=name)
    # The bias's gradient is 0 but for row 5, whose action is outside its mask (log pi = MASKED_LOGIT - lse).
    assert float(want_g["node_feat.weight"].abs().sum()) > 0 and float(want_g["node_out.bias"].abs().sum()) > 0


def test_fused_categorical_refuses_mismatched_shapes():
    actor = Actor(5, 7, head="node", hidden=8, node_hidden=4, n_feat=3, log_std_init=-0.5)
    pairs = NodePairs(np.zeros((2, 7, 3), np.float32), np.ones((2, 7), bool))
    with pytest.raises(ValueError, match=r"rows and actions must be \(2,\) .* got \(3,\), \(2,\) and 3"):
        node_log_prob_entropy(torch.zeros(2, 4), actor.node_feat, actor.node_out, pairs, np.arange(3),
                              np.zeros(2, np.int64))
    with pytest.raises(ValueError, match=r"rows must be samples in \[0, 2\), got 0 \.\. 2"):
        node_log_prob_entropy(torch.zeros(2, 4), actor.node_feat, actor.node_out, pairs, np.array([0, 2]),
                              np.zeros(2, np.int64))
    with pytest.raises(ValueError, match=r"actions must be nodes in \[0, 7\), got -1 \.\. 0"):
        node_log_prob_entropy(torch.zeros(2, 4), actor.node_feat, actor.node_out, pairs, np.arange(2),
                              np.array([0, -1]))
    with pytest.raises(ValueError, match=r"feats must be \(S, L, F\) and mask \(S, L\), got \(2, 7, 3\) and \(2, 6\)"):
        NodePairs(np.zeros((2, 7, 3), np.float32), np.ones((2, 6), bool))
