"""A noisy cloud's points moved onto their local surface: jet smoothing (Cazals and Pouget 2005; CGAL's
``jet_smooth_point_set``), each point projected onto the quadric height field fitted to its neighbours on its own
side of the surface, and the noise measured the same way.

Why: the Poisson surface of a noisy cloud follows the noise (its octree averages a point or two per cell), and
everything fitted to that surface inherits it: the medial radii scatter with the noise across a wall of even
thickness. A quadric fit over k neighbours averages the noise down by about sqrt(k) and, unlike a plane fit, keeps
the surface's curvature, so a clean surface's points barely move. Neighbours facing the other way (the far side of
a wall thinner than the neighbourhood) are left out of each fit by their oriented normals.

The noise test: on a clean cloud the quadric's residual is the surface's third-order terms over the sampling gap
(clean and sparse clouds of six bench shapes: at most 4.5% of the gap with 16 neighbours; the sparse block file
13.5%, SRB scans 6% to 13%); with noise it is the noise itself (0.5% of the box diagonal: 29% to 42% of the gap),
so the ratio decides."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: below this share of a normal's direction a neighbour counts as the other side of the surface
_SAME_SIDE = 0.3


def _local_quadrics(points: np.ndarray, normals: np.ndarray, k: int) -> tuple[np.ndarray, ...]:
    """Per point, the least-squares quadric z = c0 + c1 x + c2 y + c3 x^2 + c4 xy + c5 y^2 over its k nearest
    same-side neighbours in the frame of its normal: (coefficients (N, 6), tangent u, tangent v, residual RMS)."""
    k = int(min(k, len(points)))
    _, idx = cKDTree(points).query(points, k=k, workers=-1)
    n = normals
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(n, u)
    rel = points[idx] - points[:, None]
    x, y, z = (np.einsum("nkj,nj->nk", rel, axis) for axis in (u, v, n))
    w = (np.einsum("nkj,nj->nk", normals[idx], n) > _SAME_SIDE).astype(np.float64)
    design = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], -1) * w[..., None]
    rhs = z * w
    # a tiny ridge keeps a fit with fewer than 6 same-side neighbours (a thin spike) solvable: it stays put
    gram = np.einsum("nki,nkj->nij", design, design) + 1e-12 * np.eye(6)
    coef = np.linalg.solve(gram, np.einsum("nki,nk->ni", design, rhs)[..., None])[..., 0]
    residual = np.einsum("nki,ni->nk", design, coef) - rhs
    dof = np.maximum(w.sum(1) - 6.0, 1.0)
    return coef, u, v, np.sqrt((residual**2).sum(1) / dof)


def noise_to_gap(points: np.ndarray, normals: np.ndarray, gap: float, k: int = 16) -> float:
    """The median residual of the points' local quadric fits over ``k`` same-side neighbours, in sampling gaps."""
    return float(np.median(_local_quadrics(points, normals, k)[3]) / max(gap, 1e-12))


def jet_smooth(points: np.ndarray, normals: np.ndarray, k: int = 48, passes: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The points projected onto their local quadrics, ``passes`` times, and the quadrics' unit normals, oriented as
    ``normals``."""
    p, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    for _ in range(passes):
        coef, u, v, _ = _local_quadrics(p, n, k)
        p = p + coef[:, :1] * n
        tilted = n - coef[:, 1:2] * u - coef[:, 2:3] * v  # the height field's normal at its foot
        n = tilted / np.linalg.norm(tilted, axis=1, keepdims=True)
    return p, n
