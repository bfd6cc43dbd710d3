"""Distance to an evenly meshed surface, answered near its vertices, against brute force and the AABB tree."""

from __future__ import annotations

import numpy as np
import trimesh

from qmdf.geometry.even_mesh_distance import EvenSurfaceIndex, EvenlyMeshedSurface, even_mesh_distance_function
from qmdf.geometry.inside import mesh_distance_function
from qmdf.geometry.shapes import get_shape
from qmdf.geometry.triangles import facet_tolerance
from qmdf.medial.radii import data_distance


def test_closest_points_match_brute_force_on_every_triangle():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    p = np.random.default_rng(1).normal(scale=0.7, size=(400, 3))
    d, closest = even_mesh_distance_function(mesh.vertices, mesh.faces)(p)
    brute_closest, brute, _ = trimesh.proximity.closest_point_naive(mesh, p)
    assert np.allclose(d, brute, atol=1e-9)
    assert np.allclose(closest, brute_closest, atol=1e-9)


def test_the_torus_by_its_axis_and_by_its_surface_agrees_with_the_aabb_tree():
    mesh = get_shape("torus").mesh(64)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(0)
    t = rng.uniform(0, 2 * np.pi, 2000)
    on_axis = np.stack([0.35 * np.cos(t), 0.35 * np.sin(t), np.zeros_like(t)], 1) + rng.normal(0, 0.01, (2000, 3))
    near_surface = v[rng.integers(len(v), size=2000)] + rng.normal(0, 0.004, (2000, 3))
    anywhere = rng.uniform(-0.7, 0.7, (2000, 3))
    exact, _ = mesh_distance_function(v, f)(np.concatenate([on_axis, near_surface, anywhere]))
    near, _ = even_mesh_distance_function(v, f)(np.concatenate([on_axis, near_surface, anywhere]))
    assert np.all(near >= exact - 1e-12)  # a distance to some face: never under the true one
    assert np.abs(near - exact)[2000:4000].max() < 1e-9  # by the surface: the closest face is found
    # by the axis every face around the tube is about as near, and the nearest vertices' faces can miss the closest
    # by the facets' own depth below the smooth surface: at most edge^2 / (8 tube radius), under the facet tolerance
    edge = np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1).max()
    assert np.abs(near - exact)[:2000].max() < edge**2 / (8 * 0.15) < facet_tolerance(v, f)
    assert (np.abs(near - exact) / exact)[4000:].max() < 2e-3  # far off: second order


def test_the_data_distance_of_an_evenly_meshed_surface_is_answered_near_its_vertices():
    mesh = get_shape("torus").mesh(48)
    pair = (np.asarray(mesh.vertices), np.asarray(mesh.faces))
    even = EvenlyMeshedSurface(pair)
    v, f = even  # unpacks like the plain pair
    assert v is pair[0] and f is pair[1]
    q = np.random.default_rng(2).uniform(-0.5, 0.5, (500, 3))
    (d_even, _), (d_plain, _) = data_distance(even)[0](q), data_distance(pair)[0](q)
    assert data_distance(even)[1] == data_distance(pair)[1]
    assert np.abs(d_even - d_plain).max() < facet_tolerance(*pair)


def test_deep_queries_take_a_coarser_level_within_its_tolerance():
    # a sphere's centre is equally near every vertex: the KD-tree's worst case, answered on a coarse level
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.5)  # 10k vertices
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    index = EvenSurfaceIndex(v, f, tolerance=2e-3)
    assert len(index.levels) >= 3 and all(a.cover < b.cover for a, b in zip(index.levels, index.levels[1:]))
    rng = np.random.default_rng(3)
    deep = rng.normal(0, 0.03, (3000, 3))
    shallow = v[rng.integers(len(v), size=3000)] * (1 + rng.normal(0, 0.01, (3000, 1)))
    assert max(len(at) for at, lv in index._by_level(deep) if lv.tree.n < len(v) / 3) > 2000  # not all 10k
    assert [lv.tree.n for _, lv in index._by_level(shallow)] == [len(v)]  # by the surface: the fine level
    exact = mesh_distance_function(v, f)
    for q in (deep, shallow):
        d, closest = index.closest(q)
        assert np.all(d >= exact(q)[0] - 1e-12)  # a distance to some face: never under the true one
        assert np.abs(d - exact(q)[0]).max() <= 2e-3  # within the tolerance
        assert np.allclose(np.linalg.norm(closest - q, axis=1), d)
    dv, at_vertex = index.nearest_vertex(deep)
    brute = np.linalg.norm(deep[:, None, :] - v[None], axis=2).min(1)
    assert np.allclose(np.linalg.norm(at_vertex - deep, axis=1), dv)
    assert np.all(dv >= brute - 1e-12) and np.all(dv - brute <= 2e-3)


def test_the_shrinking_ball_finds_the_bisections_radius():
    from scipy.spatial import cKDTree

    from qmdf.geometry.medial_radius import inward_medial_radii, shrinking_ball_radii
    from qmdf.geometry.sampling import sample_surface

    for name in ("torus", "teacup"):
        mesh = get_shape(name).mesh(64)
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        s = sample_surface(v, f, 2000, np.random.default_rng(0))
        tree = cKDTree(v)

        def nearest(q):
            d, i = tree.query(q)
            return d, v[i]

        bisected = inward_medial_radii(s.points, s.normals, lambda q: nearest(q)[0], tol=2e-3, iterations=16)
        shrunk = shrinking_ball_radii(s.points, s.normals, nearest, tol=2e-3)
        assert np.abs(shrunk - bisected).max() < 2.0 / 2**16 * 1.01  # the bisection's own resolution
        assert np.all(nearest(s.points - shrunk[:, None] * s.normals)[0] >= shrunk - 2e-3 - 1e-12)  # it passes


def test_an_evenly_meshed_surface_builds_its_index_once():
    from qmdf.geometry.even_mesh_distance import surface_distance_function

    mesh = trimesh.creation.icosphere(subdivisions=3)
    even = EvenlyMeshedSurface((np.asarray(mesh.vertices), np.asarray(mesh.faces)))
    first, second = surface_distance_function(even), surface_distance_function(even)
    assert first.__self__ is second.__self__ is even.index
    q = np.random.default_rng(4).normal(size=(50, 3))
    assert np.array_equal(first(q)[0], even_mesh_distance_function(*even)(q)[0])
