"""The retired v0 entry point: importable, but building an env raises an error saying what changed in v1.

Results of v0 are not silently mixed with v1's: the infos changed shape (see the Version History of
:class:`covert_env.envs.CovertSensingParallelEnv`). ``pip install "covert_env<0.2"`` still gives v0.
"""

from __future__ import annotations

__all__ = ["env", "parallel_env", "raw_env", "V0_RETIRED"]

V0_RETIRED = (
    "covert_sensing_v0 was replaced by covert_sensing_v1 in covert_env 0.2.0: infos are flat and have the same keys "
    "at reset and step (infos[a]['reward_terms'][t] is now infos[a]['reward_' + t]), constraint costs "
    "(infos[a]['cost'], 'cost_los', ...) were added, with dict_obs=True the action mask is only in the observation, "
    "and a waypoint straight behind the UAV turns right (eq. 22 as the paper states). Observations and rewards are "
    "otherwise unchanged. Use covert_env.covert_sensing_v4 (v1, v2 and v3 changed again, see covert_sensing_v1 "
    "to _v3) "
    "or covert_env.parallel_env, or pip install 'covert_env<0.2' for v0.")


def _retired(*args, **kwargs):
    raise RuntimeError(V0_RETIRED)


env = parallel_env = raw_env = _retired
