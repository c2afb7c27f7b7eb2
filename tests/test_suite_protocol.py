"""The suite protocol (covert_env.evaluation.benchmark): normalised scores, aggregates, marl-eval output, workers,
CLI errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _extras import needs

from covert_env.evaluation.benchmark import REFERENCE, aggregate, main, marl_eval, normalised_scores, run_cells
from covert_env.evaluation.evaluate import COLUMNS


def _rows(table: dict) -> list[dict]:
    """Rows {task: {policy: [rewards per scene]}} with the metric columns filled."""
    rows = []
    for task, pols in table.items():
        for p, rewards in pols.items():
            for i, r in enumerate(rewards):
                rows.append({"task": task, "policy": p, "run": 0, "scene_seed": 1_000_000 + i, "action_mode": "x",
                             **{k: 0.0 for k, _, _ in COLUMNS}, "reward": float(r), "min_separation": 7.0 + i})
    return rows


def test_normalised_score_is_zero_for_random_and_one_for_the_best_planner():
    rows = _rows({"a": {REFERENCE: [10, 30], "dp": [110, 130], "dp-blind": [90, 90], "other": [220, 220]},
                  "b": {REFERENCE: [0, 0], "dp": [50, 50], "dp-path": [100, 100]}})
    scored, ref = normalised_scores(rows)
    assert ref == {"a": (20.0, 120.0), "b": (0.0, 100.0)}
    s = {(r["task"], r["policy"]): [] for r in scored}
    for r in scored:
        s[(r["task"], r["policy"])].append(r["score"])
    assert s[("a", REFERENCE)] == [-0.1, 0.1] and s[("a", "dp")] == [0.9, 1.1] and s[("a", "other")] == [2.0, 2.0]
    assert s[("b", "dp")] == [0.5, 0.5] and s[("b", "dp-path")] == [1.0, 1.0]
    with pytest.raises(ValueError, match="not above random"):
        normalised_scores(_rows({"a": {REFERENCE: [5], "dp": [5]}}))


def test_aggregate_uses_rliable_definitions_on_fixed_numbers():
    """IQM over tasks x scenes is scipy's trim_mean of all scores; P(X > Y) is the per-task Mann-Whitney mean."""
    from scipy.stats import trim_mean  # imported here: scipy.stats touches torch, which test_extras hides

    rng = np.random.default_rng(0)
    table = {t: {REFERENCE: [0.0] * 8, "dp": list(100 + rng.normal(0, 10, 8)), "x": list(100 + rng.normal(0, 30, 8))}
             for t in ("a", "b", "c")}
    scored, _ = normalised_scores(_rows(table))
    agg = aggregate(scored, ["dp", "x", REFERENCE])
    for p in ("dp", "x"):
        s = np.array([r["score"] for r in scored if r["policy"] == p])
        assert agg["policies"][p]["iqm"][0] == pytest.approx(trim_mean(s, 0.25))
        lo, hi = agg["policies"][p]["iqm"][1:]
        assert lo <= agg["policies"][p]["iqm"][0] <= hi and lo < hi
    want = np.mean([np.mean([[(u > v) + 0.5 * (u == v) for v in table[t]["x"]] for u in table[t]["dp"]])
                    for t in table])
    assert agg["improvement"]["dp > x"] == pytest.approx(want)
    assert agg["improvement"]["dp > x"] + agg["improvement"]["x > dp"] == pytest.approx(1.0)
    assert agg["policies"]["dp"]["min_separation"] == 7.0


def test_marl_eval_layout():
    scored, _ = normalised_scores(_rows({"a": {REFERENCE: [1, 2], "dp": [5, 6]}}))
    data = marl_eval(scored)
    run = data["covert_env"]["a"]["dp"]["run_0"]
    assert run["step_0"]["step_count"] == 0 and run["step_0"]["reward"] == [5.0, 6.0]
    assert run["absolute_metrics"]["score"] == [0.875, 1.125]              # (5 - 1.5) / 4, (6 - 1.5) / 4
    assert set(run["absolute_metrics"]) == {"score", *(k for k, _, _ in COLUMNS)}
    json.dumps(data)


@pytest.mark.slow
def test_any_number_of_workers_gives_the_same_rows():
    cells = [("paper-1uav", "dp", 0), ("paper-1uav", REFERENCE, 0), ("sparse-1uav", "dp-blind", 0)]
    one = run_cells(cells, 1, jobs=1, progress=False)
    two = run_cells(cells, 1, jobs=2, progress=False)
    for r in (*one, *two):
        r.pop("decision_time_ms")
    assert one == two and [r["task"] for r in one] == ["paper-1uav", "paper-1uav", "sparse-1uav"]


