"""Stable-Baselines3 training: the scripts (``python -m training.sb3.<script>``) and their SB3 pieces.

* :mod:`training.sb3.args` -- the settings every script shares (``SB3Args``, ``PPOArgs``);
* :mod:`training.sb3.ppo_multi` -- parameter-shared multi-agent PPO on the PettingZoo env;
* :mod:`training.sb3.ppo_single`, :mod:`training.sb3.sac_single`, :mod:`training.sb3.maskable_ppo_single` -- one
  UAV on the Gymnasium envs;
* :mod:`training.sb3.vec_env` and :mod:`training.sb3.vector_adapter` -- SB3 ``VecEnv`` adapters of our envs (one
  shared policy over copies x agents);
* :mod:`training.sb3.callbacks` -- checkpoints as JSON, the time budget, the progress bar;
* :mod:`training.sb3.convert_vecnormalize` -- old pickled VecNormalize statistics to JSON, once.
"""
