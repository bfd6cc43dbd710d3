"""The run's verdict on itself: each check against made-up evidence, and a run made to fail (three training
steps) says so in metrics.json, the manifest, the report and, under pipeline.strict, its exit code."""

from __future__ import annotations

import json

import pytest

from conftest import FAST, manifests
from qmdf.verdict import Evidence, verdict

GOOD = dict(
    zero_set_distance=1e-3,
    orientation={"method": "wnnc", "inconsistent_share": 0.001},
    proxy="poisson",
    proxy_pieces=1,
    sign_accuracy=0.998,
    volume=0.10,
    input_volume=0.098,
    chi=0,
    input_chi=0,
    vertices=3000,
    structure={
        "defective_vertices": 12,
        "edges_outside": 3,
        "faces_outside": 0,
        "vertices": 3000,
        "edges": 8000,
        "faces": 5000,
    },
)
STRUCTURE = GOOD["structure"]


def test_a_good_result_is_ok_and_unknown_evidence_is_not_held_against_it():
    assert verdict(Evidence(**GOOD)) == {"quality": "ok", "reasons": []}
    assert verdict(Evidence())["quality"] == "ok"


@pytest.mark.parametrize(
    "change,words",
    [
        ({"zero_set_distance": 0.03}, "passes a median 0.03 from the input points"),
        ({"orientation": {"method": "propagation", "inconsistent_share": 0.07}}, "7.0% of the estimated normals"),
        ({"proxy": "points (no closed Poisson surface: the normals contradict each other)"}, "no closed surface"),
        ({"proxy_pieces": 3}, "has 3 pieces"),
        ({"proxy_euler": (0, 1)}, "solid chi 0, 1 at a quarter of the sampling gap"),
        ({"sign_accuracy": 0.72}, "72.0% of the box"),
        ({"volume": 0.2}, "2.04x the volume"),
        ({"volume": 0.05}, "0.51x the volume"),
        ({"chi": -1163}, "chi -1163 is absurd for 3000 vertices"),
        ({"chi": -2}, "chi -2 differs from the input solid's 0"),
        ({"structure": {**STRUCTURE, "defective_vertices": 300}}, "10% of the MAT's vertices contradict the shape"),
        ({"structure": {**STRUCTURE, "faces_outside": 400}}, "8% of the MAT's faces contradict the shape"),
    ],
)
def test_each_contradiction_is_a_reason(change, words):
    v = verdict(Evidence(**{**GOOD, **change}))
    assert v["quality"] == "suspect" and len(v["reasons"]) == 1 and words in v["reasons"][0], v


def test_the_absurd_chi_grows_with_the_mat():
    assert verdict(Evidence(chi=-25, vertices=3000))["quality"] == "ok"  # genus 26 may be a shape's
    assert verdict(Evidence(chi=-25, vertices=1000))["quality"] == "suspect"
    assert verdict(Evidence(chi=-60, vertices=8000))["quality"] == "ok"


@pytest.mark.slow
def test_a_run_made_to_fail_says_so_and_fails_under_strict(cli):
    """Three training steps: the field has not learned the teacup. The run completes, writes everything, and
    calls itself suspect; with pipeline.strict=true it also exits with code 3."""
    proc = cli(*FAST, "pipeline.report=true")
    assert proc.returncode == 0, proc.stderr
    (m,) = manifests(cli.cwd / "runs")
    assert m["status"] == "complete" and m["quality"] == "suspect" and m["quality_reasons"]
    assert "(quality: suspect)" in proc.stdout and "quality: suspect: the result contradicts its input" in proc.stderr
    run_dir = cli.cwd / "runs" / m["_path"].split("/runs/")[1].rsplit("/", 1)[0]
    metrics = json.loads(next(run_dir.glob("*/metrics.json")).read_text())
    assert metrics["verdict"]["reasons"] == m["quality_reasons"]
    assert "from the input points" in " ".join(m["quality_reasons"])
    assert "quality: <b>suspect</b>" in (run_dir / "report.html").read_text()
    strict = cli(*FAST, "pipeline.strict=true")  # every stage from the cache: the verdict is the same
    assert strict.returncode == 3 and "pipeline.strict=true" in strict.stderr
