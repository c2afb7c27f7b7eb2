"""Reference policies with one interface, for the PettingZoo and Gymnasium environments of covert_env.

Every policy has a ``name`` and two methods::

    policy.reset(env, seed=None)            # after env.reset(); seeds the policy's own randomness
    actions = policy.act(observations, env)

``env`` is either the PettingZoo :class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv` or one
of the Gymnasium single-UAV envs (``gym.make("covert_env/CovertSensing-v4")`` or
``"covert_env/CovertSensingWaypoint-v4"``, wrapped or not; the parallel env inside is
``env.unwrapped.par``). For the parallel env ``act`` returns ``{agent: action}``; for a Gymnasium env it
returns the single agent's action. Policies read the world from the env's public attributes
(``engine``, ``scenario``, ``config``, ``lattice``, ``action_mask``) as a planner with full knowledge
of the scene would; learned agents see only the observations.

Policies:

* :class:`DPPolicy` -- the paper's DP planner (:mod:`baselines.dp`), shadow-aware or shadow-blind, with
  the team negotiation. In waypoint mode its action is the planned node, exactly the move the planner
  makes (the env's lattice is the planner's node set), so an env rollout equals
  :func:`baselines.rollout.rollout` for the same scene. In unicycle mode see :func:`arc_action`. Its variants
  by name (:data:`POLICIES`), what each guarantees and what it costs per decision (one team replan; the
  benchmark's ``decision_time_ms`` column measures it):

  ==============  ===========================================================================================
  ``dp``          the paper's method: waypoints in the visible zone (eq. 10) at slot times, headings inherited
                  along the DP (§2.4). LoS and the zone hold at every slot time (to the predicted target; a
                  best-effort fallback when no node qualifies); between slots nothing is checked.
  ``dp-path``     ``dp`` with ``check_path=True``: a move is kept only if LoS and the zone hold at samples
                  along the manoeuvre, so the target is also seen between slot times (up to the samples'
                  spacing). 2-3.5 times ``dp``'s time (a 3-UAV episode on a paper and a downtown scene).
  ``dp-blind``    the shadow-blind predecessor [1]: the feasible zone (eq. 5) without shadows; no LoS
                  guarantee at all. About ``dp``'s time.
  ``dp-binned``   ``dp`` with 16 heading bins per node instead of one inherited heading: the DP's optimum over
                  headings (``python -m benchmarks.dp --optimality`` measures how often the inherited heading
                  misses it). 2.5-3 times ``dp``'s time.
  ==============  ===========================================================================================
* :class:`RandomPolicy` -- uniform over the allowed waypoints (the action mask), or uniform in the box.
* :class:`HoldZoneCentrePolicy` -- heads for the centre of the feasible zone behind the target, every slot:
  covert-naive (no disguise) but always in the zone when it can be reached.

:func:`run_episode` (:mod:`covert_env.evaluation.episodes`, imported here) runs any of them to the end and scores
the episode with :func:`covert_env.world.metrics.episode_metrics`, the code every policy is scored with.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from baselines.dp import DPPlanner, DPTeamPlanner, TeamPlan
from covert_env.envs.batch import MIN_SPEED_FRACTION  # the env's unicycle action scaling, inverted below
from covert_env.evaluation.episodes import parallel_env_of, run_episode
from covert_env.geometry.ties import first_argmin
from covert_env.geometry.zone import to_world

__all__ = [
    "ALIASES",
    "DPPolicy",
    "HoldZoneCentrePolicy",
    "POLICIES",
    "Policy",
    "RandomPolicy",
    "arc_action",
    "builtin_policy",
    "make_policy",
    "parallel_env_of",
    "run_episode",
]



def arc_action(xy, theta, goal, config) -> np.ndarray:
    """The unicycle action (env scaling, in [-1, 1]^2) whose constant (v, omega) arc ends at ``goal``.

    Holding (v, omega) for the slot flies a circular arc tangent to the heading (eq. 1). The arc from
    (xy, theta) through ``goal`` turns by twice the goal's bearing beta, so ``omega = 2 beta / delta`` and
    ``v = chord * beta / (delta sin beta)``. What this loses against the turn-then-straight manoeuvre the
    planner assumes (a turn at +-W_max, then straight):

    * the heading on arrival is ``theta + 2 beta`` instead of the manoeuvre's, so the next plan starts
      from another heading than the one planned for (the policy replans every slot from the true pose);
    * goals with ``|beta| > W_max delta / 2`` need ``|omega| > W_max`` in a single arc: omega is clipped and
      the arc misses the goal, although the two-segment manoeuvre reaches it;
    * the path length, hence the energy term of eq. 18, differs from the planned one;
    * speeds below 1% of V_max cannot be commanded.

    Returns:
        (2,) float32 action: ``a0`` maps to ``v = V_max (0.01 + 0.99 (a0 + 1) / 2)``, ``a1`` to ``omega = W_max a1``.
    """
    c = config
    rel = np.asarray(goal, float) - np.asarray(xy, float)
    ct, st = math.cos(theta), math.sin(theta)
    a, b = ct * rel[0] + st * rel[1], -st * rel[0] + ct * rel[1]
    chord = math.hypot(a, b)
    beta = math.atan2(b, a)
    if chord < 1e-9:
        v, omega = 0.0, 0.0
    else:
        omega = 2.0 * beta / c.delta
        v = chord / c.delta * (beta / math.sin(beta) if abs(beta) > 1e-9 else 1.0)
    a0 = 2.0 * ((min(v / c.v_max, 1.0) - MIN_SPEED_FRACTION) / (1.0 - MIN_SPEED_FRACTION)) - 1.0
    a1 = omega / c.w_max
    return np.clip(np.array([a0, a1]), -1.0, 1.0).astype(np.float32)


class Policy:
    """The common interface (see the module docstring). Subclasses implement :meth:`act_parallel`."""

    name = "policy"

    def reset(self, env, seed: int | None = None) -> None:
        """Start a new episode (call after ``env.reset()``); ``seed`` seeds the policy's own RNG."""
        self._rng = np.random.default_rng(seed)

    def act(self, observations, env):
        """Actions for the current slot: ``{agent: action}`` for a parallel env, one action for a Gymnasium env."""
        par, single = parallel_env_of(env)
        if not hasattr(self, "_rng"):
            self._rng = np.random.default_rng()
        acts = self.act_parallel(par)
        return acts[single] if single is not None else acts

    def act_parallel(self, par) -> dict[str, Any]:  # pragma: no cover - interface
        raise NotImplementedError


