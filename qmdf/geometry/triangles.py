"""Per-face quantities of a triangle mesh, written once."""

from __future__ import annotations

import numpy as np


def face_cross(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) cross product of each face's two edges from its first corner: the normal times twice the area."""
    tri = np.asarray(vertices)[np.asarray(faces)]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) area of each face."""
    return 0.5 * np.linalg.norm(face_cross(vertices, faces), axis=1)
