"""The rims' walk to the axis's end (qmdf.medial.rims) against exact shapes whose medial axis is known."""

import numpy as np
import pytest

from qmdf.geometry import ellipsoid
from qmdf.medial.rims import extend_rims, rim_directions

AXES = np.array([0.5, 0.35, 0.25])
DISC = ellipsoid.medial_disc(AXES)[1]  # the medial disc's semi-axes, (0.375, 0.171)


def ellipsoid_data():
    def distance(q):
        foot, _ = ellipsoid.closest_point(q, AXES)
        return np.linalg.norm(q - foot, axis=1), foot

    return distance, lambda q: ((np.asarray(q) / AXES) ** 2).sum(1) < 1.0


def disc_mesh(share: float, rings: int = 8, spokes: int = 48):
    """A triangulated elliptic disc in z = 0 reaching ``share`` of the medial disc's elliptic radius."""
    pts = [np.zeros(3)]
    for i in range(1, rings + 1):
        a = np.linspace(0, 2 * np.pi, spokes, endpoint=False)
        s = share * i / rings
        pts += list(np.column_stack([s * DISC[0] * np.cos(a), s * DISC[1] * np.sin(a), np.zeros(spokes)]))
    faces = [[0, 1 + j, 1 + (j + 1) % spokes] for j in range(spokes)]
    for i in range(rings - 1):
        o, p = 1 + i * spokes, 1 + (i + 1) * spokes
        for j in range(spokes):
            k = (j + 1) % spokes
            faces += [[o + j, p + j, p + k], [o + j, p + k, o + k]]
    return np.array(pts), np.array(faces)


def elliptic_radius(x):
    return np.sqrt((x[:, 0] / DISC[0]) ** 2 + (x[:, 1] / DISC[1]) ** 2)


def test_rim_directions_of_a_flat_disc_point_outward_in_its_plane():
    v, f = disc_mesh(0.9)
    index, out, normal = rim_directions(v, np.zeros((0, 2), int), f)
    assert sorted(index) == list(range(len(v) - 48, len(v)))
    radial = v[index] / np.linalg.norm(v[index], axis=1)[:, None]
    assert np.all((out * radial).sum(1) > 0.7)
    assert np.allclose(np.abs(normal[:, 2]), 1.0) and np.allclose(out[:, 2], 0.0)


def test_a_curve_end_points_along_its_edge_and_a_closed_curve_has_none():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    index, out, normal = rim_directions(v, np.array([[0, 1], [1, 2]]), np.zeros((0, 3), int))
    assert list(index) == [0, 2]
    assert np.allclose(out, [[-1, 0, 0], [1, 0, 0]]) and np.allclose(normal, 0)
    loop = np.array([[0, 1], [1, 2], [2, 0]])
    assert len(rim_directions(v + [[0, 0, 0], [0, 1, 0], [0, 0, 0]], loop, np.zeros((0, 3), int))[0]) == 0


def test_the_ellipsoids_short_disc_is_carried_out_to_its_true_rim():
    distance, inside = ellipsoid_data()
    v, f = disc_mesh(0.9)
    r = distance(v)[0]
    out, radii, stats = extend_rims(v, r, np.zeros((0, 2), int), f, distance, inside)
    rim = np.arange(len(v) - 48, len(v))
    rho = elliptic_radius(out[rim])
    # from 90% to the rim: within the walk's last step (reach 4 r / 32 / 64, about 3e-4) and the 2.6-degree stop
    assert rho.min() > 0.98 and rho.max() < 1.005, (rho.min(), rho.max())
    assert np.allclose(out[: rim[0]], v[: rim[0]]) and np.allclose(radii[: rim[0]], r[: rim[0]])
    assert np.abs(out[rim, 2]).max() < 1e-9  # stays in the disc's plane
    assert np.allclose(radii[rim], distance(out[rim])[0])  # each radius its ball's distance to the surface
    truth = ellipsoid.medial_radius(out[rim] * [1, 1, 0], AXES)
    assert np.abs(radii[rim] - truth).max() < 2e-3
    assert stats["moved"] == 48 and stats["at_reach"] == 0


