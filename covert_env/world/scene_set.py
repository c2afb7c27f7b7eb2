"""A scene set as data: a family's scenes written to one JSON file, so two labs compare on the exact same scenes.

    from covert_env.world.scene_set import SceneSet
    scenes = SceneSet.generate("downtown", 20)              # its first 20 held-out scenes
    scenes.save("downtown20.json")
    same = SceneSet.load("downtown20.json")                 # bit-identical scenarios: the same scores
    env = covert_env.parallel_env(scenario=same[0])

    covert-env scene-set --family downtown --scenes 20 --out downtown20.json
    covert-env evaluate --scene-set downtown20.json ...      # the harness on those scenes

A file holds the config, the family and seeds it was drawn from, and per scene its terrain (a GeoJSON
FeatureCollection, :meth:`Terrain.to_geojson`), road points, the target's speed profile and the UAVs' starts. JSON
floats round-trip exactly, so a loaded scene is the saved one to the last bit.
No pickle: a file is data, read through the same checks as a hand-written one (:meth:`Terrain.from_geojson`,
:class:`Road`, :class:`TargetTrack`, :class:`Scenario`), with errors naming the scene and the field.

A set is also checked against itself when it is made or loaded, since labs compare on it: every scene's team is
the config's ``n_uavs``; no scene repeats another; no polytope's footprint touches the road (the target drives
through no building); a seed is an integer in the scene seeds' range (all scenes have one, or none does); and a
set that names its family carries that family's config. A set with a family and seeds is drawn again from them
(:meth:`SceneSet.generate`) and must equal the file's scenes to within 1e-9 (relative) in every number, so a
mislabelled or edited scene is refused, naming the scene and the part that differs.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from covert_env.world.config import Config, read_json
from covert_env.world.families import FAMILIES, HELD_OUT_SEEDS, family_config, scene_family
from covert_env.world.road import Road, TargetTrack
from covert_env.world.scenario import Scenario
from covert_env.world.terrain import Terrain

__all__ = ["FORMAT", "MAX_SCENES", "SceneSet"]

#: The file's ``format`` and ``version`` fields.
FORMAT = ("covert_env.world.scene_set", 1)
#: Most scenes in one set (a file is also capped at 64 MiB by the JSON reader).
MAX_SCENES = 100_000
#: Scene seeds are integers in [0, MAX_SEED] (what numpy's generators take, as int64).
MAX_SEED = 2 ** 63 - 1
#: How far a loaded seeded scene may be from the scene drawn again from its seed (relative, and absolute in m): a
#: file written on another CPU may differ in the last bits (docs/decisions/flight.md#settled-slot-end-poses).
REDRAW_TOL = 1e-9


class SceneSet(Sequence):
    """Scenarios under one config, with the family and seeds they were drawn from (None for hand-made ones).

    Args:
        scenarios: the scenes, all with the same config.
        family: the scene family's name (:mod:`covert_env.world.families`), if drawn from one.
        seeds: the scene seed of each scenario, if drawn (``Scenario.random(seed, config)``).
    """

    def __init__(self, scenarios: Sequence[Scenario], *, family: str | None = None,
                 seeds: Sequence[int] | None = None):
        scenarios = list(scenarios)
        if not scenarios or not all(isinstance(s, Scenario) for s in scenarios):
            raise ValueError("SceneSet: scenarios must be a non-empty list of Scenario")
        if len(scenarios) > MAX_SCENES:
            raise ValueError(f"SceneSet: at most {MAX_SCENES} scenes, got {len(scenarios)}")
        if any(s.config != scenarios[0].config for s in scenarios):
            raise ValueError("SceneSet: every scenario must have the same config")
        if family is not None:
            _check_family_config(family, scenarios[0].config)
        if seeds is not None:
            if len(seeds) != len(scenarios):
                raise ValueError(f"SceneSet: {len(seeds)} seeds for {len(scenarios)} scenarios")
            for i, seed in enumerate(seeds):
                if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) \
                        or not 0 <= seed <= MAX_SEED:
                    raise ValueError(f"SceneSet: scene {i}: seed must be an integer in [0, 2^63 - 1], got {seed!r}")
        _check_scenes(scenarios)
        self._scenarios = scenarios
        self.family = family
        self.seeds = None if seeds is None else [int(s) for s in seeds]

    @property
    def config(self) -> Config:
        """The scenes' config."""
        return self._scenarios[0].config

    def __len__(self) -> int:
        return len(self._scenarios)

    def __getitem__(self, i):
        return self._scenarios[i]

    def __iter__(self) -> Iterator[Scenario]:
        return iter(self._scenarios)

    @classmethod
    def generate(cls, family: str = "paper", n: int = 20, *, seeds: Sequence[int] | None = None,
                 config: Config | None = None) -> SceneSet:
        """``Scenario.random(seed, family_config(family, config))`` for the family's first ``n`` held-out seeds, or
        for ``seeds``."""
        cfg = family_config(family, config)
        if seeds is None:
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_SCENES:
                raise ValueError(f"SceneSet.generate: n must be an integer in [1, {MAX_SCENES}], got {n!r}")
            seeds = HELD_OUT_SEEDS[:int(n)]
        return cls([Scenario.random(int(s), cfg) for s in seeds], family=family, seeds=list(seeds))

    # ------------------------------------------------------------------ files
    def to_json(self) -> dict:
        """The set as a JSON object (see the module docstring)."""
        scenes = []
        for i, sc in enumerate(self._scenarios):
            tr = sc.track
            scenes.append({
                "name": sc.name, "seed": None if self.seeds is None else self.seeds[i],
                "terrain": sc.terrain.to_geojson(), "road": tr.road.to_json(),
                "track": {"speeds": tr.speeds.tolist(), "delta": tr.delta, "z": tr.z, "s0": tr.s0,
                          "nominal_speeds": None if tr.nominal_speeds is None else tr.nominal_speeds.tolist()},
                "starts": {"xy": sc.uav_xy.tolist(), "theta": sc.uav_theta.tolist()}})
        return {"format": FORMAT[0], "version": FORMAT[1], "family": self.family, "config": self.config.to_dict(),
                "scenes": scenes}

    @classmethod
    def from_json(cls, obj: dict) -> SceneSet:
        """The set of :meth:`to_json`'s object; a ValueError naming the scene and the field otherwise."""
        if not isinstance(obj, dict) or obj.get("format") != FORMAT[0]:
            raise ValueError(f"not a scene set: format must be {FORMAT[0]!r}")
        if obj.get("version") != FORMAT[1]:
            raise ValueError(f"scene set version {obj.get('version')!r}: this covert_env reads version {FORMAT[1]}")
        try:
            config = Config.from_dict(obj["config"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"scene set config: {exc}") from None
        family = obj.get("family")
        if family is not None:
            scene_family(family)
        scenes = obj.get("scenes")
        if not isinstance(scenes, list) or not 1 <= len(scenes) <= MAX_SCENES:
            raise ValueError(f"scene set scenes must be a list of 1 to {MAX_SCENES} scenes")
        scenarios, seeds = [], []
        for i, s in enumerate(scenes):
            try:
                scenarios.append(_scenario(s, config))
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"scene set scene {i}: {type(exc).__name__ if isinstance(exc, KeyError) else ''}"
                                 f"{exc}") from None
            seeds.append(s.get("seed"))
        if all(seed is None for seed in seeds):
            seeds = None
        elif any(seed is None for seed in seeds):
            raise ValueError(f"scene set: scene {seeds.index(None)} has no seed but others have one (every scene "
                             "has a seed, or none does)")
        out = cls(scenarios, family=family, seeds=seeds)
        if family is not None and seeds is not None:
            out.check_against_seeds()
        return out

    def check_against_seeds(self) -> None:
        """Draw every scene again from the family and its seed and compare (module docstring); a ValueError names
        the first scene that differs and the part (terrain, road, target track or starts)."""
        if self.family is None or self.seeds is None:
            raise ValueError("SceneSet.check_against_seeds: the set has no family or no seeds to draw from")
        for i, (sc, seed) in enumerate(zip(self._scenarios, self.seeds, strict=True)):
            again = Scenario.random(seed, self.config)
            parts = {"terrain": (_terrain_numbers(sc.terrain), _terrain_numbers(again.terrain)),
                     "road": (sc.track.road.points, again.track.road.points),
                     "target track": (sc.track.speeds, again.track.speeds),
                     "UAV starts": (np.column_stack([sc.uav_xy, sc.uav_theta]),
                                np.column_stack([again.uav_xy, again.uav_theta]))}
            for part, (got, want) in parts.items():
                if np.shape(got) != np.shape(want) or not np.allclose(got, want, rtol=REDRAW_TOL, atol=REDRAW_TOL):
                    raise ValueError(f"scene {i} (seed {seed}) is not what family {self.family!r} draws from seed "
                                     f"{seed} with this config (first difference: {part}); the file was edited or "
                                     "mislabelled (a hand-made set has no family or no seeds)")

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_json` to ``path``."""
        Path(path).write_text(json.dumps(self.to_json(), allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> SceneSet:
        """Read a file :meth:`save` wrote; errors name the file, the scene and the field."""
        obj = read_json(path, "scene set file")
        try:
            return cls.from_json(obj)
        except ValueError as exc:
            raise ValueError(f"scene set file {path}: {exc}") from None


def _check_family_config(family: str, config: Config) -> None:
    """The generator fields of ``config`` are the family's (a set labelled downtown holds downtown's scenes)."""
    scene_family(family)
    want = family_config(family)
    fields = sorted({k for f in FAMILIES.values() for k in f.fields})
    wrong = {k: getattr(config, k) for k in fields if getattr(config, k) != getattr(want, k)}
    if wrong:
        raise ValueError(f"SceneSet: family {family!r} draws with {({k: getattr(want, k) for k in wrong})}, but the "
                         f"config has {wrong}; the family label and the config disagree")


def _terrain_numbers(terrain: Terrain) -> np.ndarray:
    return np.concatenate([p.vertices.reshape(-1) for p in terrain] or [np.zeros(0)])


def _check_scenes(scenarios: list[Scenario]) -> None:
    """Every scene flies the config's team, repeats no other scene and has no polytope on its road."""
    from shapely import LineString, Polygon

    u = scenarios[0].config.n_uavs
    seen: dict[bytes, int] = {}
    for i, sc in enumerate(scenarios):
        if sc.n_uavs != u:
            raise ValueError(f"SceneSet: scene {i} has {sc.n_uavs} UAV starts, but the config's n_uavs is {u}")
        key = b"".join(np.ascontiguousarray(a, float).tobytes() for a in (
            _terrain_numbers(sc.terrain), sc.track.road.points, sc.track.speeds, sc.uav_xy, sc.uav_theta))
        if key in seen:
            raise ValueError(f"SceneSet: scene {i} repeats scene {seen[key]} (a set's scenes are distinct)")
        seen[key] = i
        road = LineString(sc.track.road.points)
        on_road = [j for j, p in enumerate(sc.terrain) if Polygon(p.base).intersects(road)]
        if on_road:
            raise ValueError(f"SceneSet: scene {i}: polytope {on_road[0]} stands on the road (its footprint crosses "
                             "the target's road)")


def _scenario(s: dict, config: Config) -> Scenario:
    """One scene of a file, through the constructors' own checks."""
    if not isinstance(s, dict):
        raise TypeError(f"must be an object, got {type(s).__name__}")
    terrain = Terrain.from_geojson(s["terrain"], altitude=config.altitude)
    road = Road.from_points(s["road"]["points"])
    t = s["track"]
    for key in ("delta", "z", "s0"):
        if isinstance(t[key], bool) or not isinstance(t[key], (int, float)):
            raise TypeError(f"track.{key} must be a number, got {t[key]!r}")
    nominal = t.get("nominal_speeds")
    track = TargetTrack(road, np.asarray(t["speeds"], dtype=float), delta=float(t["delta"]), z=float(t["z"]),
                        s0=float(t["s0"]), nominal_speeds=None if nominal is None else np.asarray(nominal, float))
    starts = s["starts"]
    return Scenario(config, terrain, track, np.asarray(starts["xy"], dtype=float),
                    np.asarray(starts["theta"], dtype=float), name=str(s.get("name", "scene")))
