"""Pictures of what a run made, drawn with matplotlib (no display needed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _decimated(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray | None, max_faces: int):
    """At most ``max_faces`` faces for drawing; per-vertex values follow their nearest kept vertex."""
    if len(faces) <= max_faces:
        return vertices, faces, values
    import pymeshlab
    from scipy.spatial import cKDTree

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=max_faces, preservetopology=True)
    m = ms.current_mesh()
    v, f = m.vertex_matrix(), m.face_matrix()
    if values is not None:
        _, idx = cKDTree(vertices).query(v)
        values = values[idx]
    return v, f, values


def render_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray, values: np.ndarray | None = None,
                title: str = "", label: str = "", cmap: str = "viridis", max_faces: int = 30000,
                views: tuple[tuple[float, float], ...] = ((20, -60), (20, 120))) -> Path:
    """Shaded views of a triangle mesh, coloured by per-vertex ``values`` when given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v, f, val = _decimated(np.asarray(vertices, float), np.asarray(faces), values, max_faces)
    tri = v[f]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    shade = 0.45 + 0.55 * np.abs(normals @ np.array([0.3, -0.4, 0.85]) / np.linalg.norm([0.3, -0.4, 0.85]))
    if val is not None:
        fv = val[f].mean(1)
        norm = matplotlib.colors.Normalize(vmin=float(np.min(val)), vmax=float(np.percentile(val, 99)) or 1e-12)
        colors = plt.get_cmap(cmap)(norm(fv))
    else:
        colors = np.tile([0.75, 0.75, 0.78, 1.0], (len(f), 1))
    colors[:, :3] *= shade[:, None]
    fig = plt.figure(figsize=(5 * len(views) + (1 if val is not None else 0), 5))
    lo, hi = v.min(0), v.max(0)
    c, r = (lo + hi) / 2, float((hi - lo).max()) / 2
    for i, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolor="none"))
        ax.set_xlim(c[0] - r, c[0] + r), ax.set_ylim(c[1] - r, c[1] + r), ax.set_zlim(c[2] - r, c[2] + r)
        ax.view_init(elev, azim)
        ax.set_axis_off()
    if val is not None:
        sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=fig.axes, shrink=0.7, label=label)
    fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
