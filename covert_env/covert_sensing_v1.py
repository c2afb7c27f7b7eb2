"""The retired v1 entry point: importable, but building an env raises an error saying what changed in v2
(:data:`covert_env.retired.RETIRED`)."""

from __future__ import annotations

from covert_env.retired import RETIRED, retired_entry

__all__ = ["env", "parallel_env", "raw_env", "V1_RETIRED"]

V1_RETIRED = RETIRED["covert_sensing_v1"]
env = parallel_env = raw_env = retired_entry("covert_sensing_v1")
