"""A mesh brought onto a point cloud sampled from the same shape in another frame (rotated, scaled, moved): the
reference a benchmark scores that cloud's field against. The 2,000-point bunny of the data is such a cloud: its
axes are bunny.off's permuted and its size 13x.

Principal axes give the start (each of the four proper sign choices of the axes is tried, since an axis's sign
is arbitrary), trimesh's ICP with scale the rest; the start with the lowest ICP cost wins."""

from __future__ import annotations

import numpy as np


def register_mesh_to_points(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, iterations: int = 100
) -> tuple[np.ndarray, float]:
    """The mesh's vertices moved by the similarity that best lays the mesh's surface on ``points``, and the median
    distance from the points to the moved surface (what the two disagree by: the floor of any score against it)."""
    import trimesh

    from qmdf.geometry.inside import mesh_distance

    v, p = np.asarray(vertices, np.float64), np.asarray(points, np.float64)
    # the moments of the mesh's surface, not of its vertices: vertices crowd where the mesh is fine, points don't
    surface = trimesh.sample.sample_surface_even(trimesh.Trimesh(v, faces, process=False), len(p), seed=0)[0]
    cv, cp = surface.mean(0), p.mean(0)
    scale = np.sqrt(((p - cp) ** 2).sum(1).mean() / ((surface - cv) ** 2).sum(1).mean())
    av, ap = _principal_axes(surface - cv), _principal_axes(p - cp)
    best = None
    for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        rotation = ap @ np.diag(signs) @ av.T  # mesh axes onto cloud axes
        start = (v - cv) @ rotation.T * scale + cp
        mesh = trimesh.Trimesh(start, faces, process=False)
        # icp moves the points onto the mesh: its inverse moves the mesh onto the points
        matrix, _, cost = trimesh.registration.icp(p, mesh, threshold=1e-9, max_iterations=iterations, scale=True)
        if best is None or cost < best[0]:
            best = (cost, trimesh.transform_points(start, np.linalg.inv(matrix)))
    moved = best[1]
    residual = float(np.median(mesh_distance(moved, np.asarray(faces, np.int64), p)[0]))
    return moved, residual


def _principal_axes(centred: np.ndarray) -> np.ndarray:
    """Columns: the principal axes, largest variance first, as a proper rotation."""
    _, vecs = np.linalg.eigh(centred.T @ centred)
    axes = vecs[:, ::-1]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes
