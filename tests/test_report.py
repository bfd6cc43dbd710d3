"""report.html: one self-contained page per run (no network needed), with the 3D view and its layers, the
pictures, the metrics beside the paper's, the stage times and the config; opened in a real headless browser
where one is installed."""

from __future__ import annotations

import re

import pytest

from conftest import FAST


@pytest.fixture(scope="module")
def report_run(tmp_path_factory):
    from qmdf.api import run

    tmp = tmp_path_factory.mktemp("report")
    res = run(
        None,
        [
            f"cache.dir={tmp / 'cache'}",
            *FAST,
            "pipeline.report=true",
            "train.trainer.picture=true",
            "export.picture=true",
        ],
        run_dir=tmp / "run",
    )
    return res.run_dir


@pytest.mark.slow
def test_the_run_writes_a_self_contained_report(report_run):
    page = (report_run / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    # self-contained: plotly's JavaScript inlined, nothing fetched, pictures as data URIs
    assert not re.search(r"<script[^>]+src=", page) and not re.search(r"<(img|link)[^>]+(src|href)=\"http", page)
    assert "Plotly.newPlot" in page and 'id="mat-view"' in page
    for layer in (
        "MAT (by radius)",
        "input points",
        "covering (before contraction)",
        "covering after contraction",
        "reconstruction",
    ):
        assert f'"name":"{layer}"' in page, layer
    assert page.count("data:image/png;base64,") >= 3  # slices, losses, mat
    assert "<td>CD</td>" in page and "<h2>Stages</h2>" in page and "<td>contract</td>" in page
    assert "<td>structure: vertices outside</td>" in page and "<td>structure: edges outside</td>" in page
    assert "<h2>Config</h2>" in page and "contract:" in page
    assert len(page) < 12e6


def test_the_report_cli_rewrites_it_and_refuses_a_non_run(report_run, tmp_path):
    from qmdf.report import main

    (report_run / "report.html").unlink()
    assert main([str(report_run)]) == 0 and (report_run / "report.html").exists()
    assert main([str(tmp_path)]) == 2


def test_the_3d_view_renders_in_a_headless_browser(report_run, tmp_path):
    playwright = pytest.importorskip("playwright.sync_api", reason="playwright (and its Chromium) not installed")
    with playwright.sync_playwright() as p:
        import shutil

        try:
            browser = p.chromium.launch()
        except Exception as exc:  # the package without its browser download: the system's Chromium, if any
            system = shutil.which("chromium") or shutil.which("chromium-browser")
            if system is None:
                pytest.skip(f"no Chromium for playwright: {exc}")
            browser = p.chromium.launch(executable_path=system)
        page = browser.new_page()
        page.goto((report_run / "report.html").as_uri())
        page.wait_for_selector("#mat-view canvas", timeout=30_000)
        shot = page.locator("#mat-view").screenshot(path=str(tmp_path / "view.png"))
        browser.close()
    from io import BytesIO

    import numpy as np
    from PIL import Image

    pixels = np.asarray(Image.open(BytesIO(shot)).convert("L"), float)
    assert pixels.std() > 5  # not blank


def test_the_viewer_serves_every_layer_of_a_run_and_toggles_them(report_run, tmp_path):
    viser = pytest.importorskip("viser", reason="the viewer's extra (qmdf[view]) not installed")
    import socket

    from qmdf.pipeline import RunResult
    from qmdf.view import build_scene, main

    with socket.socket() as s:  # a free port
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    try:
        scene = build_scene(server, RunResult.open(report_run))
        for layer in (
            "MAT (colour: radius)",
            "input points",
            "covering (before contraction)",
            "covering after contraction",
            "reconstruction",
        ):
            assert layer in scene.layers and layer in scene.controls
        assert any(name.startswith("medial balls") for name in scene.layers)
        # the MAT shows at start, the rest one click away; a checkbox sets its layer's visibility
        assert scene.layers["MAT (colour: radius)"].visible and not scene.layers["reconstruction"].visible
        box = scene.controls["reconstruction"]
        box.value = True
        assert scene.layers["reconstruction"].visible
    finally:
        server.stop()
    assert main([str(tmp_path)]) == 2  # not a run: one line, no traceback
