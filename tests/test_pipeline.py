"""The pipeline runner: wiring checked at start, content-keyed caching, atomic stage outputs, the manifest."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from qmdf.artifacts import JSON, POINTS
from qmdf.errors import InputError, PipelineError
from qmdf.pipeline import Pipeline
from qmdf.plugins.registry import load_all
from qmdf.registry import STAGES
from qmdf.rundir import new_run_name
from qmdf.schema import param
from qmdf.stage import Stage, register_stage

load_all()
RUNS: dict[str, int] = {}


@dataclass
class ScaleConfig:
    factor: float = param(2.0, gt=0)


class Scale(Stage):
    """Scale the points."""

    Config = ScaleConfig
    inputs = {"points": POINTS}
    outputs = {"scaled": POINTS}

    def run(self, ctx):
        RUNS["scale"] = RUNS.get("scale", 0) + 1
        pts = ctx.load("points")
        ctx.save("scaled", pts.with_points(pts.points * ctx.cfg.factor))


class Count(Stage):
    """Count the scaled points and measure their extent."""

    inputs = {"scaled": POINTS}
    outputs = {"count": JSON}

    def run(self, ctx):
        RUNS["count"] = RUNS.get("count", 0) + 1
        pts = ctx.load("scaled").points
        ctx.save("count", {"n": len(pts), "extent": float(np.ptp(pts, axis=0).max())})


class NeedsField(Stage):
    inputs = {"field": POINTS}
    outputs = {"x": JSON}


class Boom(Stage):
    inputs = {"points": POINTS}
    outputs = {"x": JSON}

    def run(self, ctx):
        (ctx.stage_dir / "half_written.txt").write_text("partial")
        raise InputError("something about the input is wrong")


class Lazy(Stage):
    inputs = {"points": POINTS}
    outputs = {"x": JSON}

    def run(self, ctx):
        pass


TEST_STAGES = {"scale": Scale, "count": Count, "needs_field": NeedsField, "boom": Boom, "lazy": Lazy}


@pytest.fixture(autouse=True)
def test_stages():
    for name, cls in TEST_STAGES.items():
        register_stage(name)(cls)
    RUNS.clear()
    yield
    for name in TEST_STAGES:
        STAGES.remove(name)


def run(compose_cfg, tmp_path, *overrides, run_dir=None):
    cfg = compose_cfg(*overrides)
    out = run_dir or tmp_path / "runs" / new_run_name()
    return Pipeline(cfg, out, tmp_path).run()


def statuses(result):
    return [(s["name"], s["status"]) for s in result.manifest["stages"]]


def test_wiring_is_checked_before_anything_runs(compose_cfg, tmp_path):
    with pytest.raises(PipelineError) as err:
        run(compose_cfg, tmp_path, "pipeline.stages=[sample,needs_field,count]")
    msg = str(err.value)
    assert "stage 'needs_field' (#1) reads 'field', which no earlier stage makes" in msg
    assert "stage 'count' (#2) reads 'scaled', which no earlier stage makes (made by: scale)" in msg
    assert not (tmp_path / "runs").exists()
    assert RUNS == {}


def test_results_are_reused_and_invalidated_by_content(compose_cfg, tmp_path):
    stages = "pipeline.stages=[sample,scale,count]"
    first = run(compose_cfg, tmp_path, stages)
    assert statuses(first) == [("sample", "ran"), ("scale", "ran"), ("count", "ran")]
    assert first.load("count")["n"] == 2000
    again = run(compose_cfg, tmp_path, stages)
    assert statuses(again) == [("sample", "cached"), ("scale", "cached"), ("count", "cached")]
    assert again.load("count") == first.load("count") and RUNS == {"scale": 1, "count": 1}
    # a downstream change reuses the upstream work
    changed = run(compose_cfg, tmp_path, stages, "scale.factor=3")
    assert statuses(changed) == [("sample", "cached"), ("scale", "ran"), ("count", "ran")]
    assert changed.load("count")["extent"] == pytest.approx(first.load("count")["extent"] * 1.5)
    # an upstream change reaches every stage below it
    upstream = run(compose_cfg, tmp_path, stages, "seed=1")
    assert statuses(upstream) == [("sample", "ran"), ("scale", "ran"), ("count", "ran")]


def test_force_recomputes_and_identical_content_stops_the_cascade(compose_cfg, tmp_path):
    stages = "pipeline.stages=[sample,scale,count]"
    run(compose_cfg, tmp_path, stages)
    forced = run(compose_cfg, tmp_path, stages, "cache.force=[scale]")
    # scale ran again and wrote the same bytes, so count's inputs are unchanged: it stays cached
    assert statuses(forced) == [("sample", "cached"), ("scale", "ran"), ("count", "cached")]
    everything = run(compose_cfg, tmp_path, stages, "cache.force=[all]")
    assert [s for _, s in statuses(everything)] == ["ran"] * 3
    off = run(compose_cfg, tmp_path, stages, "cache.enabled=false")
    assert [s for _, s in statuses(off)] == ["ran"] * 3


def test_a_changed_input_file_is_not_served_from_the_cache(compose_cfg, tmp_path):
    path = tmp_path / "cloud.xyz"
    rng = np.random.default_rng(0)
    np.savetxt(path, rng.normal(size=(300, 3)))
    a = run(compose_cfg, tmp_path, "pipeline.stages=[sample]", "input.path=cloud.xyz")
    assert statuses(a) == [("sample", "ran")]
    assert statuses(run(compose_cfg, tmp_path, "pipeline.stages=[sample]", "input.path=cloud.xyz")) == [
        ("sample", "cached")
    ]
    np.savetxt(path, rng.normal(size=(300, 3)))
    b = run(compose_cfg, tmp_path, "pipeline.stages=[sample]", "input.path=cloud.xyz")
    assert statuses(b) == [("sample", "ran")]
    assert not np.allclose(a.load("points").points, b.load("points").points)


def test_relative_input_paths_resolve_against_the_callers_directory(compose_cfg, tmp_path):
    (tmp_path / "data").mkdir()
    np.save(tmp_path / "data" / "p.npy", np.random.default_rng(0).normal(size=(100, 3)))
    res = run(compose_cfg, tmp_path, "pipeline.stages=[sample]", "input.path=data/p.npy")
    assert len(res.load("points")) == 100


def test_a_failing_stage_leaves_no_complete_looking_output(compose_cfg, tmp_path):
    out = tmp_path / "runs" / "failing"
    with pytest.raises(InputError, match="something about the input"):
        run(compose_cfg, tmp_path, "pipeline.stages=[sample,boom]", run_dir=out)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "failed" and "something about the input" in manifest["error"]
    assert [s["name"] for s in manifest["stages"]] == ["sample"]
    assert sorted(p.name for p in out.iterdir()) == ["00_sample", "config.yaml", "manifest.json"]
    assert not list((tmp_path / "cache").glob("boom/*/artifacts.json"))
    assert not list((tmp_path / "cache").glob("boom/*.work"))  # no empty scratch folder left behind
    with pytest.raises(InputError):
        run(compose_cfg, tmp_path, "pipeline.stages=[sample,boom]", "cache.enabled=false", run_dir=out)
    assert not (out / ".work").exists()


def test_a_stage_that_skips_an_output_fails(compose_cfg, tmp_path):
    with pytest.raises(PipelineError, match="stage 'lazy' finished without writing: x"):
        run(compose_cfg, tmp_path, "pipeline.stages=[sample,lazy]")


@pytest.mark.slow
def test_unavailable_builtin_stages_are_reported_not_pretended(compose_cfg, tmp_path):
    res = run(compose_cfg, tmp_path)  # the default pipeline names stages later issues add
    m = res.manifest
    missing = [s for s in m["pipeline"] if s not in STAGES]
    assert m["unavailable_stages"] == missing
    if missing:
        assert m["status"] == "partial" and m["not_run"][0] == missing[0]
    else:
        assert m["status"] == "complete"


def test_stop_after(compose_cfg, tmp_path):
    res = run(compose_cfg, tmp_path, "pipeline.stages=[sample,scale,count]", "pipeline.stop_after=scale")
    assert statuses(res) == [("sample", "ran"), ("scale", "ran")]
    assert res.manifest["status"] == "partial" and res.manifest["not_run"] == ["count"]


def test_manifest_records_every_artifact(compose_cfg, tmp_path):
    res = run(compose_cfg, tmp_path, "pipeline.stages=[sample,scale]")
    m = json.loads((res.run_dir / "manifest.json").read_text())
    assert m["status"] == "complete"
    arts = m["stages"][0]["artifacts"]
    assert set(arts) == {"points", "normalization", "surface", "input_info"}
    for a in arts.values():
        path = res.run_dir / a["path"]
        assert path.stat().st_size == a["bytes"] and len(a["sha256"]) == 64
    # the points before degradations are kept only when a degradation changed them (no identical copy)
    degraded = run(
        compose_cfg,
        tmp_path,
        "pipeline.stages=[sample,scale]",
        "+sample.degradations.subsample.n=500",
        run_dir=tmp_path / "runs" / "degraded",
    )
    assert len(degraded.load("clean_points")) > len(degraded.load("points")) == 500
    assert m["stages"][1]["artifacts"]["scaled"]["path"] == "01_scale/scaled.npz"
    assert (res.run_dir / "config.yaml").exists()


def test_run_names_are_unique():
    names = {new_run_name() for _ in range(1000)}
    assert len(names) == 1000


def test_a_run_whose_process_died_is_recognised_as_abandoned(compose_cfg, tmp_path, caplog):
    """After SIGKILL the manifest said 'running' forever and a hidden .01_train.partial/ stayed."""
    import socket
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    run_dir = tmp_path / "killed"
    (run_dir / ".01_train.partial").mkdir(parents=True)
    (run_dir / "manifest.json").write_text(
        json.dumps(
            {
                "status": "running",
                "pid": dead.pid,
                "host": socket.gethostname(),
                "started": "then",
                "stages": [{"name": "sample"}],
            }
        )
    )
    result = run(compose_cfg, tmp_path, "pipeline.stages=[sample]", run_dir=run_dir)
    assert result.manifest["previous"] == {
        "status": "abandoned",
        "pid": dead.pid,
        "started": "then",
        "stages_done": ["sample"],
    }
    assert not (run_dir / ".01_train.partial").exists() and "was abandoned" in caplog.text
    # a run still alive (this very process) is never taken for abandoned
    alive = tmp_path / "alive"
    alive.mkdir()
    (alive / "manifest.json").write_text(
        json.dumps({"status": "running", "pid": __import__("os").getpid(), "host": socket.gethostname(), "stages": []})
    )
    assert "previous" not in run(compose_cfg, tmp_path, "pipeline.stages=[sample]", run_dir=alive).manifest


def test_the_debug_fast_overlay_is_the_tests_fast_settings():
    """`+debug=fast` composes to exactly the settings the test suite runs with (conftest.FAST)."""
    from omegaconf import OmegaConf

    from conftest import FAST
    from qmdf.api import compose

    overlay, listed = compose(["+debug=fast"]), compose(FAST)
    assert OmegaConf.to_container(overlay) == OmegaConf.to_container(listed)


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="reads the resident size from Linux's /proc")
def test_memory_a_stage_freed_goes_back_to_the_system():
    """glibc keeps freed heap chunks resident under a live one; between stages they are handed back, so one
    stage's peak does not stack on the last one's (the teacup's run: 2.89 -> 2.68 GB)."""
    from qmdf.pipeline import release_freed_memory

    def resident_mb():
        return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

    chunks = [np.ones(8000) for _ in range(2000)]  # 64 KB each: heap chunks, under the mmap threshold
    live = np.ones(8000)  # above them, so the heap's top cannot shrink by itself
    filled = resident_mb()
    del chunks
    freed = resident_mb()
    release_freed_memory()
    trimmed = resident_mb()
    assert live.sum() == 8000
    if freed < filled - 20:
        pytest.skip("this allocator hands freed chunks back by itself")
    assert trimmed < freed - 100
