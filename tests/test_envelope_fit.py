"""The envelope fit: its Jacobian against finite differences, and the ellipsoid's MAT recovered from a shrunk one."""

from __future__ import annotations

import numpy as np
from mats import ellipsoid_mat

from qmdf.geometry.envelope import EnvelopeUnion
from qmdf.medial.envelope_fit import fit_envelope_to_samples, foot_weights

A, B, C = 0.5, 0.35, 0.25


def _ellipsoid_samples(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the ellipsoid x^2/A^2 + y^2/B^2 + z^2/C^2 = 1 (directions uniform on the sphere, scaled)."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * [A, B, C]


def _mat():
    mat = ellipsoid_mat(A, B, C, rings=10, sectors=32)
    return mat.vertices, mat.radii, np.zeros((0, 2), int), mat.faces


def test_foot_weights_rebuild_the_foot_and_are_the_radius_derivative():
    v, r, e, f = _mat()
    rng = np.random.default_rng(0)
    p = _ellipsoid_samples(400, rng)
    union = EnvelopeUnion(v, r, e, f)
    d, prim = union.sdf(p, return_argmin=True)
    _, foot, foot_r = union.eval_prims(p, prim)
    ids = union.prims[prim]
    w = foot_weights(foot, v[ids], union.kind[prim])
    assert np.allclose(w.sum(1), 1.0)
    assert np.abs(np.einsum("pk,pkj->pj", w, v[ids]) - foot).max() < 1e-9
    assert np.abs((w * r[ids]).sum(1) - foot_r).max() < 1e-9
    # d(sdf)/d(r_k) = -w_k: grow one vertex's radius a little and compare with the samples it serves
    k = int(np.bincount(ids.ravel()).argmax())
    h = 1e-6
    r2 = r.copy()
    r2[k] += h
    moved = (EnvelopeUnion(v, r2, e, f).sdf(p) - d) / h
    expected = -(w * (ids == k)).sum(1)
    served = expected < -0.05
    assert served.sum() > 3
    assert np.abs(moved[served] - expected[served]).max() < 1e-3


def test_fit_recovers_a_shrunk_and_displaced_ellipsoid_mat():
    v, r, e, f = _mat()
    rng = np.random.default_rng(1)
    samples = _ellipsoid_samples(6000, rng)
    exact = float(np.abs(EnvelopeUnion(v, r, e, f).sdf(samples)).mean())  # the sheet's own discretisation error
    shrunk = r * 0.85
    shifted = v + [0.0, 0.0, 0.01]  # off the plane of symmetry
    start = float(np.abs(EnvelopeUnion(shifted, shrunk, e, f).sdf(samples)).mean())
    fv, fr, stats = fit_envelope_to_samples(shifted, shrunk, e, f, samples, iterations=8)
    end = float(np.abs(EnvelopeUnion(fv, fr, e, f).sdf(samples)).mean())
    assert start > 10 * exact
    assert end < 2 * exact, (start, end, exact)
    assert stats["mean_distance"][0] == start and stats["mean_distance"][stats["iteration"]] == end
    deep = r > 0.5 * C  # where the radius is well determined (at the rim it goes to zero)
    assert np.median(np.abs(fr[deep] - r[deep])) < 0.25 * np.median(r[deep] - shrunk[deep])
    assert np.median(np.abs(fv[deep, 2])) < 0.2 * 0.01
    assert np.all(fr >= 0)


def test_fixed_vertices_stay_and_zero_iterations_change_nothing():
    v, r, e, f = _mat()
    samples = _ellipsoid_samples(3000, np.random.default_rng(2))
    fixed = np.zeros(len(v), bool)
    fixed[::3] = True
    fv, fr, _ = fit_envelope_to_samples(v, r * 0.9, e, f, samples, fixed=fixed, iterations=3)
    assert np.array_equal(fv[fixed], v[fixed]) and np.array_equal(fr[fixed], (r * 0.9)[fixed])
    assert np.abs(fr[~fixed] - r[~fixed] * 0.9).max() > 1e-3  # the free ones did move
    same_v, same_r, stats = fit_envelope_to_samples(v, r, e, f, samples, iterations=0)
    assert np.array_equal(same_v, v) and np.array_equal(same_r, r)
    assert stats["iteration"] == 0 and len(stats["mean_distance"]) == 1


def test_rim_fairness_smooths_a_sawtooth_rim_without_losing_the_fit():
    """The ellipsoid's MAT cut short at 90% of its disc (where a covering's sheet ends), its rim zigzagging in
    and out by 4% (the grid's sawtooth), each ball touching the ellipsoid: the samples alone barely see where
    along the disc a rim ball sits, so they leave the teeth; the fairness term smooths them at the same fit."""
    from qmdf.geometry.metrics import boundary_smoothness, single_face_edges

    a2, b2 = A * A - C * C, B * B - C * C
    s = np.linspace(0, 0.9, 9)[1:]
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    scale = np.outer(s, np.ones_like(t))
    scale[-1] *= 1 + np.where(np.arange(len(t)) % 2, 0.04, -0.04)  # the sawtooth
    xy = np.vstack([[0.0, 0.0], np.c_[(scale * np.cos(t)).ravel() * a2 / A, (scale * np.sin(t)).ravel() * b2 / B]])
    m = len(t)
    ring = 1 + np.arange(len(s))[:, None] * m + np.arange(m)  # vertex ids, ring by ring
    nxt = np.roll(ring, -1, axis=1)
    f = np.vstack(
        [np.c_[np.zeros(m, int), ring[0], nxt[0]]]
        + [np.c_[ring[k], ring[k + 1], nxt[k + 1]] for k in range(len(s) - 1)]
        + [np.c_[ring[k], nxt[k + 1], nxt[k]] for k in range(len(s) - 1)]
    )
    v = np.c_[xy, np.zeros(len(xy))]
    r = C * np.sqrt(np.clip(1 - xy[:, 0] ** 2 / a2 - xy[:, 1] ** 2 / b2, 0, None))
    e = np.zeros((0, 2), int)
    samples = _ellipsoid_samples(8000, np.random.default_rng(3))
    rim = single_face_edges(f)
    before = boundary_smoothness(v, rim)
    plain_v, plain_r, _ = fit_envelope_to_samples(v, r, e, f, samples, iterations=12, rim_fairness=0.0)
    fair_v, fair_r, _ = fit_envelope_to_samples(v, r, e, f, samples, iterations=12, rim_fairness=0.03)

    def misfit(x, rr):
        return float(np.abs(EnvelopeUnion(x, rr, e, f).sdf(samples)).mean())

    plain, fair = boundary_smoothness(plain_v, rim), boundary_smoothness(fair_v, rim)
    # measured: C_avg 1.05 -> 0.68 (samples alone) and 0.30 (fairness), misfit 2.35e-4 and 2.22e-4
    assert plain > 0.5 * before, (before, plain)  # the samples alone leave the teeth
    assert fair < 0.5 * plain, (plain, fair)
    assert misfit(fair_v, fair_r) < 1.05 * misfit(plain_v, plain_r) < 0.5 * misfit(v, r)
    edge = np.unique(rim)
    assert np.all(fair_r[edge] > 0.5 * r[edge])  # the rim's balls keep their size (faired with their radii)
