"""A point set with optional per-point normals (input normals, kept for evaluation; for feature points from
a mesh, the mean normal of the two faces that meet there)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PointSet:
    points: np.ndarray  # (N, 3) float64
    normals: np.ndarray | None = None  # (N, 3) or None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
        object.__setattr__(self, "points", pts)
        if self.normals is not None:
            nrm = np.asarray(self.normals, dtype=np.float64)
            if nrm.shape != pts.shape:
                raise ValueError(f"normals shape {nrm.shape} does not match points {pts.shape}")
            object.__setattr__(self, "normals", nrm)

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, index: np.ndarray) -> "PointSet":
        """The points selected by a boolean mask or an index array."""
        return PointSet(self.points[index], None if self.normals is None else self.normals[index])

    def with_points(self, points: np.ndarray) -> "PointSet":
        return PointSet(points, self.normals)

    @property
    def bbox_diagonal(self) -> float:
        if len(self.points) == 0:
            return 0.0
        return float(np.linalg.norm(self.points.max(0) - self.points.min(0)))
