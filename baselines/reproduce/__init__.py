"""Reproduce the paper's experiments: ``covert-env reproduce --out DIR`` (or ``python -m baselines.reproduce``).

Runs the paper's DP planner (:mod:`baselines.dp`) on the paper's defaults (Config(): N = 5, delta = 1 s,
V_max = 50 m/s, W_max = 3 rad/s, eta = 55, lambda = 10, 70 slots):

1. the paper scenario with 1 UAV (§3.1) and with 3 UAVs (§3.2), the shadow-aware planner (the paper's
   method, "aware") against the shadow-blind one (the earlier method [1], "blind");
2. both methods on 20 held-out random scenes (``Scenario.random(1_000_000 + i)``: terrain, road and
   starts), with 1 and 3 UAVs;
3. the shadow-aware planner with ``check_path=True`` ("aware-path") on the held-out scenes, which also
   keeps the line of sight between slot times (1 UAV by default; ``--path-uavs 1 3`` adds 3 UAVs).

Every run drives a :class:`covert_env.world.engine.Engine` exactly as the waypoint environment does (same
scenario, same lattice nodes as waypoints), and is scored by :func:`covert_env.world.metrics.episode_metrics`.

Outputs in ``--out``:

* ``fig08_trajectories_1uav.png`` ... ``fig15_disguise_3uav.png``: like the paper's Figs. 8-15 --
  trajectories (a top view per method, a 3D view of the flown area, the positions in the target's frame),
  the LoS occlusion index I_LoS per slot, the zones with shadows at one slot (:func:`figure_slot`: where the
  shadow-blind method loses LoS for the most UAVs, else where the zone is most in shadow), disguise kappa per slot;
* ``fig_heldout.png``: occlusion and disguise per held-out scene, with the mean and its 95 % CI;
* ``fig_los_between_slots.png``: per held-out scene, UAV-slots whose LoS was clear at the slot time but lost
  along the manoeuvre before it (the paper checks slot times only);
* ``metrics.json``: one record per run and UAV (episode metrics of docs/model.md#metrics, blocked-LoS counts,
  infeasible-slot counts, planning time, negotiation rounds);
* ``metrics.md``: every rate with a 95 % percentile bootstrap confidence interval over the held-out scenes
  (:func:`bootstrap_ci`), counts, the paper's claims checked, and where the time went;
* ``sensitivity.md`` (``--sensitivity``): grid step, r_u, h_min and target speed varied one at a time;
* ``prediction_study.md``, ``.json`` and ``fig_prediction.png`` (``--prediction-study``): a prediction error of
  4 m, the planner with r_u = 0, with the eroded zone of eq. 5, and with it and the widened shadows
  (docs/decisions/model.md#prediction-los): zone violations and blocked LoS against the true target, with 95 % CIs
  (:mod:`baselines.prediction_study`).

``--quick`` flies the paper scene and 2 held-out scenes for 15 slots, chosen so that the paper's effects show:
the paper scene's zone is in shadow at slots 11-15 and the held-out scenes are the 2 of the first 20 whose zone is
most in shadow over those slots (:func:`most_shadowed_scenes`, geometry only). ``--jobs`` sets worker processes.
``covert-env animate --out docs/dp_team.gif`` (:func:`write_gif`) writes the README's animation.

The modules: ``runs`` (the scenes and the runs), ``figures``, ``report`` (``metrics.md``), ``sensitivity`` and
``command`` (the command line and the job).
"""


from baselines.intervals import bootstrap_ci
from baselines.reproduce.command import build_parser, main
from baselines.reproduce.figures import write_gif
from baselines.reproduce.runs import (
    HELDOUT_SEED_BASE,
    METHODS,
    QUICK_POOL,
    QUICK_SCENES,
    QUICK_SLOTS,
    RunSpec,
    figure_slot,
    make_scenario,
    most_shadowed_scenes,
    run,
    run_pairs,
    zone_shadow_shares,
)
from baselines.reproduce.sensitivity import sensitivity
from baselines.rollout import rollout

__all__ = ["HELDOUT_SEED_BASE", "METHODS", "QUICK_POOL", "QUICK_SCENES", "QUICK_SLOTS", "RunSpec", "bootstrap_ci",
           "build_parser", "figure_slot", "main", "make_scenario", "most_shadowed_scenes", "rollout", "run",
           "run_pairs", "sensitivity", "write_gif", "zone_shadow_shares"]
