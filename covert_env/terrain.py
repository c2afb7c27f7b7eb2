"""Terrain: M convex polytopes C_m (buildings, hills) standing on flat ground z = 0 (paper §2.1, Fig. 2).

Each polytope is the convex hull of a base polygon Q_m at z = 0 (convex, counter-clockwise) and a top
polygon D_m with the same number of vertices, each with its own height z > 0 (a top may be slanted).
Geometry code uses the half-space form ``n . x + d <= 0`` of every polytope, padded into arrays so
that line-of-sight tests vectorise over polytopes and faces.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial import ConvexHull
from shapely.geometry import Polygon

__all__ = ["Polytope", "Terrain"]


@dataclass(frozen=True, eq=False)
class Polytope:
    """One convex polytope C_m: the convex hull of ``base`` (z = 0) and ``top``.

    Attributes:
        base: (n, 2) float array, the footprint Q_m, counter-clockwise, not closed.
        top: (n, 3) float array, the top D_m's vertices (x, y, z), same count and order as ``base``.
    """

    base: np.ndarray
    top: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "base", np.asarray(self.base, dtype=float).reshape(-1, 2))
        object.__setattr__(self, "top", np.asarray(self.top, dtype=float).reshape(-1, 3))
        self.base.setflags(write=False)
        self.top.setflags(write=False)

    @property
    def n_vertices(self) -> int:
        return len(self.base)

    @cached_property
    def vertices(self) -> np.ndarray:
        """(2n, 3) array: base vertices at z = 0 followed by the top vertices (the paper's C_m set)."""
        return np.vstack([np.column_stack([self.base, np.zeros(len(self.base))]), self.top])

    @cached_property
    def halfspaces(self) -> np.ndarray:
        """(F, 4) array of faces ``[nx, ny, nz, d]`` with unit normals; the polytope is ``n.x + d <= 0``.

        Coplanar hull triangles are merged, so F is the number of planar faces.
        """
        hull = ConvexHull(self.vertices)
        eq = hull.equations
        # Merge coplanar triangles: round the plane equation (unit normal, offset in metres).
        key = np.round(eq, 9)
        _, idx = np.unique(key, axis=0, return_index=True)
        return eq[np.sort(idx)]

    @property
    def z_max(self) -> float:
        """Height of the highest point (the point the eq. 3 safety distance is measured to)."""
        return float(self.top[:, 2].max())

    @property
    def highest_point(self) -> np.ndarray:
        """(3,) the highest top vertex (first one on ties)."""
        return self.top[int(np.argmax(self.top[:, 2]))].copy()

    @cached_property
    def footprint(self) -> Polygon:
        """The base Q_m as a shapely polygon (plan view of the whole polytope)."""
        return Polygon(self.base)

    @cached_property
    def centroid_xy(self) -> np.ndarray:
        return np.asarray(self.footprint.centroid.coords[0])

    @cached_property
    def radius_xy(self) -> float:
        """Radius of a circle about ``centroid_xy`` enclosing the footprint."""
        return float(np.linalg.norm(self.base - self.centroid_xy, axis=1).max())


@dataclass(frozen=True, eq=False)
class Terrain:
    """A set of non-overlapping convex polytopes on flat ground.

    Attributes:
        polytopes: the polytopes C_1..C_M.
    """

    polytopes: tuple[Polytope, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        object.__setattr__(self, "polytopes", tuple(self.polytopes))

    def __len__(self) -> int:
        return len(self.polytopes)

    def __iter__(self):
        return iter(self.polytopes)

    def __getitem__(self, i: int) -> Polytope:
        return self.polytopes[i]

    # ------------------------------------------------------------------ padded arrays
    @cached_property
    def halfspace_array(self) -> np.ndarray:
        """(M, F_max, 4) faces of every polytope, padded with the always-true row ``0.x - 1 <= 0``."""
        m = len(self.polytopes)
        f = max((len(p.halfspaces) for p in self.polytopes), default=1)
        out = np.zeros((m, f, 4))
        out[:, :, 3] = -1.0
        for i, p in enumerate(self.polytopes):
            out[i, : len(p.halfspaces)] = p.halfspaces
        out.setflags(write=False)
        return out

    @cached_property
    def centroids_xy(self) -> np.ndarray:
        """(M, 2) footprint centroids."""
        return np.array([p.centroid_xy for p in self.polytopes]).reshape(-1, 2)

    @cached_property
    def radii_xy(self) -> np.ndarray:
        """(M,) radii of circles about the centroids enclosing each footprint."""
        return np.array([p.radius_xy for p in self.polytopes])

    @cached_property
    def z_max(self) -> np.ndarray:
        """(M,) height of each polytope's highest point."""
        return np.array([p.z_max for p in self.polytopes])

    @cached_property
    def highest_points(self) -> np.ndarray:
        """(M, 3) each polytope's highest point (eq. 3 measures the safety distance to it)."""
        return np.array([p.highest_point for p in self.polytopes]).reshape(-1, 3)
