"""The benchmark runner: one model through the real CLI, scored, with the paper's numbers beside it."""
from __future__ import annotations

import json
from pathlib import Path

from mats import install_torus_mat_plugin


def test_bench_models_on_one_procedural_model(cli):
    env = install_torus_mat_plugin(cli.cwd / "site", Path(__file__).parent)
    proc = cli("models", "--only", "torus", "--data", str(cli.cwd / "no_data"), "--json", "rows.json",
               "input.shape_resolution=256", "sample.n_points=2000", "pipeline.stages=[sample,torus_mat,evaluate]",
               "evaluate.samples=2000", "evaluate.resolution=40", env=env, module="qmdf.bench")
    assert proc.returncode == 0, proc.stderr
    assert "running the procedural shapes only" in proc.stderr
    (row,) = json.loads((cli.cwd / "rows.json").read_text())
    assert row["model"] == "torus" and row["status"] == "complete" and row["returncode"] == 0
    assert row["cd"] < 2e-4 and row["chi"] == row["expected_chi"] == 0
    assert row["peak_mb"] > 50 and set(row["stage_s"]) == {"sample", "torus_mat", "evaluate"}
    assert "torus" in proc.stdout and "CD / HD: exact point-to-surface distances" in proc.stdout
