"""Envelope distances of medial primitives against brute-force minimisation over the primitive."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from qmdf.geometry.envelope import cone_sdf, slab_sdf, sphere_sdf

RNG = np.random.default_rng(42)


def brute_cone(p, c1, r1, c2, r2):
    t = np.linspace(0, 1, 20001)
    c = c1 + t[:, None] * (c2 - c1)
    f = np.linalg.norm(p - c, axis=1) - (r1 + t * (r2 - r1))
    i = int(np.argmin(f))
    res = minimize(
        lambda x: np.linalg.norm(p - c1 - x[0] * (c2 - c1)) - r1 - x[0] * (r2 - r1),
        [t[i]],
        bounds=[(0, 1)],
        method="L-BFGS-B",
        options={"ftol": 1e-15, "gtol": 1e-12},
    )
    return min(f[i], res.fun)


def brute_slab(p, c, r):
    n = 300
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    l2, l3 = i[keep] / n, j[keep] / n
    l1 = 1 - l2 - l3
    L = np.stack([l1, l2, l3], 1)
    f = np.linalg.norm(p - L @ c, axis=1) - L @ r
    k = int(np.argmin(f))

    def fun(x):
        lam = np.array([1 - x[0] - x[1], x[0], x[1]])
        return np.linalg.norm(p - lam @ c) - lam @ r

    res = minimize(
        fun,
        [l2[k], l3[k]],
        method="SLSQP",
        bounds=[(0, 1), (0, 1)],
        constraints=[{"type": "ineq", "fun": lambda x: 1 - x[0] - x[1]}],
        options={"ftol": 1e-14},
    )
    return min(f[k], res.fun if res.success and res.x.sum() <= 1 + 1e-9 and res.x.min() >= -1e-9 else np.inf)


def test_sphere():
    p = np.array([[3.0, 4.0, 0.0], [0.5, 0, 0]])
    assert np.allclose(sphere_sdf(p, np.zeros((2, 3)), np.array([1.0, 1.0]))[0], [4.0, -0.5])


def test_cone_closed_cases():
    c1, c2 = np.zeros((1, 3)), np.array([[1.0, 0, 0]])
    # a cylinder: equal radii
    assert cone_sdf(np.array([[0.5, 2.0, 0]]), c1, np.array([0.5]), c2, np.array([0.5]))[0] == pytest.approx(1.5)
    # one sphere inside the other: the big sphere alone
    p = np.array([[-3.0, 0, 0]])
    assert cone_sdf(p, c1, np.array([2.0]), c2, np.array([0.5]))[0] == pytest.approx(1.0)
    # coincident centres
    assert cone_sdf(p, c1, np.array([1.0]), c1, np.array([2.0]))[0] == pytest.approx(1.0)


@pytest.mark.parametrize("trial", range(6))
def test_cone_against_brute_force(trial):
    n = 60
    c1, c2 = RNG.normal(size=(n, 3)), RNG.normal(size=(n, 3))
    r1, r2 = RNG.uniform(0.05, 1.2, n), RNG.uniform(0.05, 1.2, n)
    if trial == 0:  # nearly degenerate: tiny axis, large radius difference
        c2 = c1 + 1e-3 * RNG.normal(size=(n, 3))
    p = RNG.normal(size=(n, 3)) * 2
    got, foot_c, foot_r = cone_sdf(p, c1, r1, c2, r2)
    assert np.allclose(np.linalg.norm(p - foot_c, axis=1) - foot_r, got)  # the foot attains the distance
    want = np.array([brute_cone(p[i], c1[i], r1[i], c2[i], r2[i]) for i in range(n)])
    assert np.abs(got - want).max() < 1e-7


@pytest.mark.parametrize("trial", range(6))
def test_slab_against_brute_force(trial):
    n = 40
    c = RNG.normal(size=(n, 3, 3))
    r = RNG.uniform(0.05, 0.8, size=(n, 3))
    if trial == 0:  # near-collinear centres
        c[:, 2] = c[:, 0] + 0.5 * (c[:, 1] - c[:, 0]) + 1e-7 * RNG.normal(size=(n, 3))
    p = RNG.normal(size=(n, 3)) * 1.5
    if trial == 1:  # points on the triangle's plane, inside and just outside it
        w = RNG.dirichlet([1, 1, 1], size=n) * 1.4 - 0.1
        p = np.einsum("nk,nkd->nd", w, c)
    got, foot_c, foot_r = slab_sdf(p, c[:, 0], r[:, 0], c[:, 1], r[:, 1], c[:, 2], r[:, 2])
    assert np.allclose(np.linalg.norm(p - foot_c, axis=1) - foot_r, got)
    want = np.array([brute_slab(p[i], c[i], r[i]) for i in range(n)])
    assert np.abs(got - want).max() < 1e-6


def test_slab_with_equal_radii_is_a_thickened_triangle():
    c = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    p = np.array([[0.2, 0.2, 0.5], [0.2, 0.2, -0.05], [-1.0, 0.2, 0.0]])
    rows = [np.tile(c[k], (3, 1)) for k in range(3)]
    r = np.full(3, 0.1)
    got = slab_sdf(p, rows[0], r, rows[1], r, rows[2], r)[0]
    assert np.allclose(got, [0.4, -0.05, 0.9])


def _random_mat(rng, n_vertices=300, n_faces=200, n_edges=40, n_lone_vertices=5):
    from scipy.spatial import Delaunay

    xy = rng.uniform(-1, 1, size=(n_vertices, 2))
    tri = Delaunay(xy).simplices[:n_faces]
    v = np.column_stack([xy, 0.2 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])])
    r = rng.uniform(0.02, 0.25, n_vertices)
    e = rng.integers(0, n_vertices, size=(n_edges, 2))
    v = np.vstack([v, rng.uniform(-1, 1, size=(n_lone_vertices, 3))])
    r = np.concatenate([r, rng.uniform(0.05, 0.2, n_lone_vertices)])
    return v, r, e, tri


def _brute_union(u, p):
    best = np.full(len(p), np.inf)
    for j in range(len(u.prims)):
        val, _, _ = u.eval_prims(p, np.full(len(p), j))
        best = np.minimum(best, val)
    return best


def test_union_with_culling_equals_brute_force():
    from qmdf.geometry.envelope import EnvelopeUnion

    rng = np.random.default_rng(0)
    v, r, e, f = _random_mat(rng)
    u = EnvelopeUnion(v, r, e, f)
    in_use = set(f.ravel()) | set(e[e[:, 0] != e[:, 1]].ravel())
    assert np.sum(u.kind == 0) == len(v) - len(in_use)  # vertices in no edge or face are spheres
    assert np.sum(u.kind == 2) == len(f)
    p = rng.uniform(-1.4, 1.4, size=(3000, 3))
    exact = _brute_union(u, p)
    assert np.abs(u.sdf(p) - exact).max() < 1e-12
    banded = u.sdf(p, band=0.05)
    near = np.abs(exact) <= 0.05
    assert np.abs(banded[near] - exact[near]).max() < 1e-12
    assert np.all(np.sign(banded[~near]) == np.sign(exact[~near]))
    assert np.all(np.abs(banded[~near]) > 0.05)


def test_snapped_points_lie_on_the_union_boundary():
    from qmdf.geometry.envelope import EnvelopeUnion

    rng = np.random.default_rng(1)
    u = EnvelopeUnion(*_random_mat(rng))
    p = rng.uniform(-1.2, 1.2, size=(4000, 3))
    near = p[np.abs(u.sdf(p)) < 0.02]
    snapped, d = u.snap(near)
    exposed = d > -1e-9
    assert exposed.mean() > 0.8  # most feet are on the union's boundary, not buried in a neighbour
    assert np.abs(d[exposed]).max() < 1e-9
