"""The retired v2 entry point: importable, but building an env raises an error saying what changed in v3.

Results of v2 are not silently mixed with v3's: v3's reward has a term for LoS lost along the flown path and its infos
a cost and a flag for it (see the Version History of :class:`covert_env.envs.CovertSensingParallelEnv`).
``pip install "covert_env<0.7"`` still gives v2.
"""

from __future__ import annotations

__all__ = ["env", "parallel_env", "raw_env", "V2_RETIRED"]

V2_RETIRED = (
    "covert_sensing_v2 was replaced by covert_sensing_v3 in covert_env 0.7.0: line of sight lost between slot times "
    "now counts. The reward has a new term reward_los_path = -los_path_penalty * (share of the slot's flown path "
    "with LoS to the target blocked), the infos a cost cost_los_path (that share, in [0, 1], also in 'cost') and a "
    "flag los_path (LoS clear along the whole slot). Observations, dynamics, scenes and every other reward term and "
    "cost are unchanged: v3 with los_path_penalty=0 gives v2's rewards (v3 changed again in 0.10.0, see "
    "covert_sensing_v3). Use covert_env.covert_sensing_v4 (or "
    "covert_env.parallel_env, gym.make('covert_env/CovertSensing-v4'), covert_env.vector_env), or "
    "pip install 'covert_env<0.7' for v2.")


def _retired(*args, **kwargs):
    raise RuntimeError(V2_RETIRED)


env = parallel_env = raw_env = _retired
