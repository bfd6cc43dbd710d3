"""A MAT's structural defects: parts of it that contradict the shape it is the axis of.

A medial ball lies inside the shape and touches its surface, so its centre is inside and its radius is its
centre's distance to the surface; the sheet between the balls lies inside too. Scores of the envelope do not see
their violations (a chord of zero-radius balls across a torus's hole left CD at 7.8e-5: the coverage balls hid
it); these counts do:

- ``vertices_outside``: centres outside the shape by more than ``tolerance``;
- ``balls_protruding``: balls reaching out of the surface by more than ``tolerance`` (radius over the centre's
  distance to the surface);
- ``zero_radius_inside``: balls of no radius (under ``tolerance``) whose centre lies inside, farther than
  ``tolerance`` from the surface (a zero radius belongs on the surface: a sharp edge or corner);
- ``edges_outside`` / ``faces_outside``: edges whose midpoint, faces whose centroid lies outside by more than
  ``tolerance`` (a sheet or chord bridging a hole or a cavity)."""

from __future__ import annotations

from typing import Callable

import numpy as np

#: The default tolerance (unit box): half a percent of the box, above the fitted spheres' own error (about 1e-4)
#: and the meshed surfaces' facets, below any wall the benchmarks have (the teacup's is 0.05 thick).
TOLERANCE = 5e-3


def structural_defects(
    vertices: np.ndarray,
    radii: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    distance: Callable[[np.ndarray], np.ndarray],
    is_inside: Callable[[np.ndarray], np.ndarray],
    tolerance: float = TOLERANCE,
) -> dict:
    """The counts of the module doc, the vertices with any defect (``defective_vertices``), the MAT's own
    ``vertices``, ``edges`` and ``faces`` (what the counts are shares of) and ``tolerance``; ``distance(q)``:
    unsigned distance to the shape's surface, ``is_inside(q)``: a bool mask."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    r = np.asarray(radii, np.float64)
    e = np.asarray(edges, np.int64).reshape(-1, 2)
    f = np.asarray(faces, np.int64).reshape(-1, 3)

    def out(points: np.ndarray) -> np.ndarray:
        if not len(points):
            return np.zeros(0, bool)
        return ~np.asarray(is_inside(points), bool) & (np.asarray(distance(points)) > tolerance)

    d = np.asarray(distance(v)) if len(v) else np.zeros(0)
    inside = np.asarray(is_inside(v), bool) if len(v) else np.zeros(0, bool)
    outside = ~inside & (d > tolerance)
    protruding = r - d > tolerance
    zero_inside = (r < tolerance) & inside & (d > tolerance)
    edges_out = out(0.5 * (v[e[:, 0]] + v[e[:, 1]])) if len(e) else np.zeros(0, bool)
    faces_out = out(v[f].mean(axis=1)) if len(f) else np.zeros(0, bool)
    return {
        "vertices_outside": int(outside.sum()),
        "balls_protruding": int(protruding.sum()),
        "zero_radius_inside": int(zero_inside.sum()),
        "edges_outside": int(edges_out.sum()),
        "faces_outside": int(faces_out.sum()),
        "defective_vertices": int((outside | protruding | zero_inside).sum()),
        "vertices": len(v),
        "edges": len(e),
        "faces": len(f),
        "tolerance": float(tolerance),
    }
