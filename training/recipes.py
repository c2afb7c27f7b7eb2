"""Named training settings (documented recipes). ``python -m training.sb3.ppo_multi --recipe NAME``; flags override.

``3uav-ppo`` -- the documented 3-UAV parameter-shared PPO recipe: trains in <= 60 minutes on 2 CPU cores.

    OMP_NUM_THREADS=1 python -m training.sb3.ppo_multi --recipe 3uav-ppo          # stops at its time budget, saves
    covert-env evaluate --policies random hold-centre dp sb3:runs/<run> --trust-checkpoint --episodes 20

Why these settings:

* 8 env copies x 3 agents = 24 rows of one shared policy; 256-step rollouts (6144 agent-steps per update),
  5 epochs of 1024-sample minibatches: small updates keep the learner cheap next to the (exact, vectorised, but
  not free) line-of-sight simulation, which dominates the wall clock.
* gamma 0.97 (a ~33-slot horizon inside the 70-slot route) and GAE lambda 0.95; truncation at the end of the
  route is flagged ``TimeLimit.truncated`` by our adapter, so SB3 bootstraps the last value instead of treating
  the route's end as a terminal state.
* Observations are roughly unit scale already; VecNormalize still normalises them (the map bits are rare) and,
  above all, normalises rewards (the disguise term can reach +4 per slot while penalties are -1..-3).
* Training-time reward shaping (evaluation always uses the env's default reward):
  ``los_penalty = zone_penalty = 2`` and the disguise bonus only counts while the UAV is inside the feasible
  zone (``disguise_in_zone_only``). Without that, circling close to the target earns more disguise
  (|d alpha| is large near the target) than the zone penalty costs: a covertness-violating exploit.
* Small MLP (128, 128, tanh), initial action std exp(-0.5): near-random actions fly away from the target
  (random unicycle actions leave the zone in almost every slot), a narrower start helps the team find the zone
  sooner.
* Time budget: ``time_budget_minutes = 50`` stops training gracefully and saves; ``total_timesteps`` is an
  upper bound that the 2-core machine does not reach in 50 minutes.

The runs of this recipe and what they scored: docs/training.md, "The 3-UAV PPO recipe".

``smoke`` -- a few thousand steps, for CI.
"""

from __future__ import annotations

__all__ = ["RECIPES", "MAPPO_RECIPES"]

RECIPES: dict[str, dict] = {
    "3uav-ppo": dict(
        n_uavs=3, n_copies=8, action_mode="unicycle", total_timesteps=20_000_000, time_budget_minutes=50.0,
        learning_rate=3e-4, n_steps=256, batch_size=1024, n_epochs=5, gamma=0.97, gae_lambda=0.95,
        clip_range=0.2, ent_coef=0.0, net_arch=(128, 128), log_std_init=-0.5, norm_obs=True, norm_reward=True,
        los_penalty=2.0, zone_penalty=2.0, disguise_in_zone_only=True, checkpoint_freq=500_000,
    ),
    "smoke": dict(
        n_uavs=3, n_copies=2, total_timesteps=3_000, n_steps=128, batch_size=256, n_epochs=2,
        time_budget_minutes=5.0, checkpoint_freq=1_536, progress_bar=False, max_cycles=20,
    ),
}


