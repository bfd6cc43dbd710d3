"""Uniform, area-weighted samples on a triangle mesh."""

from __future__ import annotations

import numpy as np

from qmdf.geometry.pointset import PointSet
from qmdf.geometry.triangles import face_cross


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator) -> PointSet:
    """Uniform (area-weighted) samples on a triangle mesh, with the face normals at the samples."""
    tri = vertices[faces]
    cross = face_cross(vertices, faces)
    area2 = np.linalg.norm(cross, axis=1)
    face = rng.choice(len(faces), size=count, p=area2 / area2.sum())
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    t = tri[face]
    pts = t[:, 0] + r1[:, None] * (t[:, 1] - t[:, 0]) + r2[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[face] / np.maximum(area2[face], 1e-300)[:, None]
    return PointSet(pts, normals)
