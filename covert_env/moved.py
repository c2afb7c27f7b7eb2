"""Module paths that moved after 0.10, still importable for one more release.

``covert_env``'s model is in two subpackages: :mod:`covert_env.geometry` (scene-free geometry) and
:mod:`covert_env.world` (the scenes and what is measured in them). ``import covert_env.zone`` and ``from
covert_env.config import Config`` still work: they give the module at its new place (the same module object) and
warn with a ``DeprecationWarning`` that names it; ``python -m OLD`` runs the new module and warns with a
``FutureWarning`` (shown by default). The names ``covert_env`` exports (``covert_env.Config``, ``covert_env.Scenario``,
...) did not move. A package above covert_env serves its own moved modules with the same finder
(:meth:`MovedModules.install`, e.g. ``training``'s).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

__all__ = ["MOVED", "MovedModules"]

#: covert_env's old module names -> their names after 0.10.
MOVED = {
    **{f"covert_env.{m}": f"covert_env.geometry.{m}"
       for m in ("angles", "cost", "dynamics", "flight", "reach", "separation", "sight_kernel", "ties", "zone")},
    **{f"covert_env.{m}": f"covert_env.world.{m}"
       for m in ("config", "engine", "families", "generation", "metrics", "polytope", "road", "roles", "scenario",
                 "scene_set", "shadows", "tasks", "terrain", "trajectory", "visibility")},
}


class MovedModules(importlib.abc.MetaPathFinder, importlib.abc.InspectLoader):
    """Finds the modules of ``moved`` (old name -> new name) by their old names, after every other finder has
    failed (no file of that name is left), and loads each as the module at its new place; ``python -m OLD`` runs
    the new module's code."""

    def __init__(self, moved: dict[str, str]):
        self.moved = moved

    @classmethod
    def install(cls, moved: dict[str, str]) -> None:
        """Serve ``moved`` from ``sys.meta_path`` (once per mapping)."""
        if not any(isinstance(f, cls) and f.moved is moved for f in sys.meta_path):
            sys.meta_path.append(cls(moved))

    def _new(self, old: str, category: type[Warning], stacklevel: int) -> str:
        new = self.moved[old]
        warnings.warn(f"{old} moved to {new} after covert_env 0.10 (CHANGELOG.md); use the new name, the old one will "
                      "be removed", category, stacklevel=stacklevel)
        return new

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in self.moved:
            return None
        # The new file as the origin: ``python -m OLD`` runs the new module's code with its __file__.
        return importlib.util.spec_from_loader(fullname, self,
                                               origin=importlib.util.find_spec(self.moved[fullname]).origin)

    def create_module(self, spec):
        return importlib.import_module(self._new(spec.name, DeprecationWarning, 3))

    def exec_module(self, module) -> None:
        """Nothing to run: the module is the new one, already executed."""

    def get_code(self, fullname):
        """The new module's code (``python -m OLD``: runpy runs it as ``__main__``; a person reads the warning)."""
        new = self._new(fullname, FutureWarning, 3)
        return importlib.util.find_spec(new).loader.get_code(new)

    def get_source(self, fullname):
        new = self.moved[fullname]
        return importlib.util.find_spec(new).loader.get_source(new)
