"""The sharp-feature module: feature points from a mesh's dihedral angles and by the paper's procedure on an
exact field, and retraining that pins the field to them."""

from __future__ import annotations

import pytest

import numpy as np

from qmdf.geometry.shapes import BOX_HALF
from qmdf.pipeline import Pipeline


def box_edge_distance(p: np.ndarray) -> np.ndarray:
    """Distance from p to the nearest of the box's 12 edges."""
    d = BOX_HALF - np.abs(p)  # depth below each pair of faces
    s = np.sort(np.abs(d), axis=1)
    return np.hypot(s[:, 0], s[:, 1])


def test_mesh_features_lie_on_the_box_edges(compose_cfg, tmp_path):
    cfg = compose_cfg("input.shape=box", "pipeline.stages=[sample,feature_detect]", "feature_detect.spacing=0.01")
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    feats = res.load("feature_points").points
    assert box_edge_distance(feats).max() < 1e-7  # the surface is stored in float32
    total = 4 * 2 * BOX_HALF.sum()  # the 12 edges' length
    assert 0.9 * total / 0.01 < len(feats) < 1.5 * total / 0.01
    # every edge is covered: points near each of the 8 corners
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * BOX_HALF
    assert (np.linalg.norm(feats[None] - corners[:, None], axis=2).min(1) < 0.02).all()
    assert res.load("features")["source"] == "mesh"


@pytest.mark.slow
def test_field_procedure_reaches_the_box_edges(compose_cfg, tmp_path):
    """From the exact box field and its MAT: membrane boundary -> march along g1 + g2 -> QEM onto the edge."""
    cfg = compose_cfg(
        "input.shape=box",
        "input.shape_resolution=64",
        "sample.n_points=20000",
        "pipeline.stages=[sample,analytic_field,cover,contract,export,feature_detect]",
        "cover.resolution=128",
        "cover.eps=0.01",
        "contract.iterations=300",
        "feature_detect.source=field",
        "feature_detect.field_seeds=membrane",
        "contract.outside_weight=0",
    )
    # outside_weight=0: the exact field's q already rises outside (q = sdf there); the learned field's falls, and
    # the +2 sdf that stops it would triple this slope and pull the first MAT's tips back (21 boundary edges, not 60)
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    feats = res.load("feature_points").points
    stats = res.load("features")
    assert stats["source"] == "field" and stats["boundary_edges"] > 50 and len(feats) > 100
    d = box_edge_distance(feats)
    assert np.median(d) < 3e-3 and np.mean(d < 0.01) > 0.9, (np.median(d), np.mean(d < 0.01))


def test_point_cloud_features_cover_every_box_edge_with_face_normals(compose_cfg, tmp_path):
    """From the input points and the field's gradients alone (no first MAT): two-plane fits find every edge
    but the corners, on the edge, with the faces' right angle in their mean normal."""
    from scipy.spatial import cKDTree

    cfg = compose_cfg(
        "input.shape=box",
        "sample.n_points=20000",
        "pipeline.stages=[sample,analytic_field,feature_detect]",
        "feature_detect.source=field",
        "feature_detect.field_seeds=points",
    )
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    found = res.load("feature_points")
    stats = res.load("features")
    assert "boundary_edges" not in stats and stats["point_fits"] > 1000
    d = box_edge_distance(found.points)
    assert np.percentile(d, 99) < 0.005, np.percentile(d, 99)
    assert np.mean(cKDTree(found.points).query(box_edge_samples(0.005))[0] < 0.01) > 0.9
    m = np.linalg.norm(found.normals, axis=1)
    assert np.mean(np.abs(m - np.sqrt(0.5)) < 0.02) > 0.95


