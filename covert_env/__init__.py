"""covert_env: covert multi-UAV video sensing of a target on uneven terrain.

The model (terrain, shadows, feasible zone, line of sight, dynamics, cost, engine) implements
Almuzaini & Savkin, "Navigation of a Team of UAVs for Covert Video Sensing of a Target Moving on an
Uneven Terrain", Remote Sensing 16(22):4273, 2024.
"""

from covert_env.config import Config
from covert_env.road import Road, TargetTrack
from covert_env.terrain import Polytope, Terrain

__all__ = ["Config", "Polytope", "Road", "TargetTrack", "Terrain"]
__version__ = "0.1.0"
