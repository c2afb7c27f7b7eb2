"""Scenarios: a config, a terrain, a road with the target's track, and the UAVs' start poses.

:meth:`Scenario.paper` is the paper's setting (§3): the target starts at (120, 0) heading +x, so the
paper's UAV starts (40, 10), (60, 0), (50, -10) with headings 2 pi, pi, pi/2 lie inside its feasible
zone; 16 polytopes line a 70-slot road. :meth:`Scenario.random` draws a held-out scene (terrain and
road seeds) with starts sampled in the visible zone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from covert_env.geometry.zone import SPREAD_MARGIN, spread_nodes, spread_picks, to_world, zone_lattice
from covert_env.world.config import (
    MAX_N_UAVS,
    SCENE_ROAD_LEAD_IN,
    SCENE_ROAD_TAIL,
    Config,
    check_coordinates,
    short_repr,
)
from covert_env.world.generation import frustum_faces, random_roads, random_terrains
from covert_env.world.metrics import terrain_clearance
from covert_env.world.road import Road, TargetTrack, arc_lengths, cumulative_lengths, headings_along, points_along
from covert_env.world.terrain import Polytope, Terrain
from covert_env.world.visibility import TerrainArrays, growth_factors, register_terrain_arrays, visible_nodes

__all__ = ["Scenario", "PAPER_UAV_STARTS", "PAPER_SEED", "SceneArrays", "pick_starts", "pick_starts_many",
           "random_scene_arrays", "random_worlds", "sample_starts_on", "start_candidates", "valid_start_shapes"]

#: The paper's UAV starts (x, y, heading), §3.1-3.2.
PAPER_UAV_STARTS = np.array([[40.0, 10.0, 2 * math.pi], [60.0, 0.0, math.pi], [50.0, -10.0, math.pi / 2]])
#: Seed of the paper scenario's road and terrain (the paper's own map is not published).
PAPER_SEED = 2024
#: Where the target is at slot 0 in the paper scenario.
PAPER_TARGET_START = (120.0, 0.0)
#: Road driven before the target's start (m): buildings there cast shadows on the first zones.
_ROAD_LEAD_IN = SCENE_ROAD_LEAD_IN


@dataclass(frozen=True, eq=False)
class Scenario:
    """Everything that defines an episode apart from the policy.

    Attributes:
        config: model parameters.
        terrain: the polytopes, every top strictly below ``config.altitude`` (ValueError naming the
            polytope otherwise). A top within ``d_safe2`` of the altitude is legal: eq. 3 then only
            rules out the operational plane near it.
        track: the target's true motion (road + speed profile), at least ``n_slots + horizon`` slots
            long, with ``delta`` and ``z`` equal to the config's ``delta`` and ``target_height``. Its
            :meth:`~covert_env.world.road.TargetTrack.predict` is what planners and observations see; with
            ``config.prediction_error`` > 0 the constructors :meth:`paper` and :meth:`random` give it
            bounded speed noise (a hand-built track is taken as given).
        uav_xy: (U, 2) start positions; uav_theta: (U,) start headings (rad).
        name: a label for logs and figures.

    The team size is ``U = len(uav_xy)`` (:attr:`n_uavs`), 1 <= U <= 64; it may differ from
    ``config.n_uavs``, which is only the default team of the constructors (``Scenario.paper(n_uavs=1)``
    with the default config is the paper's 1-UAV experiment) and of the environments. The engine and
    the planners fly ``U`` UAVs; an environment built from a scenario requires ``U == config.n_uavs``
    (it sizes its agents and spaces from the config) and says so.
    """

    config: Config
    terrain: Terrain
    track: TargetTrack
    uav_xy: np.ndarray
    uav_theta: np.ndarray
    name: str = "scenario"

    def __post_init__(self) -> None:
        for attr, kind in (("config", Config), ("terrain", Terrain), ("track", TargetTrack)):
            if not isinstance(getattr(self, attr), kind):
                raise TypeError(f"Scenario.{attr} must be a {kind.__name__}, got {type(getattr(self, attr)).__name__}")
        try:
            xy = np.asarray(self.uav_xy, dtype=float).reshape(-1, 2)
            th = np.asarray(self.uav_theta, dtype=float).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"Scenario: uav_xy must be (U, 2) and uav_theta (U,) numbers ({exc})") from None
        if not valid_start_shapes(self.uav_xy, self.uav_theta):
            raise ValueError(f"Scenario: uav_xy must be (U, 2) and uav_theta (U,) (or (2,) and a number for one UAV), "
                             f"got shapes {np.shape(self.uav_xy)} and {np.shape(self.uav_theta)}")
        if not isinstance(self.name, str):
            raise TypeError(f"Scenario.name must be a str, got {short_repr(self.name)}")
        if len(xy) != len(th):
            raise ValueError(f"Scenario: {len(xy)} start positions but {len(th)} start headings")
        if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(th))):
            raise ValueError("Scenario: start poses must be finite")
        check_coordinates(xy, "Scenario.uav_xy")
        need = self.config.n_slots + self.config.horizon
        if self.track.n_slots < need:
            raise ValueError(f"Scenario.track must cover n_slots + horizon = {need} slots, has {self.track.n_slots}")
        _check_consistent(self.config, self.terrain, self.track)
        _check_team(len(xy), "Scenario")
        object.__setattr__(self, "uav_xy", xy)
        object.__setattr__(self, "uav_theta", th)

    @property
    def n_uavs(self) -> int:
        return len(self.uav_xy)

    @property
    def road(self) -> Road:
        return self.track.road

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def _road_and_track(config: Config, seed, start=PAPER_TARGET_START, heading: float = 0.0, noise_seed=None):
        """The road and the target's true track; with ``config.prediction_error`` > 0 the track drives
        with bounded speed noise drawn from ``noise_seed`` (default ``seed``), a stream of its own so
        the road, terrain and starts of a scene do not depend on the option."""
        c = config
        travel = c.target_speed * c.delta * (c.n_slots + c.horizon + 1)
        road_start = np.asarray(start, float) - _ROAD_LEAD_IN * np.array([math.cos(heading), math.sin(heading)])
        road = Road.random(seed, length=_ROAD_LEAD_IN + travel + SCENE_ROAD_TAIL, start=road_start, heading=heading,
                           straight_start=_ROAD_LEAD_IN + 30.0, max_curvature=c.road_max_curvature)
        track = TargetTrack.constant(road, c.target_speed, c.n_slots + c.horizon + 1, delta=c.delta,
                                     z=c.target_height, s0=_ROAD_LEAD_IN)
        if c.prediction_error > 0:
            track = track.with_speed_noise(c.prediction_error, _noise_generator(seed if noise_seed is None
                                                                                else noise_seed))
        return road, track

    @classmethod
    def paper(cls, config: Config | None = None, n_uavs: int | None = None) -> Scenario:
        """The paper's scenario (§3) with the first ``n_uavs`` (default ``config.n_uavs``) paper starts.

        The paper's map is not published; ours is the seeded random generator's output with the
        paper's M = 16, along a road whose first 170 m are straight so the paper's starts are in the zone.
        """
        c = _check_config(config, "Scenario.paper")
        u = c.n_uavs if n_uavs is None else n_uavs
        _check_team(u, "Scenario.paper")
        if not 1 <= u <= len(PAPER_UAV_STARTS):
            raise ValueError(f"Scenario.paper: n_uavs must be in [1, {len(PAPER_UAV_STARTS)}], got {u}")
        road, track = cls._road_and_track(c, PAPER_SEED)
        terrain = Terrain.random(seed=PAPER_SEED, road=road, config=c)
        starts = PAPER_UAV_STARTS[:u]
        return cls(c, terrain, track, starts[:, :2], starts[:, 2], name=f"paper-{u}uav")

    @classmethod
    def random(cls, seed: int, config: Config | None = None, n_uavs: int | None = None) -> Scenario:
        """A random scene: road, terrain and UAV starts drawn from ``seed``.

        Road and terrain come from the batched generator (:mod:`covert_env.world.generation`), the starts from
        ``np.random.default_rng(seed)``: a scene is the same whether drawn alone or with others (the environments
        draw the scenes a reset needs in one batch, :func:`random_worlds`). Starts are distinct grid nodes of the
        eroded zone at slot 0 with clear LoS, at least ``2 d_safe1`` apart, with headings drawn uniformly (with the
        fallbacks of :meth:`sample_starts` when shadows leave too little room).

        ``seed`` is an integer >= 0 (a numpy integer too); ``config`` a :class:`Config` or None (a dict
        is refused: build it with ``Config.from_dict``, which names unknown fields).
        """
        _check_seed(seed, "Scenario.random")
        c = _check_config(config, "Scenario.random")
        u = c.n_uavs if n_uavs is None else n_uavs
        _check_team(u, "Scenario.random")
        terrain, track, rng = cls.random_world(seed, c)
        xy, th = sample_starts_on(c, terrain, track, rng, u, f"random-{seed}")
        return cls(c, terrain, track, xy, th, name=f"random-{seed}")

    @classmethod
    def random_world(cls, seed: int, config: Config) -> tuple[Terrain, TargetTrack, np.random.Generator]:
        """The terrain and track of :meth:`random` (seed), and the generator to draw its starts from.

        Environments that draw their own starts use this (or :func:`random_worlds` for many) and skip the
        seeded ones."""
        return random_worlds([seed], config)[0]

    def sample_starts(self, rng: np.random.Generator | int, n_uavs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Random start poses on the waypoint lattice at slot 0. Returns (xy (U, 2), theta (U,)).

        ``rng`` is a numpy Generator (advanced by the draws) or an integer seed >= 0
        (``np.random.default_rng(rng)``); anything else is a TypeError naming ``rng``.

        Always: distinct lattice nodes of the eroded zone (eq. 5) at slot 0, pairwise at least
        ``d_safe1`` apart (eq. 2) and at least ``d_safe2`` from every polytope top (eq. 3; only a top
        within d_safe2 of the altitude removes nodes, which the random generator's default heights never
        make), headings uniform in [0, 2 pi). Placement tries, in order:

        1. nodes with clear LoS (eq. 6), at least ``2 d_safe1`` apart, in a random order (the
           usual case; these starts are bit-identical to earlier releases, same generator draws);
        2. if shadows leave too few such nodes on this scene: every zone node, the visible ones
           first (in step 1's order) then the shadowed ones (in a random order), ``2 d_safe1`` apart;
        3. the same order with the eq. 2 minimum ``d_safe1`` instead of ``2 d_safe1``;
        4. the nodes in lattice order, ``d_safe1`` apart: :class:`~covert_env.Config` rejects a
           config for which this leaves fewer than ``config.n_uavs`` starts, so a reset with the
           config's team never fails on some seeds (unless eq. 3 removes nodes). A larger ``n_uavs``
           than the config's can fail (ValueError naming n_uavs and d_safe1, on every seed alike).

        So starts may be in shadow (fallbacks 2-4) only when the scene leaves no other choice.
        """
        if not isinstance(rng, np.random.Generator):
            if isinstance(rng, bool) or not isinstance(rng, (int, np.integer)):
                raise TypeError(f"Scenario.sample_starts: rng must be a numpy Generator (np.random.default_rng(seed)) "
                                f"or an integer seed >= 0, got {short_repr(rng)} ({type(rng).__name__})")
            _check_seed(rng, "Scenario.sample_starts", "rng")
            rng = np.random.default_rng(rng)
        u = self.n_uavs if n_uavs is None else n_uavs
        _check_team(u, "Scenario.sample_starts")
        return sample_starts_on(self.config, self.terrain, self.track, rng, u, self.name)


class SceneArrays:
    """N random scenes as padded arrays (:func:`random_scene_arrays`), before any scene object is built.

    Attributes (scenes N, polytopes M, vertices V):
        seeds (N,); roads (N, P, 2): the road points; base (N, M, V, 2), top (N, M, V, 3), n_vertices (N, M): the
        polytopes (:class:`~covert_env.world.generation.TerrainBatch`); hs (N, M, V + 2, 4): their half-spaces; centre
        (N, M, 2), radius (N, M): footprint circles; verts (N, M, 2 V, 3): base and top vertices; z_max (N, M);
        highest (N, M, 3): each polytope's highest top vertex (eq. 3, the first on ties); growth (N, M):
        :func:`~covert_env.world.visibility.growth_factors`.
    """

    def __init__(self, seeds, roads, batch, config: Config):
        base, top, k = batch.base, batch.top, batch.n_vertices
        n, m, v = base.shape[:3]
        self.seeds, self.roads, self.config = list(seeds), roads, config
        self.base, self.top, self.n_vertices = base, top, k
        self.hs = frustum_faces(base.reshape(-1, v, 2), top.reshape(-1, v, 3), k.reshape(-1)).reshape(n, m, v + 2, 4)
        real = np.arange(v) < k[..., None]
        self.centre = (base * real[..., None]).sum(2) / np.maximum(k, 1)[..., None]
        self.radius = np.sqrt(((base - self.centre[:, :, None]) ** 2).sum(-1)).max(2, initial=0.0)
        self.verts = np.concatenate([np.concatenate([base, np.zeros((n, m, v, 1))], axis=-1), top], axis=2)
        self.z_max = top[..., 2].max(2, initial=-np.inf)
        self.highest = np.take_along_axis(top, top[..., 2].argmax(2)[..., None, None], axis=2)[:, :, 0]
        self.growth = growth_factors(self.hs, self.verts)

    def __len__(self) -> int:
        return len(self.seeds)

    def tracks(self) -> tuple[np.ndarray, np.ndarray]:
        """The targets' true positions (N, n + 1, 3) and headings (N, n + 1) at slots 0..n of the scenes' tracks
        (``TargetTrack.positions`` and ``headings`` of :func:`random_worlds`' tracks, bit for bit), for tracks
        without prediction error."""
        if self.config.prediction_error > 0:
            raise ValueError("SceneArrays.tracks: a track with prediction error is drawn per scene (random_worlds)")
        arc = self.nominal_arc()
        s = np.broadcast_to(arc, (len(self), len(arc)))
        cl = cumulative_lengths(self.roads)
        xy = points_along(self.roads, cl, s)
        q = np.concatenate([xy, np.full(xy.shape[:-1] + (1,), self.config.target_height)], axis=-1)
        return q, headings_along(self.roads, cl, s)

    def nominal_arc(self) -> np.ndarray:
        """(n + 1,) the arc length at slots 0..n of every scene's track driven at the nominal speed
        (``TargetTrack.arc`` of a track without prediction error)."""
        c = self.config
        return arc_lengths(np.full(c.n_slots + c.horizon + 1, float(c.target_speed)), c.delta, _ROAD_LEAD_IN)

    def world(self, i: int) -> tuple[Terrain, TargetTrack, np.random.Generator]:
        """Scene i's objects: :meth:`Scenario.random_world` of its seed."""
        seed, k = self.seeds[i], self.n_vertices[i]
        f, b_i, t_i = self.hs[i].copy(), self.base[i].copy(), self.top[i].copy()     # no batch array kept alive
        polys = tuple(Polytope._prevalidated(b_i[j, :kk], t_i[j, :kk], frustum=True, halfspaces=f[j, :kk + 2])
                      for j, kk in enumerate(k.tolist()))
        terrain = Terrain._checked(polys)
        if len(polys):
            v2 = self.verts.shape[2]
            pair_i, pair_j = np.triu_indices(v2, k=1)
            register_terrain_arrays(terrain, TerrainArrays(f, t_i[..., 2].max(1), b_i, self.centre[i].copy(),
                                                           self.radius[i].copy(), self.verts[i].copy(), pair_i,
                                                           pair_j))
        return terrain, self.track(i), np.random.default_rng(seed)

    def track(self, i: int) -> TargetTrack:
        """Scene i's target track (with its speed noise under a prediction error, drawn from the scene's seed)."""
        c = self.config
        track = TargetTrack.constant(Road(self.roads[i]), c.target_speed, c.n_slots + c.horizon + 1, delta=c.delta,
                                     z=c.target_height, s0=_ROAD_LEAD_IN)
        if c.prediction_error > 0:
            track = track.with_speed_noise(c.prediction_error, _noise_generator(self.seeds[i]))
        return track


def random_scene_arrays(seeds, config: Config) -> SceneArrays:
    """The roads and terrains of the random scenes ``seeds`` as arrays, drawn as one batch
    (:mod:`covert_env.world.generation`): each scene is the same whatever batch it is drawn in."""
    seeds = [int(s) for s in seeds]
    roads = random_roads(seeds, config, start=np.asarray(PAPER_TARGET_START, float) - (_ROAD_LEAD_IN, 0.0))
    return SceneArrays(seeds, roads, random_terrains(seeds, roads, config), config)


def random_worlds(seeds, config: Config) -> list[tuple[Terrain, TargetTrack, np.random.Generator]]:
    """:meth:`Scenario.random_world` of every seed, drawn as one batch (:func:`random_scene_arrays`)."""
    arrays = random_scene_arrays(seeds, config)
    return [arrays.world(i) for i in range(len(arrays))]


def sample_starts_on(c: Config, terrain: Terrain, track: TargetTrack, rng: np.random.Generator, u: int,
                   name: str) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Scenario.sample_starts` on the parts of a scenario."""
    return pick_starts(c, *start_candidates(c, terrain, track), rng, u, name)


def start_candidates(c: Config, terrain: Terrain, track: TargetTrack) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the start sampler draws from, the same for every draw on a scene (the vector env computes it once per
    scene): the zone lattice at slot 0 (world positions), and the indices of its nodes at least d_safe2 from every
    polytope top (eq. 3) with clear LoS, and without it."""
    q0, phi0 = track.position(0), float(track.heading(0))
    lattice = zone_lattice(c)
    nodes = to_world(lattice, q0[:2], phi0)
    clear = terrain_clearance(nodes, c.altitude, terrain) >= c.d_safe2
    visible = visible_nodes(terrain, lattice, q0, phi0, c.altitude)
    return nodes, np.flatnonzero(visible & clear), np.flatnonzero(~visible & clear)


def pick_starts(c: Config, nodes: np.ndarray, visible: np.ndarray, shadowed: np.ndarray, rng: np.random.Generator,
                u: int, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Steps 1-4 of :meth:`Scenario.sample_starts` on the candidates of :func:`start_candidates`."""
    xy, theta = pick_starts_many(c, nodes[None], [visible], [shadowed], [rng], u, [name])
    return xy[0], theta[0]


def pick_starts_many(c: Config, nodes: np.ndarray, visible: list, shadowed: list, rngs: list, u: int,
                     names: list) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pick_starts` of B copies, each with its own generator: ``nodes`` (B, L, 2), and per copy the indices
    of its ``visible`` and ``shadowed`` candidates. Step 1's greedy pick
    (:func:`~covert_env.geometry.zone.spread_picks`) runs for all copies at once; a copy that needs
    the fallbacks takes them alone. Returns (B, U, 2) positions and (B, U) headings."""
    b = len(rngs)
    orders = [vis[rng.permutation(len(vis))] for vis, rng in zip(visible, rngs, strict=True)]
    lens = np.array([len(o) for o in orders], dtype=np.intp)
    idx = np.zeros((b, max(int(lens.max(initial=0)), 1)), dtype=np.intp)
    valid = np.arange(idx.shape[1]) < lens[:, None]
    idx[valid] = np.concatenate(orders) if b else []
    picked = spread_picks(nodes, idx, valid, 2 * c.d_safe1, u)
    xy, theta = np.empty((b, u, 2)), np.empty((b, u))
    for n in range(b):                                   # each copy's own draws, in its generator's order
        pick = picked[n]
        if pick[-1] < 0:
            pick = _fallback_starts(c, nodes[n], orders[n], visible[n], shadowed[n], rngs[n], u, names[n])
        xy[n], theta[n] = nodes[n][pick], rngs[n].uniform(0, 2 * math.pi, u)
    return xy, theta


def _fallback_starts(c: Config, nodes: np.ndarray, order: np.ndarray, visible: np.ndarray, shadowed: np.ndarray,
                     rng: np.random.Generator, u: int, name: str) -> np.ndarray:
    """Steps 2-4 of :meth:`Scenario.sample_starts`, when step 1 (``order``: the visible nodes in random order)
    found fewer than ``u`` starts: the picked indices."""
    order = np.concatenate([order, shadowed[rng.permutation(len(shadowed))]])
    picked = spread_nodes(nodes, order, 2 * c.d_safe1, u)
    if len(picked) < u:
        picked = spread_nodes(nodes, order, c.d_safe1, u)
    if len(picked) < u:
        # Decided on the target-frame offsets, exactly as Config's check, with its margin (the lattice's
        # order; eq. 3 can only remove nodes near a top within d_safe2 of the flight altitude).
        picked = spread_nodes(zone_lattice(c), np.union1d(visible, shadowed), c.d_safe1 * (1.0 + SPREAD_MARGIN), u)
    if len(picked) < u:
        raise ValueError(f"Scenario {name}: the eroded zone has room for only {len(picked)} starts "
                         f"d_safe1={c.d_safe1:g} m apart, asked for n_uavs={u} (the config's n_uavs="
                         f"{c.n_uavs} fit); use fewer UAVs or a smaller d_safe1 (starts also keep "
                         f"d_safe2={c.d_safe2:g} m from every polytope top, eq. 3)")
    return picked


def _noise_generator(seed) -> np.random.Generator:
    """The target's speed-noise generator of a scene: a child of the scene seed's SeedSequence, so it
    is reproducible and independent of the draws of road, terrain and starts."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])



def valid_start_shapes(xy, theta) -> bool:
    """Start poses shaped (U, 2) and (U,), or (2,) and a number for one UAV: a flat (2U,) array or a (U, 3) one would
    otherwise be reshaped into some other team without a word."""
    xy_shape = np.shape(xy)
    return (len(xy_shape) == 2 and xy_shape[1] == 2 or xy_shape == (2,)) and np.ndim(theta) <= 1


def _check_seed(seed, where: str, name: str = "seed") -> None:
    """A scene seed: an integer >= 0 (numpy integers too; bools, floats and strings are refused)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"{where}: {name} must be an integer >= 0, got {short_repr(seed)} ({type(seed).__name__})")


def _check_config(config, where: str) -> Config:
    """``config`` or the default Config; anything but a Config or None is a TypeError naming it."""
    if config is None:
        return Config()
    if not isinstance(config, Config):
        hint = "; build it with Config.from_dict(...)" if isinstance(config, dict) else ""
        raise TypeError(f"{where}: config must be a Config or None, got {short_repr(config)} "
                        f"({type(config).__name__}){hint}")
    return config


def _check_team(u, where: str) -> None:
    if isinstance(u, bool) or not isinstance(u, (int, np.integer)) or not 1 <= u <= MAX_N_UAVS:
        raise ValueError(f"{where}: n_uavs must be an integer >= 1 and <= {MAX_N_UAVS}, got {u!r}")


def _check_consistent(c: Config, terrain: Terrain, track: TargetTrack) -> None:
    """The parts must describe one model: the engine flies config.delta per slot of the track and films
    the track's z, and nothing can fly through a polytope that reaches the operational plane."""
    if not math.isclose(track.delta, c.delta, rel_tol=1e-9):
        raise ValueError(f"Scenario: track.delta = {track.delta:g} s but config.delta = {c.delta:g} s; build the "
                         f"track with delta=config.delta")
    if not math.isclose(track.z, c.target_height, rel_tol=1e-9, abs_tol=1e-12):
        raise ValueError(f"Scenario: track.z = {track.z:g} m but config.target_height = {c.target_height:g} m; "
                         f"build the track with z=config.target_height")
    if len(terrain):
        high = np.flatnonzero(terrain.z_max >= c.altitude)
        if high.size:
            i = int(high[0])
            raise ValueError(f"Scenario: polytope {i} is {terrain.z_max[i]:g} m high, not below the flight "
                             f"altitude config.altitude = {c.altitude:g} m ({high.size} such polytope(s)); "
                             f"lower it or raise the altitude")