class DPPolicy(Policy):
    """The paper's DP planner as a policy (:class:`baselines.dp.DPTeamPlanner` over the env's engine).

    Args:
        shadow_aware: the paper's method (visible zone, eq. 10); False is the shadow-blind method [1].
        heading: ``"inherited"`` (the paper) or ``"binned"``; heading_bins: B for ``"binned"``.
        check_path: also keep LoS and the zone along every manoeuvre (see :class:`~baselines.dp.DPPlanner`).
        max_rounds, separation_margin: negotiation settings (:class:`~baselines.dp.DPTeamPlanner`).
        horizon: plan over this many slots, from 1 to the env's ``config.horizon`` (default: all of them, the
            paper's N). Shorter horizons measure what the look-ahead is worth (``benchmarks/dp_horizon.py``).
        known_slots: read only this many slots of the target's prediction (>= 1) and extrapolate the rest at a
            constant speed and turn rate (:func:`baselines.dp.team.extrapolate_target`); default None: all. A
            planner as far-sighted as the paper's that knows the target's future only as far as the default
            observation shows it (1 slot): what the target's path is worth apart from the look-ahead itself.
            Only on targets without prediction error (the planner's possible targets lie on the road).
        path_cost: None (the paper), or a cost per stage on LoS blocked along the manoeuvre
            (:class:`~baselines.dp.DPPlanner`'s ``path_cost``; the learned planner fits it).
        separated_continuation: the team's one-slot look-ahead past plans that end after the slot flown
            (:class:`~baselines.dp.DPTeamPlanner`); off for the paper's planner.
        best_effort_escape: the safety layer may fly a best effort toward an unreachable node where no priority
            order separates the team with its moves (:class:`~baselines.dp.DPTeamPlanner`); off for the paper's
            planner.

    Waypoint mode acts with the planned node indices (exact). Unicycle mode flies :func:`arc_action` toward
    the planned first waypoint; read its docstring for what that mapping loses. ``last_plan`` holds the
    latest :class:`~baselines.dp.TeamPlan` (per-UAV fallback flags, negotiation rounds, timing).
    """

    def __init__(self, shadow_aware: bool = True, heading: str = "inherited", heading_bins: int = 16,
                 check_path: bool = False, max_rounds: int = 5, separation_margin: float = 0.5,
                 horizon: int | None = None, known_slots: int | None = None, path_cost=None,
                 separated_continuation: bool = False, best_effort_escape: bool = False):
        for name, v in (("horizon", horizon), ("known_slots", known_slots)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1):
                raise ValueError(f"DPPolicy: {name} must be None or an integer >= 1, got {v!r}")
        if known_slots is not None and horizon is not None and known_slots > horizon:
            raise ValueError(f"DPPolicy: known_slots {known_slots} is more than the horizon {horizon}: the planner "
                             "reads at most horizon slots")
        if known_slots is not None and check_path:
            raise ValueError("DPPolicy: known_slots does not go with check_path (the path's samples are the track's "
                             "prediction)")
        for name, flag in (("separated_continuation", separated_continuation),
                           ("best_effort_escape", best_effort_escape)):
            if not isinstance(flag, (bool, np.bool_)):
                raise ValueError(f"DPPolicy: {name} must be True or False, got {flag!r}")
        self.horizon = None if horizon is None else int(horizon)
        self.known_slots = None if known_slots is None else int(known_slots)
        if known_slots is not None and path_cost is not None:
            raise ValueError("DPPolicy: known_slots does not go with path_cost (the path's samples are the track's "
                             "prediction)")
        self.kw = dict(shadow_aware=shadow_aware, heading=heading, heading_bins=heading_bins,
                       check_path=check_path, path_cost=path_cost)
        self.team_kw = dict(max_rounds=max_rounds, separation_margin=separation_margin,
                            separated_continuation=separated_continuation, best_effort_escape=best_effort_escape)
        self._world = None
        self.team: DPTeamPlanner | None = None
        self.last_plan: TeamPlan | None = None
        h = "inherited" if heading == "inherited" else f"binned{heading_bins}"
        self.name = (f"dp-{'aware' if shadow_aware else 'blind'}-{h}{'-path' if check_path else ''}"
                     f"{'' if path_cost is None else '-pathcost'}"
                     f"{'-continuation' if separated_continuation else ''}"
                     f"{'-escape' if best_effort_escape else ''}"
                     f"{'' if horizon is None else f'-horizon{horizon}'}"
                     f"{'' if known_slots is None else f'-known{known_slots}'}")

    def _team(self, par) -> DPTeamPlanner:
        # One planner per scene: its caches are keyed by the target's poses, which only hold for one terrain.
        # (The env builds a new Scenario object per reset when it draws the starts, so compare the world.)
        world = (par.scenario.terrain, par.scenario.track)
        if self.team is None or self._world is None or world[0] is not self._world[0] \
                or world[1] is not self._world[1]:
            self._world = world
            # The road bounds where the true target may be under a prediction error
            # (docs/decisions/model.md#prediction-los).
            self.team = DPTeamPlanner(DPPlanner(par.config, par.scenario.terrain, road=par.scenario.track.road,
                                                **self.kw), **self.team_kw)
        return self.team

    def reset(self, env, seed: int | None = None) -> None:
        super().reset(env, seed)
        self.last_plan = None

    def act_parallel(self, par) -> dict[str, Any]:
        team = self._team(par)
        if self.horizon is not None and self.horizon > par.config.horizon:
            raise ValueError(f"DPPolicy: horizon {self.horizon} is longer than the env's config.horizon "
                             f"{par.config.horizon} (the route reaches that many slots past the episode's last)")
        if self.known_slots is not None and self.known_slots > par.config.horizon:
            raise ValueError(f"DPPolicy: known_slots {self.known_slots} is more than the env's config.horizon "
                             f"{par.config.horizon} (the planner reads at most that many slots)")
        if self.known_slots is not None and par.config.prediction_error > 0:
            raise ValueError(f"DPPolicy: known_slots needs a target without prediction error, got "
                             f"config.prediction_error = {par.config.prediction_error:g} (the planner's possible "
                             "targets lie on the road; an extrapolated path leaves it)")
        plan = team.plan_engine(par.engine, self.horizon, self.known_slots)
        self.last_plan = plan
        if par.action_mode == "waypoint":
            return {a: int(plan.nodes[i]) for i, a in enumerate(par.possible_agents) if a in par.agents}
        eng = par.engine
        return {a: arc_action(eng.uav_xy[i], eng.uav_theta[i], plan.waypoints[i], par.config)
                for i, a in enumerate(par.possible_agents) if a in par.agents}


