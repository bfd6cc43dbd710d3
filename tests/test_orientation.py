"""Orientation of raw clouds by the winding number's normal consistency (WNNC) against the true normals: a
sparse thin-walled teacup, whose two wall sides are as close as the sampling gap, and a dense ellipsoid; the
operators against brute force; the even subsample."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from qmdf.geometry.orientation import estimate_oriented_normals
from qmdf.geometry.shapes import get_shape
from qmdf.geometry.winding_orientation import WnncSettings, even_subsample, sampling_gap, wnnc_normals


def _cloud(shape: str, n: int, seed: int = 0, resolution: int = 64):
    mesh = get_shape(shape).mesh(resolution)
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    nrm = np.asarray(mesh.face_normals[face])
    return np.asarray(pts), (nrm if mesh.volume > 0 else -nrm)


def _right(est, true):
    return float(np.mean((est * true).sum(1) > 0))


@pytest.fixture(scope="module")
def sparse_teacup():
    return _cloud("teacup", 1500)


def test_wnnc_orients_a_sparse_thin_walled_cup_where_propagation_cannot(sparse_teacup):
    """1,500 points on the teacup: its 0.05-thick wall is thinner than the sampling gap (about 0.065), so a
    neighbour graph crosses it; the winding number sees the two sides apart."""
    pts, true = sparse_teacup
    assert sampling_gap(pts) > 0.05
    est, _, info = estimate_oriented_normals(pts, method="wnnc")
    assert _right(est, true) > 0.98, info  # 98.9-99.7% over three samples
    assert info["inconsistent_share"] < 0.01 and info["method"] == "wnnc"
    tree, _, tree_info = estimate_oriented_normals(pts, method="propagation")
    assert _right(tree, true) < 0.9  # measured 56-72% on such clouds: why WNNC is the default
    assert tree_info["inconsistent_share"] > info["inconsistent_share"]


def test_wnnc_on_a_dense_cloud_runs_on_a_subsample_and_keeps_the_plane_fits():
    pts, true = _cloud("ellipsoid", 8000, seed=1)
    est, _, info = estimate_oriented_normals(pts, method="wnnc")
    assert info["subsample"] <= WnncSettings().max_points and _right(est, true) > 0.999
    assert info["plane_fit_kept"] > 0.95  # the sharper plane-fit normals, signed by the field
    angle = np.degrees(np.arccos(np.clip((est * true).sum(1), -1, 1)))
    assert np.median(angle) < 3


def test_the_compiled_operators_equal_brute_force():
    from qmdf.geometry._winding_kernels import winding_adjoint, winding_at, winding_descent

    rng = np.random.default_rng(2)
    p, mu, q, s = rng.normal(size=(40, 3)), rng.normal(size=(40, 3)), rng.normal(size=(7, 3)), rng.normal(size=40)
    w = 0.3

    def pairs(a, b):
        r = b[None, :, :] - a[:, None, :]  # r[i, j] = b_j - a_i
        d = np.linalg.norm(r, axis=2)
        return r, d, d >= w

    r, d, keep = pairs(q, p)
    a = np.where(keep, (r * mu[None]).sum(2) / np.maximum(d, 1e-9) ** 3, 0).sum(1) / (4 * math.pi)
    assert np.allclose(winding_at(p, mu, q, w), a)
    # minus the gradient of the winding number, by central differences
    h = 1e-5
    grad = np.stack(
        [(winding_at(p, mu, q + h * e, w) - winding_at(p, mu, q - h * e, w)) / (2 * h) for e in np.eye(3)], 1
    )
    assert np.allclose(winding_descent(p, mu, q, w), -grad, atol=1e-5 * np.abs(grad).max())
    # the adjoint: <A mu, s> = <mu, A^T s>
    assert np.isclose(winding_at(p, mu, p, w) @ s, (mu * winding_adjoint(p, s, w)).sum())


def test_the_even_subsample_spreads_over_a_non_uniform_cloud():
    rng = np.random.default_rng(3)
    dense = rng.uniform(0, 0.1, (20000, 3))  # a dense corner
    sparse = rng.uniform(0, 1, (2000, 3))
    pts = np.concatenate([dense, sparse])
    sub = even_subsample(pts, 1000)
    assert 700 <= len(sub) <= 1000 and len(np.unique(sub)) == len(sub)
    assert np.mean(sub < len(dense)) < 0.2  # a random choice would take 91% from the corner
    assert np.array_equal(even_subsample(pts[:50], 1000), np.arange(50))


def test_wnnc_settings_are_used():
    pts, true = _cloud("ellipsoid", 600, seed=4)
    _, info = wnnc_normals(pts, WnncSettings(iterations=5, max_points=300))
    assert info["subsample"] <= 300 and info["final_width"] == pytest.approx(0.5 * info["gap"])
