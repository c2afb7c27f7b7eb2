"""The task suite: named tasks over scene families x team size x target behaviour, each with fixed scenes.

A task is what a benchmark row is measured on: a scene family (:mod:`covert_env.world.families`), a team size and how
the target drives. Pass its name wherever an env is made, or to the suite protocol::

    covert_env.parallel_env(task="downtown-3uav")            # PettingZoo; also env(), vector_env(), gym.make
    covert-env benchmark --tasks core --policies dp dp-blind random --out outputs/suite

Names are ``{family}-{U}uav`` (nominal target) or ``{family}-{U}uav-deviating``. Every task trains on the family's
training scenes (:data:`~covert_env.world.families.TRAIN_SEEDS`) and is scored on its first :data:`TEST_SCENES`
held-out scenes (:data:`~covert_env.world.families.HELD_OUT_SEEDS`), each flown from its own seeded starts.

=============  ========================================================================================================
target         what it is
=============  ========================================================================================================
``nominal``    the paper's setting: the target drives the predicted track exactly (``prediction_error`` = 0).
``deviating``  the target's speed deviates from the prediction, by at most :data:`DEVIATION` m along the road at any
               slot a prediction covers (``prediction_error`` = :data:`DEVIATION`,
               docs/decisions/model.md#prediction-error); the zone is eroded by as much (``r_u`` = :data:`DEVIATION`,
               eq. 5), so a planner that keeps to it stays in the true zone; line of sight is where the prediction
               breaks down.
=============  ========================================================================================================

The suite is versioned (:data:`SUITE_VERSION`): a change to any task's scenes, team, target or test scenes makes a
new version, so results carry the version they were measured on. :data:`DEFAULT_TASKS` is the set the protocol
runs by default (every family with 3 UAVs, the paper family with 1 and 6, two deviating tasks).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

from covert_env.world.config import Config
from covert_env.world.families import FAMILIES, HELD_OUT_SEEDS, TRAIN_SEEDS, family_config

__all__ = ["DEFAULT_TASKS", "DEVIATION", "SUITE_VERSION", "TASKS", "TEAM_SIZES", "TEST_SCENES", "Task", "get_task",
           "resolve_tasks"]

SUITE_VERSION = "suite-v0"
"""The version of the task list, the tasks' scenes and their test scenes."""
TEAM_SIZES = (1, 3, 6)
"""Team sizes of the suite."""
DEVIATION = 4.0
"""Largest deviation (m) of the ``deviating`` tasks' target from its prediction (and the zone's erosion r_u)."""
TEST_SCENES = 20
"""Held-out scenes per task (the first of :data:`~covert_env.world.families.HELD_OUT_SEEDS`)."""
# The nominal target names its prediction error too, so that a config with another one clashes with the task.
_TARGETS = {"nominal": {"prediction_error": 0.0}, "deviating": {"prediction_error": DEVIATION, "r_u": DEVIATION}}


@dataclass(frozen=True)
class Task:
    """One task of the suite.

    Attributes:
        name: what users pass (``task="paper-3uav"``).
        family: the scene family; n_uavs: the team size; target: ``"nominal"`` or ``"deviating"``.
    """

    name: str
    family: str
    n_uavs: int
    target: str

    @property
    def description(self) -> str:
        how = "target on its predicted track" if self.target == "nominal" else \
            f"target deviating up to {DEVIATION:g} m from its prediction"
        return f"{FAMILIES[self.family].description}; {self.n_uavs} UAV(s); {how}"

    @property
    def train_seeds(self) -> range:
        """The scene seeds training draws from (an env's ``scene_pool`` takes the first ones)."""
        return TRAIN_SEEDS

    @property
    def test_seeds(self) -> range:
        """The held-out scene seeds the task is scored on."""
        return range(HELD_OUT_SEEDS.start, HELD_OUT_SEEDS.start + TEST_SCENES)

    def config(self, base: Config | None = None) -> Config:
        """The task's config: the family's on top of ``base`` (default ``Config()``), the team size and the target's
        fields. A ValueError if ``base`` sets one of them to another value (two sources for one field)."""
        cfg = family_config(self.family, base)
        fields = {"n_uavs": self.n_uavs, **_TARGETS[self.target]}
        default = Config()
        clash = {k: getattr(cfg, k) for k, v in fields.items()
                 if getattr(cfg, k) != getattr(default, k) and getattr(cfg, k) != v}
        if clash:
            raise ValueError(f"task={self.name!r} sets {fields}, but the config sets {clash}; pass the task or set "
                             f"these fields, not both")
        return cfg.replace(**fields)


def _name(family: str, n_uavs: int, target: str) -> str:
    return f"{family}-{n_uavs}uav" + ("" if target == "nominal" else f"-{target}")


TASKS = MappingProxyType({_name(f, u, t): Task(_name(f, u, t), f, u, t)
                          for t in _TARGETS for f in FAMILIES for u in TEAM_SIZES})
"""Every task by name: each family x team size x target."""

DEFAULT_TASKS = ("sparse-3uav", "paper-3uav", "winding-3uav", "dense-3uav", "downtown-3uav", "towers-3uav",
                 "paper-1uav", "paper-6uav", "paper-3uav-deviating", "downtown-3uav-deviating")
"""The tasks ``covert-env benchmark`` runs by default."""


def get_task(name) -> Task:
    """The task called ``name``; a ValueError naming the pattern and an example otherwise."""
    if isinstance(name, Task):
        return name
    if not isinstance(name, str) or name not in TASKS:
        raise ValueError(f"task must be a task name '{{family}}-{{U}}uav[-deviating]' with family in "
                         f"{list(FAMILIES)} and U in {list(TEAM_SIZES)} (e.g. 'paper-3uav', "
                         f"'downtown-3uav-deviating'), got {name!r}")
    return TASKS[name]


def resolve_tasks(names) -> list[Task]:
    """Tasks from names, ``"core"`` (:data:`DEFAULT_TASKS`) or ``"all"`` (every task), in the order given,
    without repeats."""
    out: dict[str, Task] = {}
    for name in names:
        group = DEFAULT_TASKS if name == "core" else tuple(TASKS) if name == "all" else (name,)
        for n in group:
            out.setdefault(n, get_task(n))
    return list(out.values())
