"""The node head's compiled scores (training.mappo.node_head): the torch arithmetic they replace, values and
gradients."""

from __future__ import annotations

import numpy as np
import pytest
from _extras import needs

torch = needs("torch")

from training.mappo.networks import Actor  # noqa: E402
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
