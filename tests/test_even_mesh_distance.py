"""Distance to an evenly meshed surface, answered near its vertices, against brute force and the AABB tree."""

from __future__ import annotations

import numpy as np
import trimesh

from qmdf.geometry.even_mesh_distance import EvenlyMeshedSurface, even_mesh_distance_function
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
