"""Environments on the covert-sensing model: PettingZoo (multi-UAV) and Gymnasium (single UAV)."""

from covert_env.envs.covert_sensing import CovertSensingParallelEnv, env, parallel_env, raw_env
from covert_env.envs.single import CovertSensingEnv, CovertSensingWaypointEnv
from covert_env.envs.vector import CovertSensingVectorEnv, vector_env

__all__ = ["CovertSensingParallelEnv", "CovertSensingEnv", "CovertSensingWaypointEnv", "CovertSensingVectorEnv", "env",
           "parallel_env", "raw_env", "vector_env"]
