"""Vector envs of several tasks (covert_env.envs.task_mix; training.task_mix) and the node head's map features
(training.pretrained.map_at / node_features with map_offsets)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import covert_env
from training.pretrained import map_at, node_features
from training.shield import end_poses
from training.task_mix import make_training_env


def _grid(size, lo=(-120.0, -60.0), hi=(40.0, 60.0)):
    """Cell centres of an S x S map as the env lays them out: row-major, +y on top."""
    gx = lo[0] + (np.arange(size) + 0.5) * (hi[0] - lo[0]) / size
    gy = lo[1] + (np.arange(size) + 0.5) * (hi[1] - lo[1]) / size
    return np.array([(x, y) for y in gy[::-1] for x in gx])


@settings(max_examples=60, deadline=None)
@given(size=st.integers(2, 12), seed=st.integers(0, 2**31 - 1))
def test_map_at_reads_the_nearest_cell_and_zero_outside(size, seed):
    """map_at equals a brute-force nearest-cell lookup for points inside the map, and is 0 beyond its edge."""
    rng = np.random.default_rng(seed)
    cells = _grid(size)
    grid = rng.integers(0, 2, (3, size * size)).astype(np.float32)
    half = np.array([(cells[1, 0] - cells[0, 0]) / 2, (cells[0, 1] - cells[size, 1]) / 2])
    lo, hi = cells.min(0) - half, cells.max(0) + half
    pts = rng.uniform(lo - 30, hi + 30, (3, 50, 2))
    got = map_at(grid, cells, pts)
    nearest = np.argmin(((pts[:, :, None] - cells) ** 2).sum(-1), axis=-1)
    inside = np.all((pts > lo + 1e-9) & (pts < hi - 1e-9), axis=-1)
    want = np.take_along_axis(grid, nearest, axis=1)
    # Away from the cell borders (ties), nearest-cell and map_at agree; outside the map it is 0.
    d = np.sort(((pts[:, :, None] - cells) ** 2).sum(-1), axis=-1)
    clear = d[..., 1] - d[..., 0] > 1e-6
    np.testing.assert_array_equal(got[inside & clear], want[inside & clear])
    outside = np.any((pts < lo - 1e-9) | (pts > hi + 1e-9), axis=-1)
    assert (got[outside] == 0).all()
    np.testing.assert_array_equal(map_at(grid, cells, cells[None]), grid)          # each centre reads its cell


def test_map_feature_agrees_with_the_visible_nodes():
    """The map feature at a node is the observation's map_next there: with a 16 x 16 map it agrees with the env's
    visible-zone nodes (the visible mask) on nearly every reachable node of a shadowed family, far above what a
    wrong frame would give (on downtown, 18 % of the reachable nodes are shadowed or outside the eroded zone)."""
    kw = dict(num_envs=8, n_uavs=3, action_mode="waypoint", map_size=16, task="downtown-3uav")
    vis = covert_env.vector_env(mask_mode="visible", **kw)
    kin = covert_env.vector_env(mask_mode="kinematic", **kw)
    vis.reset(seed=1)
    obs, _ = kin.reset(seed=1)
    rng = np.random.default_rng(0)
    c = kin.config
    agree, hidden = [], []
    for _ in range(10):
        mv, mk = vis.action_masks().astype(bool), kin.action_masks().astype(bool)
        f = node_features(obs.reshape(-1, obs.shape[-1]), kin.lattice, 3, r2=c.r2, v_max=c.v_max, delta=c.delta,
                          d_safe1=c.d_safe1, map_offsets=kin.map_offsets).reshape(*mk.shape, -1)[..., -2]
        sel = mk & ~mk.all(-1, keepdims=True)
        agree.append(((f > 0.5) == mv)[sel].mean())
        hidden.append((~mv)[sel].mean())
        act = np.array([[rng.choice(np.flatnonzero(mv[b, u])) for u in range(3)] for b in range(8)])
        vis.step(act)
        obs, *_ = kin.step(act)
    assert np.mean(hidden) > 0.1
    assert np.mean(agree) > 0.9


def _own_nodes(mix, solo):
    """(L_mix,) each node of the mix's lattice as an index of ``solo``'s (-1: it has none there)."""
    at = np.abs(solo.lattice[:, None] - mix.lattice[None]).sum(-1).argmin(1)
    inv = np.full(len(mix.lattice), -1)
    inv[at] = np.arange(len(at))
    return at, inv


@pytest.mark.parametrize(("tasks", "mask_mode"), [(["paper-3uav", "towers-3uav"], "visible"),
                                                  (["sparse-3uav", "downtown-3uav-deviating"], "kinematic"),
                                                  (["paper-3uav-deviating", "winding-3uav"], "visible")])
def test_mix_rows_are_the_tasks_envs(tasks, mask_mode):
    """A vector env of two tasks steps exactly as the two tasks' envs would, each on its rows (seed + i per task),
    a deviating task's nodes at their places in the larger lattice; through an automatic reset too."""
    kw = dict(action_mode="waypoint", max_cycles=3, mask_mode=mask_mode)
    mix = covert_env.vector_env(num_envs=4, task=tasks, **kw)
    solo = [covert_env.vector_env(num_envs=2, task=t, **kw) for t in tasks]
    assert mix.task == tuple(tasks) and mix.family is None
    maps = [_own_nodes(mix, e) for e in solo]
    obs, _ = mix.reset(seed=5)
    ref = [e.reset(seed=5 + i)[0] for i, e in enumerate(solo)]
    np.testing.assert_array_equal(obs, np.concatenate(ref))
    avail = mix.available_nodes
    for i, (at, _) in enumerate(maps):
        assert avail[2 * i:2 * i + 2].sum() == 2 * len(at) and avail[2 * i:2 * i + 2, at].all()
    rng = np.random.default_rng(0)
    for step in range(4):                                                  # the route's 3 slots, then one more
        m = mix.action_masks().astype(bool)
        for i, ((at, _), e) in enumerate(zip(maps, solo, strict=True)):
            np.testing.assert_array_equal(m[2 * i:2 * i + 2][..., at], e.action_masks().astype(bool))
            assert m[2 * i:2 * i + 2].sum() == e.action_masks().sum()             # nothing at nodes it lacks
        act = np.array([[rng.choice(np.flatnonzero(m[b, u])) for u in range(3)] for b in range(4)])
        own = [inv[a] for (_, inv), a in zip(maps, np.split(act, 2), strict=True)]
        np.testing.assert_array_equal(mix.waypoint_paths(act[..., None]),
                                      np.concatenate([e.waypoint_paths(a[..., None]) for e, a in zip(solo, own,
                                                                                                   strict=True)]))
        ends = end_poses(mix.waypoint_paths(act[..., None]))
        np.testing.assert_array_equal(mix.onward_reach(*ends),
                                      np.concatenate([e.onward_reach(x, t) for e, x, t in
                                                      zip(solo, np.split(ends[0], 2), np.split(ends[1], 2),
                                                          strict=True)]))
        got = mix.step(act)
        want = [e.step(a) for e, a in zip(solo, own, strict=True)]
        for j in range(4):
            np.testing.assert_array_equal(got[j], np.concatenate([w[j] for w in want]))
        for key in ("cost_los_path", "infeasible", "in_zone"):
            np.testing.assert_array_equal(got[4][key], np.concatenate([w[4][key] for w in want]))
        np.testing.assert_array_equal(mix.state(), np.concatenate([e.state() for e in solo]))
        assert ("final_info" in got[4]) == (step == 2)
        if step == 2:
            np.testing.assert_array_equal(got[4]["final_state"],
                                          np.concatenate([w[4]["final_state"] for w in want]))
            np.testing.assert_array_equal(got[4]["final_info"]["reward_zone"],
                                          np.concatenate([w[4]["final_info"]["reward_zone"] for w in want]))
    for i in (0, 3):                                                       # each copy's scene is its task's
        assert mix.scene(i).config == solo[i // 2].scene(i % 2).config
        assert mix.copy_view(i).config == solo[i // 2].copy_view(i % 2).config == solo[i // 2].config
        np.testing.assert_array_equal(mix.scenario(i).uav_xy, solo[i // 2].scenario(i % 2).uav_xy)


def test_mix_flies_a_node_its_task_lacks_as_infeasible():
    """A deviating copy sent to a node only the nominal lattice has flies there, flagged infeasible (an action
    outside the mask), as any masked-out node is flown."""
    mix = covert_env.vector_env(num_envs=2, task=["paper-3uav", "paper-3uav-deviating"], action_mode="waypoint",
                                mask_mode="kinematic")
    mix.reset(seed=3)
    assert mix.lattice.shape == (577, 2)
    missing = np.flatnonzero(~mix.available_nodes[1])
    assert len(missing) == 577 - 483
    m = mix.action_masks().astype(bool)
    act = np.array([[int(np.flatnonzero(m[b, u])[0]) for u in range(3)] for b in range(2)])
    act[1, 0] = missing[0]
    infos = mix.step(act)[4]
    assert infos["infeasible"][1, 0] and not infos["infeasible"][1, 1:].any()


def test_mix_safety_state_and_filter_keep_each_copy_on_its_tasks_lattice():
    """A mix's safety_state is its tasks' states on the mix's lattice (masks at their nodes' places, tops padded
    with inf), available_nodes says which nodes each copy's task has, and the safety filter never flies a copy to
    a node its task lacks, even where it looks beyond the masks."""
    from covert_env.envs.safety_filter import SafetyFilter, SafetyFilteredVectorEnv

    mix = covert_env.vector_env(num_envs=2, task=["towers-3uav", "paper-3uav-deviating"], action_mode="waypoint",
                                mask_mode="kinematic")
    dev = covert_env.vector_env(num_envs=1, task="paper-3uav-deviating", action_mode="waypoint",
                                mask_mode="kinematic")
    tow = covert_env.vector_env(num_envs=1, task="towers-3uav", action_mode="waypoint", mask_mode="kinematic")
    mix.reset(seed=3)
    tow.reset(seed=3)
    dev.reset(seed=4)
    at, _ = _own_nodes(mix, dev)
    state, own_t, own_d = mix.safety_state(2), tow.safety_state(2), dev.safety_state(2)
    np.testing.assert_array_equal(state.masks[1][:, at], own_d.masks[0])
    assert state.masks[1].sum() == own_d.masks.sum()
    np.testing.assert_array_equal(state.masks[0], own_t.masks[0])
    for name in ("xy", "theta", "q_next", "phi_next", "q_ahead", "phi_ahead", "slots_left", "slot"):
        np.testing.assert_array_equal(getattr(state, name)[1], getattr(own_d, name)[0])
        np.testing.assert_array_equal(getattr(state, name)[0], getattr(own_t, name)[0])
    np.testing.assert_array_equal(state.tops[0][np.isfinite(state.tops[0, :, 0])], own_t.tops[0])
    np.testing.assert_array_equal(state.tops[1][np.isfinite(state.tops[1, :, 0])], own_d.tops[0])
    avail = mix.available_nodes
    assert avail.shape == (2, 577) and avail[0].all() and avail[1].sum() == 483 and avail[1, at].all()
    # Looking beyond the masks (every stage but the last refused), the filter keeps to the available nodes.
    flt = SafetyFilter(mix.config, mix.lattice)
    flt._search = flt._search[-1:]                                                  # every lattice node
    state = mix.safety_state(flt.depth)
    proposed = np.array([[int(np.flatnonzero(state.masks[b, u])[0]) for u in range(3)] for b in range(2)])
    out = flt.filter(state, proposed, available=avail)
    assert avail[1, out[1]].all()
    with pytest.raises(ValueError, match=r"available must be bools of shape \(2, 577\)"):
        flt.filter(state, proposed, available=avail[:1])
    # Through the vector wrapper, over whole episodes of masked-random proposals: no violation.
    env = SafetyFilteredVectorEnv(mix)
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(25):
        m = env.action_masks().astype(bool)
        _, _, _, _, infos = env.step(np.argmax(np.where(m, rng.random(m.shape), -1.0), axis=2))
        assert (infos["cost_separation"] == 0).all() and (infos["cost_terrain"] == 0).all()
        assert avail[np.arange(2)[:, None], infos["shield_node"]].all()
        plan = env.safety._plan.nodes                                    # the backup plans (B, depth, U), -1: none
        for b in range(2):
            assert avail[b, plan[b][plan[b] >= 0]].all(), f"copy {b}'s backup plan leaves its task's lattice"


def test_mix_errors_name_the_problem():
    def make(tasks, n, **kw):
        return covert_env.vector_env(num_envs=n, task=tasks, **kw)

    with pytest.raises(ValueError, match="list of distinct task names"):
        make(["paper-3uav", "paper-3uav"], 2)
    with pytest.raises(ValueError, match="multiple of the 2 tasks .* got 3"):
        make(["paper-3uav", "dense-3uav"], 3)
    assert make(["paper-3uav", "dense-3uav"], 2, n_uavs=3).task == ("paper-3uav", "dense-3uav")
    assert make(np.array(["paper-3uav", "dense-3uav"]), 2).task == ("paper-3uav", "dense-3uav")
    with pytest.raises(ValueError, match=r"task='paper-3uav' flies 3 UAV\(s\), got n_uavs=6"):
        make(["paper-3uav", "dense-3uav"], 2, n_uavs=6)
    with pytest.raises(ValueError, match="task='dense-3uav' flies the 'dense' family, got family='paper'"):
        make(["paper-3uav", "dense-3uav"], 2, family="paper")
    with pytest.raises(ValueError, match=r"task 'paper-6uav' differs from 'paper-3uav' in \['n_uavs'\]"):
        make(["paper-3uav", "paper-6uav"], 2)
    with pytest.raises(ValueError, match="got 'nope'"):
        make(["paper-3uav", "nope"], 2)
    with pytest.raises(RuntimeError, match=r"waypoint_paths\(\) is for action_mode='waypoint'"):
        uni = make(["paper-3uav", "dense-3uav"], 2)
        uni.reset(seed=0)
        uni.waypoint_paths(np.zeros((2, 3, 1), int))
    with pytest.raises(ValueError, match="several tasks are for the vector env"):
        covert_env.parallel_env(task=["paper-3uav", "dense-3uav"])
    with pytest.raises(ValueError, match="does not render"):
        make(["paper-3uav", "dense-3uav"], 2, render_mode="human")


def test_make_training_env_gives_one_vector_env():
    one = make_training_env(["towers-3uav"], 2)
    mixed = make_training_env(["paper-3uav", "dense-3uav"], 4, action_mode="waypoint")
    assert one.task == "towers-3uav" and mixed.task == ("paper-3uav", "dense-3uav")
    assert mixed.num_envs == 4 and mixed.task_mix.copy_task.tolist() == [0, 0, 1, 1]
