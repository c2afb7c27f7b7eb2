"""Where a training run is expected to stop: the total of its progress bar, and so the bar's ETA (the SB3
callbacks and MAPPO share it)."""

from __future__ import annotations

__all__ = ["expected_steps"]


def expected_steps(total_timesteps: int, steps: int, seconds: float, time_budget_minutes: float,
                   rate: float) -> int:
    """The step count at which a run is expected to stop, for a progress bar's total (and so its ETA): the step
    budget ``total_timesteps``, or fewer when the time budget ends the run first. ``steps`` done after ``seconds``
    of the budget's clock, at ``rate`` steps per second (0 or less: not known yet, the step budget is shown)."""
    if time_budget_minutes <= 0 or rate <= 0:
        return int(total_timesteps)
    left = max(60.0 * time_budget_minutes - seconds, 0.0)
    return int(min(total_timesteps, steps + rate * left))
