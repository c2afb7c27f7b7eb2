"""BenchMARL task for the covert multi-UAV sensing environment.

A BenchMARL user writes only the experiment::

    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig
    from covert_env.integrations.benchmarl import CovertSensingTask

    experiment = Experiment(
        task=CovertSensingTask.UNICYCLE.get_task(),        # or .WAYPOINT (discrete, masked)
        algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=ExperimentConfig.get_from_yaml(),
    )
    experiment.run()

Tasks (one group ``"uav"`` with agents ``uav_0 .. uav_{U-1}``, global ``"state"`` for centralised critics):

* ``CovertSensingTask.UNICYCLE``: continuous actions (speed, turn rate); MAPPO, IPPO, MADDPG, MASAC, ...
* ``CovertSensingTask.WAYPOINT``: discrete lattice waypoints with the env's action mask
  (``("uav", "action_mask")``, taken from ``infos[agent]["action_mask"]``); MAPPO, IPPO, QMIX, VDN, ...

``get_task(config={"vectorized": True})``: the copies BenchMARL collects from are one batched env in this process
(:class:`covert_env.integrations.torchrl.CovertSensingTorchRLEnv`), not one PettingZoo env per copy.

Every flat per-agent info of the env (``reward_*``, ``cost``, ``cost_*``, ``los``, ``in_zone``, ...) is
under ``("uav", "info")`` and BenchMARL logs its mean per iteration (``collection/uav/info/cost``, ...).

The default task config is :class:`TaskConfig` (shipped in Python, not in BenchMARL's yaml folder);
``get_task(config={...})`` overrides fields, e.g. ``{"n_uavs": 1, "max_cycles": 40}``, or picks a task of the
suite, ``{"suite_task": "downtown-3uav"}`` (:mod:`covert_env.world.tasks`: family, team and target).
``CovertSensingTask.UNICYCLE.get_from_yaml(path)`` reads a yaml file with the same fields.
:func:`register` also makes the tasks known to BenchMARL's hydra runner as ``task=covert_sensing/unicycle``
and ``task=covert_sensing/waypoint``; this module runs it::

    python -m covert_env.integrations.benchmarl algorithm=mappo task=covert_sensing/waypoint task.n_uavs=3
    python -m covert_env.integrations.benchmarl algorithm=mappo task=covert_sensing/waypoint \
        task.suite_task=downtown-3uav

Requires ``benchmarl`` (``pip install "covert_env[benchmarl]"``); this module is not imported by
``import covert_env``.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
from dataclasses import dataclass, field
from typing import Any

from benchmarl.environments.common import Task, TaskClass
from benchmarl.utils import _read_yaml_config
from torchrl.data import Composite
from torchrl.envs import EnvBase, PettingZooWrapper

import covert_env

__all__ = ["CovertSensingClass", "CovertSensingTask", "TaskConfig", "register"]

#: Name of the environment in BenchMARL's sense (its logs and output folders use it).
ENV_NAME = "covert_sensing"
#: Keywords the task sets itself: they are not allowed in ``env_kwargs``.
_TASK_SET = ("action_mode", "dict_obs", "render_mode", "n_uavs", "scenario", "max_cycles", "map_size", "config",
             "family", "task")


@dataclass
class TaskConfig:
    """Default config of both tasks (every field is a keyword of ``covert_env.parallel_env``)."""

    #: team size U; ``None``: the config's (3 UAVs by default) or the suite task's
    n_uavs: int | None = None
    #: a task of the suite (:mod:`covert_env.world.tasks`, e.g. ``"downtown-3uav"``): its family, team and target
    suite_task: str | None = None
    #: a scene family (:mod:`covert_env.world.families`, e.g. ``"dense"``) when no ``suite_task`` is given
    family: str | None = None
    #: ``"random"`` (a training scene per reset) or ``"paper"``
    scenario: str = "random"
    #: bound on the episode length in slots; ``None``: the route's length ``config.n_slots`` (70)
    max_cycles: int | None = None
    #: side of the observation maps
    map_size: int = 8
    #: :class:`covert_env.Config` overrides as a dict (``None``: the paper's defaults)
    config: dict[str, Any] | None = None
    #: any other keyword of ``covert_env.parallel_env`` (reward weights, ``scene_pool``, ...)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: ``True``: BenchMARL's ``n_envs_per_worker`` copies are one batched env in this process
    #: (:class:`~covert_env.integrations.torchrl.CovertSensingTorchRLEnv` on ``covert_env.vector_env``) instead of
    #: a ``SerialEnv`` of PettingZoo envs; it does not render
    vectorized: bool = False


class CovertSensingClass(TaskClass):
    """BenchMARL :class:`TaskClass` of the two covert-sensing tasks (see the module docstring)."""

    def _env_kwargs(self) -> dict[str, Any]:
        cfg = {**dataclasses.asdict(TaskConfig()), **copy.deepcopy(self.config or {})}
        unknown = sorted(set(cfg) - {f.name for f in dataclasses.fields(TaskConfig)})
        if unknown:
            raise ValueError(f"covert_sensing task config: unknown fields {unknown}; "
                             f"allowed: {[f.name for f in dataclasses.fields(TaskConfig)]}")
        cfg.pop("vectorized")
        extra = dict(cfg.pop("env_kwargs") or {})
        clash = sorted(set(extra) & set(_TASK_SET))
        if clash:
            raise ValueError(f"covert_sensing task config: env_kwargs may not set {clash} "
                             "(they are task fields or set by the task)")
        for key in ("max_cycles", "n_uavs", "family"):
            if cfg[key] is None:
                del cfg[key]
        suite_task = cfg.pop("suite_task")
        if suite_task is not None:
            cfg["task"] = suite_task
        waypoint = self.name.upper() == "WAYPOINT"
        # dict_obs=False: the mask comes through infos[agent]["action_mask"], which TorchRL's PettingZooWrapper
        # moves to ("uav", "action_mask"); the observation stays one flat tensor for BenchMARL's models.
        return {**cfg, **extra, "action_mode": "waypoint" if waypoint else "unicycle", "dict_obs": False}

    @property
    def vectorized(self) -> bool:
        return bool((self.config or {}).get("vectorized", False))

    def get_env_fun(self, num_envs: int, continuous_actions: bool, seed: int | None, device) -> Any:
        kwargs = self._env_kwargs()
        if self.vectorized:
            from covert_env.integrations.torchrl import CovertSensingTorchRLEnv

            def make_batched() -> EnvBase:
                env = CovertSensingTorchRLEnv(num_envs, device=device, **kwargs)
                env.set_seed(seed)                 # copy i from SeedSequence(seed), as covert_env.vector_env
                return env

            return make_batched
        # BenchMARL builds the num_envs copies of a non-vectorised env from this one function: give each copy
        # its own seed (seed, seed + 1, ...) so that they do not fly identical episodes.
        seeds = itertools.count(0 if seed is None else int(seed))

        def make() -> EnvBase:
            return PettingZooWrapper(env=covert_env.parallel_env(**kwargs, render_mode="rgb_array"),
                                     return_state=True, categorical_actions=True, seed=next(seeds),
                                     device=device)

        return make

    def supports_continuous_actions(self) -> bool:
        return self.name.upper() == "UNICYCLE"

    def supports_discrete_actions(self) -> bool:
        return self.name.upper() == "WAYPOINT"

    def max_steps(self, env: EnvBase) -> int:
        kwargs = self._env_kwargs()
        pz = covert_env.parallel_env(**kwargs)
        try:
            return int(pz.episode_length)          # min(max_cycles, config.n_slots)
        finally:
            pz.close()

    def has_render(self, env: EnvBase) -> bool:
        return not self.vectorized

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def _only(self, env: EnvBase, key: str) -> Composite | None:
        # One copy's specs, as BenchMARL asks of batched envs (VMAS); the same for a PettingZoo env.
        spec = env.full_observation_spec_unbatched.clone()
        for group in self.group_map(env):
            for k in list(spec[group].keys()):
                if k != key:
                    del spec[group][k]
            if spec[group].is_empty():
                del spec[group]
        if "state" in spec.keys():
            del spec["state"]
        return None if spec.is_empty() else spec

    def observation_spec(self, env: EnvBase) -> Composite:
        return self._only(env, "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        return self._only(env, "info")

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return self._only(env, "action_mask")

    def state_spec(self, env: EnvBase) -> Composite | None:
        spec = env.full_observation_spec_unbatched
        if "state" in spec.keys():
            return Composite({"state": spec["state"].clone()})
        return None

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


class CovertSensingTask(Task):
    """The covert-sensing tasks: ``UNICYCLE`` (continuous) and ``WAYPOINT`` (discrete, masked)."""

    UNICYCLE = None
    WAYPOINT = None

    @staticmethod
    def associated_class():
        return CovertSensingClass

    def get_from_yaml(self, path: str | None = None) -> TaskClass:
        """The task with its default :class:`TaskConfig` (``path=None``: shipped in Python, BenchMARL's own
        yaml folder does not know this task) or with the fields of the yaml file at ``path``."""
        config = dataclasses.asdict(TaskConfig())
        if path is not None:
            config.update(_read_yaml_config(str(path)))
        return self.get_task(config=config)


def register() -> None:
    """Make the tasks known to BenchMARL's hydra runner (``task=covert_sensing/unicycle``, ``.../waypoint``):
    adds them to ``benchmarl.environments.task_config_registry`` and their :class:`TaskConfig` to hydra's
    ``ConfigStore`` (group ``task``). Call it before composing the hydra config."""
    from benchmarl.environments import task_config_registry
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    for task in CovertSensingTask:
        name = f"{ENV_NAME}/{task.name.lower()}"
        task_config_registry[name] = task
        cs.store(group=f"task/{ENV_NAME}", name=task.name.lower(), node=TaskConfig)


def main() -> None:
    """BenchMARL's hydra runner with the covert-sensing tasks registered::

        python -m covert_env.integrations.benchmarl algorithm=mappo task=covert_sensing/waypoint task.n_uavs=3
    """
    register()
    from benchmarl.run import hydra_experiment

    hydra_experiment()


if __name__ == "__main__":
    main()