#: Named settings of :mod:`training.mappo` (``python -m training.mappo --recipe NAME``; flags override).
#: ``3uav-mappo``: MAPPO in the waypoint mode with the separation shield (training.shield) and the Lagrangian
#: on the separation cost, 45 minutes of wall clock (three seeds at once on 2 cores; docs/training.md has the
#: measured runs).
#: ``3uav-suite``: the team of the task suite, trained through the safety filter. It trains on the training scenes of
#: the suite's eight 3-UAV core tasks at once (one vector env of 256 copies, 32 per task, covert_env.envs.task_mix; 16
#: slots per update), with the kinematic mask (every reachable node: the team must learn the shadows), the node head
#: reading the 24 x 24 visibility map under each node (docs/training.md says what it is worth), a Lagrange multiplier
#: per constraint (LoS at slot times, LoS along the path, the zone, separation) with a dual step of 1 and a bound of 4,
#: and the safety filter (covert_env.envs.safety_filter: eqs. 2 and 3 kept on the flown path, every move certified) with
#: its viability rule at a bar of 10 (no node from which fewer than 10 nodes are reachable next slot, where another
#: leaves 10). The team proposes, the filter's preferences are its logits, and a replacement inside the mask is learned
#: as the action flown. 40 minutes of wall clock, one seed per core. The bound keeps a limit the team does not reach
#: from drowning the reward (docs/decisions/learning.md, "Learned teams across the suite" and "Safety filter").
#: ``6uav-suite``: ``3uav-suite`` for teams of six, on the eight 6-UAV tasks of the same families and deviations; 128
#: copies (16 per task), so that an update holds as many agent-samples (128 x 16 x 6) as the 3-UAV recipe's.
#: ``3uav-suite-shield``: the suite team before the filter (``pretrained:mappo-suite-shield``): 16
#: copies, 64 slots per update, the separation shield with its look-ahead and its viability rule instead of the
#: filter; 45 minutes (three seeds at once on 2 cores).
#: ``3uav-suite-path``: ``3uav-suite-shield`` with the target's path predicted over the planner's five slots in the
#: observation (the env's ``target_path=5``): the DP planner plans on that path; the suite team sees one slot.
#: ``3uav-suite-manoeuvre``: ``3uav-suite-shield`` with the node head also reading the manoeuvre to each node
#: (whether one exists, its length, the heading the UAV arrives with): the heading at a node sets what the next slot
#: reaches, which the planner's search weighs and the node's position alone does not tell.
MAPPO_RECIPES: dict[str, dict] = {
    "3uav-suite-shield": dict(
        algo="mappo", n_uavs=3, num_envs=16, action_mode="waypoint", head="node", node_map=True, map_size=16,
        mask_mode="kinematic", learning_rate=1e-3, time_budget_minutes=45.0, separation_shield=True,
        viability_shield=True, viability_min_reach=10, shield_lookahead=True, shield_end_margin=10.0, lagrangian=True,
        constraints="los=0.01,los_path=0.04,zone=0.015", lagrange_lr=1.0, lambda_max=4.0,
        tasks="sparse-3uav,paper-3uav,winding-3uav,dense-3uav,downtown-3uav,towers-3uav,paper-3uav-deviating,"
              "downtown-3uav-deviating",
        checkpoint_every=100_000,
    ),
    "3uav-mappo": dict(
        algo="mappo", n_uavs=3, num_envs=16, action_mode="waypoint", head="node", learning_rate=1e-3,
        time_budget_minutes=45.0, separation_shield=True, shield_end_margin=10.0, lagrangian=True,
        checkpoint_every=100_000,
    ),
}
MAPPO_RECIPES["3uav-suite"] = {
    **MAPPO_RECIPES["3uav-suite-shield"], "num_envs": 256, "num_steps": 16, "time_budget_minutes": 40.0,
    "separation_shield": False, "shield_lookahead": False, "safety_filter": True, "filter_scores": True,
    "learn_flown_nodes": True, "map_size": 24,
}
MAPPO_RECIPES["6uav-suite"] = {
    **MAPPO_RECIPES["3uav-suite"], "n_uavs": 6, "num_envs": 128,
    "tasks": "sparse-6uav,paper-6uav,winding-6uav,dense-6uav,downtown-6uav,towers-6uav,paper-6uav-deviating,"
             "downtown-6uav-deviating",
}
MAPPO_RECIPES["3uav-suite-path"] = {**MAPPO_RECIPES["3uav-suite-shield"], "target_path": 5}
MAPPO_RECIPES["3uav-suite-manoeuvre"] = {**MAPPO_RECIPES["3uav-suite-shield"], "node_manoeuvre": True}
