"""The module paths that moved after 0.10, still importable for one more release.

``covert_env``'s model is in two subpackages: :mod:`covert_env.geometry` (scene-free geometry) and
:mod:`covert_env.world` (the scenes and what is measured in them). The evaluation commands and their statistics
moved from ``training`` to :mod:`covert_env.evaluation`. ``import covert_env.zone``, ``from covert_env.config import
Config``, ``import training.evaluate`` and ``python -m training.evaluate`` still work: they give the module at its
new place (the same module object; ``-m`` runs it) and warn with a ``DeprecationWarning`` that names it. The names
``covert_env`` exports (``covert_env.Config``, ``covert_env.Scenario``, ...) did not move.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import warnings

__all__ = ["MOVED", "MovedModules"]

#: Old module name -> its name after 0.10.
MOVED = {
    **{f"covert_env.{m}": f"covert_env.geometry.{m}"
       for m in ("angles", "cost", "dynamics", "flight", "reach", "separation", "sight_kernel", "ties", "zone")},
    **{f"covert_env.{m}": f"covert_env.world.{m}"
       for m in ("config", "engine", "families", "generation", "metrics", "polytope", "road", "roles", "scenario",
                 "scene_set", "shadows", "tasks", "terrain", "trajectory", "visibility")},
    **{f"training.{m}": f"covert_env.evaluation.{m}"
       for m in ("benchmark", "evaluate", "leaderboard", "provenance", "stats", "tiers")},
}


def _warn(old: str) -> str:
    new = MOVED[old]
    warnings.warn(f"{old} moved to {new} after covert_env 0.10 (CHANGELOG.md); import it from there, the old path "
                  "will be removed", DeprecationWarning, stacklevel=3)
    return new


class MovedModules(importlib.abc.MetaPathFinder, importlib.abc.InspectLoader):
    """Finds the modules of :data:`MOVED` by their old names (after every other finder has failed: no file of that
    name is left) and loads each as the module at its new place; ``python -m OLD`` runs the new module's code."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in MOVED:
            return None
        # The new file as the origin: ``python -m OLD`` runs the new module's code with its __file__.
        return importlib.util.spec_from_loader(fullname, self, origin=importlib.util.find_spec(MOVED[fullname]).origin)

    def create_module(self, spec):
        return importlib.import_module(_warn(spec.name))

    def exec_module(self, module) -> None:
        """Nothing to run: the module is the new one, already executed."""

    def get_code(self, fullname):
        """The new module's code (``python -m OLD``: runpy runs it as ``__main__``)."""
        new = _warn(fullname)
        return importlib.util.find_spec(new).loader.get_code(new)

    def get_source(self, fullname):
        new = MOVED[fullname]
        return importlib.util.find_spec(new).loader.get_source(new)
