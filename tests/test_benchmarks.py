"""The env benchmarks run (tiny sizes, no peers): each prints its table with a row per configuration (the safety
filter's training-scenes check too).

They read the env's internals (the scene pool's fill, to count the scenes built), so a change there must keep them
running; their figures are measured by hand (docs/performance.md), never asserted here.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, *args: str) -> str:
    run = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), *args], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, f"{script} failed:\n{run.stdout}\n{run.stderr}"
    return run.stdout


@pytest.mark.parametrize(("script", "args", "rows"), [
    ("vector_throughput.py", ("--sizes", "2", "--episodes", "1", "--rounds", "1", "--seconds", "0.1", "--no-vmas",
                              "--no-memory"),
     ("default unicycle", "cached unicycle", "default waypoint", "cached waypoint", "waypoint / unicycle, default")),
    ("env_throughput.py", ("--seconds", "0.1", "--episodes", "1", "--rounds", "1", "--mode", "both"),
     ("default unicycle", "cached unicycle", "default waypoint", "cached waypoint", "default waypoint / cached")),
    ("scene_throughput.py", ("--sizes", "4", "--families", "paper", "--profile-size", "0"), ("paper ",)),
    ("safety_filter.py", ("--training", "--sizes", "8", "--steps", "3", "--min-reach", "10"), ("| 8 | 0 | 3 | 24 | ",)),
])
def test_env_benchmarks_run_and_print_their_rows(script, args, rows):
    out = _run(script, *args)
    for row in rows:
        assert row in out, f"{script}: no row {row!r} in\n{out}"
