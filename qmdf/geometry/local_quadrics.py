"""Local quadric height fields of an oriented cloud (jets of order 2; Cazals and Pouget 2005): per point, the
least-squares quadric over its nearest neighbours on its own side of the surface, in the frame of its normal.

Why a quadric, not a plane: a plane fit shrinks a curved surface (a noisy sphere's mean radius error -3.5e-3 after
two projections against the quadric's -1.8e-4), and a point placed on a plane beside a sample leaves the surface
by the curvature times the offset squared. Why its own side: on a wall thinner than the neighbourhood the far
side's points would pull the fit into the wall; a neighbour whose normal turns more than 73 degrees from the point's
is left out."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

#: below this share of a normal's direction a neighbour counts as the other side of the surface
_SAME_SIDE = 0.3


@dataclass(frozen=True)
class LocalQuadrics:
    """z = c0 + c1 x + c2 y + c3 x^2 + c4 xy + c5 y^2 over (x, y, z) in the frame (u, v, normal) at each point."""

    origins: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3) the frames' z axes, as the cloud's normals
    u: np.ndarray  # (N, 3)
    v: np.ndarray  # (N, 3)
    coef: np.ndarray  # (N, 6)
    residual: np.ndarray  # (N,) the fit's RMS height residual

    def at(self, x: float | np.ndarray, y: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points of each quadric above tangent offset (x, y), and the quadrics' unit normals there (oriented
        as the cloud's)."""
        c = self.coef
        x, y = np.broadcast_to(x, len(c))[:, None], np.broadcast_to(y, len(c))[:, None]
        z = c[:, :1] + c[:, 1:2] * x + c[:, 2:3] * y + c[:, 3:4] * x * x + c[:, 4:5] * x * y + c[:, 5:6] * y * y
        dzdx = c[:, 1:2] + 2 * c[:, 3:4] * x + c[:, 4:5] * y
        dzdy = c[:, 2:3] + c[:, 4:5] * x + 2 * c[:, 5:6] * y
        points = self.origins + x * self.u + y * self.v + z * self.normals
        tilted = self.normals - dzdx * self.u - dzdy * self.v
        return points, tilted / np.linalg.norm(tilted, axis=1, keepdims=True)


def fit_local_quadrics(points: np.ndarray, normals: np.ndarray, k: int) -> LocalQuadrics:
    """The quadric of each point over its ``k`` nearest same-side neighbours (itself included)."""
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
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
    return LocalQuadrics(points, n, u, v, coef, np.sqrt((residual**2).sum(1) / dof))
