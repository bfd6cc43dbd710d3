"""A source mesh registered onto a cloud sampled from it in another frame (the benchmark's reference for such
clouds)."""

from __future__ import annotations

import pytest

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from qmdf.geometry.registration import register_mesh_to_points
from qmdf.geometry.shapes import get_shape


@pytest.mark.slow
def test_a_mesh_lands_on_its_cloud_given_in_another_frame():
    cup = get_shape("teacup").mesh(48)  # no symmetry that would make the answer ambiguous: the handle
    v, f = np.asarray(cup.vertices), np.asarray(cup.faces)
    rotation = Rotation.from_euler("zyx", [100, -35, 60], degrees=True).as_matrix()
    moved = v @ rotation.T * 7.0 + np.array([3.0, -1.0, 20.0])  # the frame the cloud was taken in
    points = trimesh.sample.sample_surface(trimesh.Trimesh(moved, f, process=False), 2000, seed=0)[0]
    registered, residual = register_mesh_to_points(v, f, points, iterations=40)
    size = np.ptp(moved, axis=0).max()
    assert np.abs(registered - moved).max() < 2e-3 * size
    assert residual < 1e-4 * size