@pytest.mark.slow
def test_feature_retrain_pins_the_field_to_the_features(compose_cfg, tmp_path):
    # the paper's route: its field has no mf targets, so the sharp terms alone move mf at the features (the mesh
    # route's mf targets near an edge also go to 0, but over more steps than this smoke test runs)
    cfg = compose_cfg(
        "input.shape=box",
        "pipeline.stages=[sample,train,feature_detect,feature_retrain]",
        "train.optim.steps=60",
        "train.optim.surface_batch=512",
        "train.optim.volume_batch=512",
        "train.supervision.route=paper",
        "feature_retrain.steps=60",
        "feature_detect.spacing=0.02",
    )
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    stats = res.load("training")
    assert stats["feature_abs_sdf_after"] < 0.5 * stats["feature_abs_sdf_before"]
    assert stats["feature_mf_after"] < stats["feature_mf_before"]
    assert stats["bisector_samples"] > 10 * stats["feature_points"]  # mesh features carry their faces' normals
    assert (res.run_dir / "03_feature_retrain" / "field.pt").exists()


def box_edge_samples(spacing: float) -> np.ndarray:
    from qmdf.medial.features import sample_segments

    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * BOX_HALF
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(c[i] != c[j]) == 1]
    return sample_segments(c[[i for i, _ in edges]], c[[j for _, j in edges]], spacing)


@pytest.mark.slow
def test_covering_and_pulled_membrane_reach_the_box_edges():
    """Exact box: the covering's tips end on the edges (not a voxel short), and the feature pull keeps the
    contracted membrane there, where the paper's energy lets the tips slide back."""
    import logging

    from scipy.spatial import cKDTree

    from qmdf.fields.analytic import BoxField
    from qmdf.medial.contraction import ContractionSettings, contract
    from qmdf.medial.covering import CoveringSettings, build_covering

    field, sharp = BoxField(), box_edge_samples(0.01)
    voxel = 2 * 0.55 / (96 - 1)
    covering, _, _ = build_covering(
        field, CoveringSettings(resolution=96, eps=0.01, max_faces=0), log=logging.getLogger("test")
    )
    d = cKDTree(covering.vertices).query(sharp)[0]
    # measured 0.58 / 0.72 voxel; the step to a constant outside gave 0.78 / 1.02
    assert np.median(d) < 0.65 * voxel and np.percentile(d, 90) < 0.85 * voxel, (
        np.median(d) / voxel,
        np.percentile(d, 90) / voxel,
    )

    v, f = np.asarray(covering.vertices), np.asarray(covering.faces)
    reach = {}
    # the pull alone (zip off): a vertex on each edge (measured 0.991 with the pull, 0.086 without); then the
    # zip folds the tips flat there: edge samples within 0.01 of the membrane's fold edges, measured 0.29 without
    # the zip and 0.99 with it (its pairs sit a little inward, so fewer vertices lie within 0.003: 0.52)
    from qmdf.bench.features import boundary_distance
    from qmdf.geometry.ma_format import MedialMesh

    folded = {}
    for weight, zip_weight in ((10.0, 0.0), (0.0, 0.0), (10.0, 1000.0)):
        settings = ContractionSettings(iterations=300, feature_weight=weight, zip_weight=zip_weight)
        x, history, vol0, _ = contract(field, v, f, features=sharp, settings=settings)
        reach[weight, zip_weight] = np.mean(cKDTree(x).query(sharp)[0] < 0.003)
        mat = MedialMesh(x, np.abs(field.evaluate(x)["sdf"]), np.zeros((0, 2), np.int64), f).with_face_edges()
        folded[weight, zip_weight] = np.mean(boundary_distance(sharp, mat) < 0.01)
        assert np.percentile(np.abs(field.evaluate(x)["q"]), 95) < 2e-4  # still on the medial axis
        assert abs(history[-1]["volume"]) < 1e-3 * vol0
    assert reach[10.0, 0.0] > 0.95 and reach[0.0, 0.0] < 0.5, reach
    assert folded[10.0, 0.0] < 0.5 and folded[10.0, 1000.0] > 0.95, folded


