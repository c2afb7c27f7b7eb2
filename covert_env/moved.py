"""The module paths that moved after 0.10, still importable for one more release.

``covert_env``'s model is in two subpackages: :mod:`covert_env.geometry` (scene-free geometry) and
:mod:`covert_env.world` (the scenes and what is measured in them). ``import covert_env.zone`` and
``from covert_env.config import Config`` still work: they give the module at its new place (the same module object)
and warn with a ``DeprecationWarning`` that names it. The names ``covert_env`` exports (``covert_env.Config``,
``covert_env.Scenario``, ...) did not move.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import warnings

__all__ = ["MOVED", "MovedModules"]

#: Old module name under covert_env -> the subpackage it moved to after 0.10.
MOVED = {
    **dict.fromkeys(("angles", "cost", "dynamics", "flight", "reach", "separation", "sight_kernel", "ties", "zone"),
                    "geometry"),
    **dict.fromkeys(("config", "engine", "families", "generation", "metrics", "polytope", "road", "roles",
                     "scenario", "scene_set", "shadows", "tasks", "terrain", "trajectory", "visibility"), "world"),
}


class MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``covert_env.<old>`` for the modules of :data:`MOVED` (after every other finder has failed: no file
    of that name is left) and loads it as the module at its new place."""

    def find_spec(self, fullname, path=None, target=None):
        parent, _, leaf = fullname.rpartition(".")
        if parent == "covert_env" and leaf in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        leaf = spec.name.rpartition(".")[2]
        new = f"covert_env.{MOVED[leaf]}.{leaf}"
        warnings.warn(f"{spec.name} moved to {new} after covert_env 0.10 (CHANGELOG.md); import it from there, "
                      "the old path will be removed", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module) -> None:
        """Nothing to run: the module is the new one, already executed."""