def test_a_disc_already_at_its_rim_stays_and_fixed_vertices_stay():
    distance, inside = ellipsoid_data()
    v, f = disc_mesh(0.999)
    out, _, _ = extend_rims(v, distance(v)[0], np.zeros((0, 2), int), f, distance, inside)
    assert elliptic_radius(out).max() < 1.005  # nothing walks off the axis beyond it
    v, f = disc_mesh(0.9)
    fixed = np.zeros(len(v), bool)
    fixed[-48:-24] = True
    out, _, stats = extend_rims(v, distance(v)[0], np.zeros((0, 2), int), f, distance, inside, fixed=fixed)
    assert np.array_equal(out[fixed], v[fixed]) and stats["rim_vertices"] == 24


def test_a_capsules_axis_reaches_the_centres_of_its_caps():
    """A capsule of radius 0.1 around the segment |x| <= 0.3: its medial axis is that segment, radius 0.1."""
    half, rho = 0.3, 0.1

    def distance(q):
        c = np.column_stack([np.clip(q[:, 0], -half, half), np.zeros((len(q), 2))])
        away = q - c
        n = np.linalg.norm(away, axis=1)
        return np.abs(rho - n), c + away / np.maximum(n, 1e-300)[:, None] * rho

    def inside(q):
        return distance(q)[0] < rho  # good enough near the axis

    x = np.linspace(-0.2, 0.2, 9)
    v = np.column_stack([x, np.zeros((9, 2))])
    edges = np.column_stack([np.arange(8), np.arange(1, 9)])
    out, radii, stats = extend_rims(v, np.full(9, rho), edges, np.zeros((0, 3), int), distance, inside)
    assert out[0, 0] == pytest.approx(-half, abs=2e-3) and out[-1, 0] == pytest.approx(half, abs=2e-3)
    assert np.allclose(out[1:-1], v[1:-1]) and np.allclose(radii, rho, atol=2e-3)


def test_the_guard_keeps_moves_that_improve_the_fit_and_sends_back_one_that_does_not():
    from qmdf.geometry.envelope import EnvelopeUnion

    distance, inside = ellipsoid_data()
    rng = np.random.default_rng(0)
    g = rng.normal(size=(20000, 3))
    samples = ellipsoid.closest_point(g / np.linalg.norm(g, axis=1)[:, None] * AXES, AXES)[0]
    v, f = disc_mesh(0.9)
    r = distance(v)[0]
    none = np.zeros((0, 2), int)
    out, radii, stats = extend_rims(v, r, none, f, distance, inside, samples=samples)
    assert stats["reverted"] == 0 and stats["moved"] == 48

    def fit(x, rr):
        return np.abs(EnvelopeUnion(x, rr, none, f).sdf(samples)).mean()

    assert fit(out, radii) < 0.8 * fit(v, r)  # 1.01e-3 -> 0.75e-3 (the coarse disc's slabs keep the rest)
    # a move that shrinks the envelope goes back; the good ones beside it stay
    from qmdf.medial.rims import keep_local_gains

    rim = np.arange(len(v) - 48, len(v))
    moved_v, moved_r = out.copy(), radii.copy()
    bad = rim[:6]
    moved_v[bad] = v[bad] * 0.75 / 0.9
    moved_r[bad] = distance(moved_v[bad])[0]
    moved = np.ones(48, bool)
    back = keep_local_gains(v, r, moved_v, moved_r, none, f, rim, moved, samples, 1e-4)
    # the six go back, and with them some neighbours that share their samples (the blame is by reach)
    assert set(range(6)) <= set(np.flatnonzero(~moved)) and back == (~moved).sum() <= 12
    assert np.array_equal(moved_v[bad], v[bad]) and np.array_equal(moved_v[rim[moved]], out[rim[moved]])
    assert fit(moved_v, moved_r) < fit(v, r)
