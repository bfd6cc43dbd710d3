"""Metrics against cases with a known answer."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from qmdf.geometry import metrics as M
from qmdf.geometry.envelope import EnvelopeUnion
from qmdf.geometry.envelope_scores import reconstruction_distances
from qmdf.geometry.shapes import get_shape, torus_sdf


def test_point_to_mesh_distance_matches_the_exact_torus():
    mesh = get_shape("torus").mesh(256)
    p = np.random.default_rng(0).uniform(-0.6, 0.6, size=(5000, 3))
    d = M.point_to_mesh_distance(p, mesh.vertices, mesh.faces)
    assert np.abs(d - np.abs(torus_sdf(p))).max() < 1e-4  # the mesh's own polygonal error at this resolution


def test_point_to_mesh_distance_against_brute_force_triangles():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    p = np.random.default_rng(1).normal(size=(300, 3))
    _, brute, _ = trimesh.proximity.closest_point_naive(mesh, p)
    assert np.allclose(M.point_to_mesh_distance(p, mesh.vertices, mesh.faces), brute, atol=1e-6)


def torus_mat(n=400, R=0.35, r=0.15):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    c = np.c_[R * np.cos(t), R * np.sin(t), np.zeros(n)]
    return c, np.full(n, r), np.c_[np.arange(n), (np.arange(n) + 1) % n], np.zeros((0, 3), int)


def test_reconstruction_of_the_torus_mat_matches_the_torus():
    union = EnvelopeUnion(*torus_mat())
    gt = get_shape("torus").mesh(256)
    out, mesh, (R, r_to_g), (G, g_to_r) = reconstruction_distances(
        union, gt.vertices, gt.faces, 20000, np.random.default_rng(0), resolution=96
    )
    assert mesh.is_watertight and (2 - mesh.euler_number) // 2 == 1
    assert np.abs(torus_sdf(R)).max() < 2e-5  # samples lie on the envelope: the polyline's sagitta, 1.1e-5
    assert out["chamfer"] < 1e-4 and out["hausdorff"] < 3e-4
    assert "exact distance" in out["definition"]


def test_a_shifted_reconstruction_measures_its_shift():
    c, r, e, f = torus_mat()
    union = EnvelopeUnion(c, r - 0.01, e, f)  # a thinner tube: every surface point moves in by 0.01
    gt = get_shape("torus").mesh(256)
    out, *_ = reconstruction_distances(union, gt.vertices, gt.faces, 10000, np.random.default_rng(0), resolution=96)
    assert out["chamfer"] == pytest.approx(0.01, abs=3e-4)
    assert out["hausdorff"] == pytest.approx(0.01, abs=3e-4)


def test_euler_characteristics():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert M.euler_surface(len(sphere.vertices), sphere.faces) == 2
    torus = get_shape("torus").mesh(32)
    assert M.euler_surface(len(torus.vertices), torus.faces) == 0
    # a single tetrahedron, and two sharing a face: both contractible
    assert M.euler_tetrahedral(4, [[0, 1, 2, 3]]) == 1
    assert M.euler_tetrahedral(5, [[0, 1, 2, 3], [1, 2, 3, 4]]) == 1
    # a ring of tets around an axis: chi = 0 (a solid torus)
    n = 8
    tets = [[i, (i + 1) % n, n + i, n + (i + 1) % n] for i in range(n)]
    assert M.euler_tetrahedral(2 * n, tets) == 0
    # medial meshes: a triangle fan (disc, chi 1) plus a dangling edge (still chi 1), and a polyline loop
    fan = [[0, i, i + 1] for i in range(1, 5)]
    assert M.euler_medial_mesh(6, [[5, 0]], fan) == 1
    assert M.euler_medial_mesh(4, [[0, 1], [1, 2], [2, 3], [3, 0]], np.zeros((0, 3), int)) == 0


def test_boundary_edges_and_smoothness_of_known_curves():
    # a flat square split into two triangles: boundary is the square, C_avg = 4 * s * pi/2 / (4 s) = pi/2
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    b = M.single_face_edges(f)
    assert sorted(map(tuple, b)) == [(0, 1), (0, 3), (1, 2), (2, 3)]
    assert M.boundary_smoothness(v, b) == pytest.approx(np.pi / 2)
    # a regular n-gon loop: C_avg = 2 pi / n (turning angles over length, as the paper writes it)
    n = 50
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    loop = np.c_[np.cos(t), np.sin(t), np.zeros(n)]
    assert M.boundary_smoothness(loop, np.c_[np.arange(n), (np.arange(n) + 1) % n]) == pytest.approx(2 * np.pi / n)
    # a straight open chain has no turning
    line = np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)]
    assert M.boundary_smoothness(line, np.c_[np.arange(4), np.arange(1, 5)]) == 0.0


def test_resampled_smoothness_does_not_reward_subdivision():
    """A circle of radius 0.3 resampled every 0.01 turns by 2 pi over its length whatever its vertex count;
    a sawtooth rim stays rough when subdivided, which lowers the paper's C_avg but not the resampled one."""

    def loop(n, tooth=0.0):
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        rad = 0.3 + tooth * (np.arange(n) % 2)
        return np.c_[rad * np.cos(t), rad * np.sin(t), np.zeros(n)], np.c_[np.arange(n), (np.arange(n) + 1) % n]

    for n in (40, 400):
        v, e = loop(n)
        assert M.boundary_smoothness(v, e, 0.01) == pytest.approx(2 * np.pi / (2 * np.pi * 0.3 / 0.01), rel=0.1)
    coarse, fine = loop(60, 0.02), loop(60, 0.02)
    fine_v = np.repeat(fine[0], 4, axis=0)  # each vertex four times, then spread along the edge to the next
    fine_v = fine_v + (np.roll(fine[0], -1, 0) - fine[0]).repeat(4, axis=0) * np.tile(np.arange(4) / 4, 60)[:, None]
    fine_e = np.c_[np.arange(240), (np.arange(240) + 1) % 240]
    assert M.boundary_smoothness(fine_v, fine_e) < 0.5 * M.boundary_smoothness(*coarse)
    assert M.boundary_smoothness(fine_v, fine_e, 0.01) == pytest.approx(M.boundary_smoothness(*coarse, 0.01), rel=0.1)
    assert M.boundary_smoothness(*coarse, 0.01) > 5 * M.boundary_smoothness(*loop(60), 0.01)


