"""Scene families: named presets of the random scene generator, from open country to street canyons.

A benchmark is its scenes. Each family is a set of :class:`~covert_env.world.config.Config` fields of the generator
(how many polytopes, how large and tall, how close to the road, how sharply the road turns); a scene of a family is
``Scenario.random(seed, family.config())``. Select one by name wherever scenes are drawn::

    covert_env.parallel_env(family="downtown")              # PettingZoo; also env(), vector_env(), gym.make
    covert-env evaluate --family dense ...                  # the harness, on the family's held-out scenes

Every family shares the seed ranges: training scenes are drawn from :data:`TRAIN_SEEDS` (an env's ``scene_pool``
takes the first seeds of it) and evaluations fly :data:`HELD_OUT_SEEDS`, which no training pool reaches. The same
seed gives different scenes in different families (the config shapes every draw).

============  =====================================================================================================
family        what it is
============  =====================================================================================================
``sparse``    8 polytopes beside a straight road: few shadows.
``paper``     the paper's setting (§3): 16 buildings and hills beside a gently bending road (the default).
``winding``   the paper's terrain along a road with sharp turns (30 m turn radius).
``dense``     48 polytopes beside the paper's road.
``downtown``  56 tall, narrow buildings close to a road with 40 m corners: street canyons, the zone often shadowed.
``towers``    24 masts and towers rising to 76 m, within d_safe2 of the 80 m flight altitude: eq. 3 binds.
============  =====================================================================================================

Their measured difficulty (shadowed share of the zone, the planners' blocked line of sight, slots where eq. 3
binds) is printed by ``python -m baselines.difficulty`` and tabled in ``docs/model.md#scene-families``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from covert_env.world.config import Config

__all__ = ["FAMILIES", "HELD_OUT_SEEDS", "SceneFamily", "TRAIN_SEEDS", "family_config", "scene_family"]

TRAIN_SEEDS = range(0, 1_000_000)
"""Scene seeds training draws from (an env's ``scene_pool`` = P takes seeds 0 .. P - 1)."""
HELD_OUT_SEEDS = range(1_000_000, 1_100_000)
"""Scene seeds evaluations fly (the harness and ``reproduce`` take the first ones), disjoint from training's."""


@dataclass(frozen=True)
class SceneFamily:
    """A named preset of the random scene generator.

    Attributes:
        name: what users pass (``family="dense"``).
        description: one line for tables and ``--help``.
        fields: the :class:`Config` fields the family sets (read-only); the others keep the caller's values.
    """

    name: str
    description: str
    fields: Any = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fields", MappingProxyType(dict(self.fields)))

    def config(self, base: Config | None = None) -> Config:
        """The family's config: ``base`` (default ``Config()``) with the family's fields.

        Raises:
            ValueError: ``base`` sets one of the family's fields to another value than the default and the family's
                (two sources for one field: pass the family, or set the field, not both).
        """
        base = Config() if base is None else base
        default = Config()
        clash = {k: getattr(base, k) for k, v in self.fields.items()
                 if getattr(base, k) != getattr(default, k) and getattr(base, k) != v}
        if clash:
            raise ValueError(f"family={self.name!r} sets {dict(self.fields)}, but the config sets "
                             f"{clash}; pass the family or set these fields, not both")
        return base.replace(**self.fields) if self.fields else base


FAMILIES = MappingProxyType({f.name: f for f in (
    SceneFamily("sparse", "8 polytopes beside a straight road: few shadows",
                {"n_polytopes": 8, "road_max_curvature": 0.0}),
    SceneFamily("paper", "the paper's setting: 16 buildings and hills beside a gently bending road"),
    SceneFamily("winding", "the paper's terrain along a road with sharp turns (30 m turn radius)",
                {"road_max_curvature": 1 / 30}),
    SceneFamily("dense", "48 polytopes beside the paper's road", {"n_polytopes": 48}),
    SceneFamily("downtown", "56 tall, narrow buildings close to a road with 40 m corners: street canyons",
                {"n_polytopes": 56, "min_radius": 6.0, "max_radius": 14.0, "min_height": 30.0,
                 "road_clearance": 5.0, "road_max_offset": 34.0, "road_max_curvature": 1 / 40}),
    SceneFamily("towers", "24 masts and towers up to 76 m, within d_safe2 of the flight altitude: eq. 3 binds",
                {"n_polytopes": 24, "min_height": 45.0, "max_height": 76.0, "min_radius": 5.0, "max_radius": 12.0}),
)})
"""Every family by name, in order of the table above."""


def scene_family(name) -> SceneFamily:
    """The family called ``name``; a ValueError naming the families otherwise."""
    if not isinstance(name, str) or name not in FAMILIES:
        raise ValueError(f"family must be one of {list(FAMILIES)}, got {name!r}")
    return FAMILIES[name]


def family_config(name, base: Config | None = None) -> Config:
    """``scene_family(name).config(base)``: the config of family ``name`` on top of ``base``."""
    return scene_family(name).config(base)
