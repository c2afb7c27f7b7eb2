"""The retired v1 entry point: importable, but building an env raises an error saying what changed in v2.

Results of v1 are not silently mixed with v2's: random scenes come from another generator and the waypoint action
mask changed on the zone's eroded boundary (see the Version History of
:class:`covert_env.envs.CovertSensingParallelEnv`). ``pip install "covert_env<0.6"`` still gives v1.
"""

from __future__ import annotations

__all__ = ["env", "parallel_env", "raw_env", "V1_RETIRED"]

V1_RETIRED = (
    "covert_sensing_v1 was replaced by covert_sensing_v2 in covert_env 0.6.0: random scenes come from a new, batched "
    "generator (every random scene differs; the paper scene does not), and the waypoint action mask, the "
    "observation maps and the start sampler read the planner's rule for the visible zone (eq. 10, "
    "covert_env.visibility.visible_nodes): lattice nodes on the eroded zone's boundary, which v1 dropped by "
    "rounding, are offered, and line of sight is decided with the polytopes grown by 1 micrometre. Seeded rollouts "
    "on random scenes differ; on the paper scene or a given Scenario they can (waypoint masks; in both modes the "
    "maps and starts where a sight line grazes a polytope); rewards and costs are unchanged, and so are the "
    "dynamics except that, with a prediction error, a waypoint node is placed about the target's predicted next "
    "pose (v1: its true one). v2 and v3 changed again in 0.7.0 and 0.10.0 (see covert_sensing_v2, _v3). Use "
    "covert_env.covert_sensing_v4 "
    "(or covert_env.parallel_env, gym.make('covert_env/CovertSensing-v4'), covert_env.vector_env), or "
    "pip install 'covert_env<0.6' for v1.")


def _retired(*args, **kwargs):
    raise RuntimeError(V1_RETIRED)


env = parallel_env = raw_env = _retired
