"""Inside, outside and distance to the input: the generalized winding number of a triangle mesh (Jacobson et al.
2013) or of an oriented point cloud (Barill et al. 2018), and unsigned distances to either.

libigl's fast winding number and AABB distance do the work (measured on 2 cores, 300k queries in the unit box:
the 7k-face bunny's winding number 0.23 s and distance 0.7 s; against 20k oriented points 1.8 s, agreeing with the
mesh's sign on 99.96% of the queries). The winding number stays right where a sign test by normals or rays fails:
holes, open boundaries, self-intersections, inconsistent winding.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


class _MeshIndex:
    """One mesh's AABB tree (distances) and winding-number hierarchy, each built on first use."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices, self.faces = vertices, faces
        self._aabb = self._winding = None

    def aabb(self):
        import igl

        if self._aabb is None:
            self._aabb = igl.AABB()
            self._aabb.init(self.vertices, self.faces)
        return self._aabb

    def winding(self):
        import igl

        if self._winding is None:
            self._winding = igl.FastWindingNumberBVH()
            self._winding.init(self.vertices, self.faces)
        return self._winding


# The stages query the same input mesh many times (a bisection along rays, inside tests, closest points: on the
# teacup's 199k faces each tree takes 0.24-0.29 s to build, once rebuilt 20 times per stage). Keyed by content
# (hashing 10 MB: 15 ms), so a caller's copy of the mesh finds the same trees; the last few meshes are kept.
_INDEXES: OrderedDict[bytes, _MeshIndex] = OrderedDict()
_KEEP = 4


def _mesh_index(vertices: np.ndarray, faces: np.ndarray) -> _MeshIndex:
    v, f = _f64(vertices), np.ascontiguousarray(faces, np.int64)
    digest = hashlib.blake2b(digest_size=16)
    for a in (v, f):
        digest.update(str(a.shape).encode())
        digest.update(a.tobytes())
    key = digest.digest()
    index = _INDEXES.pop(key, None) or _MeshIndex(v, f)
    _INDEXES[key] = index
    while len(_INDEXES) > _KEEP:
        _INDEXES.popitem(last=False)
    return index


def mesh_winding_number(vertices: np.ndarray, faces: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Generalized winding number of the mesh at each query: about 1 inside, 0 outside, fractional near holes
    (libigl's fast winding number, its hierarchy kept between calls: the same values as ``igl.fast_winding_number``)."""
    if len(queries) == 0:
        return np.zeros(0)
    return _mesh_index(vertices, faces).winding().winding_number(_f64(queries))


def mesh_inside_test(vertices: np.ndarray, faces: np.ndarray):
    """``is_inside(queries) -> bool array``: the mesh's generalized winding number above 1/2."""

    index = _mesh_index(vertices, faces)

    def is_inside(queries: np.ndarray) -> np.ndarray:
        if len(queries) == 0:
            return np.zeros(0, bool)
        return index.winding().winding_number(_f64(queries)) > 0.5

    return is_inside


def mesh_distance(vertices: np.ndarray, faces: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unsigned distance from each query to the mesh and the closest point on it."""
    dist, _, closest = mesh_closest(vertices, faces, queries)
    return dist, closest


def mesh_closest(
    vertices: np.ndarray, faces: np.ndarray, queries: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unsigned distance from each query to the mesh, the face it is closest to and the closest point."""
    if len(queries) == 0:
        return np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3))
    index = _mesh_index(vertices, faces)
    sq, face, closest = index.aabb().squared_distance(index.vertices, index.faces, _f64(queries))
    return np.sqrt(np.maximum(sq, 0.0)), np.asarray(face, np.int64), closest


def mesh_distance_function(vertices: np.ndarray, faces: np.ndarray):
    """``mesh_distance`` as a function of the queries alone, the mesh's index looked up once: for callers that
    query the same mesh many times (a bisection along rays queries it at every halving)."""
    index = _mesh_index(vertices, faces)
    tree, v, f = index.aabb(), index.vertices, index.faces

    def distance(queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if len(queries) == 0:
            return np.zeros(0), np.zeros((0, 3))
        sq, _, closest = tree.squared_distance(v, f, _f64(queries))
        return np.sqrt(np.maximum(sq, 0.0)), closest

    return distance


def mesh_signed_distance(vertices: np.ndarray, faces: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Distance to the mesh, negative where the winding number exceeds 1/2 (inside)."""
    dist, _ = mesh_distance(vertices, faces, queries)
    return np.where(mesh_winding_number(vertices, faces, queries) > 0.5, -dist, dist)


def point_areas(points: np.ndarray, k: int = 16) -> np.ndarray:
    """Each point's share of the surface: the disc through its k-th neighbour, divided among the k points in it."""
    from scipy.spatial import cKDTree

    k = int(min(k, len(points) - 1))
    d, _ = cKDTree(points).query(points, k=k + 1)
    return np.pi * d[:, -1] ** 2 / k


def points_winding_number(
    points: np.ndarray, normals: np.ndarray, queries: np.ndarray, areas: np.ndarray | None = None
) -> np.ndarray:
    """Barill et al.'s winding number of an oriented point cloud (outward normals) at each query."""
    import igl

    if len(queries) == 0:
        return np.zeros(0)
    a = point_areas(points) if areas is None else areas
    return igl.fast_winding_number(_f64(points), _f64(normals), _f64(a), _f64(queries))


def points_distance(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Distance from each query to the nearest input point."""
    from scipy.spatial import cKDTree

    if len(queries) == 0:
        return np.zeros(0)
    return cKDTree(points).query(queries, workers=-1)[0]
