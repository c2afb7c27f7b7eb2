"""Training across the suite's tasks: several batched vector envs, one per task, stepped as one batch of copies.

``TaskMix(["paper-3uav", "downtown-3uav", ...], num_envs=18, ...)`` makes one ``covert_env.vector_env`` per task
with ``num_envs / len(tasks)`` copies each and concatenates them along the copy axis: ``reset``, ``step``,
``action_masks``, ``waypoint_paths`` and ``state`` take and return ``(B, ...)`` arrays as one vector env does, the
copies of task i being rows ``i * b : (i + 1) * b``. Every copy draws its scenes from its own task's training
scenes (:attr:`covert_env.world.tasks.Task.train_seeds`), so a team trained on the mix sees every family in every
rollout.

The tasks must agree on what the actor and the batch see: team size, observation and state widths and action
mode. Their waypoint lattices may differ if one holds every other's nodes (a ``deviating`` task erodes the zone,
so its lattice is the nominal lattice without the nodes near the zone's edge): the mix acts on the largest
lattice, each task's nodes at their places in it, and a node a task does not have is never allowed in its
copies' masks. A ``ValueError`` names the first task that does not fit.
"""

from __future__ import annotations

import numpy as np

import covert_env
from covert_env.envs.batch import fly_to_goals
from covert_env.envs.waypoint_queries import SafetyState

__all__ = ["TaskMix", "make_training_env"]


def _concat_infos(parts: list[dict], obs: list, states: list) -> dict:
    """One infos dict from the sub-envs' (their arrays joined along the copy axis). The ``final_*`` entries appear
    where some sub-env ended a copy; the others fill them with their current ``obs``, ``states`` and infos,
    flagged False."""
    keys = [k for k in parts[0] if not k.startswith(("final_", "_final_"))]
    out = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    if any("final_info" in p for p in parts):
        none = [np.zeros(len(o), bool) for o in obs]
        out["final_obs"] = np.concatenate([p.get("final_obs", o) for p, o in zip(parts, obs, strict=True)])
        out["_final_obs"] = np.concatenate([p.get("_final_obs", n) for p, n in zip(parts, none, strict=True)])
        out["final_state"] = np.concatenate([p.get("final_state", s) for p, s in zip(parts, states, strict=True)])
        out["final_info"] = {k: np.concatenate([p.get("final_info", p)[k] for p in parts]) for k in keys}
        out["_final_info"] = np.concatenate([p.get("_final_info", n) for p, n in zip(parts, none, strict=True)])
    return out


