"""The classic Voronoi-pole medial axis (Amenta, Choi and Kolluri 2001: the power crust's inner poles), the
baseline qmdf is timed against (``bench speed``).

The Voronoi vertices of a dense sample of a smooth surface converge to its medial axis, and each sample's *inner
pole*, the vertex of its Voronoi cell farthest from it on the inner side, lies on the medial ball through it: the
Delaunay tetrahedron dual to that vertex has an empty circumsphere through the sample. So the inner pole is the
circumcentre, among the Delaunay tetrahedra incident to the sample, reaching deepest along its inward normal, and
its distance to the sample is the pole ball's radius. qhull (scipy.spatial.Delaunay) does the Delaunay."""

from __future__ import annotations

import numpy as np


def circumspheres(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres and radii of the circumspheres of tetrahedra ``tets`` (T, 4, 3); a flat one gets an infinite
    radius (its centre at infinity)."""
    a = tets[:, 0]
    e = tets[:, 1:] - a[:, None, :]  # (T, 3, 3): rows b - a, c - a, d - a
    rhs = 0.5 * np.einsum("tij,tij->ti", e, e)
    det = np.linalg.det(e)
    flat = np.abs(det) < 1e-15 * np.maximum(np.einsum("tij,tij->t", e, e), 1e-300) ** 1.5
    e[flat] = np.eye(3)  # solved and discarded below
    centre = a + np.linalg.solve(e, rhs[..., None])[..., 0]
    radius = np.linalg.norm(centre - a, axis=1)
    radius[flat] = np.inf
    return centre, radius


def inner_poles(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's inner pole and its radius: of the circumcentres of the Delaunay tetrahedra incident to the
    sample (its Voronoi cell's vertices), the farthest one behind it, against its outward ``normals``. A sample
    with none behind it keeps its own position, radius 0. On a faceted mesh's samples the poles find the facets'
    own medial sheets too (one at every convex edge), as the exact axis of that mesh has them."""
    from scipy.spatial import Delaunay

    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    simplices = Delaunay(p).simplices
    centre, radius = circumspheres(p[simplices])
    corner = simplices.ravel()
    tet = np.repeat(np.arange(len(simplices)), 4)
    ok = np.isfinite(radius)[tet]
    corner, tet = corner[ok], tet[ok]
    behind = np.einsum("ij,ij->i", centre[tet] - p[corner], n[corner]) < 0
    order = np.lexsort((np.where(behind, radius[tet], -1.0), corner))  # by sample, the farthest behind last
    last = np.flatnonzero(np.r_[corner[order][1:] != corner[order][:-1], True])
    best_tet, owner = tet[order][last], corner[order][last]
    poles, radii = p.copy(), np.zeros(len(p))
    deep = behind[order][last]
    poles[owner[deep]] = centre[best_tet[deep]]
    radii[owner[deep]] = radius[best_tet[deep]]
    return poles, radii
