"""MAPPO and IPPO on the batched vector env (``covert_env.vector_env``).

    OMP_NUM_THREADS=1 python -m training.mappo --recipe 3uav-mappo --seed 0        # the documented recipe
    OMP_NUM_THREADS=1 python -m training.mappo --algo mappo --action-mode waypoint --time-budget-minutes 55
    OMP_NUM_THREADS=1 python -m training.mappo --algo ippo --action-mode unicycle
    python -m training.mappo --resume runs/<run>                  # continue from the newest checkpoint
    covert-env evaluate --policies dp random@waypoint mappo:runs/<run>
    tensorboard --logdir runs

The modules, in the order the loop runs them: ``args`` (the settings and their checks); ``agents`` (the networks of
``networks``, whose node head scores nodes in ``node_head``, read and written as numpy rows); ``rollout`` (same-step
autoreset, truncation bootstrap, episode statistics); ``ppo`` (GAE and the PPO update, whose node head's
log-probabilities and entropies are ``node_categorical``'s); ``checkpoints`` (progress,
model card, ``.npz`` + JSON checkpoints: nothing is pickled); ``train``, which runs them in that order.

* **Actor** (parameter-shared, every UAV of every copy): an MLP on the agent's own observation. Waypoint mode:
  a masked categorical over the lattice nodes (masked nodes get -inf), by default scoring each node from its
  geometry relative to the UAV and teammates (``--head node``, :func:`training.pretrained.node_features`;
  ``--head flat`` is one logit per node). Unicycle mode: a Gaussian with a state-independent std; actions are
  **clipped** to [-1, 1] by the env (no tanh squashing; the log-probability is that of the unclipped sample,
  as in CleanRL's continuous PPO).
* **Map under each node** (``--node-map``): the node head also reads the observation's ``map_next`` under each
  node and the move's midpoint, so that a team acting with ``--mask-mode kinematic`` sees the shadows where it
  scores the nodes (docs/decisions/learning.md, "Learned teams across the suite").
* **Tasks** (``--tasks a,b,...``): the copies are split evenly over suite tasks and draw from each task's training
  scenes, all in one vector env (:mod:`covert_env.envs.task_mix`); without it, random scenes of the paper family.
* **Separation shield** (waypoint mode, ``--separation-shield``, on by default): the UAVs of a copy choose one
  after another, and a UAV may not choose a node whose path comes closer than d_safe1 to a teammate's chosen
  path (:mod:`training.shield`; the env's ``waypoint_paths`` flies the candidates). The shielded masks are
  stored with the actions, so PPO's ratios use the masks the actions were sampled under, and the harness runs
  the same shield (the model card's ``separation_shield``).
* **Safety filter** (waypoint mode, ``--safety-filter``; with the separation shield on too, the team proposes
  through the shield): the team's sampled
  nodes are proposals, and the env flies the nodes of :class:`covert_env.envs.safety_filter.SafetyFilteredVectorEnv`,
  which keeps eqs. 2 and 3 along the flown path and certifies each move by a backup plan (action projection: PPO
  keeps the probabilities of the proposals, the rewards and costs are those of the moves flown). The harness
  flies a team trained so through the same filter (the model card's ``safety_filter``). With ``--filter-scores``
  the filter orders each UAV's alternatives by the policy's node logits instead of by the distance to its
  proposal, in training and in the harness alike (the card's ``filter_scores``).
* **Critic**: MAPPO (``--algo mappo``) sees the centralised ``state()`` of the copy plus a one-hot of the agent
  (the rewards are per agent, so one state value would not do); IPPO (``--algo ippo``) sees the agent's own
  observation. Value targets are normalised by running statistics (``--value-norm``, MAPPO's ValueNorm).
* **Autoreset**: the vector env resets an ended copy within ``step()`` and hands back its last observation and
  state in ``infos["final_obs"/"final_state"]``. A step that ended a copy is a done for GAE (no bootstrap across
  episodes). Truncated before the route's end (``--max-cycles`` < the track's ``n_slots``), the value of the
  final observation/state is added as ``gamma V(final)`` to the last reward (the time limit is not part of the
  task). At the route's end (the default 70 slots) there are no more slots: the episode truly ends, V = 0.
* **Reward**: the env's default reward (eq. 18 / reward_scale plus unit penalties); the constraint costs
  ``cost_*`` of the infos are logged per episode. Constrained RL, one Lagrange multiplier per constraint:
  ``--constraints zone=0.01,los_path=0.005`` subtracts ``lambda_c * cost_c`` from the training reward for each
  named env cost c (``covert_env.envs.batch.COSTS``), lambda_c >= 0 raised by dual ascent while the rollout's mean
  cost per UAV and slot exceeds its limit; ``--lagrangian`` adds ``separation=--cost-limit`` (eq. 2);
  ``--lambda-max`` bounds every multiplier.
* **Two cores for one run** (``--overlap-update``, off by default): the PPO update of a rollout runs in a second
  thread while the next rollout is collected, by a copy of the networks one update behind (PPO's ratios and GAE
  against the weights that acted, as in asynchronous PPO). The update draws its minibatches from its own
  generator, so a seed's run does not depend on the threads' timing. Checkpoints and logs count the env-steps
  learned from. With it, the logged ``approx_kl`` and clip fraction include the lag.
* **Warm start** (``--init-actor pretrained:NAME``): the actor starts from trained weights (with ``--node-map``
  added, its map inputs start at zero), and ``--actor-warmup-updates`` lets the fresh critic learn first.

Env steps count copy-slots (one step of one env copy, all its UAVs); agent-steps are ``n_uavs`` times more.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from training.common import checked_main
from training.mappo.args import Args, actor_fields, check_args, constraint_limits, init_actor_fits, task_list
from training.pretrained import PRETRAINED_DIR
from training.recipes import MAPPO_RECIPES

#: The loop's pieces and their modules: they need torch, so they are imported when first asked for.
_LAZY = {
    "Agents": "agents", "RunningNorm": "agents", "Sizes": "agents", "behaviour_copy": "agents",
    "copy_weights": "agents", "gumbel_pick": "agents",
    "load_initial_actor": "agents", "make_networks": "agents", "sizes_of": "agents",
    "COST_KEYS": "rollout", "Episodes": "rollout", "Rollout": "rollout", "collect_rollout": "rollout",
    "advantages": "ppo", "ppo_update": "ppo",
    "Progress": "checkpoints", "latest_checkpoint": "checkpoints", "load_checkpoint": "checkpoints",
    "model_card": "checkpoints", "resume": "checkpoints", "save_checkpoint": "checkpoints", "save_final": "checkpoints",
    "log_update": "train", "train": "train",
}

__all__ = ["PRETRAINED_DIR", "Args", "actor_fields", "check_args", "constraint_limits", "init_actor_fits", "main",
           "task_list", *sorted(_LAZY)]


def __getattr__(name: str):
    """The loop's pieces (``_LAZY``), imported when first asked for: the settings and ``main`` need no torch."""
    if name in _LAZY:
        return getattr(importlib.import_module(f"training.mappo.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'training.mappo' has no attribute {name!r}")


def main(argv: list[str] | None = None) -> Path:
    """``python -m training.mappo``: parse and check the flags (a bad one exits with status 2 and names it), then
    train; returns the run folder."""
    return checked_main(Args, argv, description=__doc__.split("\n")[0], check=check_args, run=_train,
                        presets=MAPPO_RECIPES)


def _train(args: Args) -> Path:
    """The loop, imported here: it needs torch, the flags' checks do not."""
    from training.mappo.train import train

    return train(args)
