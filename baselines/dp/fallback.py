"""When the visible zone is empty or unreachable: the planner's fallback levels 2 and 3 (see :mod:`baselines.dp`)."""

from __future__ import annotations

import numpy as np

from baselines.dp.lattice import Stage
from baselines.dp.path_checks import FALLBACK_PENALTY
from covert_env.geometry.ties import first_argmin
from covert_env.world.config import Config

__all__ = ["fallback_penalties", "nearest_zone_node", "nearness"]


def fallback_penalties(allowed: np.ndarray, blocked: np.ndarray) -> list[np.ndarray]:
    """Level 2: per stage j, (U, L) penalties over every zone node: inf where ``blocked`` (U, N, L), 0 where
    ``allowed`` (N, L), else ``FALLBACK_PENALTY * 2^(N-1-j)`` (keeping LoS at an earlier stage always wins)."""
    n = allowed.shape[0]
    return [np.where(blocked[:, j], np.inf, np.where(allowed[j], 0.0, FALLBACK_PENALTY * 2.0 ** (n - 1 - j))[None])
            for j in range(n)]


def nearest_zone_node(config: Config, stage: Stage, start, allowed: np.ndarray, blocked: np.ndarray) -> int:
    """Level 3: the stage-1 node nearest to ``start`` (not ``blocked`` if any is free; a visible one on near-ties)."""
    free = ~blocked if (~blocked).any() else np.ones(len(stage.xy), bool)
    return first_argmin(np.where(free, nearness(config, stage, start, allowed), np.inf))


def nearness(config: Config, stage: Stage, start, allowed: np.ndarray) -> np.ndarray:
    """(L,) level 3's preference among the stage-1 nodes, lowest first: the distance from ``start``, one grid step
    less for an ``allowed`` node (keeping LoS matters more than one grid step of distance)."""
    return np.hypot(*(stage.xy - start).T) - np.where(allowed, config.grid_step, 0.0)