class TaskMix:
    """Vector envs of several tasks as one batch of ``num_envs`` copies (module docstring).

    Args:
        tasks: suite task names (:data:`covert_env.world.tasks.TASKS`), at least one, no repeats.
        num_envs: copies in all; a multiple of ``len(tasks)`` (each task gets as many).
        **kwargs: passed to every task's ``covert_env.vector_env`` (``action_mode``, ``mask_mode``, ``map_size``,
            ``max_cycles``, ...; not ``task``, ``n_uavs`` or ``scene_pool``: the task sets them).
    """

    def __init__(self, tasks, num_envs: int, **kwargs):
        tasks = list(tasks)
        if not tasks or len(set(tasks)) != len(tasks):
            raise ValueError(f"tasks must be distinct task names, at least one, got {tasks!r}")
        for key in ("task", "n_uavs", "scene_pool"):
            if key in kwargs:
                raise ValueError(f"TaskMix: {key} is set by each task, not passed ({key}={kwargs[key]!r})")
        if kwargs.get("dict_obs"):
            raise ValueError("TaskMix: dict_obs=True is not supported (the mix joins flat observation arrays)")
        if num_envs % len(tasks):
            raise ValueError(f"num_envs {num_envs} must be a multiple of the {len(tasks)} tasks (each gets as many "
                             "copies)")
        self.tasks = tasks
        self.envs = [covert_env.vector_env(num_envs=num_envs // len(tasks), task=t, **kwargs) for t in tasks]
        first = self.envs[0]
        for t, e in zip(tasks[1:], self.envs[1:], strict=True):
            for what, a, b in (("team size", len(e.possible_agents), len(first.possible_agents)),
                               ("observation width", e.single_observation_space.shape,
                                first.single_observation_space.shape),
                               ("state width", e.single_state_space.shape, first.single_state_space.shape),
                               ("action mode", e.action_mode, first.action_mode),
                               ("flight (V_max, W_max, delta, path samples)",
                                (e.config.v_max, e.config.w_max, e.config.delta, e.path_samples),
                                (first.config.v_max, first.config.w_max, first.config.delta, first.path_samples)),
                               # What the trainer reads from the mix's config and maps (node features, episodes).
                               ("R2, d_safe1, d_safe2, altitude and slots",
                                (e.config.r2, e.config.d_safe1, e.config.d_safe2, e.config.altitude, e.config.n_slots),
                                (first.config.r2, first.config.d_safe1, first.config.d_safe2, first.config.altitude,
                                 first.config.n_slots)),
                               ("map cells", e.map_offsets.tobytes(), first.map_offsets.tobytes())):
                if a != b:
                    shown = "they differ" if isinstance(a, bytes) else f"{a} against {b}"
                    raise ValueError(f"task {t!r} differs from {tasks[0]!r} in its {what} ({shown}): a task mix "
                                     "needs one team size, observation, action mode and flight")
        self.num_envs = num_envs
        self.config, self.map_offsets = first.config, first.map_offsets
        self.path_samples = first.path_samples
        self._times = np.linspace(0.0, 1.0, self.path_samples) * self.config.delta      # the envs' sample times
        self.waypoint = first.action_mode == "waypoint"
        if self.waypoint:
            biggest = max(range(len(tasks)), key=lambda i: len(self.envs[i].lattice))
            self.lattice = self.envs[biggest].lattice
            #: Per task: its lattice's nodes as indices into the mix's lattice, and the inverse (-1: not its node).
            self._to_mix, self._from_mix = [], []
            for t, e in zip(tasks, self.envs, strict=True):
                d = np.abs(e.lattice[:, None, :] - self.lattice[None]).sum(-1)
                at = d.argmin(axis=1)
                if not np.all(d[np.arange(len(at)), at] < 1e-9):
                    raise ValueError(f"task {t!r}: its waypoint lattice is not part of {tasks[biggest]!r}'s, so "
                                     "the two cannot share one actor's action space")
                inverse = np.full(len(self.lattice), -1)
                inverse[at] = np.arange(len(at))
                self._to_mix.append(at)
                self._from_mix.append(inverse)
        else:
            self.lattice = first.lattice
        self.possible_agents, self.action_mode = first.possible_agents, first.action_mode
        self.single_observation_space, self.single_state_space = (first.single_observation_space,
                                                                  first.single_state_space)
        self.metadata = dict(first.metadata)            # the env's id: the tasks are in ``tasks`` (and the card)

    @property
    def episode_length(self) -> int:
        return min(e.episode_length for e in self.envs)

    def _split(self, x):
        return np.split(np.asarray(x), len(self.envs))

    def reset(self, *, seed=None):
        """Reset every copy; sub-env i is seeded ``seed + i`` (None: unseeded)."""
        out = [e.reset(seed=None if seed is None else seed + i) for i, e in enumerate(self.envs)]
        return np.concatenate([o for o, _ in out]), _concat_infos([i for _, i in out], [o for o, _ in out], [])

    def _nodes(self, what: str, nodes, extra: int) -> np.ndarray:
        """Node indices ``(B, U, ...)`` of the mix's lattice checked: shape, integer type, range (-1 allowed in
        ``waypoint_paths``: no node); a ValueError names ``what``."""
        if not self.waypoint:
            raise RuntimeError(f"TaskMix.{what} is for action_mode='waypoint'")
        nodes = np.asarray(nodes)
        b, u = self.num_envs, len(self.possible_agents)
        lo = -1 if extra else 0
        if nodes.ndim != 2 + extra or nodes.shape[:2] != (b, u) or not np.issubdtype(nodes.dtype, np.integer):
            raise ValueError(f"TaskMix.{what}: nodes must be integer indices of shape ({b}, {u}"
                             + (", M)" if extra else ")") + f", got {nodes.dtype} {nodes.shape}")
        if nodes.size and (nodes.min() < lo or nodes.max() >= len(self.lattice)):
            raise ValueError(f"TaskMix.{what}: node indices must be in [{lo}, {len(self.lattice) - 1}], got "
                             f"[{nodes.min()}, {nodes.max()}]")
        return nodes

    def step(self, actions):
        if self.waypoint:
            actions = self._nodes("step()", actions, 0)
        parts = self._split(actions)
        if self.waypoint:
            parts = [inv[a] for inv, a in zip(self._from_mix, parts, strict=True)]
            for t, a, n in zip(self.tasks, parts, self._split(actions), strict=True):
                if (a < 0).any():
                    c, i = np.argwhere(a < 0)[0]
                    raise ValueError(f"TaskMix.step(): task {t!r} has no node {n[c, i]} (copy {c} of the task, UAV "
                                     f"{i}); its masks never allow one")
        results = [e.step(a) for e, a in zip(self.envs, parts, strict=True)]
        obs, rew, term, trunc = (np.concatenate([r[j] for r in results]) for j in range(4))
        infos = _concat_infos([r[4] for r in results], [r[0] for r in results],
                              [e.state() for e in self.envs] if any("final_info" in r[4] for r in results) else [])
        return obs, rew, term, trunc, infos

    def state(self) -> np.ndarray:
        return np.concatenate([e.state() for e in self.envs])

    def action_masks(self) -> np.ndarray:
        """``(B, U, L)`` on the mix's lattice (L its nodes): each task's mask at its nodes' places, 0 elsewhere."""
        if not self.waypoint:
            return np.concatenate([e.action_masks() for e in self.envs])
        out = []
        for e, at in zip(self.envs, self._to_mix, strict=True):
            m = e.action_masks()
            full = np.zeros((*m.shape[:2], len(self.lattice)), m.dtype)
            full[..., at] = m
            out.append(full)
        return np.concatenate(out)

    @property
    def available_nodes(self) -> np.ndarray:
        """(B, L) bool: the nodes of the mix's lattice that each copy's task has (what its masks may allow)."""
        if not self.waypoint:
            raise RuntimeError("TaskMix.available_nodes is for action_mode='waypoint'")
        return np.concatenate([np.repeat((inv >= 0)[None], e.num_envs, axis=0)
                               for e, inv in zip(self.envs, self._from_mix, strict=True)])

    def safety_state(self, depth: int = 1) -> SafetyState:
        """The tasks' ``safety_state`` joined along the copy axis, on the mix's lattice: masks at each task's nodes'
        places (False elsewhere), polytope tops padded with inf to the most any task has."""
        if not self.waypoint:
            raise RuntimeError("TaskMix.safety_state() is for action_mode='waypoint'")
        parts = [e.safety_state(depth) for e in self.envs]
        tops = max(p.tops.shape[1] for p in parts)
        fields = {}
        for name in SafetyState._fields:
            if name == "masks":
                full = []
                for p, at in zip(parts, self._to_mix, strict=True):
                    m = np.zeros((*p.masks.shape[:2], len(self.lattice)), bool)
                    m[..., at] = p.masks
                    full.append(m)
                fields[name] = np.concatenate(full)
            elif name == "tops":
                fields[name] = np.concatenate([np.pad(p.tops, ((0, 0), (0, tops - p.tops.shape[1]), (0, 0)),
                                                      constant_values=np.inf) for p in parts])
            else:
                fields[name] = np.concatenate([getattr(p, name) for p in parts])
        return SafetyState(**fields)

    def waypoint_paths(self, nodes) -> np.ndarray:
        """The tasks' ``waypoint_paths`` for nodes ``(B, U, M)`` of the mix's lattice (-1: none): each task places
        its nodes (``waypoint_goals``), and every copy's paths are flown in one batch (the tasks fly alike: the same
        V_max, W_max, delta and sample times, checked at construction)."""
        nodes = self._nodes("waypoint_paths()", nodes, 1)
        goals = np.concatenate([e.waypoint_goals(np.where(n >= 0, inv[np.maximum(n, 0)], -1))
                                for e, inv, n in zip(self.envs, self._from_mix, self._split(nodes), strict=True)])
        return fly_to_goals(self.uav_xy, self.uav_theta, goals, self.config, self._times)

    def onward_reach(self, xy, theta) -> np.ndarray:
        """The tasks' ``onward_reach`` (each counts the nodes of its own lattice)."""
        if not self.waypoint:
            raise RuntimeError("TaskMix.onward_reach() is for action_mode='waypoint'")
        xy, theta = np.asarray(xy), np.asarray(theta)
        b, u = self.num_envs, len(self.possible_agents)
        if xy.ndim != 4 or xy.shape[:2] != (b, u) or xy.shape[3] != 2 or theta.shape != xy.shape[:3]:
            raise ValueError(f"TaskMix.onward_reach(): xy must have shape ({b}, {u}, M, 2) and theta ({b}, {u}, M), "
                             f"got {xy.shape} and {theta.shape}")
        return np.concatenate([e.onward_reach(x, t) for e, x, t in zip(self.envs, self._split(xy), self._split(theta),
                                                                         strict=True)])

    @property
    def uav_xy(self) -> np.ndarray:
        """(B, U, 2) the UAVs' positions."""
        return np.concatenate([e.uav_xy for e in self.envs])

    @property
    def uav_theta(self) -> np.ndarray:
        """(B, U) the UAVs' headings."""
        return np.concatenate([e.uav_theta for e in self.envs])

    def close(self) -> None:
        for e in self.envs:
            e.close()


def make_training_env(tasks: list[str], num_envs: int, **kwargs):
    """One vector env of ``num_envs`` copies: ``covert_env.vector_env`` for no task or one, a :class:`TaskMix`
    for several."""
    if len(tasks) <= 1:
        return covert_env.vector_env(num_envs=num_envs, **({"task": tasks[0]} if tasks else {}), **kwargs)
    return TaskMix(tasks, num_envs, **kwargs)
