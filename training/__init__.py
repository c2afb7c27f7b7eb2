"""Training and evaluation for covert_env (layout: docs/development.md#layout).

* :mod:`training.sb3` -- Stable-Baselines3: the scripts share their settings (:mod:`training.sb3.args`);
  :mod:`training.sb3.ppo_multi` is parameter-shared multi-agent PPO (the 3-UAV recipe of :mod:`training.recipes`),
  :mod:`training.sb3.ppo_single`, :mod:`training.sb3.sac_single` and :mod:`training.sb3.maskable_ppo_single` train
  one UAV. :class:`~training.sb3.vec_env.ParallelEnvVecAdapter` is our small SB3 ``VecEnv`` over PettingZoo
  ParallelEnvs (copies x agents flattened, one shared policy, no SuperSuit);
  :func:`~training.sb3.vec_env.make_vec_env` returns the batched one of :mod:`training.sb3.vector_adapter` for our env.
* :mod:`training.rllib_ppo` -- multi-agent PPO on RLlib (``[rllib]`` extra), one shared policy.
* :mod:`training.mappo` -- MAPPO / IPPO on the batched ``covert_env.vector_env`` (the ``3uav-mappo`` recipe),
  with the separation shield of :mod:`training.shield`; :mod:`training.curves` draws its learning curves.
* :mod:`training.pretrained` -- the learned actor in numpy and the shipped weights (``pretrained:mappo``).
* :mod:`training.dp_cost` -- the DP planner's cost for LoS lost along the path, learned with CEM
  (``pretrained:dp-cost``, loaded by :mod:`baselines.learned_cost`).
* :mod:`covert_env.evaluation.evaluate` -- ``covert-env evaluate``: every policy on the same held-out seeds,
  scored by :func:`covert_env.world.metrics.episode_metrics`, written to ``leaderboard.md`` / ``.csv`` and a figure;
  :mod:`covert_env.evaluation.stats` gives its IQM and bootstrap intervals.

Outputs go to the git-ignored ``runs/`` (training) and ``outputs/`` (evaluation) folders.
"""

from covert_env.moved import MovedModules  # noqa: E402

#: training's modules that moved after covert_env 0.10 -> their new names (importable for one more release).
MOVED = {
    **{f"training.{m}": f"covert_env.evaluation.{m}" for m in ("benchmark", "evaluate", "stats")},
    "training.pretrained.learned_cost": "baselines.learned_cost",
}
MovedModules.install(MOVED)
