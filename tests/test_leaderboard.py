"""The leaderboard the README and the documentation site show (covert_env.evaluation.leaderboard): made from a suite
run, in tiers, published into a repository and checked against it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from covert_env.command_line import UsageError
from covert_env.evaluation import leaderboard
from covert_env.evaluation.benchmark import aggregate, normalised_scores
from covert_env.evaluation.evaluate import COLUMNS

ROOT = Path(__file__).resolve().parents[1]


def _results() -> dict:
    """A two-task run: two planners, a hybrid, a learned team and random, fixed rewards."""
    rewards = {"dp": 200.0, "dp-binned": 210.0, "pretrained:dp-cost": 215.0, "pretrained:mappo-suite": 190.0,
               "random@waypoint": 100.0}
    rows = []
    for task in ("paper-3uav", "downtown-3uav"):
        for p, r in rewards.items():
            for i in range(3):
                rows.append({"task": task, "policy": p, "run": 0, "scene_seed": 1_000_000 + i,
                             "action_mode": "waypoint", **{k: 0.0 for k, _, _ in COLUMNS}, "reward": r + i,
                             "min_separation": 6.0,
                             "decision_time_ms": 10.0 * (i + 1)})
    scored, ref = normalised_scores(rows)
    return {"suite": "suite-v0", "reference": ref, "aggregate": aggregate(scored, list(rewards)), "cells": scored,
            "meta": {"scenes": 3, "jobs": 1, "seconds": 1.0, "command": "covert-env benchmark --scenes 3",
                     "tasks": ["paper-3uav", "downtown-3uav"], "policies": list(rewards)}}


def test_summary_needs_the_version_and_env_it_ran_on():
    with pytest.raises(ValueError, match="names no covert_env version or env id"):
        leaderboard.summary(_results())
    s = leaderboard.summary(_results(), "0.10.0", "covert_sensing_v4")
    assert s["meta"]["covert_env"] == "0.10.0" and s["meta"]["env"] == "covert_sensing_v4"
    assert len(s["cells"]) == 30
    assert s["policies"]["dp"]["decision_time_ms"] == 20.0                   # the median over its cells


def test_tier_table_groups_tiers_and_orders_by_score():
    s = leaderboard.summary(_results(), "0.10.0", "covert_sensing_v4")
    rows = [line for line in leaderboard.tier_table(s).splitlines()[2:]]
    assert [r.split(" | ")[1] for r in rows] == ["`dp-binned`", "`dp`", "`pretrained:dp-cost`",
                                                "`pretrained:mappo-suite`", "`random@waypoint`"]
    assert [r.split(" | ")[0] for r in rows] == ["| planner", "| planner", "| hybrid", "| learned", "| reference"]
    assert "| 1.000 [" in rows[0] and "| 0.000 [" in rows[-1]               # the best planner is 1, random 0
    compact = leaderboard.tier_table(s, compact=True).splitlines()
    assert "sep. viol./UAV" in compact[0] and "decision" not in compact[0] and "path share" not in compact[0]
    assert len(compact) == len(rows) + 2
    assert "covert_env 0.10.0, `covert_sensing_v4`" in leaderboard.caption(s)
    assert "covert-env benchmark --scenes 3" in leaderboard.caption(s)


def test_publish_writes_the_run_and_check_finds_a_stale_readme(tmp_path):
    (tmp_path / "docs").mkdir()
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{leaderboard.README_MARKERS[0]}\nold\n{leaderboard.README_MARKERS[1]}\n\nend\n")
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(UsageError, match="no summary.json or results.json"):
        leaderboard.publish(run, tmp_path)
    (run / "results.json").write_text(json.dumps(_results()))
    with pytest.raises(UsageError, match="pass --covert-env-version and --env-id"):
        leaderboard.publish(run, tmp_path)
    leaderboard.publish(run, tmp_path, "0.10.0", "covert_sensing_v4")
    text = readme.read_text()
    assert "old" not in text and "| planner | `dp-binned` |" in text and text.endswith("\n\nend\n")
    assert (tmp_path / "docs" / "suite_profile.png").stat().st_size > 10_000
    assert leaderboard.check(tmp_path) == []
    readme.write_text(text.replace("dp-binned", "dp-x"))
    assert leaderboard.check(tmp_path) != []


def test_the_published_run_is_a_complete_summary():
    """docs/results/suite.json: what the README's table and the site are made from, with what made it."""
    s = json.loads(leaderboard.SUMMARY.read_text())
    assert s["meta"]["covert_env"] and s["meta"]["env"].startswith("covert_sensing_v")
    assert s["meta"]["command"].startswith("covert-env benchmark")
    assert any(p["tier"] == "planner" for p in s["policies"].values())
    assert {c[1] for c in s["cells"]} == set(s["policies"])


def test_the_readme_without_markers_is_refused():
    with pytest.raises(ValueError, match="must hold the markers"):
        leaderboard._replace_block("# no markers\n", "x")
