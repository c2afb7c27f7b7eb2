"""Reference policies for covert_env: the paper's DP planner and simple baselines.

* :mod:`baselines.dp` -- the receding-horizon dynamic-programming planner of Almuzaini & Savkin (2024,
  §2.5, eqs. 17-21), shadow-aware (the paper's method) or shadow-blind (its comparison method [1]),
  with the decentralised team negotiation.
* :mod:`baselines.policies` -- one interface for every policy acting in the PettingZoo / Gymnasium
  environments: :class:`~baselines.policies.DPPolicy`, :class:`~baselines.policies.RandomPolicy`,
  :class:`~baselines.policies.HoldZoneCentrePolicy`.
* :mod:`baselines.reproduce` -- ``covert-env reproduce --out DIR``: the paper's figures and metrics.
"""

from baselines.dp import DPPlan, DPPlanner, DPTeamPlanner, TeamPlan
from baselines.policies import DPPolicy, HoldZoneCentrePolicy, Policy, RandomPolicy, make_policy, run_episode

__all__ = ["DPPlan", "DPPlanner", "DPTeamPlanner", "TeamPlan", "DPPolicy", "HoldZoneCentrePolicy", "Policy",
           "RandomPolicy", "make_policy", "run_episode"]
