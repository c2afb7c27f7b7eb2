"""Aggregate scores a reviewer trusts: IQM, stratified-bootstrap confidence intervals, probability of improvement.

The definitions are rliable's (Agarwal et al., "Deep RL at the edge of the statistical precipice", NeurIPS 2021),
written out here in numpy (the ``rliable`` package pulls in ``arch`` and more for ~50 lines). Scores are a matrix
``(n_runs, n_tasks)``: for us runs are training seeds and tasks are held-out scenes, so a leaderboard cell is an
aggregate over seeds x scenes.

* **IQM** (interquartile mean): the mean of the middle 50 % of all ``n_runs * n_tasks`` scores, i.e.
  ``scipy.stats.trim_mean(scores, 0.25, axis=None)``: ``floor(0.25 n)`` scores are cut from each end.
* **Stratified bootstrap CI**: each replicate resamples, within every task separately, ``n_runs`` runs with
  replacement (the task is the stratum; every task keeps its weight), and recomputes the aggregate; the interval
  is the percentile interval of the replicates (rliable's default ``percentile`` method, 95 %).
  With a single run per task (one seed, or a deterministic planner) there is nothing to resample: the interval
  is the point itself, which says that no seed variation was measured -- not that there is none.
* **Probability of improvement** ``P(X > Y)``: per task, the Mann-Whitney statistic over all pairs of runs,
  ``mean_ij [x_i > y_j] + 0.5 [x_i = y_j]``, then the mean over tasks. Its CI bootstraps the runs of X and of Y
  independently, each stratified by task.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["iqm", "mean", "stratified_bootstrap_ci", "probability_of_improvement", "poi_ci", "aggregate_ci"]


def _matrix(scores, name: str = "scores") -> np.ndarray:
    a = np.asarray(scores, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.size == 0:
        raise ValueError(f"{name} must be a non-empty (n_runs, n_tasks) matrix, got shape {np.shape(scores)}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} holds NaN or inf")
    return a


def iqm(scores) -> float:
    """Interquartile mean of all scores (``scipy.stats.trim_mean(scores, 0.25, axis=None)``)."""
    x = np.sort(_matrix(scores).ravel())
    cut = int(0.25 * len(x))
    return float(x[cut:len(x) - cut].mean())


def mean(scores) -> float:
    return float(_matrix(scores).mean())


def _iqm_rows(x: np.ndarray) -> np.ndarray:
    """IQM of each row of x (R, n) at once (the bootstrap's replicates)."""
    x = np.sort(x, axis=1)
    cut = int(0.25 * x.shape[1])
    return x[:, cut:x.shape[1] - cut].mean(axis=1)


_BATCHED = {iqm: _iqm_rows, mean: lambda x: x.mean(axis=1)}


def _resample(a: np.ndarray, rng: np.random.Generator, reps: int) -> np.ndarray:
    """``reps`` stratified resamples of ``a`` (n_runs, n_tasks): runs drawn with replacement within each task."""
    n, m = a.shape
    idx = rng.integers(0, n, size=(reps, n, m))
    return np.take_along_axis(np.broadcast_to(a, (reps, n, m)), idx, axis=1)


def stratified_bootstrap_ci(scores, fn: Callable[[np.ndarray], float] = iqm, reps: int = 2000,
                            confidence: float = 0.95, seed: int = 0) -> tuple[float, float, float]:
    """``(point, low, high)``: ``fn`` of the scores and its percentile interval over ``reps`` stratified resamples."""
    a = _matrix(scores)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if reps < 1:
        raise ValueError(f"reps must be >= 1, got {reps}")
    boots = _resample(a, np.random.default_rng(seed), reps)
    batched = _BATCHED.get(fn)
    vals = batched(boots.reshape(reps, -1)) if batched else np.array([fn(b) for b in boots])
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(vals, [tail, 100.0 - tail])
    return float(fn(a)), float(low), float(high)


def probability_of_improvement(x, y) -> float:
    """``P(X > Y)``: the mean over tasks of the Mann-Whitney statistic of X's runs against Y's (ties count 1/2).
    X and Y are ``(runs, n_tasks)`` matrices over the same tasks (their numbers of runs may differ)."""
    a, b = _matrix(x, "x"), _matrix(y, "y")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x and y must score the same tasks, got {a.shape[1]} and {b.shape[1]} columns")
    return float(_poi(a[None], b[None])[0])


def _poi(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched P(X > Y) of (R, n, m) and (R, k, m) matrices: (R,)."""
    gt = (a[:, :, None, :] > b[:, None, :, :]).mean(axis=(1, 2))
    eq = (a[:, :, None, :] == b[:, None, :, :]).mean(axis=(1, 2))
    return (gt + 0.5 * eq).mean(axis=-1)


def poi_ci(x, y, reps: int = 2000, confidence: float = 0.95, seed: int = 0) -> tuple[float, float, float]:
    """``(P(X > Y), low, high)``: X's and Y's runs resampled independently, each stratified by task."""
    a, b = _matrix(x, "x"), _matrix(y, "y")
    point = probability_of_improvement(a, b)
    rng = np.random.default_rng(seed)
    vals = _poi(_resample(a, rng, reps), _resample(b, rng, reps))
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(vals, [tail, 100.0 - tail])
    return point, float(low), float(high)


def aggregate_ci(scores, reps: int = 2000, seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """IQM and mean, each with its 95 % stratified-bootstrap interval."""
    return {"iqm": stratified_bootstrap_ci(scores, iqm, reps, seed=seed),
            "mean": stratified_bootstrap_ci(scores, mean, reps, seed=seed)}
