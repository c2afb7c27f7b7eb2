"""The SB3 callbacks of the SB3 scripts (:func:`training.sb3.run.make_callbacks` builds them): a time budget, a
progress bar and checkpoints with JSON VecNormalize statistics.

This module imports Stable-Baselines3 (the ``train`` extra); :mod:`training.common` imports it only when a run
starts, so the scripts' ``--help`` and :mod:`training.mappo` work without SB3.
"""

from __future__ import annotations

import sys
import time

from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

from training.budget import expected_steps
from training.sb3.vec_env import save_vecnormalize

__all__ = ["TimeBudgetCallback", "TqdmCallback", "JsonCheckpointCallback"]


class TimeBudgetCallback(BaseCallback):
    """Stop training gracefully once ``minutes`` of wall-clock time have passed (0 or less: no budget)."""

    def __init__(self, minutes: float):
        super().__init__()
        self.minutes = float(minutes)
        self.t0 = time.monotonic()
        self.stopped = False

    def _on_training_start(self) -> None:
        self.t0 = time.monotonic()

    def _on_step(self) -> bool:
        if self.minutes > 0 and time.monotonic() - self.t0 > 60.0 * self.minutes:
            if not self.stopped:
                print(f"time budget of {self.minutes:g} min reached at {self.num_timesteps} steps: stopping",
                      flush=True)
            self.stopped = True
            return False
        return True


class TqdmCallback(BaseCallback):
    """A tqdm progress bar over timesteps (starts at the resumed step count). Its total, and so its ETA, is where
    the run is expected to stop: ``total``, or fewer when a time budget of ``minutes`` ends it first (at the rate
    so far, :func:`training.budget.expected_steps`)."""

    def __init__(self, total: int, minutes: float = 0.0):
        super().__init__()
        self.total = int(total)
        self.minutes = float(minutes)
        self.bar = None
        self.t0, self.step0 = time.monotonic(), 0

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        tty = sys.stderr.isatty()
        self.t0, self.step0 = time.monotonic(), self.model.num_timesteps
        self.bar = tqdm(total=self.total, initial=self.model.num_timesteps, unit="step", dynamic_ncols=True,
                        mininterval=0.5 if tty else 30.0, smoothing=0.05)

    def _on_step(self) -> bool:
        if self.bar is not None:
            steps, seconds = self.model.num_timesteps, time.monotonic() - self.t0
            self.bar.total = expected_steps(self.total, steps, seconds, self.minutes,
                                            (steps - self.step0) / max(seconds, 1e-9))
            self.bar.n = steps
            self.bar.update(0)
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.n = self.model.num_timesteps
            if self.bar.n < self.total:             # stopped early (the time budget): the bar ends full
                self.bar.total = self.bar.n
            self.bar.close()


class JsonCheckpointCallback(CheckpointCallback):
    """SB3's ``CheckpointCallback``, with the VecNormalize statistics saved as JSON beside each checkpoint
    (``{prefix}_vecnormalize_{steps}_steps.json``) instead of SB3's pickle."""

    def __init__(self, save_freq: int, save_path: str, name_prefix: str = "rl_model", **kw):
        super().__init__(save_freq, save_path, name_prefix, save_vecnormalize=False, **kw)

    def _on_step(self) -> bool:
        super()._on_step()
        vn = self.model.get_vec_normalize_env()
        if self.n_calls % self.save_freq == 0 and vn is not None:
            save_vecnormalize(vn, self._checkpoint_path("vecnormalize_", extension="json"))
        return True
