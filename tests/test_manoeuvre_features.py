"""The node head's manoeuvre features (``node_manoeuvre``): the manoeuvre to each node, read from the observation."""

import json

import numpy as np
import pytest
from _extras import needs
from hypothesis import given, settings
from hypothesis import strategies as st

import covert_env
from covert_env.envs.observation import field_slices
from covert_env.geometry.dynamics import solve_manoeuvre
from training.pretrained import (
    N_MANOEUVRE_FEATURES,
    N_MAP_FEATURES,
    N_OWN_FEATURES,
    load_learned,
    manoeuvre_features,
    n_node_features,
    node_features,
)


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-120, 40), y=st.floats(-80, 80), theta=st.floats(-7, 7), seed=st.integers(0, 2**16))
def test_manoeuvre_features_are_the_solvers_manoeuvre(x, y, theta, seed):
    """Within one slot's reach the features are the solver's (feasible, length, arrival heading); beyond it, no
    manoeuvre, the straight line's length and heading; the relative heading is the heading minus the bearing."""
    nodes = np.random.default_rng(seed).uniform(-110, 20, (30, 2))
    f = manoeuvre_features(np.array([x, y]), np.array(theta), nodes, v_max=50.0, w_max=3.0, delta=1.0)
    assert f.shape == (30, N_MANOEUVRE_FEATURES) and f.dtype == np.float32
    m = solve_manoeuvre(np.array([x, y]), theta, nodes, v_max=50.0, w_max=3.0, delta=1.0)
    np.testing.assert_array_equal(f[:, 0], m.feasible.astype(np.float32))
    rel = nodes - [x, y]
    length = np.where(m.feasible, m.length, np.hypot(rel[:, 0], rel[:, 1]))
    head = np.where(m.feasible, m.heading_after, np.arctan2(rel[:, 1], rel[:, 0]))
    np.testing.assert_allclose(f[:, 1], length / 50.0, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(f[:, 2:4], np.stack([np.cos(head), np.sin(head)], 1), atol=1e-5)
    bearing = np.arctan2(nodes[:, 1], nodes[:, 0])
    np.testing.assert_allclose(f[:, 4:6], np.stack([np.cos(head - bearing), np.sin(head - bearing)], 1), atol=1e-5)
    assert not f[np.hypot(rel[:, 0], rel[:, 1]) > 50.0, 0].any()


def test_node_features_with_w_max_append_the_manoeuvre_and_keep_the_rest():
    lat = np.random.default_rng(0).uniform(-100, 30, (40, 2))
    obs = np.random.default_rng(1).normal(0, 0.5, (5, 60)).astype(np.float32)
    plain = node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0)
    with_m = node_features(obs, lat, 3, r2=100.0, v_max=50.0, delta=1.0, d_safe1=5.0, w_max=3.0)
    assert with_m.shape == (5, 40, n_node_features(3, {"node_manoeuvre": True}))
    assert n_node_features(3, {"node_map": True, "node_manoeuvre": True}) == (N_OWN_FEATURES + 2 + N_MAP_FEATURES
                                                                              + N_MANOEUVRE_FEATURES)
    np.testing.assert_array_equal(with_m[..., :-N_MANOEUVRE_FEATURES], plain)


def test_the_arrival_heading_is_the_one_the_env_flies():
    """Flown by the env to a node the mask allows, a UAV arrives with the heading the features predicted (in the
    target's frame at the next slot, read back from the next observation), and the feasible flag agrees with the
    kinematic mask: on the paper scene the median error is under 3 degrees and the flag agrees on 95 % of nodes."""
    env = covert_env.parallel_env(task="paper-3uav", action_mode="waypoint", mask_mode="kinematic")
    obs, _ = env.reset(seed=3)
    c, rng = env.config, np.random.default_rng(0)
    heading = field_slices(3, env.map_size)["heading"]          # cos, sin of own heading minus the target's
    errors, agree = [], []
    for _ in range(20):
        o = np.stack([obs[a] for a in env.agents])
        f = node_features(o, env.lattice, 3, r2=c.r2, v_max=c.v_max, delta=c.delta, d_safe1=c.d_safe1,
                          w_max=c.w_max)[..., -N_MANOEUVRE_FEATURES:]
        masks = np.stack([env.action_mask(a) for a in env.agents]).astype(bool)
        acts = {a: int(rng.choice(np.nonzero(masks[i])[0])) for i, a in enumerate(env.agents)}
        for i in range(3):
            if not masks[i].all():
                agree.append(((f[i, :, 0] > 0.5) == masks[i]).mean())
        obs, *_ = env.step(acts)
        for i, a in enumerate(env.agents):
            h = obs[a][heading]
            want = f[i, acts[a], 2:4]
            errors.append(abs(np.angle(complex(*h) / complex(*want))))
    env.close()
    assert np.degrees(np.median(errors)) < 3.0 and np.mean(agree) > 0.95


def test_card_and_loader_know_node_manoeuvre(tmp_path):
    """``--node-manoeuvre`` trains an actor whose card records it; the loader checks the weights against it and the
    field's type; --init-actor from such a run needs the flag; the flag needs the node head."""
    for module in ("torch", "tensorboard"):
        needs(module)
    from training import mappo

    run = mappo.main(["--num-envs", "2", "--num-steps", "8", "--num-minibatches", "2", "--update-epochs", "1",
                      "--hidden", "16", "--node-hidden", "8", "--max-cycles", "5", "--progress-bar", "false",
                      "--action-mode", "waypoint", "--node-manoeuvre", "--mask-mode", "kinematic",
                      "--total-timesteps", "16", "--runs-dir", str(tmp_path), "--run-name", "m"])
    card = json.loads((run / "model.json").read_text())
    assert card["actor"]["node_manoeuvre"] is True
    assert card["actor"]["n_feat"] == N_OWN_FEATURES + 2 + N_MANOEUVRE_FEATURES
    assert load_learned(run).actor.spec["node_manoeuvre"] is True
    with pytest.raises(ValueError, match=r"actor.node_manoeuvre = True, this run's --node-manoeuvre is False"):
        mappo.check_args(mappo.Args(action_mode="waypoint", hidden=16, node_hidden=8, mask_mode="kinematic",
                                    init_actor=str(run)))
    with pytest.raises(ValueError, match=r"--node-manoeuvre needs --action-mode waypoint and --head node"):
        mappo.check_args(mappo.Args(action_mode="waypoint", node_manoeuvre=True, head="flat"))
    for value, pattern in (("yes", r"actor.node_manoeuvre must be true or false, got 'yes'"),
                           (False, r"node_feat.weight has shape \(8, 17\), expected \(8, 11\) \(11 node features "
                                   r"for 3 UAVs, node_obs")):
        card["actor"]["node_manoeuvre"] = value
        (run / "model.json").write_text(json.dumps(card))
        with pytest.raises(ValueError, match=pattern):
            load_learned(run)
