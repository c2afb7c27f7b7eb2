"""Moved to :mod:`baselines.learned_cost` (the planner with a learned cost, beside the planner) after covert_env 0.10
(CHANGELOG.md). This path still imports, with a ``DeprecationWarning``; it will be removed."""

import warnings

from baselines.learned_cost import *  # noqa: F403
from baselines.learned_cost import __all__  # noqa: F401

warnings.warn("training.pretrained.learned_cost moved to baselines.learned_cost after covert_env 0.10 (CHANGELOG.md); "
              "import it from there, the old path will be removed", DeprecationWarning, stacklevel=2)
