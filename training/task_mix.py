"""Training across the suite's tasks: one vector env whose copies fly several tasks.

``make_training_env(["paper-3uav", "downtown-3uav", ...], num_envs=256, ...)`` is
``covert_env.vector_env(num_envs=256, task=[...], ...)``: every copy draws its scenes from its own task's training
scenes (:attr:`covert_env.world.tasks.Task.train_seeds`), the copies of task i in rows ``i * b : (i + 1) * b``
(``b = num_envs / len(tasks)``), all stepped in one batch (:mod:`covert_env.envs.task_mix`), so a team trained on
the mix sees every family in every rollout. The tasks must share the team size and every config field but the scene
family's and the target model's; a deviating task's copies act on the largest lattice and their masks allow only
their own nodes (``env.available_nodes``).
"""

from __future__ import annotations

import covert_env

__all__ = ["make_training_env"]


def make_training_env(tasks: list[str], num_envs: int, **kwargs):
    """One vector env of ``num_envs`` copies of ``tasks`` (none: the env's defaults; one: that task; several: a mix,
    ``num_envs`` a multiple of their number). ``kwargs`` go to ``covert_env.vector_env``."""
    if not tasks:
        return covert_env.vector_env(num_envs=num_envs, **kwargs)
    return covert_env.vector_env(num_envs=num_envs, task=tasks[0] if len(tasks) == 1 else list(tasks), **kwargs)
