"""The retired env versions in one table: what replaced each and what changed, and the entry points that raise it.

Results of a retired version are not silently mixed with the current one's: ``covert_env.covert_sensing_vN`` (N < 4)
stays importable, but building an env from it, or from its Gymnasium and PettingZoo ids, raises
``RuntimeError(RETIRED["covert_sensing_vN"])``. ``CHANGELOG.md`` has every version's changes.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["RETIRED", "retired_entry"]

#: Per retired module name, the error its constructors raise: what replaced it, when, and what changed.
RETIRED: dict[str, str] = {
    "covert_sensing_v0": (
        "covert_sensing_v0 was replaced by covert_sensing_v1 in covert_env 0.2.0: infos are flat and have the "
        "same keys at reset and step (infos[a]['reward_terms'][t] is now infos[a]['reward_' + t]), constraint "
        "costs (infos[a]['cost'], 'cost_los', ...) were added, with dict_obs=True the action mask is only in the "
        "observation, and a waypoint straight behind the UAV turns right (eq. 22 as the paper states). "
        "Observations and rewards are otherwise unchanged. Use covert_env.covert_sensing_v4 (v1, v2 and v3 "
        "changed again, see covert_sensing_v1 to _v3) or covert_env.parallel_env, or pip install 'covert_env<0.2' "
        "for v0."
    ),
    "covert_sensing_v1": (
        "covert_sensing_v1 was replaced by covert_sensing_v2 in covert_env 0.6.0: random scenes come from a new, "
        "batched generator (every random scene differs; the paper scene does not), and the waypoint action mask, "
        "the observation maps and the start sampler read the planner's rule for the visible zone (eq. 10, "
        "covert_env.world.visibility.visible_nodes): lattice nodes on the eroded zone's boundary, which v1 dropped by "
        "rounding, are offered, and line of sight is decided with the polytopes grown by 1 micrometre. Seeded "
        "rollouts on random scenes differ; on the paper scene or a given Scenario they can (waypoint masks; in "
        "both modes the maps and starts where a sight line grazes a polytope); rewards and costs are unchanged, "
        "and so are the dynamics except that, with a prediction error, a waypoint node is placed about the "
        "target's predicted next pose (v1: its true one). v2 and v3 changed again in 0.7.0 and 0.10.0 (see "
        "covert_sensing_v2, _v3). Use covert_env.covert_sensing_v4 (or covert_env.parallel_env, "
        "gym.make('covert_env/CovertSensing-v4'), covert_env.vector_env), or pip install 'covert_env<0.6' for v1."
    ),
    "covert_sensing_v2": (
        "covert_sensing_v2 was replaced by covert_sensing_v3 in covert_env 0.7.0: line of sight lost between slot "
        "times now counts. The reward has a new term reward_los_path = -los_path_penalty * (share of the slot's "
        "flown path with LoS to the target blocked), the infos a cost cost_los_path (that share, in [0, 1], also "
        "in 'cost') and a flag los_path (LoS clear along the whole slot). Observations, dynamics, scenes and "
        "every other reward term and cost are unchanged: v3 with los_path_penalty=0 gives v2's rewards (v3 "
        "changed again in 0.10.0, see covert_sensing_v3). Use covert_env.covert_sensing_v4 (or "
        "covert_env.parallel_env, gym.make('covert_env/CovertSensing-v4'), covert_env.vector_env), or pip install "
        "'covert_env<0.7' for v2."
    ),
    "covert_sensing_v3": (
        "covert_sensing_v3 was replaced by covert_sensing_v4 in covert_env 0.10.0: every UAV's pose is settled at "
        "each slot end on a grid of 2^-20 m (about 1 micrometre) and 2^-24 rad, so that results reproduce bit for "
        "bit on CPUs whose math libraries differ in the last bit (AVX-512 or not). Observations, rewards, costs, "
        "scenes and spaces are otherwise unchanged, but seeded rollouts differ from v3's (in the last digits, and "
        "after tens of slots in the decisions). Use covert_env.covert_sensing_v4 (or covert_env.parallel_env, "
        "gym.make('covert_env/CovertSensing-v4'), covert_env.vector_env), or pip install 'covert_env<0.10' for "
        "v3."
    ),
}


def retired_entry(name: str) -> Callable[..., None]:
    """A constructor of the retired ``name`` (a key of :data:`RETIRED`): it raises what changed."""
    message = RETIRED[name]

    def retired(*args, **kwargs):
        raise RuntimeError(message)

    retired.__name__ = retired.__qualname__ = f"{name}_retired"
    return retired
