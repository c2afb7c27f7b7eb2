"""Versioned entry point, PettingZoo/mpe2 style: ``from covert_env import covert_sensing_v4``."""

from covert_env.envs.covert_sensing import CovertSensingParallelEnv, env, parallel_env, raw_env

__all__ = ["CovertSensingParallelEnv", "env", "parallel_env", "raw_env"]
