"""Skips for the tests that need a package of an optional extra: the skip reason names the package and the pip
command that installs it, e.g. ``needs stable_baselines3: pip install -e ".[train]"``.

    from _extras import needs
    needs("stable_baselines3")             # at module level: the whole file skips without it
    torch = needs("torch")                 # returns the module, like pytest.importorskip
"""

from __future__ import annotations

from types import ModuleType

import pytest

#: Top-level package -> the extra of pyproject.toml that installs it (torch comes with Stable-Baselines3).
EXTRA_OF = {
    "stable_baselines3": "train", "sb3_contrib": "train", "torch": "train", "tensorboard": "train",
    "rich": "train", "ray": "rllib", "torchrl": "torchrl", "tensordict": "torchrl", "benchmarl": "benchmarl",
    "tianshou": "tianshou", "moviepy": "dev",
}


def reason(module: str) -> str:
    """The skip reason for a missing ``module`` (a package of :data:`EXTRA_OF` or one of its submodules)."""
    top = module.split(".")[0]
    first = " (a CPU torch first: README, Quick start)" if top == "torch" else ""
    return f'needs {top}: pip install -e ".[{EXTRA_OF[top]}]"{first}'


def needs(module: str) -> ModuleType:
    """``pytest.importorskip(module)`` with the reason of :func:`reason` (reported at the caller's line)."""
    __tracebackhide__ = True
    return pytest.importorskip(module, reason=reason(module))
