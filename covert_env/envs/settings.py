"""The covert-sensing env's arguments, checked once, and what follows from them (lattice, maps, layout, spaces).

The parallel env and the vector env take the same keyword arguments; both build an :class:`EnvSettings` from them,
so an argument is validated, and a space built, in one place.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from gymnasium import spaces

from covert_env.envs.arguments import bool_arg, int_arg, number_arg
from covert_env.envs.observation import ObservationLayout
from covert_env.geometry.zone import in_feasible_zone, lattice_offsets, zone_lattice
from covert_env.world.config import Config
from covert_env.world.engine import MAX_PATH_SAMPLES
from covert_env.world.families import TRAIN_SEEDS, family_config
from covert_env.world.scenario import PAPER_UAV_STARTS, Scenario
from covert_env.world.tasks import get_task

__all__ = ["ACTION_MODES", "EnvSettings", "LiveSettings", "MASK_MODES", "MAX_PATH_SAMPLES", "MAX_SCENE_POOL",
           "PENALTIES", "RENDER_MODES", "PenaltyWeights", "check_penalties", "check_reward_scale"]

ACTION_MODES = ("unicycle", "waypoint")
#: What the waypoint action mask allows: reachable nodes of the visible zone (eq. 10), or every reachable node.
MASK_MODES = ("visible", "kinematic")
RENDER_MODES = ("human", "rgb_array")
#: Largest ``scene_pool``: training scene seeds 0 .. scene_pool-1 stay below the held-out seeds 1_000_000 + i.
MAX_SCENE_POOL = len(TRAIN_SEEDS)


#: The reward's penalty terms, the keys of ``penalties``.
PENALTIES = ("los", "los_path", "zone", "separation", "terrain")


def check_reward_scale(value) -> float:
    """``reward_scale`` as a float in [1e-6, 1e12]: outside, rewards over- or underflow (eq. 18 / reward_scale)."""
    v = number_arg("reward_scale", value)
    if not 1e-6 <= v <= 1e12:
        raise ValueError(f"reward_scale must be a finite number in [1e-06, 1e+12], got {value!r}")
    return v


#: Largest penalty weight: beyond it a slot's reward loses the stage cost's precision (and 1e308 overflows).
MAX_PENALTY = 1e6


def _penalty(key, value) -> float:
    if key not in PENALTIES:
        raise KeyError(f"penalties: unknown term {key!r}; the terms are {list(PENALTIES)}")
    v = number_arg(f"{key}_penalty", value)
    if not 0 <= v <= MAX_PENALTY:
        raise ValueError(f"{key}_penalty must be a finite number in [0, {MAX_PENALTY:g}], got {value!r}")
    return v


class PenaltyWeights(dict):
    """The penalty weights by term (``los``, ``los_path``, ``zone``, ``separation``, ``terrain``), each a finite
    number >= 0.

    A dict that checks what is written into it: ``penalties["los"] = 2.0`` is validated as the constructor
    arguments are (a NaN, a negative weight or an unknown term raise), and no term can be removed (set it to 0.0)."""

    def __init__(self, values) -> None:
        if not isinstance(values, Mapping) or set(values) != set(PENALTIES):
            raise ValueError(f"penalties must be a dict with the keys {list(PENALTIES)}, got {values!r}")
        super().__init__((key, _penalty(key, values[key])) for key in PENALTIES)

    def __setitem__(self, key, value) -> None:
        super().__setitem__(key, _penalty(key, value))

    def update(self, *args, **kwargs) -> None:
        for key, value in dict(*args, **kwargs).items():
            self[key] = value

    def setdefault(self, key, default=None):
        if key not in self:
            self[key] = default              # every term is present: an absent key is unknown, and raises here
        return self[key]

    def _fixed_keys(self, *args, **kwargs):
        raise TypeError(f"penalties keep one weight per term {list(PENALTIES)}: set a weight to 0.0 to turn a term "
                        "off")

    __delitem__ = pop = popitem = clear = _fixed_keys


def check_penalties(values) -> PenaltyWeights:
    """The penalty weights by term, validated (:class:`PenaltyWeights`)."""
    return PenaltyWeights(values)


class EnvSettings:
    """The env's keyword arguments (see :class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv`),
    validated, with the waypoint lattice, the observation maps' cells, the observation layout and the spaces.

    Every bad value raises at construction, naming the argument, the value and what is allowed.
    """

    def __init__(self, config: Config | dict | None = None, *, n_uavs: int | None = None,
                 scenario: str | Scenario = "random", action_mode: str = "unicycle",
                 max_cycles: int | None = None, render_mode: str | None = None, map_size: int = 8,
                 dict_obs: bool = False, reward_scale: float = 100.0, los_penalty: float = 1.0,
                 los_path_penalty: float = 1.0,
                 zone_penalty: float = 1.0, separation_penalty: float = 1.0, terrain_penalty: float = 1.0,
                 terminate_on_collision: bool = False, scene_pool: int = 10_000, path_samples: int = 11,
                 random_starts: bool = False, family: str | None = None, task: str | None = None,
                 mask_mode: str = "visible", target_path: int = 0):
        if isinstance(config, Mapping):
            cfg = Config.from_dict(dict(config))
        elif config is None or isinstance(config, Config):
            cfg = config or Config()
        else:
            raise TypeError(f"config must be a covert_env.Config, a dict of its fields or None, "
                            f"got {type(config).__name__} {config!r}")
        if n_uavs is not None:
            cfg = cfg.replace(n_uavs=int_arg("n_uavs", n_uavs, 1))
        if isinstance(task, (list, tuple)):
            raise ValueError(f"task={list(task)!r}: several tasks are for the vector env "
                             "(covert_env.vector_env(num_envs=B, task=[...])); this env flies one task")
        if task is not None:
            t = get_task(task)
            if family is not None and family != t.family:
                raise ValueError(f"task={t.name!r} flies the {t.family!r} family, got family={family!r}; pass one")
            if n_uavs is not None and cfg.n_uavs != t.n_uavs:
                raise ValueError(f"task={t.name!r} flies {t.n_uavs} UAV(s), got n_uavs={cfg.n_uavs}; pass one")
            if not (isinstance(scenario, str) and scenario == "random"):
                raise ValueError(f"task={t.name!r} draws random scenes: it needs scenario='random'")
            cfg, family, task = t.config(cfg), None, t.name
        if family is not None:
            if not (isinstance(scenario, str) and scenario == "random"):
                raise ValueError(f"family={family!r} draws random scenes: it needs scenario='random', got "
                                 f"scenario={scenario if isinstance(scenario, str) else type(scenario).__name__!r}")
            cfg = family_config(family, cfg)
        if isinstance(scenario, Scenario):
            # A scenario's terrain and track were built and checked under its own config: flying them under
            # another one (altitude, speeds, zone) would mix two worlds, so the two must agree.
            if config is not None:
                differ = [f for f in cfg.to_dict() if f != "n_uavs" and getattr(cfg, f) != getattr(scenario.config, f)]
                if differ:
                    raise ValueError(f"config differs from scenario.config in {differ}; build the Scenario with this "
                                     "config, or pass only the scenario")
            cfg = scenario.config if n_uavs is None else scenario.config.replace(n_uavs=cfg.n_uavs)
            if scenario.n_uavs != cfg.n_uavs:
                raise ValueError(f"n_uavs={cfg.n_uavs} but the scenario has {scenario.n_uavs} UAVs")
        elif not isinstance(scenario, str) or scenario not in ("random", "paper"):
            raise ValueError(f"scenario must be 'random', 'paper' or a Scenario, got {scenario!r}")
        elif scenario == "paper" and cfg.n_uavs > len(PAPER_UAV_STARTS):
            raise ValueError(f"scenario='paper' has starts for {len(PAPER_UAV_STARTS)} UAVs, got n_uavs={cfg.n_uavs}; "
                             "use scenario='random' or a Scenario with your own starts")
        if not isinstance(action_mode, str) or action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be None or one of {list(RENDER_MODES)}, got {render_mode!r}")
        if bool_arg("dict_obs", dict_obs) and action_mode != "waypoint":
            raise ValueError("dict_obs=True needs action_mode='waypoint': the unicycle mode has no action mask")
        if not isinstance(mask_mode, str) or mask_mode not in MASK_MODES:
            raise ValueError(f"mask_mode must be one of {MASK_MODES}, got {mask_mode!r}")
        if mask_mode != "visible" and action_mode != "waypoint":
            raise ValueError(f"mask_mode={mask_mode!r} needs action_mode='waypoint': the unicycle mode has no "
                             "action mask")
        self.map_size = int_arg("map_size", map_size, 2, 64)
        # The tracks reach config.horizon slots past slot n_slots: the furthest any prediction reaches.
        self.target_path = int_arg("target_path", target_path, 0, cfg.horizon)
        # Training scene seeds stay below the held-out ones (1_000_000 + i) that evaluations fly.
        self.scene_pool = int_arg("scene_pool", scene_pool, 1, MAX_SCENE_POOL)
        self.path_samples = int_arg("path_samples", path_samples, 2, MAX_PATH_SAMPLES)
        self.reward_scale = check_reward_scale(reward_scale)
        self.penalties = check_penalties({"los": los_penalty, "los_path": los_path_penalty, "zone": zone_penalty,
                                          "separation": separation_penalty, "terrain": terrain_penalty})
        self.config = cfg
        self.family = family if task is None else get_task(task).family
        self.task = task
        self.scenario = scenario
        self.action_mode = action_mode
        self.max_cycles = cfg.n_slots if max_cycles is None else int_arg("max_cycles", max_cycles, 1)
        self.render_mode = render_mode
        self.dict_obs = bool(dict_obs)
        self.mask_mode = mask_mode
        self.terminate_on_collision = bool_arg("terminate_on_collision", terminate_on_collision)
        self.random_starts = bool_arg("random_starts", random_starts)

        c = cfg
        self.possible_agents = [f"uav_{i}" for i in range(c.n_uavs)]
        self.lattice = zone_lattice(c)                        # the DP planner's nodes, target frame
        self.lattice.setflags(write=False)                    # the actions index it: not to be edited in place
        box = lattice_offsets(c.r1, c.r2, c.mu, c.grid_step)
        lo, hi = box.min(0), box.max(0)
        s = self.map_size
        gx = lo[0] + (np.arange(s) + 0.5) * (hi[0] - lo[0]) / s
        gy = lo[1] + (np.arange(s) + 0.5) * (hi[1] - lo[1]) / s
        self.map_offsets = np.array([(x, y) for y in gy[::-1] for x in gx])   # row-major, +y on top
        self.map_in_zone = in_feasible_zone(self.map_offsets, np.zeros(2), 0.0, c.r1, c.r2, c.mu, c.r_u)

        self.layout = ObservationLayout(c.n_uavs, s, self.target_path)
        self.obs_box = self.layout.box()
        self.state_space = self.layout.state_box()
        if action_mode == "unicycle":
            self.action_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        else:
            self.action_space = spaces.Discrete(len(self.lattice))
        if self.dict_obs:
            self.observation_space = spaces.Dict({"observation": self.obs_box,
                                                  "action_mask": spaces.Box(0, 1, (len(self.lattice),), dtype=np.int8)})
        else:
            self.observation_space = self.obs_box


class LiveSettings:
    """The settings an env reads at every step, which users may assign between steps (PettingZoo's test battery
    and wrappers set ``max_cycles`` as an attribute): every assignment is validated as the constructor's argument.

    A base of :class:`~covert_env.envs.vector.CovertSensingVectorEnv`, which sets ``config`` and the private fields
    once in its setup; the parallel env forwards these attributes to its one-copy vector env.
    """

    @property
    def max_cycles(self) -> int:
        """Episode length bound in slots (validated on assignment); episodes also end at ``config.n_slots``."""
        return self._max_cycles

    @max_cycles.setter
    def max_cycles(self, value) -> None:
        self._max_cycles = int_arg("max_cycles", value, 1)

    @property
    def episode_length(self) -> int:
        return min(self._max_cycles, self.config.n_slots)

    @property
    def reward_scale(self) -> float:
        """The stage cost's divisor in the reward (validated on assignment, read at every step)."""
        return self._reward_scale

    @reward_scale.setter
    def reward_scale(self, value) -> None:
        self._reward_scale = check_reward_scale(value)

    @property
    def penalties(self) -> dict[str, float]:
        """Penalty weights by term, read at every step. Assigning a dict validates it, and so does item
        assignment (``penalties["los"] = 2.0``, live: :class:`~covert_env.envs.settings.PenaltyWeights`)."""
        return self._penalties

    @penalties.setter
    def penalties(self, value) -> None:
        self._penalties = check_penalties(value)

    @property
    def terminate_on_collision(self) -> bool:
        """End a copy's episode when two UAVs come closer than d_safe1 (validated on assignment)."""
        return self._terminate

    @terminate_on_collision.setter
    def terminate_on_collision(self, value) -> None:
        self._terminate = bool_arg("terminate_on_collision", value)
