"""Where a result was measured: the platform and library versions that decide its last bits.

A model card records :func:`platform_record` when its scores are measured. A replay on a machine with the same
record (:func:`platform_key`) must give every number bit for bit; elsewhere, numpy's float64 transcendental
functions (``arctan2``, ``exp``, ``arccos``: SVML on CPUs with AVX-512, other code elsewhere) or another GEOS may
round differently, and the env and the planners are built so that such a difference does not change decisions
(docs/decisions/flight.md#settled-slot-end-poses), so a replay agrees within a stated tolerance.
"""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path

import numpy as np

__all__ = ["code_commit", "numpy_cpu_dispatch", "platform_key", "platform_record"]


def numpy_cpu_dispatch() -> list[str]:
    """The CPU targets numpy dispatches to on this machine (its dispatchable targets that the CPU has and
    ``NPY_DISABLE_CPU_FEATURES`` leaves on), e.g. ``["X86_V3", "X86_V4", "AVX512_ICL"]`` on an AVX-512 CPU."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:                                                    # numpy < 2
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    return [t for t in __cpu_dispatch__ if __cpu_features__.get(t)]


def platform_record() -> dict:
    """The machine and the library versions a score was measured with (JSON-ready)."""
    import scipy
    import shapely

    import covert_env

    return {"machine": platform.machine(), "system": platform.system(), "python": platform.python_version(),
            "numpy": np.__version__, "numpy_cpu_dispatch": numpy_cpu_dispatch(), "scipy": scipy.__version__,
            "shapely": shapely.__version__, "geos": shapely.geos_version_string, "covert_env": covert_env.__version__}


def platform_key(record: dict | None) -> tuple | None:
    """What two records must share for a replay to be bit for bit: everything but covert_env's version (the card's
    env id and commit say which code scored it). None for a card without a record."""
    if not isinstance(record, dict):
        return None
    return tuple(sorted((k, str(v)) for k, v in record.items() if k != "covert_env"))


def code_commit() -> str:
    """The commit of the code that measures, with ``-dirty`` when the tree has uncommitted changes (then the result
    cannot be reproduced from the commit alone); "unknown" outside a git checkout."""
    try:
        out = subprocess.run(["git", "describe", "--always", "--abbrev=40", "--dirty"], capture_output=True,
                             text=True, check=True, cwd=Path(__file__).resolve().parent)
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
