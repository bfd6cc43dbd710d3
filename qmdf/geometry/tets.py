"""Plain functions on tetrahedral meshes."""

from __future__ import annotations

import numpy as np

from qmdf.geometry.rows import unique_rows


def signed_volumes(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b, c, d = (v[t[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def boundary_faces(t: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """Faces of exactly one tet, oriented outward (when v is given and tets are positively oriented)."""
    t = np.asarray(t, np.int64)
    if v is not None:
        neg = signed_volumes(v, t) < 0
        t = t.copy()
        t[neg] = t[neg][:, [0, 2, 1, 3]]
    # faces opposite each vertex, ordered so that a positive tet's faces point outward
    f = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
    key = np.sort(f, axis=1)
    _, inv, counts = unique_rows(key, return_inverse=True, return_counts=True)
    return f[counts[inv.ravel()] == 1]
