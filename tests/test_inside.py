"""geometry.inside: the per-mesh index kept between calls gives libigl's own answers, and a changed mesh its own."""

import igl
import numpy as np
import trimesh

from qmdf.geometry import inside


def _sphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def test_cached_index_matches_libigl_and_follows_the_mesh():
    v, f = _sphere()
    q = np.random.default_rng(0).uniform(-0.5, 0.5, (2000, 3))
    w = inside.mesh_winding_number(v, f, q)
    np.testing.assert_array_equal(w, igl.fast_winding_number(v, f, q))
    d, face, closest = inside.mesh_closest(v, f, q)
    sq, face0, closest0 = igl.point_mesh_squared_distance(q, v, f)
    np.testing.assert_array_equal(d, np.sqrt(sq))
    np.testing.assert_array_equal(face, face0)
    # a copy with the same content finds the same index; a moved mesh gets its own answers
    assert inside._mesh_index(v.copy(), f.copy()) is inside._mesh_index(v, f)
    moved = v + np.array([0.2, 0.0, 0.0])
    assert inside._mesh_index(moved, f) is not inside._mesh_index(v, f)
    inside_moved = inside.mesh_inside_test(moved, f)(q)
    np.testing.assert_array_equal(inside_moved, igl.fast_winding_number(moved, f, q) > 0.5)
    assert inside_moved.sum() != (w > 0.5).sum()
    exact = np.sqrt(igl.point_mesh_squared_distance(q, moved, f)[0])
    np.testing.assert_array_equal(inside.mesh_distance_function(moved, f)(q)[0], exact)
    np.testing.assert_array_equal(inside.mesh_winding_number(v, f, q), w)  # the first mesh's answers unchanged


def test_index_cache_keeps_the_last_few_meshes():
    v, f = _sphere()
    for k in range(inside._KEEP + 3):
        inside.mesh_winding_number(v * (1 + 0.01 * k), f, v[:3])
    assert len(inside._INDEXES) == inside._KEEP
