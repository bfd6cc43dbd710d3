"""Distance to an evenly meshed surface, answered near its vertices.

An AABB tree's worst case is a query equally near every face: the centre of a sphere, the axis of a tube, where
medial balls are measured and centred. On a 3,000-point sphere's Poisson surface (16k vertices) each such query
visited all 32k faces, and the sheet and export stages ran for minutes. On a surface whose edges are all about
as long (marching cubes, a Poisson solve), the closest point lies on a face around one of the query's nearest
vertices: a KD-tree finds those (its worst case is a tight loop over points), and the exact closest point is
taken over their faces. 3,000 queries at that sphere's centre: 0.32 s against the AABB tree's 10.2 s; 45k
queries anywhere in the box: 0.99 s against 8.9 s (2 cores)."""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

#: The over-estimate a query deep inside may take for a coarser level's speed (unit box): a third of the ball
#: tests' facet tolerance on a depth-8 Poisson surface (3e-4 + 8% of its 4e-3 edges).
LEVEL_TOLERANCE = 2e-4


#: Nearest vertices whose faces are searched: the closest point's face has one of them as a corner.
NEAREST_VERTICES = 3


class EvenlyMeshedSurface(tuple):
    """``(vertices, faces)`` of a surface whose edges are all about as long (a Poisson surface), so that
    ``qmdf.medial.radii.data_distance`` answers distances to it near its vertices; unpacks like the plain pair.
    Its index is built once (the sheet stage asks for distances to it from each of its steps)."""

    @cached_property
    def index(self) -> "EvenSurfaceIndex":
        return EvenSurfaceIndex(*self)


