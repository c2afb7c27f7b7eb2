"""B copies of the covert-sensing env stepped as one batch of array operations (``covert_env.vector_env``)."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from covert_env.envs import batch
from covert_env.envs.arguments import MAX_SCENE_SEED, ConstructionSettings, copy_seeds, int_arg, vector_reset_options
from covert_env.envs.copies import Copies
from covert_env.envs.recorder import CopyView, EpisodeRecorder
from covert_env.envs.scene_pool import ScenePool
from covert_env.envs.settings import EnvSettings, LiveSettings, check_penalties
from covert_env.envs.task_mix import mix_settings
from covert_env.envs.waypoint_queries import SafetyState, WaypointQueries
from covert_env.geometry.angles import wrap_heading
from covert_env.geometry.flight import fly_arc, fly_waypoints
from covert_env.geometry.reach import reach_table
from covert_env.geometry.separation import nearest_teammate
from covert_env.geometry.zone import to_world, zone_distance
from covert_env.world.metrics import moves_quantities
from covert_env.world.scenario import Scenario
from covert_env.world.trajectory import Trajectory

__all__ = ["AUTORESET_MODES", "CovertSensingVectorEnv", "vector_env", "INFO_BOOLS", "INFO_KEYS", "INFO_DTYPES",
           "MAX_NUM_ENVS", "MAX_SCENE_SEED"]

#: Largest ``num_envs`` accepted: memory grows linearly with it (see benchmarks/vector_throughput.py).
MAX_NUM_ENVS = 1 << 16
#: Largest ``scene_cache_size``: a scene holds ~40 kB (~80 kB in waypoint mode), so this is a few GB at most.
MAX_SCENE_CACHE = 1 << 16
#: Float infos of a step (the parallel env's Infos table), besides the int ``slot`` and the bools.
INFO_FLOATS = (("kappa", "g", "v", "separation", "terrain_clearance") + tuple(f"reward_{t}" for t in batch.REWARD_TERMS)
               + ("cost",) + tuple(f"cost_{n}" for n in batch.COSTS))
#: Infos keys in their order (the parallel env's per-agent keys, without the action mask: see ``action_masks``).
INFO_KEYS = ("slot", "los", "los_path", "in_zone", "infeasible") + INFO_FLOATS
#: Bool infos (the parallel env's Infos table).
INFO_BOOLS = ("los", "los_path", "in_zone", "infeasible")
#: What ``autoreset_mode`` accepts: Gymnasium's same-step mode, or none (copies that ended wait for a reset).
AUTORESET_MODES = (AutoresetMode.SAME_STEP, AutoresetMode.DISABLED)
#: The infos' dtypes, for frameworks that declare them before the first step (the TorchRL env's specs).
INFO_DTYPES = {key: np.dtype(np.int64) if key == "slot" else np.dtype(bool) if key in INFO_BOOLS
               else np.dtype(np.float64) for key in INFO_KEYS}


class CovertSensingVectorEnv(ConstructionSettings, LiveSettings):
    """B copies of :class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv`, as batch-first arrays.

    ## Description

    The same task, model and numbers as the parallel env (its docstring is the reference for the task, the
    rewards, the constraint costs and the observation table), for ``num_envs`` copies (B) of a team of U UAVs
    at once. The state is a set of arrays ``(B, U, ...)`` and every step is a fixed sequence of array operations
    over all copies and UAVs (flight, manoeuvres, line of sight against each copy's own terrain, zone,
    separation along the path, cost, rewards, constraint costs, observations, masks): no Python loop runs over
    copies, UAVs, lattice nodes or polytopes. Scenes come from a pool shared by all copies
    (:class:`~covert_env.envs.scene_pool.ScenePool`): what depends only on the scene and the slot is computed
    once per scene, for all the new scenes of a reset as one batch of array operations.

    Copy ``i`` flies exactly what the parallel env flies for the same scene, starts and actions (tested, see
    Seeding): observations, rewards, costs and infos are bit-identical. (The parallel env is this env with B = 1;
    every line-of-sight question goes to one kernel, :func:`~covert_env.geometry.sight_kernel.blocked_segments`.)

    ## Action Space

    ``action_space``: the single agent's space batched to ``(B, U)``. Unicycle mode (default): floats
    ``(B, U, 2)`` in [-1, 1] (speed, turn rate; clipped, as in the parallel env). Waypoint mode: integers
    ``(B, U)``, lattice node indices in ``[0, L)``. Any other shape or dtype, or NaN/inf, raises an error naming
    the copy and the agent.

    ## Observation Space

    ``(B, U, D)`` float32, row ``[b, i]`` the parallel env's observation of agent ``uav_i`` in copy ``b``. With
    ``dict_obs=True`` (waypoint mode): ``{"observation": (B, U, D), "action_mask": (B, U, L) int8}``.
    ``state()``: ``(B, S)`` float32, row b the parallel env's ``state()`` of copy b.

    ## Action Masks

    Waypoint mode: ``action_masks()`` returns ``(B, U, L)`` int8 (1 = allowed), the parallel env's mask per copy
    and agent. It lives there (and in the observation with ``dict_obs=True``), not in the infos. A row with no
    node both reachable and visible allows the reachable nodes, and a row whose UAV can reach no node is all ones
    (how often: docs/environments.md); a node taken there is flown as a best effort (the
    admissible constant (v, omega) ending closest to it) and flagged ``infos["infeasible"]``. Reachability
    comes from :class:`~covert_env.geometry.reach.ReachTable` (a table in the UAV's frame; only nodes near its boundary
    are solved), which gives exactly ``solve_manoeuvre``'s answer. ``waypoint_paths(nodes)`` returns the paths
    the UAVs would fly to given nodes in this slot (read-only; what the separation shield of
    ``training.shield`` tests), and ``onward_reach(xy, theta)`` how many nodes a UAV ending the slot at a given
    pose may reach in the next (its viability rule).

    ## Rewards, Terminations, Truncations

    ``(B, U)`` arrays: float64 rewards; bool terminations and truncations (all agents of a copy end together:
    truncation after ``episode_length`` slots, termination on a collision with ``terminate_on_collision``).

    ## Infos

    A dict of ``(B, U)`` arrays, the same keys as the parallel env's per-agent infos (without ``action_mask``)
    at ``reset()`` and every ``step()``: ``slot`` (int64), ``los``, ``in_zone``, ``infeasible`` (bool),
    ``kappa``, ``g``, ``v``, ``separation``, ``terrain_clearance``, ``reward_<term>``, ``cost``,
    ``cost_<constraint>`` (float64).

    ## Autoreset

    ``metadata["autoreset_mode"] = AutoresetMode.SAME_STEP`` (Gymnasium 1.x, https://farama.org/Vector-Autoreset-Mode):
    a copy whose episode ended in ``step()`` is reset within the same call. That step returns the copy's reward,
    termination and truncation of its last slot, but its observation and infos are the first ones of its next
    episode; the last ones are in the infos as Gymnasium's same-step mode gives them, batched:

    * ``infos["final_obs"]``: the observation rows ``(B, U, D)`` at the end of the episode (the array part with
      ``dict_obs``: no action follows, so no mask), valid where ``infos["_final_obs"]`` (B,) is True;
    * ``infos["final_info"]``: the infos dict of the last slot (``(B, U)`` arrays), valid where
      ``infos["_final_info"]`` (B,) is True;
    * ``infos["final_state"]``: the ``state()`` rows ``(B, S)`` at the end of the episode, valid where
      ``infos["_final_obs"]`` is True.

    These keys are present only on steps where some copy ended (as in Gymnasium). No ``step()`` ever needs a
    manual ``reset()``. (``gym.make_vec`` on the registered single-UAV ids gives Gymnasium's own vector envs,
    which reset in next-step mode instead: the step after the end resets and ignores that copy's action.)

    ``autoreset_mode=AutoresetMode.DISABLED`` turns this off: a copy whose episode ended keeps its last
    observation and state, and ``step()`` raises until it is reset with ``reset(options={"reset_mask": m})``.
    The parallel env is the vector env with B = 1 in this mode (its agents leave at the end of an episode).

    ## Seeding

    ``reset(seed=s)`` with an int gives copy i the seed ``copy_seeds[i]`` (from ``np.random.SeedSequence(s)``);
    a sequence of B ints gives them directly. Copy i then draws its scenes and starts exactly as a parallel env
    ``reset(seed=copy_seeds[i])`` followed by plain ``reset()`` calls does, one generator per copy: the same seed
    gives the same batch, and copy i equals that parallel env across automatic resets.
    ``options={"scene_seed": s}`` (an int for every copy, or B ints) picks the scenes and their own seeded starts
    (``Scenario.random(s)``), as the parallel env's option does. ``options={"reset_mask": m}`` (B bools,
    Gymnasium's name) resets only the copies where ``m`` is True, each from its own generator as an automatic reset
    does; the others keep their observations and infos. Drawing a reset copy's starts from its own
    generator is the one per-copy step (a few µs each, once per episode).

    ## Arguments

    ``num_envs`` (B, in ``[1, MAX_NUM_ENVS]``) and the parallel env's keyword arguments (``render_mode`` must
    be None). ``scenario="random"`` builds a scene the first time a copy draws its seed, all the scenes a reset needs
    as one batch (what a scene costs: docs/performance.md); the pool keeps ``scene_cache_size`` scenes (default
    ``B + 32``, at least B): with ``scene_pool <= scene_cache_size`` every training scene is built once, otherwise
    a scene is rebuilt whenever it is drawn again after leaving the cache.
    ``autoreset_mode``: ``AutoresetMode.SAME_STEP`` (default) or ``AutoresetMode.DISABLED`` (see Autoreset).
    ``record``: keep every copy's current episode for the metrics (``trajectory(i)``,
    :class:`~covert_env.world.trajectory.EpisodeRecorder`; about ``n_slots * U * (path_samples + 4) * 16`` bytes per
    copy, so off by default). With same-step autoreset an ended episode is replaced by the next one within the
    step that ends it: to score whole episodes, record with ``autoreset_mode=DISABLED`` (as the parallel env does).

    ## Several tasks

    ``task=["paper-3uav", "downtown-3uav", ...]`` (distinct suite tasks of one team size; ``num_envs`` a multiple of
    their number T) makes one env whose copies fly them in blocks: copy i flies ``task[i // (B / T)]``, drawing its
    scenes with that task's config, and all copies step in one batch (:mod:`covert_env.envs.task_mix`; ``task_mix``
    says which copy flies which task). The tasks may differ only in the scene family's config fields and the
    target model's (``prediction_error``, ``r_u``); ``config`` is that of the task with the largest lattice, the
    env's action space. A deviating task's copies (an eroded zone, fewer nodes) have masks that allow only their
    task's nodes (``available_nodes``, (B, L)), and their maps mark their own zone. ``reset(seed=s)`` seeds task
    t's copies as that task's own env reset with ``seed=s + t``: each copy steps bit for bit as there.

    ## Reading a copy

    ``slots`` (B,), ``uav_xy`` (B, U, 2) and ``uav_theta`` (B, U) (read-only), ``scene(i)`` (terrain and track),
    ``scenario(i)`` (with the starts flown), ``trajectory(i)`` (with ``record=True``) and ``copy_view(i)``, which
    reads copy i in the terms of :class:`~covert_env.world.engine.Engine` (``k``, ``uav_xy``, ``predict``, ...), so the
    DP planner and the evaluation harness can drive a copy as they drive an engine.

    ## Version History

    The PettingZoo env's (:class:`~covert_env.envs.covert_sensing.CovertSensingParallelEnv`): each version of
    ``covert_sensing_vector_vN`` has the task and numbers of ``covert_sensing_vN``. 0.3.0 added ``autoreset_mode``,
    ``record`` and the copy readers, 0.4.0 ``waypoint_paths``, 0.8.0 ``onward_reach`` and 0.9.0 ``target_path``, with
    no number changed. What each version changed: ``CHANGELOG.md``.
    """

    metadata = {"name": "covert_sensing_vector_v4", "autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    render_mode = None

    def __init__(self, num_envs: int = 1, *, autoreset_mode: AutoresetMode = AutoresetMode.SAME_STEP,
                 record: bool = False, scene_cache_size: int | None = None, **kwargs):
        if kwargs.get("render_mode") is not None:
            raise ValueError("the vector env does not render; use the parallel env (render_mode=...) to watch a copy")
        task = kwargs.get("task")
        if isinstance(task, (list, tuple)) or (isinstance(task, np.ndarray) and task.ndim == 1):
            num_envs = int_arg("num_envs", num_envs, 1, MAX_NUM_ENVS)
            settings, mix = mix_settings(task, num_envs, {k: v for k, v in kwargs.items() if k != "task"})
            self._setup(num_envs, settings, autoreset_mode, record, scene_cache_size, mix)
        else:
            self._setup(num_envs, EnvSettings(**kwargs), autoreset_mode, record, scene_cache_size)

    @classmethod
    def from_settings(cls, num_envs: int, settings: EnvSettings, *,
                      autoreset_mode: AutoresetMode = AutoresetMode.SAME_STEP, record: bool = False,
                      scene_cache_size: int | None = None):
        """The vector env of already checked :class:`~covert_env.envs.settings.EnvSettings` (the parallel env's)."""
        venv = cls.__new__(cls)
        venv._setup(num_envs, settings, autoreset_mode, record, scene_cache_size)
        return venv

    def _setup(self, num_envs, s: EnvSettings, autoreset_mode, record, scene_cache_size, mix=None) -> None:
        self._num_envs = int_arg("num_envs", num_envs, 1, MAX_NUM_ENVS)
        cache_size = self.num_envs + 32 if scene_cache_size is None else int_arg(
            "scene_cache_size", scene_cache_size, self.num_envs, MAX_SCENE_CACHE)
        if autoreset_mode not in AUTORESET_MODES:
            raise ValueError(f"autoreset_mode must be one of {[m.name for m in AUTORESET_MODES]}, "
                             f"got {autoreset_mode!r}")
        if not isinstance(record, (bool, np.bool_)):
            raise TypeError(f"record must be True or False, got {record!r}")
        self.metadata = dict(type(self).metadata, autoreset_mode=autoreset_mode)
        self.config, self.action_mode, self.dict_obs = s.config, s.action_mode, s.dict_obs
        #: ``"visible"`` or ``"kinematic"``: what the waypoint action mask allows (the parallel env's Action Space).
        self.mask_mode = s.mask_mode
        self.scenario_spec, self.random_starts = s.scenario, s.random_starts
        self.scene_pool, self.path_samples, self.family = s.scene_pool, s.path_samples, s.family
        self.task = s.task
        self._reward_scale, self._penalties = s.reward_scale, check_penalties(s.penalties)
        self._terminate, self.max_cycles = s.terminate_on_collision, s.max_cycles
        self.lattice, self.possible_agents, self.layout = s.lattice, list(s.possible_agents), s.layout
        #: The observation maps' side S and their cells' centres (S * S, 2), target frame, row-major with +y on top.
        self.map_size, self.map_offsets = s.map_size, s.map_offsets
        #: Predicted slots of the target's path in the observation (0: none; the parallel env's ``target_path``).
        self.target_path = s.target_path
        self.single_observation_space, self.single_action_space = s.observation_space, s.action_space
        self.single_state_space = s.state_space
        b, u, c = self.num_envs, len(self.possible_agents), self.config
        self.observation_space = batch_space(batch_space(self.single_observation_space, u), b)
        self.action_space = batch_space(batch_space(self.single_action_space, u), b)
        self.state_space = batch_space(self.single_state_space, b)
        #: The copies' tasks in an env of several (:class:`~covert_env.envs.task_mix.TaskMix`), else None.
        self.task_mix = mix
        # (B, L) the lattice nodes each copy's task has (None: every node, one task).
        self._available = None if mix is None else mix.available[mix.copy_task]
        self._pool = ScenePool(s.scenario, c, self.lattice, s.map_offsets, s.map_in_zone,
                               waypoint=self.action_mode == "waypoint" and s.mask_mode == "visible",
                               capacity=cache_size, path_slots=s.target_path, mix=mix)
        self._times = np.linspace(0.0, 1.0, self.path_samples) * c.delta      # the engine's sample times
        self._fractions = np.linspace(0.0, 1.0, self.path_samples)[1:]        # of the slot, after its start
        self._rngs: list[np.random.Generator] | None = None
        self.copy_seeds: np.ndarray | None = None
        #: Where the copies stand (:class:`~covert_env.envs.copies.Copies`): what step and reset write.
        self.copies = Copies.empty(b, u, len(self.lattice) if self.action_mode == "waypoint" else 2)
        self._own: np.ndarray | None = None                 # own features of the whole batch, until a state change
        self._recorder = EpisodeRecorder(b, u, c.n_slots, self.path_samples) if record else None
        self._reach = reach_table(c.v_max, c.w_max, c.delta) if self.action_mode == "waypoint" else None
        # Where waypoint actions would fly: one object over the batch state (waypoint mode; the methods below ask it).
        self._queries = (WaypointQueries(c, self.lattice, self.copies, self._pool, self._reach, self._times,
                                         self._available) if self.action_mode == "waypoint" else None)

    @property
    def num_envs(self) -> int:
        """B, the number of copies (fixed at construction: every array is sized by it)."""
        return self._num_envs

    # ------------------------------------------------------------------ API
    def reset(self, *, seed=None, options: dict | None = None):
        """Reset every copy (or those of ``options["reset_mask"]``); returns observations and infos (class
        docstring, Seeding)."""
        if self._pool is None:
            raise RuntimeError("reset() called after close()")
        b = self.num_envs
        # Options are checked before any generator changes: a refused call leaves the batch as it was.
        scene_seeds, mask = vector_reset_options(options, b)
        if scene_seeds is not None and self.scenario_spec != "random":
            flown = "the paper scenario" if self.scenario_spec == "paper" else "a given Scenario"
            raise ValueError("reset(options={'scene_seed': ...}) picks random scenes: it needs scenario='random', "
                             f"but this env flies {flown}")
        if mask is None:
            chosen = np.arange(b)
        else:
            if not self.copies.started or seed is not None:
                raise ValueError("reset(options={'reset_mask': ...}) resets some copies of a running batch, from "
                                 "their own generators: call a full reset(seed=...) first, and not with it")
            chosen = np.flatnonzero(mask)
            scene_seeds = None if scene_seeds is None else scene_seeds[chosen]
            if chosen.size == 0:                  # nothing to reset: the batch as it is
                return self._observation(self._obs_rows()), {key: val.copy() for key, val in self._last_infos.items()}
        if seed is not None:
            mixed = self.task_mix is not None and np.ndim(seed) == 0
            self.copy_seeds = self.task_mix.copy_seeds(int_arg("seed", seed, 0)) if mixed else copy_seeds(seed, b)
            self._rngs = [gymnasium.utils.seeding.np_random(int(s))[0] for s in self.copy_seeds]
        elif self._rngs is None:
            self._rngs = [gymnasium.utils.seeding.np_random(None)[0] for _ in range(b)]
        self._reset_copies(chosen, scene_seeds)
        self.copies.started = True
        self._update_masks()
        infos = self._reset_infos(chosen)
        if mask is not None:
            # The copies left running keep their last infos, as they keep their observations.
            fresh, infos = infos, {key: val.copy() for key, val in self._last_infos.items()}
            for key, val in fresh.items():
                infos[key][chosen] = val
        self._last_infos = infos
        return self._observation(self._obs_rows()), infos

    def step(self, actions):
        """One slot in every copy; returns ``(obs, rewards, terminations, truncations, infos)`` (class docstring)."""
        self.require_running("step()")
        if self.copies.ended.any():
            raise RuntimeError(f"step(): the episodes of copies {np.flatnonzero(self.copies.ended).tolist()} ended "
                               "(autoreset_mode DISABLED) or failed to reset; reset them "
                               "(reset(options={'reset_mask': ...}))")
        c, pool, rows, k = self.config, self._pool, self.copies.rows, self.copies.k
        xy0, th0 = self.copies.xy, self.copies.theta
        q1, phi1 = pool.q[rows, k + 1], pool.phi[rows, k + 1]
        if self.action_mode == "unicycle":
            act = batch.unicycle_actions(actions, (self.num_envs, len(self.possible_agents)), self.possible_agents)
            v, w = batch.unicycle_controls(act, c)
            path, end_theta = fly_arc(xy0, th0, v, w, self._times)
            flagged = np.zeros(th0.shape, bool)
        else:
            idx = batch.waypoint_actions(actions, (self.num_envs, len(self.possible_agents)), len(self.lattice),
                                         self.possible_agents)
            flagged = np.take_along_axis(self.copies.masks, idx[..., None], axis=-1)[..., 0] == 0
            # The nodes are about the target's next pose as predicted now (what the mask and the planner use).
            goals = to_world(self.lattice[idx], pool.q_next[rows, k, :2], pool.phi_next[rows, k])
            path, end_theta, v, fallback, w = fly_waypoints(xy0, th0, goals, c, self._times)
            flagged |= fallback
        end = path[..., -1, :].copy()
        # LoS at the slot's end against q[k+1]; along the path (its samples after the start, which the previous
        # slot counted) against the target at the same instants, as the episode metrics count it.
        quant = moves_quantities(xy0, end, target_start=pool.q[rows, k], phi_start=pool.phi[rows, k],
                                 target_end=q1, phi_end=phi1, path_xy=path, path_length=v * c.delta,
                                 target_path_xyz=None, terrain=pool.copy_terrains(rows), config=c)
        clear = pool.path_line_of_sight(rows, k, path[..., 1:, :], c.altitude, self._fractions)
        quant.los_path, quant.blocked_path_share = clear.all(axis=-1), 1.0 - clear.mean(axis=-1)
        costs = batch.constraint_costs(quant, c)
        terms = batch.reward_terms(quant, costs, c, self.reward_scale, self.penalties)
        rewards = terms.sum(axis=0)
        self.copies.k, self._own = k + 1, None
        self.copies.xy, self.copies.theta = end, wrap_heading(end_theta)
        if self._recorder is not None:
            self._recorder.record(k, path, end_theta=self.copies.theta, v=v, w=w, flagged=flagged, delta=c.delta)
        self.copies.speed, self.copies.los = quant.path_length / c.delta, quant.los
        self.copies.zone = quant.zone_distance
        term = (quant.separation_path < c.d_safe1).any(axis=1) & self.terminate_on_collision
        trunc = (self.copies.k >= self.episode_length) & ~term

        infos = _step_infos(self.copies.k, quant, flagged, self.copies.speed, terms, costs)
        obs = self._obs_rows()
        done = term | trunc
        if done.any() and self.metadata["autoreset_mode"] == AutoresetMode.DISABLED:
            self.copies.ended |= done
        elif done.any():
            ended = np.flatnonzero(done)
            infos = {key: infos[key].copy() for key in INFO_KEYS}
            final_info = {key: val.copy() for key, val in infos.items()}
            final_obs = obs.copy()
            final_state = self.state()
            self._reset_copies(ended, None)
            obs[ended] = self._obs_rows(ended)
            for key, val in self._reset_infos(ended).items():
                infos[key][ended] = val
            infos.update(final_obs=final_obs, _final_obs=done.copy(), final_info=final_info, _final_info=done.copy(),
                         final_state=final_state)
        self._last_infos = {key: infos[key] for key in INFO_KEYS}
        self._update_masks()
        u = len(self.possible_agents)
        return (self._observation(obs), rewards, np.repeat(term[:, None], u, axis=1),
                np.repeat(trunc[:, None], u, axis=1), infos)

    # ------------------------------------------------------------------ reading copies
    def action_masks(self) -> np.ndarray:
        """(B, U, L) int8 waypoint masks (1 = allowed); all ones (B, U, 2) in unicycle mode. Known after
        ``reset()``: before it (or after ``close()``) a RuntimeError, as in the parallel env."""
        self.require_running("action_masks()")
        return self.copies.masks.copy()

    def state(self) -> np.ndarray:
        """(B, S) float32 global state, row b the parallel env's ``state()`` of copy b."""
        self.require_running("state()")
        return self.layout.state(self._own_features(), self._pool.blocks[self.copies.rows, self._slots()],
                                 self._remaining())

    def close(self) -> None:
        """Release the scenes; every later call but ``close()`` raises a RuntimeError."""
        self._pool = self._queries = None

    def require_running(self, what: str) -> None:
        """A RuntimeError naming ``what`` before the first ``reset()`` or after ``close()``."""
        if self._pool is None:
            raise RuntimeError(f"{what} called after close(); make a new env")
        if not self.copies.started:
            raise RuntimeError(f"{what} called before reset(); call reset() first")

    # ------------------------------------------------------------------ reading the copies
    @property
    def started(self) -> bool:
        """True once ``reset()`` has been called."""
        return self.copies.started

    @property
    def slots(self) -> np.ndarray:
        """(B,) the slot k each copy has reached (zeros before the first ``reset()``)."""
        return self.copies.k.copy()

    @property
    def uav_xy(self) -> np.ndarray:
        """(B, U, 2) the UAVs' positions (a read-only view; zeros before the first ``reset()``)."""
        return _read_only(self.copies.xy)

    @property
    def uav_theta(self) -> np.ndarray:
        """(B, U) the UAVs' headings in [0, 2 pi) (a read-only view; zeros before the first ``reset()``)."""
        return _read_only(self.copies.theta)

    def scene(self, i: int):
        """The scene copy i flies (``config``, ``terrain``, ``track``, ``name``), without starts."""
        i = self._copy("scene()", i)
        return self._pool.cache(self.copies.rows[i]).parts

    def scenario(self, i: int) -> Scenario:
        """The :class:`~covert_env.world.scenario.Scenario` of copy i's episode, with the starts actually flown."""
        i, cp = self._copy("scenario()", i), self.copies
        cache = self._pool.cache(cp.rows[i])
        if not cp.drawn[i]:
            return cache.seeded_scenario()
        w = cache.parts
        return Scenario(w.config, w.terrain, w.track, cp.start_xy[i].copy(), cp.start_theta[i].copy(), name=w.name)

    def trajectory(self, i: int) -> Trajectory:
        """Copy i's episode so far as a :class:`~covert_env.world.trajectory.Trajectory` (needs ``record=True``)."""
        if self._recorder is None:
            raise RuntimeError("trajectory() needs the vector env built with record=True")
        i = self._copy("trajectory()", i)
        return self._recorder.trajectory(i, int(self.copies.k[i]), self.scene(i).track)

    def copy_view(self, i: int) -> CopyView:
        """Copy i read as an engine (:class:`~covert_env.envs.recorder.CopyView`), after ``reset()``."""
        return CopyView(self, self._copy("copy_view()", i))

    # ------------------------------------------------------------------ where waypoint actions would fly
    # Read-only queries for policies that plan with the model (waypoint mode, after reset()); each is documented
    # where it is computed, in covert_env.envs.waypoint_queries.WaypointQueries.
    def waypoint_paths(self, nodes) -> np.ndarray:
        """The paths ``(B, U, M, path_samples, 2)`` step would fly to lattice ``nodes`` ``(B, U, M)`` (-1: none):
        :meth:`~covert_env.envs.waypoint_queries.WaypointQueries.paths`."""
        return self._running_queries("waypoint_paths()").paths(nodes)

    def waypoint_goals(self, nodes) -> np.ndarray:
        """Where lattice ``nodes`` ``(B, U, M)`` lie at slot k+1, ``(B, U, M, 2)``:
        :meth:`~covert_env.envs.waypoint_queries.WaypointQueries.goals`."""
        return self._running_queries("waypoint_goals()").goals(nodes)

    def onward_reach(self, xy, theta) -> np.ndarray:
        """How many nodes UAVs ending this slot at poses ``xy``, ``theta`` may reach next slot, ``(B, U, M)``:
        :meth:`~covert_env.envs.waypoint_queries.WaypointQueries.onward_reach`."""
        return self._running_queries("onward_reach()").onward_reach(xy, theta)

    @property
    def available_nodes(self) -> np.ndarray:
        """(B, L) bool: the lattice nodes each copy's task has, what its masks may allow (every node but in a mix
        with a deviating task, whose eroded zone holds fewer: :mod:`covert_env.envs.task_mix`). Waypoint mode."""
        if self.action_mode != "waypoint":
            raise RuntimeError("available_nodes is for action_mode='waypoint'")
        if self._available is None:
            return np.ones((self.num_envs, len(self.lattice)), bool)
        return self._available.copy()

    def safety_state(self, depth: int = 1) -> SafetyState:
        """What the safety filter reads of this slot and the next ``depth`` slots' lattices:
        :meth:`~covert_env.envs.waypoint_queries.WaypointQueries.safety_state`."""
        return self._running_queries("safety_state()").safety_state(depth, self.episode_length)

    # ------------------------------------------------------------------ internals
    def _running_queries(self, what: str) -> WaypointQueries:
        """The waypoint queries, once ``what`` is checked: waypoint mode, running."""
        if self.action_mode != "waypoint":
            raise RuntimeError(f"{what} is for action_mode='waypoint'")
        self.require_running(what)
        return self._queries

    def _copy(self, what: str, i) -> int:
        """Copy index ``i`` checked (an integer in [0, num_envs - 1]; no negative indices, bools or floats) while
        the env is running."""
        self.require_running(what)
        return int_arg(f"{what}: copy index", i, 0, self.num_envs - 1)

    def _reset_copies(self, idx: np.ndarray, scene_seeds) -> None:
        """Put copies ``idx`` at slot 0 of a new episode: scenes and starts drawn per copy (class docstring)."""
        c, pool, cp = self.config, self._pool, self.copies
        draw = self.random_starts or (self.scenario_spec == "random" and scene_seeds is None)
        try:
            xy, theta = pool.draw_episodes(cp.rows, idx, [self._rngs[j] for j in idx], scene_seeds,
                                           self.scene_pool, draw, len(self.possible_agents),
                                           None if self.task_mix is None else self.task_mix.copy_task[idx])
        except Exception:
            # A scene that failed to build leaves these copies without one: they must be reset before a step.
            cp.rows[idx] = np.maximum(cp.rows[idx], 0)
            cp.ended[idx] = True
            raise
        rows = cp.rows[idx]
        q, phi = pool.q[rows, 0], pool.phi[rows, 0]
        self._own = None
        cp.xy[idx], cp.theta[idx] = xy, wrap_heading(theta)
        cp.start_xy[idx], cp.start_theta[idx], cp.drawn[idx], cp.ended[idx] = xy, theta, draw, False
        if self._recorder is not None:
            self._recorder.start(idx, xy, cp.theta[idx])
        cp.k[idx], cp.speed[idx] = 0, 0.0
        cp.los[idx] = pool.line_of_sight(rows, xy, c.altitude, q)
        cp.zone[idx] = zone_distance(xy, q[:, None, :2], phi[:, None], c.r1, c.r2, c.mu)

    def _reset_infos(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        """Infos of copies ``idx`` at slot 0: no slot flown (0 for rewards, costs, motion), the starts' LoS, zone,
        separation and clearance (the parallel env's reset infos)."""
        cp = self.copies
        u, xy = len(self.possible_agents), cp.xy[idx]
        out = {key: np.zeros((len(idx), u)) for key in INFO_KEYS}
        out.update(slot=np.zeros((len(idx), u), np.int64), los=cp.los[idx].copy(), los_path=cp.los[idx].copy(),
                   in_zone=cp.zone[idx] <= 0,
                   infeasible=np.zeros((len(idx), u), bool), separation=nearest_teammate(xy),
                   terrain_clearance=self._pool.terrain_clearance(self.copies.rows[idx], xy, self.config.altitude))
        return {key: out[key] for key in INFO_KEYS}

    def _slots(self, idx=slice(None)) -> np.ndarray:
        return np.minimum(self.copies.k[idx], self._pool.q.shape[1] - 1)

    def _remaining(self, idx=slice(None)) -> np.ndarray:
        length = self.episode_length
        return np.maximum(length - self.copies.k[idx], 0) / length

    def _own_features(self, idx=slice(None)) -> np.ndarray:
        # The whole batch's are kept until the state changes: observations and state() (every step for centralised
        # critics) share them.
        whole = isinstance(idx, slice) and idx == slice(None)
        if whole and self._own is not None:
            return self._own
        cp = self.copies
        rows, ks = cp.rows[idx], self._slots(idx)
        own = batch.own_features(cp.xy[idx], cp.theta[idx], self._pool.q[rows, ks], self._pool.phi[rows, ks],
                                 cp.speed[idx], cp.los[idx], cp.zone[idx], self.config)
        if whole:
            self._own = own
        return own

    def _obs_rows(self, idx=slice(None)) -> np.ndarray:
        shared = self._pool.blocks[self.copies.rows[idx], self._slots(idx)]
        return self.layout.observations(self._own_features(idx), shared, self._remaining(idx))

    def _observation(self, rows: np.ndarray):
        if self.dict_obs:
            return {"observation": rows, "action_mask": self.copies.masks.copy()}
        return rows

    def _update_masks(self) -> None:
        if self.action_mode != "waypoint":
            return
        pool, cp = self._pool, self.copies
        rows, k = cp.rows, cp.k
        visible = pool.lattice_ok[rows, k + 1] if self.mask_mode == "visible" else None
        cp.masks = batch.action_masks(cp.xy, cp.theta, pool.q_next[rows, k, :2], pool.phi_next[rows, k], self.lattice,
                                      visible, self._reach, self._available)


def _read_only(a: np.ndarray) -> np.ndarray:
    out = a.view()
    out.flags.writeable = False
    return out


def _step_infos(k, quant, flagged, speed, terms, costs) -> dict[str, np.ndarray]:
    """The infos of a step, ``(B, U)`` arrays in ``INFO_KEYS`` order (the parallel env's Infos table)."""
    infos = {"slot": np.repeat(k[:, None], flagged.shape[1], axis=1), "los": quant.los, "los_path": quant.los_path,
             "in_zone": quant.in_zone,
             "infeasible": flagged, "kappa": quant.kappa, "g": quant.g, "v": speed,
             "separation": quant.separation_path, "terrain_clearance": quant.terrain_clearance}
    infos.update(zip((f"reward_{t}" for t in batch.REWARD_TERMS), terms, strict=True))
    infos["cost"] = costs.sum(axis=0)
    infos.update(zip((f"cost_{n}" for n in batch.COSTS), costs, strict=True))
    return infos


def vector_env(num_envs: int = 1, **kwargs: Any) -> CovertSensingVectorEnv:
    """``num_envs`` copies as one :class:`CovertSensingVectorEnv` (the parallel env's keyword arguments)."""
    return CovertSensingVectorEnv(num_envs, **kwargs)