def test_sharp_segments_keep_convex_edges_of_a_merged_mesh():
    """An L-shaped prism: 18 sharp edges, one of them concave (the inner corner), which the medial axis never
    reaches; repeated vertices (as OBJ files with normals load) must not hide the adjacency."""
    from trimesh.creation import extrude_triangulation

    from qmdf.medial.features import sharp_mesh_segments

    outline = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    prism = extrude_triangulation(outline, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]), 1.0)
    split = prism.vertices[prism.faces.ravel()]  # every face corner its own vertex
    faces = np.arange(len(split)).reshape(-1, 3)
    a, b, _ = sharp_mesh_segments(split, faces, 30.0, convex_only=False)
    assert len(a) == 18
    mid = (a + b) / 2
    assert np.isclose(mid[:, :2], 1).all(1).sum() == 1  # the concave edge is among them
    a, b, _ = sharp_mesh_segments(split, faces, 30.0)
    mid = (a + b) / 2
    assert len(a) == 17 and not np.isclose(mid[:, :2], 1).all(1).any()


def test_bisector_samples_lie_on_the_box_medial_axis_with_its_radius():
    """From the box's edge samples and face normals alone: medial points with radius = depth, exactly on the
    known axis, and each walk stops where the sheet ends (a third face comes nearer)."""
    import trimesh

    from qmdf.fields.analytic import BoxField
    from qmdf.geometry.bisectors import bisector_samples
    from qmdf.medial.features import sample_segments, sharp_mesh_segments

    box = trimesh.creation.box(extents=2 * BOX_HALF)
    a, b, mean_normal = sharp_mesh_segments(box.vertices, box.faces, 30.0)
    assert np.allclose(np.linalg.norm(mean_normal, axis=1), np.sqrt(0.5))  # right angles: cos 45 degrees
    feats, seg = sample_segments(a, b, 0.01, return_index=True)
    points = trimesh.sample.sample_surface(box, 20000, seed=1)[0]
    x, r = bisector_samples(feats, mean_normal[seg], points, 0.3, 0.005)
    exact = BoxField()
    err = np.abs(-exact.evaluate(x)["sdf"] - r)
    # near the sheets' ends the discrete input points let a few walks overshoot, by about their spacing (0.0125)
    assert np.mean(err > 1e-6) < 0.02 and err.max() < 0.02, (np.mean(err > 1e-6), err.max())
    assert np.percentile(exact.axis_distance(x), 99) < 1e-6
    # the walks reach as far as the sheets go: the deepest edge sheet meets the middle at r = 0.25 (half the
    # thinnest side)
    assert 0.2 < r.max() < 0.26 and len(x) > 0.8 * len(feats) * 0.3 / 0.005 * 0.5
    # a "feature" whose two normals agree (a detected point on a flat patch) has no sheet behind it
    flat = np.tile([0.0, 0.0, 1.0], (len(feats), 1))
    assert len(bisector_samples(feats, flat, points, 0.3, 0.005)[0]) == 0


