"""The Python API: the same pipeline and configs as the CLI."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import qmdf
from qmdf.errors import ConfigError, InputError, PipelineError

from conftest import FAST


def overrides(tmp_path, *more):
    return [f"cache.dir={tmp_path / 'cache'}", *FAST, *more]


def test_run_on_an_array(tmp_path):
    pts = np.random.default_rng(0).normal(size=(700, 3)) * [3, 2, 1] + 10
    res = qmdf.run(pts, overrides(tmp_path, "pipeline.stages=[sample]"), run_dir=tmp_path / "r")
    assert res.complete
    unit = res.load("points").points
    norm = res.load("normalization")
    assert np.allclose(norm.to_input(unit), pts)
    assert (tmp_path / "r" / "qmdf.log").read_text().count("[sample] running") == 1


def test_run_on_a_trimesh_and_on_a_path(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    res = qmdf.run(mesh, overrides(tmp_path, "pipeline.stages=[sample]"), run_dir=tmp_path / "a")
    assert "surface" in res.artifacts and len(res.load("points")) == 2000
    mesh.export(tmp_path / "s.off")
    res = qmdf.run(tmp_path / "s.off", overrides(tmp_path, "pipeline.stages=[sample]"), run_dir=tmp_path / "b")
    assert len(res.load("surface").faces) == len(mesh.faces)


def test_errors_are_the_same_as_the_cli(tmp_path):
    with pytest.raises(ConfigError, match="sample.n_points"):
        qmdf.run(None, overrides(tmp_path, "sample.n_points=1"), run_dir=tmp_path / "c")
    with pytest.raises(InputError, match="all points lie on a plane"):
        qmdf.run(np.c_[np.random.rand(50, 2), np.zeros(50)], overrides(tmp_path), run_dir=tmp_path / "d")
    with pytest.raises(InputError, match="cannot use a dict"):
        qmdf.run({"points": 1}, overrides(tmp_path), run_dir=tmp_path / "e")
    # a run refused before it began leaves no folder; one that failed in a stage keeps its manifest saying so
    assert not (tmp_path / "c").exists() and not (tmp_path / "e").exists()
    assert '"status": "failed"' in (tmp_path / "d" / "manifest.json").read_text()


def test_the_api_says_where_it_writes_when_not_told(tmp_path, caplog):
    import logging

    with caplog.at_level(logging.INFO, logger="qmdf"):
        res = qmdf.run(None, overrides(tmp_path, "pipeline.stages=[sample]"), base_dir=tmp_path)
    assert res.run_dir.is_relative_to(tmp_path / "runs")
    assert f"qmdf writes this run to {res.run_dir}" in caplog.text


@pytest.mark.slow
def test_medial_axis_returns_the_mat_and_metrics(tmp_path):
    chain = [
        "input.shape=torus",
        "input.shape_resolution=192",
        "pipeline.stages=[sample,analytic_field,cover,contract,sheet,export,evaluate]",
        "cover.resolution=96",
        "cover.eps=0.015",
        "contract.iterations=300",
        "export.reconstruction_resolution=48",
        "export.picture=false",
        "evaluate.samples=2000",
        "evaluate.resolution=48",
        "evaluate.picture=false",
    ]
    mat = qmdf.medial_axis(None, overrides(tmp_path, *chain), run_dir=tmp_path / "m")
    assert mat.vertices.shape[1] == 3 and len(mat.radii) == len(mat.vertices)
    assert len(mat.faces) == 0 and len(mat.edges) == len(mat.vertices)  # the torus's axis: a closed polyline
    assert mat.metrics["chi"] == 0 and mat.metrics["chamfer"] < 1e-3
    assert np.allclose(mat.in_input_units().radii, mat.radii / mat.normalization.scale)


def test_medial_axis_says_when_the_run_made_none(tmp_path):
    with pytest.raises(PipelineError, match="made no medial axis \\(stages not run: train"):
        qmdf.medial_axis(None, overrides(tmp_path, "pipeline.stop_after=sample"), run_dir=tmp_path / "n")


def test_api_inside_an_initialised_hydra_keeps_the_callers_state(tmp_path):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    conf = tmp_path / "userconf"
    conf.mkdir()
    (conf / "app.yaml").write_text("x: 1\n")
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        res = qmdf.run(None, overrides(tmp_path, "pipeline.stages=[sample]"), run_dir=tmp_path / "h")
        assert res.complete
        assert compose(config_name="app").x == 1  # the caller's Hydra still works
    assert not GlobalHydra.instance().is_initialized()