@njit(cache=True, nogil=True)
def _closest_on_triangle(p, a, b, c):
    """The point of triangle abc closest to p (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0.0 and d2 <= 0.0:
        return a
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0.0 and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return a + (d1 / (d1 - d3)) * ab
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0.0 and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return a + (d2 / (d2 - d6)) * ac
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b)
    denom = 1.0 / (va + vb + vc)
    return a + ab * (vb * denom) + ac * (vc * denom)


@njit(parallel=True, cache=True, nogil=True)
def _closest_over_rings(queries, near, ring_start, ring_faces, vertices, faces):
    n = len(queries)
    dist = np.empty(n)
    closest = np.empty((n, 3))
    for i in prange(n):
        p = queries[i]
        best = np.inf
        closest[i] = p  # stays, at distance inf, where no face meets the nearest vertices
        for j in range(near.shape[1]):
            v = near[i, j]
            for k in range(ring_start[v], ring_start[v + 1]):
                f = faces[ring_faces[k]]
                x = _closest_on_triangle(p, vertices[f[0]], vertices[f[1]], vertices[f[2]])
                d = np.sum((x - p) ** 2)
                if d < best:
                    best = d
                    closest[i] = x
        dist[i] = np.sqrt(best)
    return dist, closest


def even_mesh_distance_function(vertices: np.ndarray, faces: np.ndarray, tolerance: float = LEVEL_TOLERANCE):
    """``distance(q) -> (d, closest point)`` to the mesh over the faces of the query's ``NEAREST_VERTICES`` nearest
    vertices: exact by the surface; by an axis, where every face around is about as near, at most the facets'
    depth below the smooth surface over (edge^2 / (8 radius of curvature): 2e-4 on a 64-cell torus's tube, under
    the facet tolerance of the ball tests); never under the true distance.

    A query deep inside (a sphere's centre, a tube's axis) is equally near every vertex around it, a KD-tree's
    worst case: it visits them all (a 59k-vertex sphere: 3.6 ms a query). Such a query is answered on a coarser
    level instead (``_levels``): the nearest vertices of an even subsample covering the surface within ``cover``,
    and the faces of the fine vertices each of them stands for. Where the closest point lies among those faces the
    answer is exact; else the nearest coarse vertex over-estimates the distance d by at most about
    cover^2 / (2 d) (the surface around the closest point curves toward the query, or it would not be equally near
    so much of it). A query takes the coarsest level where that bound, with d's lower bound from the coarsest
    level, is within ``tolerance``: the farther from the surface, the fewer vertices it visits."""
    return EvenSurfaceIndex(vertices, faces, tolerance).closest


class EvenSurfaceIndex:
    """The levels of an evenly meshed surface (see ``even_mesh_distance_function``) and its two queries."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, tolerance: float = LEVEL_TOLERANCE):
        self.vertices = np.ascontiguousarray(vertices, np.float64)
        self.faces = np.ascontiguousarray(faces, np.int64)
        self.levels = _levels(self.vertices, self.faces)
        self.tolerance = float(tolerance)

    def _by_level(self, q: np.ndarray) -> list[tuple[np.ndarray, "_Level"]]:
        """The queries grouped by the coarsest level whose over-estimate bound is within the tolerance."""
        top = self.levels[-1]
        depth = np.maximum(top.tree.query(q, workers=-1)[0] - top.cover, 0.0)  # a lower bound of d
        level = np.zeros(len(q), np.int64)
        for i, lv in enumerate(self.levels[1:], 1):
            level[lv.cover**2 <= 2.0 * self.tolerance * depth] = i  # covers grow with the level
        return [(np.flatnonzero(level == i), self.levels[i]) for i in np.unique(level)]

    def closest(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, closest point) over the faces around the nearest vertices of the query's level."""
        q = np.ascontiguousarray(queries, np.float64).reshape(-1, 3)
        dist, closest = np.full(len(q), np.inf), q.copy()
        for at, lv in self._by_level(q) if len(q) else []:
            k = min(NEAREST_VERTICES, lv.tree.n)
            near = np.asarray(lv.tree.query(q[at], k=k, workers=-1)[1], np.int64).reshape(len(at), k)
            dist[at], closest[at] = _closest_over_rings(
                q[at], near, lv.ring_start, lv.ring_faces, self.vertices, self.faces
            )
        return dist, closest

    def nearest_vertex(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, position) of the nearest vertex of the query's level: the vertices' own distance (a ball
        test along a sample's normal that the facets between them would stop short: ``fields.supervision``)."""
        q = np.ascontiguousarray(queries, np.float64).reshape(-1, 3)
        dist, at_vertex = np.full(len(q), np.inf), q.copy()
        for at, lv in self._by_level(q) if len(q) else []:
            dist[at], i = lv.tree.query(q[at], workers=-1)
            at_vertex[at] = lv.tree.data[i]
        return dist, at_vertex


class _Level(NamedTuple):
    tree: cKDTree  # the level's vertices
    ring_start: np.ndarray  # (n + 1,) CSR over ring_faces: the faces a level vertex stands for
    ring_faces: np.ndarray
    cover: float  # every fine vertex lies within this of a level vertex


def _levels(vertices: np.ndarray, faces: np.ndarray, ratio: int = 4, smallest: int = 256) -> list[_Level]:
    """Level 0: every vertex and its ring of faces; then even subsamples, each about ``ratio`` times smaller (one
    vertex per grid cell), each vertex standing for the fine vertices nearest to it and their faces."""
    corner_of = faces.ravel()
    fine_faces = np.repeat(np.arange(len(faces), dtype=np.int64), 3)
    ring_start, ring_faces = _csr(corner_of, fine_faces, len(vertices))
    levels = [_Level(cKDTree(vertices), ring_start, ring_faces, 0.0)]
    edge = float(np.median(np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1))) if len(faces) else 0
    cell = edge * np.sqrt(ratio)
    while edge > 0 and len(levels[-1].tree.data) > smallest * ratio:
        # the vertex nearest its cell's centre: the cover stays near half the cell's diagonal
        cells = (vertices - vertices.min(0)) / cell
        keys = np.floor(cells).astype(np.int64)
        off = np.linalg.norm(cells - keys - 0.5, axis=1)
        span = keys.max(0) + 1
        cell_id = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
        order = np.lexsort((off, cell_id))
        _, first = np.unique(cell_id[order], return_index=True)
        keep = order[first]
        if len(keep) >= len(levels[-1].tree.data):
            break
        tree = cKDTree(vertices[keep])
        gap, owner = tree.query(vertices, workers=-1)
        ring_start, ring_faces = _csr(owner[corner_of], fine_faces, len(keep))
        levels.append(_Level(tree, ring_start, ring_faces, float(gap.max())))
        cell *= np.sqrt(ratio)
    return levels


def _csr(owner: np.ndarray, items: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Items grouped by owner (0..n-1), without repeats within a group (one sort of a combined key: numpy's
    row-wise unique is ten times slower)."""
    width = int(items.max()) + 1 if len(items) else 1
    key = np.unique(owner.astype(np.int64) * width + items)
    start = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(key // width, minlength=n), out=start[1:])
    return start, np.ascontiguousarray(key % width)


def surface_distance_function(mesh):
    """``distance(q) -> (d, closest point)`` to a ``(vertices, faces)`` pair: near the vertices of an
    ``EvenlyMeshedSurface``, else by the AABB tree (any mesh: a CAD model's long faces have far vertices)."""
    from qmdf.geometry.inside import mesh_distance_function

    if isinstance(mesh, EvenlyMeshedSurface):
        return mesh.index.closest
    return mesh_distance_function(*mesh)
