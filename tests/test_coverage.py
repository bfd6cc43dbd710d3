"""medial.coverage: balls added where the envelope falls short of the surface, against the ellipsoid's exact axis,
and the insertions' topology by counting."""

import numpy as np
from mats import ellipsoid_mat

from qmdf.fields.analytic import EllipsoidField
from qmdf.geometry.envelope import EnvelopeUnion
from qmdf.geometry.inside import mesh_distance
from qmdf.geometry.metrics import euler_medial_mesh
from qmdf.geometry.sampling import sample_surface
from qmdf.geometry.shapes import get_shape
from qmdf.medial.coverage import SurfaceBalls, _insert, refine_coverage, surface_balls


def _ellipsoid_data(count=6000):
    mesh = get_shape("ellipsoid").mesh(96)
    mesh = (np.asarray(mesh.vertices), np.asarray(mesh.faces))
    samples = sample_surface(*mesh, count, np.random.default_rng(0))
    return mesh, samples


def _short_disc(scale=0.7):
    """The ellipsoid's medial disc shrunk toward its centre, with the exact radii where its vertices land: a MAT
    on the axis that stops short of the rim, as a learned sheet does."""
    field = EllipsoidField()
    mat = ellipsoid_mat(rings=8, sectors=24)
    v = mat.vertices * scale
    return field, v, -field.sdf(v), mat.faces


def test_surface_balls_of_a_mesh_are_the_exact_medial_balls():
    field = EllipsoidField()
    mesh, samples = _ellipsoid_data(3000)
    balls = surface_balls(samples.points, samples.normals, mesh)
    assert len(balls.samples) > 0.95 * len(samples.points)
    # the centres lie on the disc, with its radius (the mesh's facets: about 1e-3 at this resolution)
    assert np.median(field.axis_distance(balls.centres)) < 2e-3
    assert np.median(np.abs(balls.radii - field.axis_radius(balls.centres))) < 2e-3
    # each ball touches its own sample, and reaches out of the faceted mesh by less than the facet tolerance
    assert np.allclose(np.linalg.norm(balls.samples - balls.centres, axis=1), balls.radii)
    assert np.all(balls.radii - mesh_distance(*mesh, balls.centres)[0] < 3e-3)


def test_surface_balls_reuse_the_mesh_routes_medial_rays():
    """train's mesh route measures the same balls from the same samples: coverage takes them as they are, and
    measures anew for other samples."""
    from qmdf.fields.settings import SupervisionSettings
    from qmdf.fields.supervision import build_supervision

    mesh, samples = _ellipsoid_data(3000)
    sup = build_supervision(
        "mesh",
        samples.points,
        samples.normals,
        np.random.default_rng(0),
        mesh,
        SupervisionSettings(volume_samples=2000),
    )
    rays = {"origins": samples.points, "directions": sup.ray_normals, "radii": sup.radii, "tol": 0.0}
    rays["tol"] = sup.stats["ray_tolerance"]
    measured = surface_balls(samples.points, samples.normals, mesh)
    reused = surface_balls(samples.points, samples.normals, mesh, rays=rays)
    for name in ("samples", "centres", "radii"):  # to rounding: the shrinking ball carries the normals' last bits
        assert np.allclose(getattr(measured, name), getattr(reused, name), rtol=0, atol=1e-12)
    fake = {**rays, "radii": np.zeros(len(samples.points))}  # reused: every ball dropped as too small
    assert len(surface_balls(samples.points, samples.normals, mesh, rays=fake).radii) == 0
    other = {**fake, "origins": samples.points + 1e-3}  # not these samples: measured anew
    assert np.array_equal(surface_balls(samples.points, samples.normals, mesh, rays=other).radii, measured.radii)


def test_surface_balls_of_a_mesh_are_centred_inside_it():
    """Near a cone's apex the rays along the smoothed normals leave the shape and never close (radius 1): such
    balls are dropped by the mesh's winding number."""
    import trimesh

    from qmdf.geometry.inside import mesh_winding_number

    cone = trimesh.creation.cone(radius=0.3, height=0.8, sections=48)
    mesh = (np.asarray(cone.vertices, np.float64), np.asarray(cone.faces, np.int64))
    samples = sample_surface(*mesh, 5000, np.random.default_rng(0))
    unchecked = surface_balls(samples.points, samples.normals, mesh, is_inside=lambda q: np.ones(len(q), bool))
    assert (mesh_winding_number(*mesh, unchecked.centres) < 0.5).sum() > 50
    balls = surface_balls(samples.points, samples.normals, mesh)
    assert (mesh_winding_number(*mesh, balls.centres) > 0.5).all()
    assert len(balls.centres) > 0.9 * len(samples.points) and balls.radii.max() < 0.3


