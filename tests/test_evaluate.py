"""Scoring MATs: the evaluate CLI on MATs we did not make, the evaluate stage, the multirun table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import manifests
from mats import ellipsoid_mat, install_torus_mat_plugin, torus_mat
from qmdf.evaluate import score_mat
from qmdf.geometry.ma_format import MedialMesh, write_ma
from qmdf.geometry.shapes import get_shape

TESTS = Path(__file__).parent
SMALL = ["--samples", "4000", "--resolution", "48"]


def test_score_of_the_closed_form_ellipsoid_mat():
    mesh = get_shape("ellipsoid").mesh(256)
    m = score_mat(ellipsoid_mat(), mesh.vertices, mesh.faces, samples=5000, resolution=48)
    assert m["chamfer"] < 2e-4 and m["hausdorff"] < 1e-3
    assert m["chi"] == 1  # a disc
    assert m["distances"]["gt_distance_from_mesh_fraction"] < 0.01  # nearly all distances exact
    # its boundary is the outer ring of 90 vertices, in order: the paper's formula by hand
    rim = ellipsoid_mat().vertices[-90:]
    prev, nxt = np.roll(rim, 1, 0) - rim, np.roll(rim, -1, 0) - rim
    lp, ln = np.linalg.norm(prev, axis=1), np.linalg.norm(nxt, axis=1)
    theta = np.pi - np.arccos(np.einsum("ij,ij->i", prev, nxt) / (lp * ln))
    assert m["boundary_smoothness"] == pytest.approx(((lp + ln) / 2 * theta).sum() / ln.sum(), rel=1e-9)


def test_score_against_points_matches_score_against_the_mesh():
    mesh = get_shape("torus").mesh(128)
    from qmdf.geometry.sampling import sample_surface

    pts = sample_surface(mesh.vertices, mesh.faces, 200_000, np.random.default_rng(0)).points
    on_mesh = score_mat(torus_mat(), mesh.vertices, mesh.faces, samples=4000, resolution=48)
    on_points = score_mat(torus_mat(), pts, None, samples=4000, resolution=48)
    assert on_points["chi"] == on_mesh["chi"] == 0  # a circle
    assert on_points["chamfer"] < on_mesh["chamfer"] + 2e-3  # nearest points add about half their spacing


def test_closed_membrane_boundary_comes_from_folds():
    """A flattened double cover of a disc (our membrane's form) has no one-face edge: its rim is its folds."""
    n = 48
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.vstack([np.c_[0.3 * np.cos(t), 0.3 * np.sin(t), np.zeros(n)], [[0, 0, 1e-3], [0, 0, -1e-3]]])
    f = np.array([[i, (i + 1) % n, n] for i in range(n)] + [[(i + 1) % n, i, n + 1] for i in range(n)])
    mat = MedialMesh(v, np.full(len(v), 0.1), np.zeros((0, 2), int), f)
    ref = get_shape("torus").mesh(32)  # any reference: only the boundary is checked here
    m = score_mat(mat, ref.vertices, ref.faces, samples=500, resolution=32)
    assert m["boundary_rule"].startswith("fold edges") and m["boundary_edges"] == n
    assert m["boundary_smoothness"] == pytest.approx(2 * np.pi / n)


def test_evaluate_cli_on_a_hand_made_ma(cli, tmp_path):
    # the ellipsoid in its own units (x 40, shifted): the CLI normalises both into the reference's unit box
    mat = ellipsoid_mat()
    write_ma(tmp_path / "e.ma", MedialMesh(mat.vertices * 40 + 7, mat.radii * 40, mat.edges, mat.faces))
    mesh = get_shape("ellipsoid").mesh(128)
    mesh.vertices = mesh.vertices * 40 + 7
    mesh.export(tmp_path / "e.off")
    proc = cli("e.ma", "e.off", "--json", "m.json", "--picture", "m.png", *SMALL, module="qmdf.evaluate")
    assert proc.returncode == 0, proc.stderr
    m = json.loads((cli.cwd / "m.json").read_text())
    assert m["chamfer"] < 3e-4 and m["chi"] == 1 and {"chamfer", "hausdorff", "chi"} <= set(m)
    assert "CD  " in proc.stdout and "definition: CD = (mean d(R->G) + mean d(G->R)) / 2" in proc.stdout
    assert (cli.cwd / "m.png").stat().st_size > 10_000


def test_evaluate_cli_bad_input(cli, tmp_path):
    (tmp_path / "bad.ma").write_text("3 0 0\nv 0 0 0 1\n")
    get_shape("box").mesh(8).export(tmp_path / "b.off")
    proc = cli("bad.ma", "b.off", module="qmdf.evaluate")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "header says 3 0 0" in proc.stderr


@pytest.mark.slow
def test_evaluate_stage_and_multirun_table(cli):
    env = install_torus_mat_plugin(cli.cwd / "site", TESTS)
    args = [
        "input.shape=torus",
        "input.shape_resolution=256",
        "sample.n_points=2000",
        "pipeline.stages=[sample,torus_mat,evaluate]",
        "evaluate.samples=3000",
        "evaluate.resolution=48",
    ]
    proc = cli(*args, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "| CD " in proc.stdout and " chi 0 -> " in proc.stdout  # the one-line summary carries the metrics
    (m,) = manifests(cli.cwd / "runs")
    assert m["status"] == "complete"
    run = Path(m["run_dir"])
    metrics = json.loads((run / "02_evaluate" / "metrics.json").read_text())
    # the torus input is already centred with longest side 1.0: the exact MAT reconstructs it
    assert metrics["chamfer"] < 2e-4 and metrics["chi"] == 0 and metrics["reference"] == "input surface"
    assert (run / "02_evaluate" / "reconstruction.png").exists() and (
        run / "02_evaluate" / "reconstruction.ply"
    ).exists()

    sweep = cli("-m", *args, "torus_mat.radius_offset=0.0,0.01,0.02", env=env)
    assert sweep.returncode == 0, sweep.stderr
    (table,) = list((cli.cwd / "runs" / "multirun").rglob("metrics.csv"))
    import csv

    rows = list(csv.DictReader(open(table)))
    assert [r["overrides"] for r in rows] == [f"torus_mat.radius_offset={v}" for v in ("0.0", "0.01", "0.02")]
    cds = [float(r["chamfer"]) for r in rows]
    assert cds[0] < 2e-4 and cds[1] == pytest.approx(0.01, abs=5e-4) and cds[2] == pytest.approx(0.02, abs=5e-4)
    assert (table.parent / "metrics.md").read_text().startswith("| job | overrides | status |")
    sweep_page = (table.parent / "report.html").read_text()  # each job linked to its own report
    assert (
        all(f'href="{j}/report.html"' in sweep_page for j in (0, 1, 2)) and "torus_mat.radius_offset=0.02" in sweep_page
    )
    # sample was computed once above and reused by every job of the sweep
    jobs = manifests(table.parent)
    assert all(j["stages"][0]["status"] == "cached" for j in jobs)


def test_evaluate_stage_prefers_the_tetrahedral_chi(compose_cfg, tmp_path):
    """With the contracted covering available, chi is V - E + F - C of its tets (paper Sec. 5.1)."""
    from qmdf.artifacts import MAT, POINTS, TETS
    from qmdf.pipeline import Pipeline
    from qmdf.registry import STAGES
    from qmdf.stage import Stage, register_stage

    class RingOfTets(Stage):
        inputs = {"points": POINTS}
        outputs = {"mat": MAT, "contracted_tets": TETS}

        def run(self, ctx):
            ctx.save("mat", torus_mat())
            n = 8  # a closed ring of tets sharing edges: a solid torus, chi 0
            v = np.vstack([torus_mat(n).vertices, torus_mat(n).vertices + [0, 0, 0.01]])
            ctx.save("contracted_tets", (v, [[i, (i + 1) % n, n + i, n + (i + 1) % n] for i in range(n)]))

    register_stage("ring_of_tets")(RingOfTets)
    try:
        cfg = compose_cfg(
            "input.shape=torus",
            "input.shape_resolution=64",
            "pipeline.stages=[sample,ring_of_tets,evaluate]",
            "evaluate.samples=500",
            "evaluate.resolution=32",
            "evaluate.picture=false",
        )
        res = Pipeline(cfg, tmp_path / "run", tmp_path).run()
    finally:
        STAGES.remove("ring_of_tets")
    m = res.load("metrics")
    assert m["chi"] == 0 and m["chi_rule"].startswith("V - E + F - C") and m["chi_membrane"] == 0


def test_edge_count_includes_lone_edges():
    mesh = get_shape("torus").mesh(32)
    m = score_mat(torus_mat(40), mesh.vertices, mesh.faces, samples=300, resolution=24)
    assert m["edges"] == 40 and m["faces"] == 0 and m["chi"] == 0  # a loop of 40 cones


def test_evaluate_reference_scores_a_sparse_cloud_against_its_source(compose_cfg, tmp_path):
    """A 600-point torus cloud scored as itself measures its gaps; against the mesh it came from (given in the
    input's units, 10x here) the exact MAT scores ~0. A reference that is not a file fails the config check."""
    import trimesh

    from qmdf.api import compose
    from qmdf.artifacts import MAT, POINTS
    from qmdf.config import check
    from qmdf.errors import ConfigError
    from qmdf.geometry.sampling import sample_surface
    from qmdf.pipeline import Pipeline
    from qmdf.registry import STAGES
    from qmdf.stage import Stage, register_stage

    torus = get_shape("torus").mesh(256)
    v = np.asarray(torus.vertices) * 10.0
    trimesh.Trimesh(v, torus.faces).export(tmp_path / "torus.ply")
    pts = sample_surface(v, np.asarray(torus.faces), 600, np.random.default_rng(0)).points
    np.savetxt(tmp_path / "cloud.xyz", pts)

    class ExactTorusMat(Stage):
        inputs = {"points": POINTS}
        outputs = {"mat": MAT}

        def run(self, ctx):  # the cloud's bounding box is the torus's, up to its sampling
            ctx.save("mat", torus_mat())

    register_stage("exact_torus_mat")(ExactTorusMat)
    try:
        base = [
            f"input.path={tmp_path / 'cloud.xyz'}",
            "pipeline.stages=[sample,exact_torus_mat,evaluate]",
            "evaluate.samples=3000",
            "evaluate.resolution=48",
            "evaluate.picture=false",
        ]
        own = Pipeline(compose_cfg(*base), tmp_path / "own", tmp_path).run().load("metrics")
        ref = (
            Pipeline(compose_cfg(*base, f"evaluate.reference={tmp_path / 'torus.ply'}"), tmp_path / "ref", tmp_path)
            .run()
            .load("metrics")
        )
    finally:
        STAGES.remove("exact_torus_mat")
    assert own["reference"] == "input points" and own["chamfer"] > 5e-3  # the gaps of 600 points
    assert own["chamfer"] < own["reference_gap"] / 2 and "reference_gap" not in ref  # the floor the gaps set
    assert ref["reference"].startswith("evaluate.reference (torus.ply)") and ref["chamfer"] < 2e-3
    with pytest.raises(ConfigError, match="evaluate.reference"):
        check(compose([f"evaluate.reference={tmp_path / 'missing.ply'}"]))
