"""covert_env.evaluation.stats against hand-computed cases (rliable's definitions: IQM, stratified bootstrap,
P(X > Y))."""

import numpy as np
import pytest

from covert_env.evaluation.stats import iqm, mean, poi_ci, probability_of_improvement, stratified_bootstrap_ci


def test_iqm_hand_computed():
    assert iqm([[1, 2, 3, 4, 5, 6, 7, 8]]) == pytest.approx(4.5)          # mean of 3, 4, 5, 6
    # n = 10: floor(2.5) = 2 cut from each end -> mean of 3..8 after sorting, whatever the layout.
    assert iqm(np.array([10, 1, 9, 2, 8, 3, 7, 4, 6, 5]).reshape(2, 5)) == pytest.approx(5.5)
    assert iqm([[0, 0, 0, 100]]) == pytest.approx(0.0)                      # the outlier is cut
    assert mean([[0, 0, 0, 100]]) == pytest.approx(25.0)


def test_iqm_equals_scipy_trim_mean():
    from scipy.stats import trim_mean

    rng = np.random.default_rng(1)
    for shape in [(3, 20), (5, 7), (1, 13), (2, 1)]:
        x = rng.normal(size=shape)
        assert iqm(x) == pytest.approx(trim_mean(x, 0.25, axis=None))


def test_bootstrap_two_runs_one_task():
    # Runs {0, 1} on one task: a resample's mean is 0, 1/2 or 1 with probabilities 1/4, 1/2, 1/4, so the 2.5 %
    # and 97.5 % percentiles are 0 and 1.
    point, lo, hi = stratified_bootstrap_ci([[0.0], [1.0]], mean, reps=4000)
    assert (point, lo, hi) == (0.5, 0.0, 1.0)
    # A 40 % interval lies inside (30th..70th percentile: the mass 1/2 at 0.5).
    assert stratified_bootstrap_ci([[0.0], [1.0]], mean, reps=4000, confidence=0.4)[1:] == (0.5, 0.5)


def test_bootstrap_is_stratified_by_task():
    # Task A's runs all score 0, task B's all 1: within-task resampling always gives the mean 1/2. A bootstrap
    # that pooled the four scores would spread from 0 to 1.
    scores = np.array([[0.0, 1.0], [0.0, 1.0]])
    assert stratified_bootstrap_ci(scores, mean, reps=500) == (0.5, 0.5, 0.5)
    assert stratified_bootstrap_ci(scores, iqm, reps=500) == (0.5, 0.5, 0.5)


def test_bootstrap_single_run_is_a_point_and_batched_equals_loop():
    x = np.arange(12.0).reshape(1, 12)
    assert stratified_bootstrap_ci(x, iqm, reps=100) == (iqm(x), iqm(x), iqm(x))
    rng = np.random.default_rng(0)
    y = rng.normal(size=(3, 10))
    fast = stratified_bootstrap_ci(y, iqm, reps=300, seed=5)
    slow = stratified_bootstrap_ci(y, lambda s: iqm(s), reps=300, seed=5)     # not batched: the plain loop
    assert fast == pytest.approx(slow)
    assert fast[1] <= fast[0] <= fast[2]


def test_probability_of_improvement_hand_computed():
    # One task, X runs {1, 3}, Y runs {2, 2}: pairs (1>2: 0, 0) and (3>2: 1, 1) -> 1/2.
    assert probability_of_improvement([[1.0], [3.0]], [[2.0], [2.0]]) == 0.5
    assert probability_of_improvement([[2.0]], [[2.0]]) == 0.5                 # a tie counts 1/2
    # Two tasks: task 0 X always better (1), task 1 X worse in 3 of 4 pairs, tie in 1 (0.5 / 4) -> mean 0.5625.
    x = [[5.0, 1.0], [6.0, 2.0]]
    y = [[0.0, 2.0], [1.0, 3.0]]
    assert probability_of_improvement(x, y) == pytest.approx((1.0 + 0.125) / 2)
    assert probability_of_improvement(y, x) == pytest.approx(1 - (1.0 + 0.125) / 2)


def test_poi_ci_brackets_and_bad_input():
    point, lo, hi = poi_ci([[1.0], [3.0]], [[2.0], [2.0]], reps=4000)
    # X's resample is {1,1}, {1,3} or {3,3}: P = 0, 1/2, 1 with probabilities 1/4, 1/2, 1/4.
    assert (point, lo, hi) == (0.5, 0.0, 1.0)
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement([[1.0, 2.0]], [[1.0]])
    with pytest.raises(ValueError, match="NaN"):
        iqm([[np.nan]])
    with pytest.raises(ValueError, match="confidence"):
        stratified_bootstrap_ci([[1.0]], confidence=1.0)


