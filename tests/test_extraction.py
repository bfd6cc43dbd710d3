"""cover -> contract -> export -> evaluate on exact fields with known medial axes (no training involved)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from qmdf.fields.analytic import BoxField, EllipsoidField, TorusField, box_medial_points
from qmdf.geometry import ellipsoid
from qmdf.geometry.normalize import Normalization
from qmdf.pipeline import Pipeline

CHAIN = [
    "input.shape=torus",
    "input.shape_resolution=192",
    "pipeline.stages=[sample,analytic_field,cover,contract,sheet,export,evaluate]",
    "cover.resolution=96",
    "cover.eps=0.015",
    "contract.iterations=300",
    "export.reconstruction_resolution=48",
    "export.picture=false",
    "evaluate.samples=3000",
    "evaluate.resolution=48",
    "evaluate.picture=false",
]


def test_analytic_fields_are_exact():
    rng = np.random.default_rng(0)
    t = TorusField()
    p = rng.uniform(-0.5, 0.5, (20000, 3))
    p = p[t.sdf(p) < 0]
    assert np.abs(t.evaluate(p)["q"] - t.axis_distance(p)).max() < 1e-12  # q is the distance to the circle
    b = BoxField()
    m = box_medial_points(b.half, 2000)
    assert np.abs(b.evaluate(m)["q"]).max() < 1e-12  # q vanishes on the box's medial axis
    inside = rng.uniform(-1, 1, (5000, 3)) * b.half
    assert np.all(b.evaluate(inside)["q"] >= -1e-12)


def test_ellipsoid_distances_against_brute_force():
    from scipy.optimize import minimize_scalar
    from scipy.spatial import cKDTree

    axes = np.array([0.5, 0.35, 0.25])
    rng = np.random.default_rng(1)
    p = rng.uniform(-0.6, 0.6, (400, 3))
    x, _ = ellipsoid.closest_point(p, axes)
    assert np.abs(((x / axes) ** 2).sum(1) - 1).max() < 1e-12  # on the surface
    normal = x / axes**2
    cross = np.cross(p - x, normal)
    assert np.abs(cross).max() < 1e-12  # p - x is along the normal: a stationary point of the distance
    # ... and the global minimum: brute force over a fine (u, v) parametrisation, refined per point
    u, v = np.meshgrid(np.linspace(0, np.pi, 400), np.linspace(0, 2 * np.pi, 800), indexing="ij")
    s = np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1).reshape(-1, 3) * axes
    brute = cKDTree(s).query(p)[0]
    d = np.abs(ellipsoid.signed_distance(p, axes))
    assert np.all(d <= brute + 1e-12) and np.abs(d - brute).max() < 2e-3
    # the medial disc: q = mf - |sdf| is the distance along the normal ray to the disc, zero on it
    f = EllipsoidField()
    inside = p[f.sdf(p) < 0]
    m = ellipsoid.medial_point(inside, axes)
    assert np.abs(m[:, 2]).max() < 1e-15
    assert np.allclose(-f.sdf(m), ellipsoid.medial_radius(m, axes), atol=1e-12)  # the maximal ball
    assert np.allclose(f.evaluate(m)["q"], 0, atol=1e-12)
    # distance to the disc against a 1-D search along its rim, for points beyond the rim
    k, semi = ellipsoid.medial_disc(axes)
    far = np.array([[0.6, 0.1, 0.05], [-0.2, 0.4, -0.1], [0.1, -0.5, 0.2]])
    for q, dist in zip(far, f.axis_distance(far)):
        best = minimize_scalar(
            lambda t: np.hypot(np.hypot(q[0] - semi[0] * np.cos(t), q[1] - semi[1] * np.sin(t)), q[2]),
            bounds=(np.arctan2(q[1] * semi[0], q[0] * semi[1]) - 0.5, np.arctan2(q[1] * semi[0], q[0] * semi[1]) + 0.5),
            method="bounded",
        )
        assert abs(best.fun - dist) < 1e-8


def test_analytic_field_answers_in_the_unit_box_of_its_input():
    norm = Normalization((0.1, -0.2, 0.05), 1.25)
    f, exact = EllipsoidField(norm), EllipsoidField()
    x = np.random.default_rng(2).uniform(-0.3, 0.3, (50, 3))
    unit = norm.to_unit(x)
    out = f.evaluate(unit, grad=True)
    assert np.allclose(out["sdf"], exact.sdf(x) * 1.25, atol=1e-12)
    assert np.allclose(out["sdf_grad"], exact.evaluate(x, grad=True)["sdf_grad"], atol=1e-6)


@pytest.mark.slow
def test_torus_chain_lands_on_the_medial_circle(compose_cfg, tmp_path):
    res = Pipeline(compose_cfg(*CHAIN, "sheet.expert.off_axis_wide=3"), tmp_path / "run", tmp_path).run()
    stats = res.load("covering_stats")
    assert stats["watertight"] and stats["components"] == 1 and stats["genus"] == [1]
    assert stats["evaluated_nodes"] < 0.2 * stats["grid_nodes"]  # only the narrow band was evaluated
    contraction = res.load("contraction")
    assert contraction["final_volume"] < 0.01 * contraction["initial_volume"]
    membrane = res.load("membrane")
    d = TorusField().axis_distance(np.asarray(membrane.vertices))
    # q is read from the 1e-3 lattice: interpolation moves the minimum by at most half a step
    assert d.mean() < 2.5e-4 and np.percentile(d, 95) < 1e-3
    assert contraction["field_evaluations"] < 0.5 * 300 * len(membrane.vertices)  # lazily, not per iteration
    mat = res.load("mat")  # the single sheet: the circle as a closed polyline, no faces
    assert len(mat.faces) == 0 and len(mat.edges) == len(mat.vertices) >= 100
    assert np.bincount(mat.edges.ravel()).tolist() == [2] * len(mat.vertices)  # every vertex on one cycle
    assert np.percentile(TorusField().axis_distance(mat.vertices), 95) < 1e-3
    assert np.percentile(np.abs(mat.radii - 0.15), 99) < 1e-3  # radius from the input: the tube radius
    m = res.load("metrics")
    assert m["chi"] == 0 and m["chi_rule"] == "V - E + F of the medial mesh" and m["chamfer"] < 1e-3
    assert len(res.load("membrane_mat").faces) == len(membrane.faces)  # the membrane stays, for comparison
    tried = res.load("sheet_stats")["off_axis"]  # both off-axis rules tried, the better fit kept
    assert [r["off_axis"] for r in tried["tried"]] == [0.75, 3.0]
    best = min((r for r in tried["tried"] if r["compact"] and r["chi"] == 0), key=lambda r: r["cd"])
    kept = next(r for r in tried["tried"] if r["off_axis"] == tried["kept"])
    assert kept["compact"] and kept["chi"] == 0 and kept["cd"] == best["cd"]  # on a tie the rule keeps the second
    run = res.run_dir / "05_export"
    ply = trimesh.load(run / "mat_ply.ply", process=False)
    assert np.allclose(ply.metadata["_ply_raw"]["vertex"]["data"]["radius"], mat.radii, atol=1e-6)
    assert (run / "mat_input_units.ma").read_text().splitlines()[
        0
    ] == f"{len(mat.vertices)} {len(mat.edges)} {len(mat.faces)}"


def test_exact_contraction_agrees_with_the_lattice(compose_cfg, tmp_path):
    """contract.lattice=0 evaluates the field at every vertex and iteration: the reference the lattice approximates."""
    cfg = compose_cfg(*CHAIN, "contract.lattice=0", "pipeline.stop_after=contract")
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    d = TorusField().axis_distance(np.asarray(res.load("membrane").vertices))
    assert d.mean() < 1e-4 and res.load("contraction")["field_evaluations"] == 300 * len(res.load("membrane").vertices)


def test_volume_gradients_match_finite_differences():
    from scipy.spatial import Delaunay

    from qmdf.geometry.tets import signed_volumes
    from qmdf.medial.contraction import volume_and_gradient

    sphere = trimesh.creation.icosphere(2)
    x, f = np.asarray(sphere.vertices) * 0.3, np.asarray(sphere.faces)
    rng = np.random.default_rng(0)
    p = rng.uniform(size=(30, 3))
    t = Delaunay(p).simplices
    t[signed_volumes(p, t) < 0] = t[signed_volumes(p, t) < 0][:, [0, 2, 1, 3]]
    assert np.isclose(volume_and_gradient(x, f, None)[0], sphere.volume * 0.027, rtol=1e-12)
    assert np.isclose(volume_and_gradient(p, None, t)[0], signed_volumes(p, t).sum(), rtol=1e-12)
    for pts, faces, tets in ((x, f, None), (p, None, t)):
        grad = volume_and_gradient(pts, faces, tets)[1]
        d = rng.normal(size=pts.shape) * 1e-6
        fd = (volume_and_gradient(pts + d, faces, tets)[0] - volume_and_gradient(pts - d, faces, tets)[0]) / 2
        assert np.isclose(fd, (grad * d).sum(), rtol=1e-6)


def test_contract_refuses_tets_it_was_not_given(compose_cfg, tmp_path):
    from qmdf.errors import QmdfError

    with pytest.raises(QmdfError, match="needs the tetrahedralize stage"):
        Pipeline(compose_cfg(*CHAIN, "contract.volume=tets"), tmp_path / "run", tmp_path).run()


def test_cover_without_a_covering_says_so(compose_cfg, tmp_path):
    from qmdf.errors import QmdfError

    with pytest.raises(QmdfError, match="never drops below cover.eps"):
        Pipeline(compose_cfg(*CHAIN, "cover.eps=0.0000001", "cover.resolution=32"), tmp_path / "run", tmp_path).run()


def test_tetrahedralize_makes_a_tet_mesh_of_the_covering(compose_cfg, tmp_path, monkeypatch):
    from qmdf.geometry.tets import boundary_faces, signed_volumes

    caller = tmp_path / "caller"  # fTetWild writes into its working directory: never the caller's
    caller.mkdir()
    monkeypatch.chdir(caller)

    cfg = compose_cfg(
        "input.shape=torus",
        "input.shape_resolution=128",
        "pipeline.stages=[sample,analytic_field,cover,tetrahedralize]",
        "cover.resolution=64",
        "cover.eps=0.03",
        "tetrahedralize.edge_length_fac=0.1",
        "tetrahedralize.optimize=false",
    )
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    v, t = res.load("covering_tets")
    vol = np.abs(signed_volumes(v, t)).sum()
    assert vol == pytest.approx(res.load("covering_stats")["volume"], rel=0.05)
    assert len(boundary_faces(t)) > 0
    assert list(caller.iterdir()) == []


def test_lattice_q_is_the_trilinear_interpolant_evaluated_once_per_node():
    from qmdf.fields.lattice import LatticeQ

    class Trilinear:
        """A trilinear function: its lattice interpolant is itself, gradient included."""

        calls = 0

        def evaluate(self, p, grad=False):
            Trilinear.calls += len(p)
            x, y, z = p.T
            out = {"q": 2 * x - 3 * y + 0.5 * z + 1 + x * y * z}
            if grad:
                out["q_grad"] = np.c_[2 + y * z, -3 + x * z, 0.5 + x * y]
            return out

    f = Trilinear()
    x = np.random.default_rng(0).uniform(-0.3, 0.3, (500, 3))
    lat = LatticeQ(f, 0.01, -0.35 * np.ones(3), 0.35 * np.ones(3))
    q, g = lat(x)
    exact = f.evaluate(x, grad=True)
    assert np.abs(q - exact["q"]).max() < 1e-12 and np.abs(g - exact["q_grad"]).max() < 1e-10
    first = lat.evaluated
    assert first <= 8 * len(x) and first == Trilinear.calls - len(x)  # each node once
    lat(x + 1e-5)  # tiny moves: mostly the same cells, and no node is evaluated twice
    assert lat.evaluated - first < 0.05 * first
    # a fresh lattice asked in another order reads back from its block pool (grown many times over from its
    # initial 64 blocks) exactly what the field gives
    again = LatticeQ(f, 0.01, -0.35 * np.ones(3), 0.35 * np.ones(3))
    rng = np.random.default_rng(1)
    for part in np.array_split(rng.permutation(len(x)), 7):
        again(x[part])
    calls = Trilinear.calls
    q2, _ = again(x)
    assert len(again.pool) > 64 and np.abs(q2 - exact["q"]).max() < 1e-12
    assert Trilinear.calls == calls  # every corner came from the pool
    far = np.array([[0.9, 0.0, 0.0]])  # off the lattice: the field itself answers
    q_far, _ = LatticeQ(f, 0.01, -0.35 * np.ones(3), 0.35 * np.ones(3))(far)
    assert np.isclose(q_far[0], f.evaluate(far)["q"][0])


class _RidgeSphere:
    """A learned-like field of a sphere of radius 0.3 whose mf is a constant 0.02 (as on a plate too thin for
    the network): q = mf - |sdf| has its ridge on the surface and falls on both sides, so a covering lying on
    the surface (where q < eps everywhere inside, the covering is the surface itself) may walk out."""

    normalization = Normalization.identity()

    def evaluate(self, points, grad=False):
        p = np.asarray(points, np.float64)
        r = np.linalg.norm(p, axis=1)
        sdf = r - 0.3
        out = {"sdf": sdf, "mf": np.full(len(p), 0.02), "q": 0.02 - np.abs(sdf)}
        if grad:
            n = p / np.maximum(r, 1e-12)[:, None]
            out["sdf_grad"], out["q_grad"] = n, -np.sign(sdf)[:, None] * n
        return out


def test_inside_q_continues_q_as_mf_plus_sdf_outside():
    from qmdf.medial.contraction import InsideQ

    rng = np.random.default_rng(0)
    p = rng.normal(size=(500, 3)) * 0.3
    raw, wrapped = _RidgeSphere().evaluate(p, grad=True), InsideQ(_RidgeSphere(), 2.0).evaluate(p, grad=True)
    inside = raw["sdf"] < 0
    assert inside.any() and (~inside).any()
    assert np.array_equal(wrapped["q"][inside], raw["q"][inside])
    assert np.allclose(wrapped["q"], raw["mf"] + raw["sdf"])  # one formula on both sides: no kink at the surface
    h, e = 1e-6, np.eye(3)
    fd = np.stack(
        [
            (
                InsideQ(_RidgeSphere(), 2.0).evaluate(p + h * e[k])["q"]
                - InsideQ(_RidgeSphere(), 2.0).evaluate(p - h * e[k])["q"]
            )
            / (2 * h)
            for k in range(3)
        ],
        1,
    )
    assert np.allclose(wrapped["q_grad"], fd, atol=1e-5)


@pytest.mark.parametrize("weight", [0.0, 2.0])
def test_contraction_stays_inside_the_shape(weight):
    """A covering just outside the ridge (the cover stage allows up to two voxels outside): with the paper's q
    (weight 0) its vertices run outward, with q continued as mf + sdf they come back and go in (this field's q
    falls all the way to the centre)."""
    from qmdf.medial.contraction import ContractionSettings, contract

    s = trimesh.creation.icosphere(subdivisions=3, radius=0.302)
    settings = ContractionSettings(
        iterations=300, lattice=0, lambda_volume=0.0, lambda_laplacian=1.0, outside_weight=weight
    )
    x = contract(_RidgeSphere(), np.asarray(s.vertices), np.asarray(s.faces), settings=settings)[0]
    r = np.linalg.norm(x, axis=1)
    if weight == 0:
        assert r.min() > 0.33  # every vertex left: the ridge is behind them
    else:
        assert r.max() < 0.29


@pytest.mark.slow
def test_a_sheet_that_cannot_be_made_compact_leaves_the_membrane_as_the_mat(compose_cfg, tmp_path, caplog):
    """The torus's circle cannot go below three vertices: asked for two with no slack, the sheet is judged not
    compact, and export writes the membrane (faces, two layers) as the MAT with a warning, the sheet kept."""
    res = Pipeline(
        compose_cfg(*CHAIN, "sheet.target_vertices=2", "sheet.expert.compact_slack=1"), tmp_path / "run", tmp_path
    ).run()
    assert res.load("sheet_stats")["compact"] is False and len(res.load("sheet").faces) == 0
    assert len(res.load("mat").faces) == len(res.load("membrane").faces) > 0
    assert "the single sheet is not compact" in caplog.text
    # the message names where the sheet is once the stage is done, not the scratch folder it ran in
    named = caplog.text.split("the sheet stays in ")[1].split()[0]
    assert ".partial" not in named and Path(named).is_file()


@pytest.mark.slow
def test_a_sheet_that_fits_far_worse_than_the_membrane_is_not_the_mat(compose_cfg, tmp_path, caplog):
    """Three vertices of the torus's circle, compact as asked, are a triangle of cones whose envelope misses most
    of the tube: export writes the membrane as the MAT, with a warning; with the default budget the sheet (a
    closed polyline) fits and is the MAT."""
    res = Pipeline(
        compose_cfg(*CHAIN, "sheet.target_vertices=3", "sheet.step.coverage.vertices=0"), tmp_path / "run", tmp_path
    ).run()
    assert len(res.load("sheet").vertices) == 3 and res.load("sheet_stats")["compact"] is True
    assert len(res.load("mat").faces) == len(res.load("membrane").faces) > 0
    assert "fits the data" in caplog.text and "worse than the membrane's" in caplog.text
    caplog.clear()
    res = Pipeline(compose_cfg(*CHAIN), tmp_path / "default", tmp_path).run()
    assert len(res.load("mat").faces) == 0 and len(res.load("mat").vertices) == len(res.load("sheet").vertices)
    assert "worse than the membrane's" not in caplog.text


def test_the_eps_floor_is_the_axis_q_noise_plus_a_margin_of_grid_cells():
    from qmdf.medial.covering import eps_floor

    cell = 1.1 / 255
    assert eps_floor({}, 256, 0.55) is None
    assert eps_floor({"p99": 0.002, "p999": 0.004}, 256, 0.55) == pytest.approx(0.002 + 2 * cell)
    # a finer grid needs less margin
    assert eps_floor({"p99": 0.002}, 512, 0.55) < eps_floor({"p99": 0.002}, 256, 0.55)


def test_the_narrow_band_gives_the_full_grids_signs_and_crossings():
    """Nodes never evaluated take the sign of the unrefined cell that holds them: every node's sign, and so
    the marching-cubes surface, is the full evaluation's (a thin torus, spheres, a grid whose sides are no
    multiple of the coarse step)."""
    from qmdf.geometry.grid import GridLevelSet, grid_axes, narrow_band_level_set

    centres = np.array([[0.2, 0.1, 0.0], [-0.25, -0.1, 0.1], [0.0, 0.3, -0.2]])
    radii = np.array([0.12, 0.07, 0.05])

    def sdf(p, band=None):
        spheres = (np.linalg.norm(p[:, None] - centres[None], axis=2) - radii).min(1)
        ring = np.hypot(np.hypot(p[:, 0], p[:, 1]) - 0.3, p[:, 2] - 0.05) - 0.012  # thinner than 2 cells
        return np.minimum(spheres, ring)

    lo, hi = np.array([-0.45, -0.4, -0.3]), np.array([0.45, 0.45, 0.3])
    banded = narrow_band_level_set(sdf, lo, hi, 61, coarse_step=8)
    axes, spacing = grid_axes(lo, hi, 61)
    full = sdf(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)).reshape(banded.values.shape)
    assert banded.evaluated < 0.5 * full.size
    assert np.array_equal(banded.values < 0, full < 0)
    a, b = banded.mesh(), GridLevelSet(full.astype(np.float32), banded.lo, spacing, full.size).mesh()
    assert len(a.faces) == len(b.faces) and np.allclose(np.sort(a.vertices, 0), np.sort(b.vertices, 0), atol=1e-9)


def test_smoothness_gradient_is_scipys_laplacian_products_to_the_bit():
    import scipy.sparse as sp

    from qmdf.medial.contraction import _add_smoothness_gradient

    rng = np.random.default_rng(3)
    n = 400
    lap_matrix = (sp.random(n, n, density=0.02, random_state=4) + sp.eye(n)).tocsr()
    transpose = lap_matrix.T.tocsr()
    x, w, g0 = rng.normal(size=(n, 3)), rng.random(n), rng.normal(size=(n, 3))
    g, lap, weighted = g0.copy(), np.zeros((n, 3)), np.zeros((n, 3))
    _add_smoothness_gradient(
        lap_matrix.indptr, lap_matrix.indices, lap_matrix.data,
        transpose.indptr, transpose.indices, transpose.data, x, w, 0.7, g, lap, weighted,
    )  # fmt: skip
    expected_lap = lap_matrix @ x
    assert np.array_equal(lap, expected_lap)
    assert np.array_equal(weighted, w[:, None] * expected_lap)
    assert np.array_equal(g, g0 + 0.7 * (transpose @ (w[:, None] * expected_lap)))
