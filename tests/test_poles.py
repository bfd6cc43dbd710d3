"""The Voronoi-pole baseline against known axes and the empty-ball property, by brute force."""

from __future__ import annotations

import numpy as np

from qmdf.geometry.poles import circumspheres, inner_poles


def test_circumspheres_pass_through_the_four_corners():
    tets = np.random.default_rng(0).normal(size=(200, 4, 3))
    centre, radius = circumspheres(tets)
    assert np.allclose(np.linalg.norm(tets - centre[:, None, :], axis=2), radius[:, None])
    flat = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]], float)
    assert np.isinf(circumspheres(flat)[1][0])


def test_the_poles_of_a_torus_lie_on_its_circle_and_their_balls_are_empty():
    rng = np.random.default_rng(1)
    u, v = rng.uniform(0, 2 * np.pi, (2, 4000))
    R, r = 0.35, 0.15
    normals = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    points = np.stack([R * np.cos(u), R * np.sin(u), np.zeros_like(u)], 1) + r * normals
    poles, radii = inner_poles(points, normals)
    from_circle = np.hypot(np.hypot(poles[:, 0], poles[:, 1]) - R, poles[:, 2])
    assert np.median(from_circle) < 2e-3 and np.median(np.abs(radii - r)) < 2e-3
    # each pole ball touches its own sample and holds no other: a Delaunay circumsphere
    assert np.allclose(np.linalg.norm(poles - points, axis=1), radii)
    nearest = np.linalg.norm(poles[:, None, :] - points[None, ::4], axis=2).min(1)
    assert np.all(nearest >= radii - 1e-9)