def test_bisector_walks_stay_inside_and_at_their_depth_when_checked_against_the_mesh():
    """Features whose normals are wrong (flipped: the walk heads out of the shape; a sliver's: it heads anywhere)
    give medial samples outside or far from their radius with the input points' test alone (on the block 853
    samples outside asked sdf = -r in its central void); with the mesh's distance and winding number every
    sample kept is inside and at its radius, and the right walks are kept."""
    import trimesh

    from qmdf.geometry.bisectors import bisector_samples
    from qmdf.geometry.inside import mesh_distance, mesh_inside_test
    from qmdf.medial.features import sample_segments, sharp_mesh_segments
    from qmdf.medial.radii import data_distance

    box = trimesh.creation.box(extents=2 * BOX_HALF).subdivide().subdivide().subdivide()  # a fine facet tolerance
    v, f = np.asarray(box.vertices, np.float64), np.asarray(box.faces, np.int64)
    a, b, mean_normal = sharp_mesh_segments(v, f, 30.0)
    feats, seg = sample_segments(a, b, 0.01, return_index=True)
    normals = mean_normal[seg].copy()
    rng = np.random.default_rng(3)
    wrong = rng.choice(len(feats), len(feats) // 5, replace=False)
    flipped, sliver = wrong[::2], wrong[1::2]
    normals[flipped] *= -1
    turned = rng.normal(size=(len(sliver), 3))
    normals[sliver] = 0.2 * turned / np.linalg.norm(turned, axis=1, keepdims=True)  # cos 0.2: faces almost folded
    points = trimesh.sample.sample_surface(box, 20000, seed=1)[0]

    def bad(x, r):
        d, _ = mesh_distance(v, f, x)
        return ~inside(x) | (d < 0.98 * r) | (d > r / 0.98 + tol)

    distance, tol = data_distance((v, f))
    inside = mesh_inside_test(v, f)
    x, r = bisector_samples(feats, normals, points, 0.3, 0.005)
    assert bad(x, r).sum() > 100  # the unchecked walks do go wrong here

    x, r = bisector_samples(
        feats,
        normals,
        points,
        0.3,
        0.005,
        distance=lambda q: distance(q)[0],
        tol=tol,
        is_inside=inside,
    )
    assert not bad(x, r).any()
    right, _ = bisector_samples(np.delete(feats, wrong, 0), np.delete(normals, wrong, 0), points, 0.3, 0.005)
    assert len(x) >= 0.95 * len(right)


def test_contract_after_feature_detect_pulls_toward_the_features(compose_cfg, tmp_path):
    """The pipeline hands feature_detect's points to a later contract (and only to a later one)."""
    cfg = compose_cfg(
        "input.shape=box",
        "input.shape_resolution=64",
        "pipeline.stages=[sample,analytic_field,cover,contract,feature_detect,cover,contract]",
        "cover.resolution=64",
        "cover.eps=0.02",
        "contract.iterations=200",
    )
    res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    first = __import__("json").loads((res.run_dir / "03_contract" / "contraction.json").read_text())
    second = res.load("contraction")
    assert first["feature_points"] == 0 and first["feature_distance"] is None
    assert second["feature_points"] > 100 and second["pulling_features"] > 0.8 * second["feature_points"]
    assert second["feature_distance"] < 5e-3, second["feature_distance"]  # measured 3.2e-3; grid step 0.017


class _FlatField:
    """q = 0 everywhere: no force from the field, as near a sharp edge where mf and |sdf| both vanish."""

    def evaluate(self, points, grad=False):
        n = len(points)
        out = {"sdf": np.zeros(n), "mf": np.zeros(n), "q": np.zeros(n)}
        if grad:
            out["sdf_grad"] = out["q_grad"] = np.zeros((n, 3))
        return out


def test_layer_zip_closes_the_layers_near_features_only():
    """A thin slab (two facing layers 0.008 apart) on a flat field: the zip closes the layers within zip_near
    of the feature points (at its +x end) and leaves the rest; without it nothing moves them. The layers
    overshoot each other under Adam's normalised steps: the pairs must hold to bring them back."""
    import trimesh

    from qmdf.medial.contraction import ContractionSettings, contract

    slab = trimesh.creation.box(extents=(0.3, 0.008, 0.1))
    while slab.edges_unique_length.max() > 0.01:
        slab = slab.subdivide()
    v, f = np.asarray(slab.vertices), np.asarray(slab.faces)
    feats = np.column_stack([np.full(11, 0.15), np.zeros(11), np.linspace(-0.05, 0.05, 11)])
    mid = (np.abs(v[:, 2]) < 0.04) & (np.abs(v[:, 1]) > 0.003)  # the two big faces, away from the z ends

    def gap(x, near):
        sel = mid & (near(v[:, 0]))
        return np.abs(x[sel, 1]).mean() * 2  # the layers' distance

    for weight, near_after, far_after in ((1000.0, (0, 2e-3), (7e-3, 9e-3)), (0.0, (7e-3, 9e-3), (7e-3, 9e-3))):
        settings = ContractionSettings(
            iterations=300,
            lattice=0,
            lambda_volume=0,
            lambda_laplacian=0,
            feature_weight=10,
            zip_weight=weight,
            zip_reach=0.01,
            zip_near=0.05,
        )
        x = contract(_FlatField(), v, f, features=feats, settings=settings)[0]
        near, far = gap(x, lambda s: (s > 0.1) & (s < 0.14)), gap(x, lambda s: s < 0.05)
        assert near_after[0] <= near <= near_after[1] and far_after[0] <= far <= far_after[1], (weight, near, far)
