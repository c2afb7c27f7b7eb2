"""The retired v3 entry point: importable, but building an env raises an error saying what changed in v4.

Results of v3 are not silently mixed with v4's: v4 settles every UAV's pose on a fine grid at each slot end, so a
seeded rollout's numbers differ from v3's in their last digits and, since the flight amplifies such differences,
in the decisions taken later in an episode (see the Version History of
:class:`covert_env.envs.CovertSensingParallelEnv`). ``pip install "covert_env<0.10"`` still gives v3.
"""

from __future__ import annotations

__all__ = ["env", "parallel_env", "raw_env", "V3_RETIRED"]

V3_RETIRED = (
    "covert_sensing_v3 was replaced by covert_sensing_v4 in covert_env 0.10.0: every UAV's pose is settled at each "
    "slot end on a grid of 2^-20 m (about 1 micrometre) and 2^-24 rad, so that results reproduce bit for bit on "
    "CPUs whose math libraries differ in the last bit (AVX-512 or not). Observations, rewards, costs, scenes and "
    "spaces are otherwise unchanged, but seeded rollouts differ from v3's (in the last digits, and after tens of "
    "slots in the decisions). Use covert_env.covert_sensing_v4 (or covert_env.parallel_env, "
    "gym.make('covert_env/CovertSensing-v4'), covert_env.vector_env), or pip install 'covert_env<0.10' for v3.")


def _retired(*args, **kwargs):
    raise RuntimeError(V3_RETIRED)


env = parallel_env = raw_env = _retired
