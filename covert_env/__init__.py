"""covert_env: covert multi-UAV video sensing of a target on uneven terrain.

The model (terrain, shadows, feasible zone, line of sight, dynamics, cost, engine) implements
Almuzaini & Savkin, "Navigation of a Team of UAVs for Covert Video Sensing of a Target Moving on an
Uneven Terrain", Remote Sensing 16(22):4273, 2024. The environments are thin adapters over it:

    import covert_env
    penv = covert_env.parallel_env(n_uavs=3)                     # PettingZoo ParallelEnv
    venv = covert_env.vector_env(num_envs=256, n_uavs=3)         # 256 copies, batch-first arrays
    aec = covert_env.env(n_uavs=3)                               # PettingZoo AEC
    import gymnasium as gym
    genv = gym.make("covert_env/CovertSensing-v4")               # Gymnasium, one UAV
"""

import os as _os

# The compiled kernels' sines and cosines must be the C library's, as numpy's float64 ones are (the env's numbers
# bit for bit: tests/test_batch_flight.py); Intel's SVML, which numba uses where installed, rounds differently.
# Effective when numba is first imported here; covert_env.geometry.flight warns otherwise.
_os.environ.setdefault("NUMBA_DISABLE_INTEL_SVML", "1")

from covert_env.moved import MOVED as _MOVED  # noqa: E402
from covert_env.moved import MovedModules as _MovedModules  # noqa: E402
from covert_env.world.config import Config  # noqa: E402
from covert_env.world.engine import Engine  # noqa: E402
from covert_env.world.road import Road, TargetTrack  # noqa: E402
from covert_env.world.scenario import Scenario  # noqa: E402
from covert_env.world.terrain import Polytope, Terrain  # noqa: E402
from covert_env.world.trajectory import Trajectory  # noqa: E402

__version__ = "0.10.0"

# Environments are imported after the model: the model modules never import them.
from covert_env import covert_sensing_v4  # noqa: E402
from covert_env.envs import env, parallel_env, raw_env, vector_env  # noqa: E402
from covert_env.retired import RETIRED as _RETIRED  # noqa: E402

_MovedModules.install(_MOVED)                                           # the old module paths (covert_env.moved)


def __getattr__(name: str):
    """The retired entry points (``covert_env.covert_sensing_v0`` .. ``_v3``, :mod:`covert_env.retired`), imported
    when first read."""
    if name in _RETIRED:
        import importlib

        return importlib.import_module(f"covert_env.{name}")
    raise AttributeError(f"module 'covert_env' has no attribute {name!r}")

__all__ = ["Config", "Engine", "Polytope", "Road", "Scenario", "TargetTrack", "Terrain", "Trajectory",
           "covert_sensing_v0", "covert_sensing_v1", "covert_sensing_v2", "covert_sensing_v3", "covert_sensing_v4",
           "env", "parallel_env", "raw_env", "vector_env"]


def _register() -> None:
    """Register the Gymnasium ids (Gymnasium 1.x has no plugin entry point) and PettingZoo ids.

    v4 is the env; the v1, v2 and v3 ids are registered to raise what changed (:data:`covert_env.retired.RETIRED`),
    and v0 is not registered:
    ``gym.make("covert_env/CovertSensing-v0")`` raises Gymnasium's own ``DeprecatedEnv`` ("... is deprecated. Please
    use `covert_env/CovertSensing-v4` instead.")."""
    import gymnasium

    ids = {"v4": ("covert_env.envs.single:CovertSensingEnv", "covert_env.envs.single:CovertSensingWaypointEnv")}
    for version in ("v3", "v2", "v1"):
        ids[version] = (f"covert_env.covert_sensing_{version}:parallel_env",) * 2
    for version, (unicycle, waypoint) in ids.items():
        for env_id, entry in ((f"covert_env/CovertSensing-{version}", unicycle),
                              (f"covert_env/CovertSensingWaypoint-{version}", waypoint)):
            if env_id not in gymnasium.registry:
                gymnasium.register(id=env_id, entry_point=entry)
    try:
        from pettingzoo import aec_registry, parallel_registry, register
    except ImportError:  # older PettingZoo without a registry
        return
    for version, module in (("v4", "covert_env.envs.covert_sensing"), ("v3", "covert_env.covert_sensing_v3"),
                            ("v2", "covert_env.covert_sensing_v2"), ("v1", "covert_env.covert_sensing_v1")):
        if f"covert_env/CovertSensing-{version}" not in parallel_registry:
            register("parallel", f"covert_env/CovertSensing-{version}", f"{module}:parallel_env")
        if f"covert_env/CovertSensing-{version}" not in aec_registry:
            register("aec", f"covert_env/CovertSensing-{version}", f"{module}:env")


_register()