def test_surface_balls_of_a_cloud_stay_inside_its_points():
    field = EllipsoidField()
    _, samples = _ellipsoid_data(3000)
    balls = surface_balls(samples.points, samples.normals, is_inside=lambda q: field.sdf(q) < 0)
    assert len(balls.samples) > 0.9 * len(samples.points)
    gaps = np.min(np.linalg.norm(balls.centres[:, None] - samples.points[None], axis=2), axis=1)
    assert np.all(balls.radii <= gaps + 1e-12)
    assert np.median(field.axis_distance(balls.centres)) < 0.02


def test_a_disc_short_of_the_rim_is_extended_onto_the_axis_with_its_topology():
    field, v, r, faces = _short_disc()
    mesh, samples = _ellipsoid_data()
    balls = surface_balls(samples.points, samples.normals, mesh)
    before = EnvelopeUnion(v, r, np.zeros((0, 2), int), faces).sdf(balls.samples)
    assert before.max() > 0.03  # the tips of the long axis are far outside
    v2, r2, e2, f2, stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, balls, 400, tolerance=2e-3)
    after = EnvelopeUnion(v2, r2, e2, f2).sdf(balls.samples)
    assert stats["added"] == len(v2) - len(v) and 0 < stats["added"] <= 400
    assert after.max() < 0.25 * before.max() and np.mean(np.maximum(after, 0)) < 0.1 * np.mean(np.maximum(before, 0))
    assert np.isclose(stats["shortfall_after"]["max"], max(after.max(), 0.0))
    # what was added lies on the true axis with its true radius, and the disc is still a disc
    new = np.arange(len(v), len(v2))
    assert np.quantile(field.axis_distance(v2[new]), 0.9) < 3e-3
    assert np.quantile(np.abs(r2[new] - field.axis_radius(v2[new])), 0.9) < 3e-3
    assert euler_medial_mesh(len(v2), e2, f2) == euler_medial_mesh(len(v), np.zeros((0, 2), int), faces) == 1
    assert set(np.unique(f2)) == set(range(len(v2)))  # every added vertex is in a face


def test_a_covered_mat_gets_nothing_and_the_budget_holds():
    field, v, r, faces = _short_disc(1.0)
    mesh, samples = _ellipsoid_data()
    balls = surface_balls(samples.points, samples.normals, mesh)
    # the exact disc: its envelope is the ellipsoid up to the mesh's facets and the disc's own triangles (3.3e-3)
    _, _, _, _, stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, balls, 100, tolerance=0.03)
    assert stats["added"] == 0 and stats["shortfall_before"]["max"] < 0.03 / 8
    # below the tolerance, what is left of the budget goes to the smaller gaps (down to an eighth of it)
    _, _, _, _, stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, balls, 100, tolerance=0.01)
    assert stats["added"] > 0 and stats["shortfall_after"]["max"] < stats["shortfall_before"]["max"]
    # compact by tolerance: every sample is within it already, so nothing goes in
    assert stats["shortfall_before"]["max"] < 0.01
    stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, balls, 100, tolerance=0.01, below_tolerance=False)[4]
    assert stats["added"] == 0
    _, short_v, short_r, short_faces = _short_disc()
    stats = refine_coverage(short_v, short_r, np.zeros((0, 2), int), short_faces, balls, 7, tolerance=1e-3)[4]
    assert stats["added"] == 7


def _never(points, *_):
    return np.zeros(len(points), bool)


def test_insertions_keep_the_euler_characteristic_of_faces_seams_and_lone_edges():
    # three triangles on one seam edge (0, 1), a free triangle, and a lone edge
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1], [3, 0, 0], [4, 0, 0], [3, 1, 0]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [5, 6, 7]])
    lone = np.array([[2, 5]])
    r = np.full(len(v), 0.1)
    chi = euler_medial_mesh(len(v), lone, faces)
    points = np.array(
        [
            [0.5, 0.02, 0.0],  # on the seam edge: split in all three faces
            [3.3, 0.3, 0.01],  # inside the free triangle
            [1.75, 0.5, 0.02],  # beside the lone edge
            [3.31, 0.3, 0.0],  # the free triangle again: waits for the next round
        ]
    )
    v2, r2, e2, f2, added, deferred = _insert(v, r, lone, faces, points, np.full(4, 0.1), _never)
    assert added == 3 and deferred.tolist() == [False, False, False, True]
    assert euler_medial_mesh(len(v2), e2, f2) == chi
    assert len(f2) == len(faces) + 3 + 2 and len(e2) == 2
    seam_split = np.flatnonzero((f2 == 8).any(1))
    assert len(seam_split) == 6  # each of the seam's three faces in two
    # the faces keep their orientation: the split faces' normals agree with their parents'
    n = np.cross(v2[f2[:, 1]] - v2[f2[:, 0]], v2[f2[:, 2]] - v2[f2[:, 0]])
    assert np.all(n[(f2 == 9).any(1)][:, 2] > 0)