def test_command_line_errors_name_the_flag(capsys):
    for argv, msg in ((["--tasks", "nowhere-3uav"], "--tasks: task must be"),
                      (["--policies", "random"], "include at least one dp planner"),
                      (["--policies", "dp", "nope"], "--policies: unknown policy"),
                      (["--scenes", "0"], "--scenes"),
                      (["--tasks", "paper-1uav", "--policies", "dp", "pretrained:mappo"],
                       "pretrained:mappo acts for another team size than every task")):
        with pytest.raises(SystemExit) as e:
            main(argv + ["--out", "/tmp/never_written_suite"])
        assert e.value.code == 2
        assert msg in capsys.readouterr().err


def test_ray_and_local_runs_give_the_same_rows():
    """On a local Ray instance (the rllib extra, CI's Ray venv) the cells give the rows of a local run."""
    ray = needs("ray")
    cells = [("paper-1uav", REFERENCE, 0), ("sparse-1uav", "hold-centre", 0)]
    local = run_cells(cells, 2, jobs=1, progress=False)
    try:
        remote = run_cells(cells, 2, progress=False, ray_address="local")
    finally:
        ray.shutdown()
    for r in (*local, *remote):
        r.pop("decision_time_ms")
    assert remote == local and len(local) == 4


def test_task_table_per_task_intervals_and_improvement_over_the_best_planner():
    """benchmarks/task_table.py: per task, the best planner is the dp* policy with the highest mean score, and a
    policy that beats it on every scene has P(> best planner) = 1 and an IQM above it."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "benchmarks" / "task_table.py"
    spec = importlib.util.spec_from_file_location("task_table", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = []
    for scene in range(4):
        for policy, score in (("dp", 0.9 + 0.01 * scene), ("dp-binned", 1.0), ("mappo:x", 1.1 + 0.01 * scene)):
            rows.append({"task": "t", "policy": policy, "score": score, "zone_violation_rate": 0.01 * scene,
                         "occlusion_rate": 0, "occlusion_rate_path": 0, "blocked_path_share": 0,
                         "separation_violations": 0, "min_separation": 5 + scene})
    text = mod.task_tables(rows, ["dp", "dp-binned", "mappo:x"])
    assert "(best planner: dp-binned)" in text
    line = next(x for x in text.splitlines() if x.startswith("| mappo:x"))
    assert line.endswith("| 5.0 | 1.00 |") and "| 0.015 |" in line          # zone mean, min sep., P(> best)
    assert next(x for x in text.splitlines() if x.startswith("| dp |")).endswith("| 0.00 |")
    # The best planner is the run's, shown or not.
    assert "(best planner: dp-binned)" in mod.task_tables(rows, ["dp", "mappo:x"])


def test_an_episode_row_reports_the_teams_smallest_separation():
    """Rows average the per-UAV metrics, but a minimum stays a minimum: two UAVs 2.9 m apart and one 5.6 m from
    both give a row of 2.9 m, not the mean of 3.8 m."""
    from covert_env.evaluation.episodes import team_row

    ms = [{"min_separation": 5.6, "separation_violations": 0}, {"min_separation": 2.9, "separation_violations": 1},
          {"min_separation": 2.9, "separation_violations": 1}]
    row = team_row({"metrics": ms, "return": {"a": 1.0, "b": 2.0, "c": 3.0}})
    assert row["min_separation"] == 2.9
    assert row["separation_violations"] == pytest.approx(2 / 3) and row["reward"] == 2.0


def test_every_policy_spec_has_a_tier():
    """The leaderboards' three tiers (and the references): what a team reads to act decides its tier."""
    from covert_env.evaluation.tiers import TIERS, spec_tier

    assert list(TIERS) == ["planner", "hybrid", "learned", "reference"]
    cases = {"dp": "planner", "dp-binned@waypoint+shield": "planner", "pretrained:dp-cost": "hybrid",
             "pretrained:dp-cost-kinematic-binned+shield": "hybrid", "pretrained:mappo-suite": "learned",
             "mappo:runs/a,runs/b@waypoint+shield": "learned", "sb3:runs/x": "learned", "rllib:runs/y": "learned",
             "pretrained:dp-cost,dp-cost-binned": "hybrid", "random@waypoint": "reference",
             "hold-centre": "reference"}
    assert {s: spec_tier(s) for s in cases} == cases