def test_fold_edges_find_the_rim_of_a_flattened_double_cover():
    # a closed "pita": two fans over one ring, a hair apart, fold back along the ring
    n = 24
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.vstack([np.c_[np.cos(t), np.sin(t), np.zeros(n)], [[0, 0, 1e-3], [0, 0, -1e-3]]])
    top = [[i, (i + 1) % n, n] for i in range(n)]
    bottom = [[(i + 1) % n, i, n + 1] for i in range(n)]
    folds = M.fold_edges(v, np.array(top + bottom), min_fold_deg=150)
    assert sorted(map(tuple, folds)) == sorted(tuple(sorted((i, (i + 1) % n))) for i in range(n))
    assert len(M.fold_edges(*(lambda s: (s.vertices, s.faces))(trimesh.creation.icosphere()))) == 0


@pytest.mark.parametrize("cols, high", [(2, 50), (3, 40_000), (4, 7), (4, 2**20)])
def test_unique_rows_is_numpys_unique_over_rows(cols, high):
    from qmdf.geometry.rows import unique_rows

    rng = np.random.default_rng(cols)
    a = rng.integers(0, high, (3000, cols))
    a = np.concatenate([a, a[:500]])  # duplicates for certain, whatever the range
    want = np.unique(a, axis=0, return_inverse=True, return_counts=True)
    got = unique_rows(a, return_inverse=True, return_counts=True)
    for w, g in zip(want, got):
        np.testing.assert_array_equal(g, w)
    np.testing.assert_array_equal(unique_rows(a), want[0])
    assert unique_rows(np.zeros((0, 2), np.int64)).shape == (0, 2)
    with pytest.raises(ValueError):
        unique_rows(np.zeros((3, 2)))  # floats: not what the key encodes


def test_rim_sides_are_the_sides_of_one_face_with_their_face():
    from qmdf.geometry.metrics import rim_sides

    faces = np.array([[0, 1, 2], [0, 2, 3], [2, 1, 4]])  # three triangles; sides 0-2 and 1-2 are shared
    sides, owner = rim_sides(faces)
    got = sorted((tuple(s), int(o)) for s, o in zip(sides, owner))
    assert got == [((0, 1), 0), ((1, 4), 2), ((2, 3), 1), ((3, 0), 1), ((4, 2), 2)]