class RandomPolicy(Policy):
    """Uniformly random actions: a random allowed waypoint (per the action mask), or a uniform box action."""

    name = "random"

    def act_parallel(self, par) -> dict[str, Any]:
        out = {}
        for a in par.agents:
            if par.action_mode == "waypoint":
                out[a] = int(self._rng.choice(np.flatnonzero(par.action_mask(a))))
            else:
                out[a] = self._rng.uniform(-1.0, 1.0, 2).astype(np.float32)
        return out


class HoldZoneCentrePolicy(Policy):
    """Head for the centre of the feasible zone at the target's next pose, every slot.

    The centre is the point (R1 + R2) / 2 straight behind the target. Waypoint mode picks the allowed node
    (action mask) nearest to it; unicycle mode flies :func:`arc_action` toward it. It keeps the UAV in the
    zone but never changes bearing or range on purpose: the "no disguise" reference.
    """

    name = "hold-centre"

    def act_parallel(self, par) -> dict[str, Any]:
        c = par.config
        eng = par.engine
        q1, phi1 = eng.predict(1)
        centre = np.array([-(c.r1 + c.r2) / 2.0, 0.0])
        goal = to_world(centre[None], q1[0, :2], float(phi1[0]))[0]
        out = {}
        for i, a in enumerate(par.possible_agents):
            if a not in par.agents:
                continue
            if par.action_mode == "waypoint":
                d = np.hypot(*(par.lattice - centre).T)
                out[a] = first_argmin(np.where(par.action_mask(a) > 0, d, np.inf))
            else:
                out[a] = arc_action(eng.uav_xy[i], eng.uav_theta[i], goal, c)
        return out