def test_a_spike_out_of_the_shape_is_refused():
    """A centre far from its nearest face on a concave axis: the balls on the new edges would leave the data."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    r = np.full(3, 0.1)
    faces = np.array([[0, 1, 2]])
    far = np.array([[0.3, 0.3, 0.5]])

    def distance(q):  # a slab |z| < 0.1 around the triangle's plane: the spike's balls poke out of it
        d = 0.1 - np.abs(q[:, 2])
        return np.maximum(d, 0.0), q

    balls = SurfaceBalls(np.array([[0.3, 0.3, 0.6]]), far, np.array([0.1]), distance)
    _, _, _, _, stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, balls, 5, overshoot=5e-3)
    assert stats["added"] == 0
    loose = SurfaceBalls(balls.samples, far, balls.radii, lambda q: (np.full(len(q), 1.0), q))
    _, _, _, _, stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, loose, 5, overshoot=5e-3)
    assert stats["added"] == 1  # once: the same ball is never offered twice


def test_a_branch_the_mesh_lacks_grows_as_a_dangling_edge():
    """Where splitting the nearest face would bulge out, but the cone from the nearest vertex stays inside (a
    tube leaving the sheet there), the ball hangs on a lone edge: V and E grow by one, chi stays."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    r = np.full(3, 0.1)
    faces = np.array([[0, 1, 2]])
    centre = np.array([[-0.3, -0.3, 0.0]])

    def distance(q):  # inside only around the tube from vertex 0 toward the centre
        tube = (q[:, 0] <= 0.05) & (q[:, 1] <= 0.05)
        return np.where(tube, 1.0, 0.0), q

    balls = SurfaceBalls(centre + [[0.0, 0.0, 0.1]], centre, np.array([0.1]), distance)
    v2, r2, e2, f2, stats = refine_coverage(v, r, np.zeros((0, 2), int), faces, balls, 5)
    assert stats["added"] == 1
    assert e2.tolist() == [[0, 3]] and np.array_equal(f2, faces)
    assert euler_medial_mesh(len(v2), e2, f2) == 1


def test_envelope_fit_is_small_on_the_exact_disc_and_grows_as_it_falls_short():
    from qmdf.medial.coverage import envelope_fit

    mesh, samples = _ellipsoid_data()
    balls = surface_balls(samples.points, samples.normals, mesh)
    no_edges = np.zeros((0, 2), int)
    fits = []
    for scale in (1.0, 0.7):
        _, v, r, faces = _short_disc(scale)
        fits.append(envelope_fit(v, r, no_edges, faces, balls, np.random.default_rng(0), samples=4000))
    exact, short = fits
    assert exact["chamfer"] < 2e-3 and exact["hausdorff"] < 8e-3  # the disc's triangles and the mesh's facets
    assert short["chamfer"] > 3 * exact["chamfer"] and short["hausdorff"] > 0.025
    # a MAT thinned to a point of radius 0 (an undertrained field) encloses nothing: it fits nothing
    point = envelope_fit(
        np.zeros((1, 3)), np.zeros(1), no_edges, np.zeros((0, 3), int), balls, np.random.default_rng(0)
    )
    assert point["chamfer"] == point["hausdorff"] == np.inf


def test_cover_mat_keeps_coverage_only_where_the_envelope_fits_better(monkeypatch):
    """cover_mat: the short disc's coverage brings its envelope closer to the data and is kept; an insertion that
    puts a ball far outside the shape makes the fit worse and the MAT comes back as it was."""
    from qmdf.geometry.ma_format import MedialMesh
    from qmdf.medial import coverage
    from qmdf.medial.coverage import cover_mat

    mesh, samples = _ellipsoid_data()
    balls = surface_balls(samples.points, samples.normals, mesh)
    _, v, r, faces = _short_disc(0.7)
    mat = MedialMesh(v, r, np.zeros((0, 2), int), faces).with_face_edges()
    covered, stats = cover_mat(mat, balls, 400, seed=0, tolerance=2e-3)
    assert stats["kept"] and stats["added"] == len(covered.vertices) - len(v) > 0
    assert stats["chamfer_after"] < 0.5 * stats["chamfer_before"]

    def spike(v, r, e, f, balls, budget, **settings):  # one vertex with a big ball above the shape, on an edge
        e = np.vstack([e, [[0, len(v)]]]).astype(int)
        return np.vstack([v, [[0, 0, 0.6]]]), np.r_[r, 0.3], e, f, {"added": 1}

    monkeypatch.setattr(coverage, "refine_coverage", spike)
    same, stats = cover_mat(mat, balls, 400, seed=0)
    assert not stats["kept"] and stats["chamfer_after"] > stats["chamfer_before"]
    assert same is mat
