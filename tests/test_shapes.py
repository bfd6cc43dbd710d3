"""Procedural shapes: watertight, the expected genus, and exact SDFs that agree with the meshes."""

from __future__ import annotations

import numpy as np
import pytest

from qmdf.geometry.shapes import genus_of, get_shape
from qmdf.plugins.registry import load_all
from qmdf.registry import SHAPES

load_all()
EXPECTED_GENUS = {"teacup": 1, "torus": 1, "box": 0, "ellipsoid": 0, "dodecahedron": 0, "cyclide": 1}


def test_the_required_shapes_are_registered():
    assert set(EXPECTED_GENUS) <= set(SHAPES.names())


@pytest.mark.parametrize("name", sorted(EXPECTED_GENUS))
@pytest.mark.parametrize("resolution", [32, 64])
def test_watertight_with_expected_genus(name, resolution):
    shape = get_shape(name)
    mesh = shape.mesh(resolution)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward-facing
    assert len(mesh.split(only_watertight=False)) == 1
    assert genus_of(mesh) == shape.genus == EXPECTED_GENUS[name]


def test_torus_volume_matches_closed_form():
    R, r = 0.35, 0.15
    mesh = get_shape("torus").mesh(128)
    assert mesh.volume == pytest.approx(
        2 * np.pi**2 * R * r * r, rel=5e-3
    )  # inscribed polygons lose ~0.2% at this resolution


def test_ellipsoid_vertices_lie_on_the_ellipsoid():
    v = get_shape("ellipsoid").mesh(64).vertices
    assert np.allclose(((v / np.array([0.5, 0.35, 0.25])) ** 2).sum(1), 1.0)


@pytest.mark.parametrize("u", [0.0, 0.7, 2.0, 3.5])
def test_cyclide_lines_of_curvature_are_circles(u):
    """A Dupin cyclide's parameter lines are circles (its defining property): check u = const."""
    from qmdf.geometry.shapes import CYCLIDE, cyclide_point

    v = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    pts = cyclide_point(np.full_like(v, u), v, **CYCLIDE)
    centred = pts - pts.mean(0)
    _, sing, basis = np.linalg.svd(centred)
    assert sing[2] < 1e-9 * sing[0]  # planar
    xy = centred @ basis[:2].T
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    (a, b, c), *_ = np.linalg.lstsq(A, (xy**2).sum(1), rcond=None)
    radius = np.sqrt(c + a * a + b * b)
    assert np.abs(np.linalg.norm(xy - [a, b], axis=1) - radius).max() < 1e-9


@pytest.mark.parametrize("name", ["torus", "box", pytest.param("teacup", marks=pytest.mark.slow)])
def test_sdf_is_zero_on_the_surface_and_negative_inside(name):
    shape = get_shape(name)
    mesh = shape.mesh(48 if name == "teacup" else 96)  # ray tests on a dense teacup are slow
    on_surface = shape.sdf(mesh.vertices)
    tol = 5e-3 if name == "teacup" else 1e-9  # teacup: marching-cubes vertices sit near, not on, the surface
    assert np.abs(on_surface).max() < tol
    rng = np.random.default_rng(0)
    q = rng.uniform(mesh.bounds[0] - 0.05, mesh.bounds[1] + 0.05, size=(3000, 3))
    d = shape.sdf(q)
    far = np.abs(d) > 0.01  # away from the surface, where the mesh approximation cannot flip the sign
    inside = mesh.contains(q[far])
    assert np.array_equal(inside, d[far] < 0)


@pytest.mark.parametrize("name", ["torus", "box"])
def test_exact_sdf_against_brute_force_distance(name):
    """|sdf| equals the distance to a dense surface sample, up to the sample spacing."""
    shape = get_shape(name)
    mesh = shape.mesh(128)
    from scipy.spatial import cKDTree

    from qmdf.geometry.sampling import sample_surface

    dense = sample_surface(mesh.vertices, mesh.faces, 400_000, np.random.default_rng(1)).points
    q = np.random.default_rng(2).uniform(-0.6, 0.6, size=(500, 3))
    brute, _ = cKDTree(dense).query(q)
    assert np.abs(np.abs(shape.sdf(q)) - brute).max() < 4e-3
