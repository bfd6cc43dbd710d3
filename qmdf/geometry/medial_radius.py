"""The radius of the medial ball behind each surface point: the largest ball inside the shape that touches the
surface at p, centred at p - r n (n the outward normal). Along that ray the distance to the surface equals the
depth t exactly up to r and falls below it after, so r is found by bisection on the test
``distance(p - t n) >= t - tol``, with any distance function (to a mesh, to the input points). ``tol`` absorbs
sampling and noise: past the axis the test fails once t exceeds r by tol / 2 (a slab), and a neighbour lying
``e`` inward of p's tangent plane passes it while e < tol."""

from __future__ import annotations

from typing import Callable

import numpy as np


def inward_medial_radii(
    points: np.ndarray,
    normals: np.ndarray,
    distance: Callable[[np.ndarray], np.ndarray],
    r_max: float | np.ndarray = 1.0,
    tol: float | np.ndarray = 1e-4,
    iterations: int = 20,
    start: np.ndarray | None = None,
) -> np.ndarray:
    """The medial radius behind each point (bisection of [start, r_max] to its width / 2**iterations); ``start``
    (default 0) is a depth known to pass the test, such as a point's own distance to the surface."""
    lo = np.zeros(len(points)) if start is None else np.array(start, np.float64)
    hi = np.broadcast_to(np.asarray(r_max, np.float64), (len(points),)).copy()
    tol = np.broadcast_to(np.asarray(tol, float), lo.shape)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        inside = distance(points - mid[:, None] * normals) >= mid - tol
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return lo


def shrinking_ball_radii(
    points: np.ndarray,
    normals: np.ndarray,
    closest: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    r_max: float = 1.0,
    tol: float | np.ndarray = 1e-4,
    steps: int = 24,
) -> np.ndarray:
    """The same radius as ``inward_medial_radii`` (the largest ball tangent at p passing the test), by the
    shrinking ball (Ma, Bae, Choi and Park, 2012): the ball at depth r holds a surface point x closer to its centre
    than r - tol, so no ball deeper than the one tangent at p whose centre lies r' - tol from x passes either,
    r' = (|p - x|^2 - tol^2) / (2 ((p - x) . n - tol)); shrink to it and test again. Each step is one
    closest-point query (``closest(q) -> (d, x)``), and most rays stop after a few: bisection needs one per halving
    (14 to 16) and each costs the most by the axis, where the surface is equally near all around. Rays still
    shrinking after ``steps`` are bisected below their last radius."""
    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    tol = np.broadcast_to(np.asarray(tol, float), (len(p),))
    r = np.full(len(p), float(r_max))
    active, stuck = np.arange(len(p)), []
    for _ in range(steps):
        if not len(active):
            break
        d, x = closest(p[active] - r[active, None] * n[active])
        held = d < r[active] - tol[active]
        active, x = active[held], x[held]
        diff, t = p[active] - x, tol[active]
        behind = np.einsum("ij,ij->i", diff, n[active]) - t
        # the ball whose centre lies exactly r - tol from x, as the test reads (x was found at that distance, to
        # rounding, where it is no smaller: the ball passes); x not behind p's tangent plane by tol (a surface
        # folded over p) leaves the ray to bisection
        shrunk = (np.einsum("ij,ij->i", diff, diff) - t * t) / np.maximum(2.0 * behind, 1e-300)
        smaller = shrunk < r[active] * (1.0 - 1e-9)
        stuck.append(active[behind <= 0])
        active = active[(behind > 0) & smaller]
        r[active] = shrunk[(behind > 0) & smaller]
    rest = np.concatenate([active, *stuck])
    if len(rest):
        r[rest] = inward_medial_radii(p[rest], n[rest], lambda q: closest(q)[0], r[rest], tol[rest], 14)
    return r


def mesh_outward_normals(
    points: np.ndarray, normals: np.ndarray | None, vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, int]:
    """The samples' normals (their faces'; PCA's when None) turned where the mesh's winding number is higher ahead
    of them than behind, and how many were turned."""
    from qmdf.geometry.inside import mesh_winding_number
    from qmdf.geometry.normals import pca_normals

    if normals is None:
        normals, _ = pca_normals(points)
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    step = 1e-3
    w = mesh_winding_number(vertices, faces, np.concatenate([points + step * n, points - step * n]))
    inward = w[: len(points)] > w[len(points) :]
    return np.where(inward[:, None], -n, n), int(inward.sum())


def mesh_ray_normals(
    points: np.ndarray, normals: np.ndarray, vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, float]:
    """The directions of the medial rays from mesh samples (outward ``normals``), and the tolerance of the ball
    test.

    A faceted mesh's exact medial axis has a sheet for every convex edge, so a ray along a face normal meets one a
    short way in (the 128-resolution torus: radii a median 0.055 short of its 0.15 tube; the 3,485-vertex bunny:
    median 0.038, the same rays with a looser test 0.07). The rays follow the smooth surface the facets
    approximate instead: normals interpolated from the corners (``corner_normals``; sharp edges keep their
    faces'), turned to the side of ``normals``. The ray's own facet then drifts from the ball by
    t * angle^2 / 2, and a marching-cubes mesh's corner normals are a few degrees off: the tolerance absorbs
    both, 3e-4 plus 8% of the median edge (the teacup 9e-4: 0.01% of its rays short of their 16 neighbours'
    median by 30%, 0.75% at 3e-4, 3.3% along face normals; the torus 1.8e-3, radii within 3e-4 of its tube;
    the bunny and kitten 2.7e-3). Past the axis the test over-shoots by at most tol / 2."""
    from qmdf.geometry.inside import mesh_closest
    from qmdf.geometry.triangles import facet_tolerance, interpolated_normals

    _, face, _ = mesh_closest(vertices, faces, points)
    smooth = interpolated_normals(vertices, faces, points, face)
    smooth = np.where((np.einsum("ij,ij->i", smooth, normals) < 0)[:, None], -smooth, smooth)
    return smooth, facet_tolerance(vertices, faces)
