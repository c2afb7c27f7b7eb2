"""The retired v3 entry point: importable, but building an env raises an error saying what changed in v4
(:data:`covert_env.retired.RETIRED`)."""

from __future__ import annotations

from covert_env.retired import RETIRED, retired_entry

__all__ = ["env", "parallel_env", "raw_env", "V3_RETIRED"]

V3_RETIRED = RETIRED["covert_sensing_v3"]
env = parallel_env = raw_env = retired_entry("covert_sensing_v3")
