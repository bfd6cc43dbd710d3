"""The benchmark runner: one model through the real CLI, scored, with the paper's numbers beside it."""

from __future__ import annotations

import pytest

import json
from pathlib import Path

from mats import install_torus_mat_plugin


@pytest.mark.slow
def test_bench_models_on_one_procedural_model(cli):
    env = install_torus_mat_plugin(cli.cwd / "site", Path(__file__).parent)
    proc = cli(
        "models",
        "--reuse",
        "--only",
        "torus",
        "--data",
        str(cli.cwd / "no_data"),
        "--json",
        "rows.json",
        "input.shape_resolution=256",
        "sample.n_points=2000",
        "pipeline.stages=[sample,torus_mat,evaluate]",
        "evaluate.samples=2000",
        "evaluate.resolution=40",
        env=env,
        module="qmdf.bench",
    )
    assert proc.returncode == 0, proc.stderr
    assert "running the procedural shapes only" in proc.stderr
    (row,) = json.loads((cli.cwd / "rows.json").read_text())
    assert row["model"] == "torus" and row["status"] == "complete" and row["returncode"] == 0
    assert row["cd"] < 2e-4 and row["chi"] == row["expected_chi"] == 0
    assert row["peak_mb"] > 50 and set(row["stage_s"]) == {"sample", "torus_mat", "evaluate"}
    assert "torus" in proc.stdout and "CD / HD: exact point-to-surface distances" in proc.stdout


def test_bench_models_sets_a_dataset_mean_beside_the_papers():
    """SRB's mean over the scans that were scored (a failed run is left out), beside the paper's Table 1 mean."""
    from qmdf.bench.models import dataset_means

    rows = [
        {"category": "pointclouds/srb", "cd": 2e-3, "hd": 10e-3},
        {"category": "pointclouds/srb", "cd": 4e-3, "hd": 30e-3},
        {"category": "pointclouds/srb", "status": "failed"},
        {"category": "organic", "cd": 9.0, "hd": 9.0},
    ]
    (line,) = dataset_means(rows)
    assert line.startswith("pointclouds/srb mean over 2: CD 3.00e-3 HD 20.00e-3")
    assert "2.10e-3 / 15.86e-3" in line
    assert dataset_means(rows[3:]) == []


@pytest.mark.slow
def test_bench_extraction_on_the_torus(cli):
    proc = cli(
        "extraction",
        "--shapes",
        "torus",
        "--json",
        "rows.json",
        # a coarse mesh of the torus: the medial balls' bisection queries its axis, where every face around the
        # ring is about as close, the AABB tree's worst case (the 65k-face mesh: 86 s in sheet, 4k faces: 7 s)
        "input.shape_resolution=64",
        "cover.resolution=96",
        "cover.eps=0.015",
        "contract.iterations=200",
        "export.reconstruction_resolution=32",
        "export.picture=false",
        "evaluate.samples=1000",
        "evaluate.resolution=32",
        "evaluate.picture=false",
        module="qmdf.bench",
    )
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads((cli.cwd / "rows.json").read_text())
    assert (
        row["axis_mean"] < 5e-4 and abs(row["volume_ratio"]) < 0.01
    )  # within half the 1e-3 q lattice and row["chi"] == row["expected_chi"] == 0
    assert row["contract_s"] > 0  # computed, not served from a cache


@pytest.mark.slow
def test_field_scores_of_the_exact_field_are_zero():
    """The field bench's scorer on the exact ellipsoid field: descending -grad q lands on the medial disc."""
    import numpy as np

    from qmdf.bench.field import descend_q, inside_points
    from qmdf.fields.analytic import EllipsoidField

    f = EllipsoidField()
    x = inside_points("ellipsoid", 300, seed=3)
    assert np.all(f.sdf(x) < 0)
    moved = descend_q(f, x, iterations=200)
    d = f.axis_distance(moved)
    assert np.median(d) < 1e-4 and d.mean() < 2e-3
    assert d.mean() < 0.05 * f.axis_distance(x).mean()