def test_learning_curve_band_and_figure(tmp_path):
    from training.curves import band, main

    # Runs at constant 0 and 2 on different step grids: mean 1, resampled means 0, 1 or 2 -> CI [0, 2].
    grid, mean_, lo, hi = band([np.array([0.0, 10.0]), np.array([2.0, 8.0, 12.0])],
                               [np.zeros(2), np.full(3, 2.0)], points=5)
    np.testing.assert_allclose(grid, [2.0, 4.0, 6.0, 8.0, 10.0])          # the runs' common range [2, 10]
    assert (mean_ == 1.0).all() and (lo == 0.0).all() and (hi == 2.0).all()
    for seed, rewards in ((0, [100.0, 150.0]), (1, [110.0, 170.0])):
        run = tmp_path / f"s{seed}"
        run.mkdir()
        (run / "curve.jsonl").write_text("".join(
            f'{{"env_steps": {1024 * (i + 1)}, "wall_seconds": {10.0 * (i + 1)}, "reward": {r}}}\n'
            for i, r in enumerate(rewards)))
    assert main([str(tmp_path / "s0"), str(tmp_path / "s1"), "--dp", "240.4", "--out", str(tmp_path / "c.png")]) == 0
    assert (tmp_path / "c.png").stat().st_size > 10_000
    # With the separation cost logged (training.mappo writes it), a second row draws the constraint.
    import matplotlib.image

    one_row = matplotlib.image.imread(tmp_path / "c.png").shape[0]
    for seed in (0, 1):
        run = tmp_path / f"s{seed}"
        (run / "curve.jsonl").write_text("".join(
            f'{{"env_steps": {1024 * (i + 1)}, "wall_seconds": {10.0 * (i + 1)}, "reward": 1.0, '
            f'"cost_separation": {c}}}\n' for i, c in enumerate((2.0, 0.3))))
    assert main([str(tmp_path / "s0"), str(tmp_path / "s1"), "--out", str(tmp_path / "c2.png")]) == 0
    assert matplotlib.image.imread(tmp_path / "c2.png").shape[0] > 1.5 * one_row


def test_learning_curves_draw_a_row_per_constrained_cost(tmp_path):
    """A run trained with --constraints gets one row per constrained cost, its limit per episode from args.json."""
    import json

    import matplotlib.image

    from training.curves import constraint_levels, main

    run = tmp_path / "r"
    run.mkdir()
    (run / "curve.jsonl").write_text("".join(
        f'{{"env_steps": {1024 * (i + 1)}, "wall_seconds": {10.0 * (i + 1)}, "reward": 1.0, "cost_los": 2.0, '
        f'"cost_zone": 1.0, "cost_separation": 0.1}}\n' for i in range(3)))
    (run / "args.json").write_text(json.dumps({"constraints": "zone=0.01, los=0.005", "lagrangian": True,
                                               "cost_limit": 0.007, "max_cycles": 70}))
    assert constraint_levels(run) == pytest.approx({"cost_los": 0.35, "cost_zone": 0.7, "cost_separation": 0.49})
    assert main([str(run), "--out", str(tmp_path / "c.png")]) == 0
    (run / "args.json").write_text(json.dumps({"constraints": "", "max_cycles": 70}))
    assert constraint_levels(run) == {}
    assert main([str(run), "--out", str(tmp_path / "c2.png")]) == 0                # reward + separation rows
    assert matplotlib.image.imread(tmp_path / "c.png").shape[0] > 1.7 * matplotlib.image.imread(
        tmp_path / "c2.png").shape[0]


def test_learning_curves_reject_a_curve_without_env_steps(tmp_path, capsys):
    """An imitation run's curve (epochs and losses) fails with one error line naming the file, not an empty figure."""
    from training.curves import main

    run = tmp_path / "bc"
    run.mkdir()
    (run / "curve.jsonl").write_text('{"epoch": 1, "train_loss": 3.2}\n')
    with pytest.raises(SystemExit) as exc:
        main([str(run), "--out", str(tmp_path / "c.png")])
    assert exc.value.code == 2
    assert "curve.jsonl is not a training.mappo curve" in capsys.readouterr().err
    assert not (tmp_path / "c.png").exists()
