"""Surface sampling, normalisation and the degradation plugins: measured against what they promise."""

from __future__ import annotations

import numpy as np
import pytest

from qmdf import schema
from qmdf.geometry.normalize import Normalization
from qmdf.geometry.pointset import PointSet
from qmdf.geometry.shapes import get_shape
from qmdf.plugins.registry import load_all
from qmdf.registry import DEGRADATIONS
from qmdf.geometry.sampling import sample_surface
from qmdf.stages.sample import outward_normals

load_all()


def degrade(name, points, seed=0, **params):
    entry = DEGRADATIONS.get(name)
    assert schema.check_section(entry.config, params, name) == []
    return entry.obj(points, schema.build(entry.config, params), np.random.default_rng(seed))


def sphere_points(n=20000, seed=0):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return PointSet(p * 0.5, p)


def test_normalization_maps_to_the_unit_box_and_back():
    pts = np.random.default_rng(0).uniform([10, -3, 100], [14, 5, 101], size=(1000, 3))
    n = Normalization.fit(pts)
    unit = n.to_unit(pts)
    assert np.allclose(unit.max(0) + unit.min(0), 0)  # centred
    assert np.ptp(unit, axis=0).max() == pytest.approx(1.0)  # longest side 1
    assert np.allclose(n.to_input(unit), pts)
    assert n.length_to_input(0.25) == pytest.approx(0.25 * np.ptp(pts, axis=0).max())
    assert Normalization.from_dict(n.to_dict()) == n


def test_surface_samples_lie_on_the_mesh_with_its_normals():
    mesh = get_shape("ellipsoid").mesh(64)
    s = sample_surface(mesh.vertices, mesh.faces, 5000, np.random.default_rng(0))
    _, dist, tri = __import__("trimesh").proximity.closest_point(mesh, s.points)
    assert dist.max() < 1e-9
    assert np.all((mesh.face_normals[tri] * s.normals).sum(1) > 0.999)


def test_sample_normals_point_outward_or_are_dropped():
    """A mesh wound inward gets its normals flipped out; one with mixed winding gets none (no side to trust)."""
    import logging

    mesh = get_shape("box").mesh(16)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    log = logging.getLogger("test")
    rng = np.random.default_rng(0)
    for faces in (f, f[:, ::-1]):
        s = outward_normals(sample_surface(v, faces, 3000, rng), v, faces, log)
        half = np.array([0.5, 0.35, 0.25])
        axis = np.argmax(np.abs(s.points) / half, axis=1)
        outward = np.sign(s.points[np.arange(len(s)), axis])  # the face each sample is on, seen from the centre
        assert np.all(s.normals[np.arange(len(s)), axis] * outward > 0.999)
    mixed = f.copy()
    mixed[::7] = mixed[::7, ::-1]
    assert outward_normals(sample_surface(v, mixed, 100, rng), v, mixed, log).normals is None


def test_surface_sampling_is_uniform_by_area():
    """On the box, the share of samples on each face pair is its share of the area (chi-square bound)."""
    mesh = get_shape("box").mesh(16)
    n = 60000
    s = sample_surface(mesh.vertices, mesh.faces, n, np.random.default_rng(3)).points
    half = np.array([0.5, 0.35, 0.25])
    axis = np.argmax(np.abs(s) / half, axis=1)  # which pair of faces each sample is on
    counts = np.bincount(axis, minlength=3)
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
    expected = n * areas / areas.sum()
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 13.8  # 99.9% quantile of chi-square with 2 degrees of freedom


def test_sampling_is_reproducible():
    mesh = get_shape("torus").mesh(32)
    a = sample_surface(mesh.vertices, mesh.faces, 100, np.random.default_rng(7)).points
    b = sample_surface(mesh.vertices, mesh.faces, 100, np.random.default_rng(7)).points
    c = sample_surface(mesh.vertices, mesh.faces, 100, np.random.default_rng(8)).points
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_subsample_keeps_n_distinct_points():
    pts = sphere_points(5000)
    out = degrade("subsample", pts, n=1234)
    assert len(out) == 1234 and len(np.unique(out.points, axis=0)) == 1234
    assert np.allclose(np.linalg.norm(out.normals, axis=1), 1)  # normals travel with their points
    assert len(degrade("subsample", pts, n=10**6)) == 5000


def test_noise_has_the_configured_std():
    pts = sphere_points(50000)
    out = degrade("noise", pts, sigma=0.01)
    measured = (out.points - pts.points).std()
    assert measured == pytest.approx(0.01 * pts.bbox_diagonal, rel=0.02)


def test_nonuniform_density_ramps_along_the_axis():
    pts = sphere_points(100000)
    out = degrade("nonuniform", pts, axis=[0, 0, 1], min_keep=0.1)
    z_in, z_out = pts.points[:, 2], out.points[:, 2]
    low = (z_out < -0.4).sum() / (z_in < -0.4).sum()
    high = (z_out > 0.4).sum() / (z_in > 0.4).sum()
    assert low < 0.2 and high > 0.9
    assert 0.5 < len(out) / len(pts) < 0.6  # mean keep probability is 0.55 on a sphere (uniform in z)


def test_missing_region_ball_and_halfspace():
    pts = sphere_points(20000)
    c = [0.0, 0.0, 0.5]
    out = degrade("missing_region", pts, centers=[c], radius=0.1)
    r = 0.1 * pts.bbox_diagonal
    assert np.linalg.norm(out.points - c, axis=1).min() > r
    removed = len(pts) - len(out)
    cap_fraction = (1 - (1 - r * r / (2 * 0.25))) / 2  # area of a spherical cap of chord radius r on R=0.5
    assert removed / len(pts) == pytest.approx(cap_fraction, rel=0.1)
    half = degrade("missing_region", pts, mode="halfspace", normal=[1, 0, 0], offset=0.0)
    assert half.points[:, 0].max() <= 0 and len(half) == pytest.approx(len(pts) / 2, rel=0.03)
    holes = degrade("missing_region", pts, count=3, radius=0.05, seed=1)
    assert len(holes) < len(pts)


def test_bad_degradation_settings_are_reported():
    entry = DEGRADATIONS.get("missing_region")
    problems = schema.check_section(entry.config, {"normal": [0, 0, 0], "radius": -1, "mode": "cube"}, "x")
    assert sorted(p.key for p in problems) == ["x.mode", "x.normal", "x.radius"]