@pytest.mark.slow
def test_recontract_replays_the_last_contraction_and_takes_overrides(cli, compose_cfg):
    """bench features --recontract: with no override it reproduces the run's own enhanced MAT (the contraction
    is deterministic to 1e-6, then the same coverage); overrides change it; a key contract does not know fails
    with its path."""
    import numpy as np
    import pytest

    from qmdf.bench.recontract import recontract
    from qmdf.errors import QmdfError
    from qmdf.geometry.ma_format import read_ma
    from qmdf.pipeline import Pipeline

    cfg = compose_cfg(
        "input.shape=box",
        "input.shape_resolution=64",
        "cover.resolution=48",
        "cover.eps=0.02",
        "contract.iterations=100",
        "export.reconstruction_resolution=32",
        "export.picture=false",
        "pipeline.stages=[sample,analytic_field,cover,contract,export,feature_detect,cover,contract,export]",
    )
    run = cli.cwd / "bench" / "box"
    Pipeline(cfg, run, cli.cwd).run()
    same = read_ma(recontract(run, cli.cwd / "again", []) / "mat.ma")
    ran = read_ma(run / "08_export" / "mat.ma")
    # the membrane's vertices come first, then export's coverage may add balls (kept only where they improve the
    # envelope's fit): a greedy choice over distances that the contraction reproduces to 1e-6, not bit for bit,
    # so the count may differ a little
    n = len(read_ma(run / "08_export" / "membrane_mat.ma").vertices)
    assert np.allclose(same.vertices[:n], ran.vertices[:n], atol=1e-6)
    added = len(ran.vertices) - n
    assert added >= 0 and abs(len(same.vertices) - len(ran.vertices)) <= 0.2 * added
    assert json.loads((run / "07_contract" / "contraction.json").read_text())["history"][-1]["zipped_vertices"] > 0
    unzipped = recontract(run, cli.cwd / "nozip", ["contract.zip_weight=0"])
    assert "zipped_vertices" not in json.loads((unzipped / "contraction.json").read_text())["history"][-1]
    assert not np.allclose(read_ma(unzipped / "mat.ma").vertices[:n], same.vertices[:n], atol=1e-4)
    with pytest.raises(QmdfError, match="contract.zip_wieght"):
        recontract(run, cli.cwd / "bad", ["contract.zip_wieght=1"])
    with pytest.raises(QmdfError, match="contract.key=value overrides only"):
        recontract(run, cli.cwd / "bad", ["cover.eps=0.1"])
    with pytest.raises(QmdfError, match="volume=surface only"):
        recontract(run, cli.cwd / "bad", ["contract.volume=tets"])
    with pytest.raises(QmdfError, match="not a run folder"):
        recontract(cli.cwd / "bench", cli.cwd / "bad", [])
    proc = cli(
        "features",
        "--recontract",
        str(cli.cwd / "bench"),
        "--json",
        "rows.json",
        "contract.iterations=50",
        module="qmdf.bench",
    )
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads((cli.cwd / "rows.json").read_text())
    assert row["shape"] == "box" and row["recontract"] == ["contract.iterations=50"]
    assert 0 <= row["sharp_within_0.01_after"] <= 1 and row["cd_after"] > 0


@pytest.mark.slow
def test_bench_speed_times_every_stage_beside_its_floor(cli):
    proc = cli(
        "speed", "--only", "teacup", "--json", "speed.json", "--out", "runs/speed", "+debug=fast", module="qmdf.bench"
    )
    assert proc.returncode == 0, proc.stderr + proc.stdout
    (row,) = json.loads((cli.cwd / "speed.json").read_text())
    stages = {s["stage"]: s for s in row["stages"]}
    assert list(stages) == ["sample", "train", "cover", "contract", "sheet", "export", "evaluate"]
    for name in ("sample", "train", "cover", "contract", "sheet", "export", "evaluate"):
        s = stages[name]
        assert s["floor_s"] > 0 and s["wall_s"] > 0 and s["cpu_s"] >= 0 and s["peak_mb"] > 0 and s["floor"], name
    assert "the membrane to" in stages["sheet"]["floor"]
    assert "one marching-cubes pass over 32^3" in proc.stdout and "ratio" in proc.stdout
    assert row["poles_s"] > 0 and row["poles_samples"] > 100 and "the Voronoi poles of the same" in proc.stdout


@pytest.mark.slow
def test_bench_faults_counts_what_survives(cli):
    """One SIGINT trial (the signals in turn over more trials), a few fuzzed files, a 2-job shared-cache multirun."""
    proc = cli(
        "faults",
        "--trials",
        "1",
        "--fuzz",
        "5",
        "--jobs",
        "2",
        "--out",
        "runs/faults",
        "--json",
        "f.json",
        module="qmdf.bench",
    )
    assert proc.returncode == 0, proc.stderr + proc.stdout
    report = json.loads((cli.cwd / "f.json").read_text())
    (trial,) = report["interrupts"]
    assert trial["signal"] == "SIGINT" and trial["stopped_exit"] == 130 and trial["rerun_exit"] == 0
    assert trial["resumed"] and trial["steps"] == 400 and trial["max_weight_diff"] < 1e-5
    fuzz = report["fuzz"]
    assert (
        fuzz["crashed"] == 0
        and fuzz["read"] + fuzz["refused"] == 35 == sum(fuzz["error_classes"].values()) + fuzz["read"]
    )
    assert report["multirun"]["complete"] == 2 and report["multirun"]["artifacts_not_matching_cache"] == 0


def test_every_cloud_of_bench_clouds_is_drawn_by_the_sample_stage(compose_cfg):
    """``bench clouds --pipeline`` draws each cloud with the sample stage's own degradations, normals dropped."""
    from qmdf import config as cfgmod
    from qmdf.bench.clouds import CLOUDS, degradation_overrides

    for kind, degradations in CLOUDS.items():
        cfg = compose_cfg(*degradation_overrides(kind))
        assert cfgmod.validate(cfg) == [], kind
        drawn = {name: dict(params) for name, params in cfg.sample.degradations.items()}
        assert drawn.pop("drop_normals") == {"enabled": True}
        assert {name: {k: drawn[name][k] for k in params} for name, params in degradations.items()} == degradations
        assert set(drawn) == set(degradations), kind


@pytest.mark.slow
def test_bench_clouds_runs_the_pipeline_on_a_raw_cloud(cli):
    proc = cli(
        "clouds",
        "--pipeline",
        "--only",
        "teacup",
        "--clouds",
        "sparse_1000",
        "--no-mesh-route",
        "--data",
        str(cli.cwd / "no_data"),
        "--json",
        "rows.json",
        "+debug=fast",
        module="qmdf.bench",
    )
    assert proc.returncode == 0, proc.stderr
    (row,) = json.loads((cli.cwd / "rows.json").read_text())
    assert row["source"] == "teacup" and row["cloud"] == "sparse_1000" and row["route"] == "raw_points"
    assert row["status"] == "complete" and row["cd"] is not None and row["quality"].startswith(("ok", "suspect"))
    assert "teacup" in proc.stdout and "sparse_1000" in proc.stdout
