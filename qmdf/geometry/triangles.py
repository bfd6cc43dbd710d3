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


def corner_normals(vertices: np.ndarray, faces: np.ndarray, crease_degrees: float = 30.0) -> np.ndarray:
    """(F, 3, 3) a smooth normal at each face's corners: the area-weighted mean of the unit normals of the faces
    around that corner's vertex that turn less than ``crease_degrees`` from this face (a sharp edge keeps its
    faces' own normals, as a renderer's smoothing groups do). Faces keep their own winding's side."""
    faces = np.asarray(faces, np.int64)
    cross = face_cross(vertices, faces)
    area2 = np.linalg.norm(cross, axis=1)
    unit = cross / np.maximum(area2, 1e-300)[:, None]
    corner_vertex = faces.ravel()  # corner k of face f is entry 3 f + k
    order = np.argsort(corner_vertex, kind="stable")
    counts = np.bincount(corner_vertex, minlength=len(vertices))
    starts = np.concatenate([[0], np.cumsum(counts)])
    # every (corner, face around its vertex) pair: sum over vertices of degree^2 pairs
    deg = counts[corner_vertex]
    pair_corner = np.repeat(np.arange(len(corner_vertex)), deg)
    offset = np.arange(len(pair_corner)) - np.repeat(np.cumsum(deg) - deg, deg)
    pair_face = order[starts[corner_vertex[pair_corner]] + offset] // 3
    own_face = pair_corner // 3
    keep = np.einsum("ij,ij->i", unit[own_face], unit[pair_face]) >= np.cos(np.radians(crease_degrees))
    summed = np.zeros((len(corner_vertex), 3))
    np.add.at(summed, pair_corner[keep], cross[pair_face[keep]])
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    out = np.where(length > 1e-300, summed / np.maximum(length, 1e-300), unit[np.arange(len(corner_vertex)) // 3])
    return out.reshape(len(faces), 3, 3)


def interpolated_normals(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, face: np.ndarray, crease_degrees: float = 30.0
) -> np.ndarray:
    """(N, 3) unit normals at points lying on the given faces, interpolated from ``corner_normals`` by the points'
    barycentric coordinates: the smooth surface's normal that the facets approximate."""
    tri = np.asarray(vertices)[np.asarray(faces)[face]]
    e0, e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], points - tri[:, 0]
    d00, d01, d11 = (e0 * e0).sum(1), (e0 * e1).sum(1), (e1 * e1).sum(1)
    d20, d21 = (e2 * e0).sum(1), (e2 * e1).sum(1)
    denom = np.maximum(d00 * d11 - d01 * d01, 1e-300)
    b1 = np.clip((d11 * d20 - d01 * d21) / denom, 0.0, 1.0)
    b2 = np.clip((d00 * d21 - d01 * d20) / denom, 0.0, 1.0)
    bary = np.stack([1.0 - b1 - b2, b1, b2], 1)
    n = (bary[:, :, None] * corner_normals(vertices, faces, crease_degrees)[face]).sum(1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def facet_tolerance(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The slack of a medial-ball test against a faceted mesh: 3e-4 plus 8% of the median edge. A ray along the
    smooth normal drifts from its own facet by t * angle^2 / 2, and a marching-cubes mesh's corner normals are a
    few degrees off (measured in ``qmdf.fields.supervision._mesh_ray_normals``)."""
    v, f = np.asarray(vertices), np.asarray(faces)
    edges = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)
    return float(3e-4 + 0.08 * np.median(edges))


def barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of points ``p`` (K, 3) in their triangles ``tri`` (K, 3, 3) (least squares: of
    the point's projection onto the triangle's plane; negative outside the triangle)."""
    e1, e2, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], p - tri[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
    det = np.maximum(d11 * d22 - d12 * d12, 1e-30)
    b1 = (d22 * w1 - d12 * w2) / det
    b2 = (d11 * w2 - d12 * w1) / det
    return np.column_stack([1 - b1 - b2, b1, b2])
