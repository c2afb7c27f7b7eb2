"""A scene set as data: a family's scenes written to one JSON file, so two labs compare on the exact same scenes.

    from covert_env.scene_set import SceneSet
    scenes = SceneSet.generate("downtown", 20)              # its first 20 held-out scenes
    scenes.save("downtown20.json")
    same = SceneSet.load("downtown20.json")                 # bit-identical scenarios: the same scores
    env = covert_env.parallel_env(scenario=same[0])

    covert-env scene-set --family downtown --scenes 20 --out downtown20.json
    covert-env evaluate --scene-set downtown20.json ...      # the harness on those scenes

A file holds the config, the family and seeds it was drawn from (for the record: loading never draws again), and
per scene its terrain (a GeoJSON FeatureCollection, :meth:`Terrain.to_geojson`), road points, the target's speed
profile and the UAVs' starts. JSON floats round-trip exactly, so a loaded scene is the saved one to the last bit.
No pickle: a file is data, read through the same checks as a hand-written one (:meth:`Terrain.from_geojson`,
:class:`Road`, :class:`TargetTrack`, :class:`Scenario`), with errors naming the scene and the field.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from covert_env.config import Config, read_json
from covert_env.families import HELD_OUT_SEEDS, family_config, scene_family
from covert_env.road import Road, TargetTrack
from covert_env.scenario import Scenario
from covert_env.terrain import Terrain

__all__ = ["FORMAT", "MAX_SCENES", "SceneSet"]

#: The file's ``format`` and ``version`` fields.
FORMAT = ("covert_env.scene_set", 1)
#: Most scenes in one set (a file is also capped at 64 MiB by the JSON reader).
MAX_SCENES = 100_000


class SceneSet(Sequence):
    """Scenarios under one config, with the family and seeds they were drawn from (None for hand-made ones).

    Args:
        scenarios: the scenes, all with the same config.
        family: the scene family's name (:mod:`covert_env.families`), if drawn from one.
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
            scene_family(family)
        if seeds is not None and len(seeds) != len(scenarios):
            raise ValueError(f"SceneSet: {len(seeds)} seeds for {len(scenarios)} scenarios")
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
        has_seeds = all(isinstance(s, int) and not isinstance(s, bool) for s in seeds)
        return cls(scenarios, family=family, seeds=seeds if has_seeds else None)

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


def _scenario(s: dict, config: Config) -> Scenario:
    """One scene of a file, through the constructors' own checks."""
    if not isinstance(s, dict):
        raise TypeError(f"must be an object, got {type(s).__name__}")
    terrain = Terrain.from_geojson(s["terrain"], altitude=config.altitude)
    road = Road.from_points(s["road"]["points"])
    t = s["track"]
    nominal = t.get("nominal_speeds")
    track = TargetTrack(road, np.asarray(t["speeds"], dtype=float), delta=float(t["delta"]), z=float(t["z"]),
                        s0=float(t["s0"]), nominal_speeds=None if nominal is None else np.asarray(nominal, float))
    starts = s["starts"]
    return Scenario(config, terrain, track, np.asarray(starts["xy"], dtype=float),
                    np.asarray(starts["theta"], dtype=float), name=str(s.get("name", "scene")))
