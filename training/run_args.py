"""The fields every training script's ``Args`` shares, declared once (CleanRL-style dataclasses).

Each script keeps its own ``Args`` dataclass, one flag per field with its docstring as ``--help``
(:func:`training.common.parse_args`). The fields they all have come from here: :class:`RunArgs` (the run folder,
the seed, the progress bar) for every script, and :class:`TrainingArgs` for the RL learners (the episodes they train
on, the time budget, torch's threads). A script overrides a default, or a field's docstring where the field means
more for it, by declaring the field again; dataclasses keep the field where the base declared it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["RunArgs", "TrainingArgs"]


@dataclass
class RunArgs:
    """The run: its seed, its folder ``runs_dir/run_name`` and its progress bar."""

    seed: int = 0
    """seed of every draw of the run (scenes, starts, networks, action sampling)"""
    runs_dir: str = "runs"
    """folder of the runs (git-ignored)"""
    run_name: str = ""
    """run folder name; empty: {env}__{algo}__{seed}__{time}"""
    progress_bar: bool = True
    """show a tqdm progress bar on stderr"""


@dataclass
class TrainingArgs(RunArgs):
    """:class:`RunArgs` and what every RL learner sets: its episodes, its wall-clock budget and torch's threads."""

    max_cycles: int = 70
    """episode length in slots (70 = the whole route)"""
    scene_pool: int = 10_000
    """training scene seeds are drawn from range(scene_pool); evaluation uses seeds >= 1_000_000"""
    time_budget_minutes: float = 0.0
    """stop gracefully after this much wall-clock training time and save (0: no budget)"""
    torch_threads: int = 1
    """torch threads (1: more threads than free cores slow a run down, docs/training.md)"""