POLICIES = {
    "dp": lambda **kw: DPPolicy(**kw),
    "dp-blind": lambda **kw: DPPolicy(shadow_aware=False, **kw),
    "dp-binned": lambda **kw: DPPolicy(heading="binned", **kw),
    "dp-path": lambda **kw: DPPolicy(check_path=True, **kw),
    "random": lambda **kw: RandomPolicy(**kw),
    "hold-centre": lambda **kw: HoldZoneCentrePolicy(**kw),
}


ALIASES = {"heuristic": "hold-centre"}
"""Other names of built-in policies: alias -> the name in :data:`POLICIES`."""


def builtin_policy(spec: str, n_uavs: int, *, trust_checkpoint: bool = False) -> tuple[Policy, dict]:
    """The factory of the built-in policy specs (a name of :data:`POLICIES` or :data:`ALIASES`; entry point group
    ``covert_env.policies``, :mod:`covert_env.evaluation.registry`): the policy and its env settings. The planners
    act in waypoint mode, where they act exactly as planned; ``random`` and ``hold-centre`` in unicycle mode, the
    action space of the learned continuous policies. ``trust_checkpoint`` is not needed: nothing is unpickled."""
    name = ALIASES.get(spec, spec)
    return make_policy(name), {"n_uavs": n_uavs, "action_mode": "waypoint" if name.startswith("dp") else "unicycle"}


# Its tier on the leaderboards (covert_env.evaluation.tiers): the planners read the terrain and the target's route.
builtin_policy.tier = lambda spec: "planner" if ALIASES.get(spec, spec).startswith("dp") else "reference"


def make_policy(name: str, **kwargs) -> Policy:
    """A policy by name: one of :data:`POLICIES` (``dp``, ``dp-path``, ``dp-blind``, ``dp-binned``, ``random``,
    ``hold-centre``)."""
    if name not in POLICIES:
        raise ValueError(f"unknown policy {name!r}; choose one of {sorted(POLICIES)}")
    return POLICIES[name](**kwargs)
