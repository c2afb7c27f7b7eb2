"""Percentile bootstrap intervals over scenes, for the tables of ``reproduce`` and the prediction study."""

from __future__ import annotations

import numpy as np

__all__ = ["BOOTSTRAP_RESAMPLES", "BOOTSTRAP_SEED", "bootstrap_ci"]

BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0


def bootstrap_ci(values, stat=None, *, level: float = 0.95, n_resamples: int = BOOTSTRAP_RESAMPLES,
                 seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``stat`` over the rows of ``values`` (one row per scene).

    Draws ``n_resamples`` samples of the n rows with replacement (rows stay whole, so paired quantities such as
    (aware, blind) of one scene are resampled together), evaluates ``stat`` on each and returns the
    ``(1 - level) / 2`` and ``(1 + level) / 2`` percentiles.

    Args:
        values: (n,) or (n, ...) array; row i belongs to scene i.
        stat: maps a (B, n, ...) array of B resamples to (B,) statistics; default: the mean over the scenes.
        level: confidence level in (0, 1).
        n_resamples: number of bootstrap resamples B.
        seed: seed of the resampling (numpy's default_rng).

    Returns:
        (low, high); (nan, nan) with no scene; (s, s) with one scene (s = ``stat`` of it: no spread to estimate).
    """
    x = np.asarray(values, dtype=float)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    if stat is None:
        def stat(sample):
            return sample.mean(axis=1)
    n = len(x)
    if n == 0:
        return float("nan"), float("nan")
    if n == 1:
        s = float(np.asarray(stat(x[None]))[0])
        return s, s
    idx = np.random.default_rng(seed).integers(0, n, size=(int(n_resamples), n))
    stats = np.asarray(stat(x[idx]), dtype=float)
    lo, hi = np.percentile(stats, [50 * (1 - level), 50 * (1 + level)])
    return float(lo), float(hi)
