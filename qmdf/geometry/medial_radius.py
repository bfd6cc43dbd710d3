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
    r_max: float = 1.0,
    tol: float | np.ndarray = 1e-4,
    iterations: int = 20,
) -> np.ndarray:
    """The medial radius behind each point (bisection to r_max / 2**iterations)."""
    lo = np.zeros(len(points))
    hi = np.full(len(points), float(r_max))
    tol = np.broadcast_to(np.asarray(tol, float), lo.shape)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        inside = distance(points - mid[:, None] * normals) >= mid - tol
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return lo
