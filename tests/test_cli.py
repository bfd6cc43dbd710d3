"""The CLI as users run it: `python -m qmdf ...` in a subprocess, from their own working directory."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import FAST, manifests
from qmdf.geometry.ma_format import read_ma

STAGES_ONLY_SAMPLE = "pipeline.stages=[sample]"


def test_default_run_on_the_embedded_shape(cli):
    proc = cli(*FAST)
    assert proc.returncode == 0, proc.stderr
    (m,) = manifests(cli.cwd / "runs")
    assert m["stages"][0]["name"] == "sample" and m["stages"][0]["status"] == "ran"
    assert proc.stdout.startswith(f"qmdf {m['status']} (quality: {m['quality']}): sample ran")
    run_dir = cli.cwd / "runs" / m["_path"].split("/runs/")[1].rsplit("/", 1)[0]
    log = (run_dir / "qmdf.log").read_text()
    assert log.count("[sample] running") == 1
    # not a terminal: no progress bars, but the loops' heartbeat (here only its closing line: the run is short)
    assert "train: step: 3 of 3, loss " in log and "contract: iteration: 5 of 5, 0 s left" in log
    assert (run_dir / ".hydra" / "config.yaml").exists()
    if m["unavailable_stages"]:
        assert "not available in this version: " + ", ".join(m["unavailable_stages"]) in proc.stdout


def test_a_raw_sphere_cloud_runs_in_seconds_and_its_mat_is_one_ball(cli):
    """The raw-cloud route end to end under +debug=fast: WNNC normals, a Poisson surface, train's medial rays on it
    reused by the sheet, distances near its vertices (at a sphere's centre every face is equally near: minutes in
    the AABB tree before), and the MAT a point whose one fitted ball is the sphere."""
    rng = np.random.default_rng(0)
    p = rng.normal(size=(3000, 3))
    np.savetxt(cli.cwd / "sphere.xyz", p / np.linalg.norm(p, axis=1, keepdims=True))
    proc = cli(*FAST, "input.path=sphere.xyz")
    assert proc.returncode == 0, proc.stderr
    (m,) = manifests(cli.cwd / "runs")
    run_dir = Path(m["_path"]).parent
    sup = json.loads((run_dir / "01_train" / "training.json").read_text())["supervision"]
    assert sup["route"] == "raw_points" and sup["orientation"]["method"] == "wnnc" and sup["proxy"] == "poisson"
    assert sup["orientation"]["inconsistent_share"] < 0.01
    mat = read_ma(run_dir / "05_export" / "mat.ma")
    assert len(mat.vertices) == 1 and len(mat.faces) == 0
    assert np.linalg.norm(mat.vertices[0]) < 0.01 and abs(mat.radii[0] - 0.5) < 0.01  # the unit box: radius 0.5
    assert json.loads((run_dir / "04_sheet" / "sheet_stats.json").read_text())["fits_data"]


def test_experiment_overlay(cli):
    proc = cli("+experiment=sparse_teacup", *FAST, STAGES_ONLY_SAMPLE)
    assert proc.returncode == 0, proc.stderr
    assert "degradation subsample: 2000 -> 1500 points" in proc.stderr


def test_cfg_job_prints_the_composed_config(cli):
    proc = cli("+experiment=cut_cyclide", "--cfg", "job")
    assert proc.returncode == 0
    assert "shape: cyclide" in proc.stdout and "mode: halfspace" in proc.stdout
    assert not (cli.cwd / "runs").exists()


def test_hydra_run_dir_and_relative_input(cli):
    (cli.cwd / "clouds").mkdir()
    np.savetxt(cli.cwd / "clouds" / "c.xyz", np.random.default_rng(0).normal(size=(400, 3)))
    proc = cli("input.path=clouds/c.xyz", "hydra.run.dir=out/here", STAGES_ONLY_SAMPLE)
    assert proc.returncode == 0, proc.stderr
    m = json.loads((cli.cwd / "out" / "here" / "manifest.json").read_text())
    assert m["status"] == "complete"
    pts = np.load(cli.cwd / "out" / "here" / "00_sample" / "points.npz")["points"]
    assert pts.shape == (400, 3) and np.ptp(pts, axis=0).max() == pytest.approx(1.0)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "input.path: file not found: .*missing.xyz"),
        ("", "input file is empty"),
        ("1 2 3\nnan 0 0\n" + "0 1 0\n" * 20, "NaN or infinite"),
        (
            "0 0 0\n1 1 1\n2 2 2\n3 3 3\n4 4 4\n5 5 5\n6 6 6\n7 7 7\n8 8 8\n9 9 9\n10 10 10\n",
            "all points lie on a line",
        ),
    ],
)
def test_bad_input_one_line_no_traceback(cli, content, message):
    import re

    if content is not None:
        (cli.cwd / "missing.xyz").write_text(content)
    proc = cli("input.path=missing.xyz", STAGES_ONLY_SAMPLE)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr + proc.stdout
    errors = [ln for ln in proc.stderr.splitlines() if " ERROR " in ln or ln.startswith("  - ")]
    assert re.search(message, " ".join(errors)) and len(errors) <= 2, proc.stderr
    (m,) = manifests(cli.cwd / "runs")
    assert m["status"] == "failed" and not any(p.name == "points.npz" for p in (cli.cwd / "runs").rglob("*"))


def test_bad_config_lists_every_problem_and_exits_nonzero(cli):
    proc = cli("sample.n_points=0", "seed=-1", "pipeline.stages=[sample,smooth]")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "invalid configuration (3 problems)" in proc.stderr
    for key in ("sample.n_points", "seed", "pipeline.stages[1]: unknown stage 'smooth'"):
        assert key in proc.stderr


@pytest.mark.slow
def test_multirun_over_a_sample_parameter(cli):
    args = ["-m", "sample.n_points=500,800", "input.shape_resolution=32", STAGES_ONLY_SAMPLE]
    proc = cli(*args)
    assert proc.returncode == 0, proc.stderr
    jobs = manifests(cli.cwd / "runs" / "multirun")
    assert len(jobs) == 2 and len({j["run_dir"] for j in jobs}) == 2
    assert [j["stages"][0]["status"] for j in jobs] == ["ran", "ran"]
    assert jobs[0]["stages"][0]["key"] != jobs[1]["stages"][0]["key"]
    sizes = sorted(np.load(f"{j['run_dir']}/00_sample/points.npz")["points"].shape[0] for j in jobs)
    assert sizes == [500, 800]
    # the same sweep again: every job reuses its own earlier result, and only that one
    proc = cli(*args[:1], "sample.n_points=500,800,1000", *args[2:])
    again = [m for m in manifests(cli.cwd / "runs" / "multirun") if m["run_dir"] not in {j["run_dir"] for j in jobs}]
    by_n = {np.load(f"{m['run_dir']}/00_sample/points.npz")["points"].shape[0]: m["stages"][0] for m in again}
    assert {n: s["status"] for n, s in by_n.items()} == {500: "cached", 800: "cached", 1000: "ran"}
    assert by_n[500]["key"] in {j["stages"][0]["key"] for j in jobs}


@pytest.mark.slow
def test_joblib_launcher_runs_identical_jobs_once(cli):
    # two jobs with the same key start together: one computes, the other waits on the lock and reuses it
    proc = cli("-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "seed=5,5", *FAST, STAGES_ONLY_SAMPLE)
    assert proc.returncode == 0, proc.stderr
    jobs = manifests(cli.cwd / "runs" / "multirun")
    assert sorted(j["stages"][0]["status"] for j in jobs) == ["cached", "ran"]


def test_submitit_slurm_launcher_composes(cli):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    proc = cli("hydra/launcher=submitit_slurm", "hydra.launcher.timeout_min=30", "--cfg", "hydra")
    assert proc.returncode == 0, proc.stderr
    assert "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher" in proc.stdout
    assert "timeout_min: 30" in proc.stdout


def _external_plugin(site):
    """An installed third-party distribution with a stage, written out as pip would lay it down."""
    pkg = site / "qmdf_centroid"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(
        textwrap.dedent('''
        from dataclasses import dataclass
        from qmdf.artifacts import JSON, POINTS
        from qmdf.schema import param
        from qmdf.stage import Stage

        @dataclass
        class CentroidConfig:
            scale: float = param(1.0, gt=0)

        class Centroid(Stage):
            """Centroid of the sampled points, scaled."""
            Config = CentroidConfig
            inputs = {"points": POINTS}
            outputs = {"centroid": JSON}

            def run(self, ctx):
                pts = ctx.load("points").points
                ctx.save("centroid", {"c": (pts.mean(0) * ctx.cfg.scale).tolist(), "n": len(pts)})
    ''')
    )
    (site / "qmdf_broken").mkdir()
    (site / "qmdf_broken" / "__init__.py").write_text(
        "import numpy\nraise RuntimeError('the plugin author broke this')\n"
    )
    info = site / "qmdf_centroid-0.3.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: qmdf-centroid\nVersion: 0.3\n")
    (info / "entry_points.txt").write_text(
        "[qmdf.stages]\ncentroid = qmdf_centroid:Centroid\nbroken = qmdf_broken:Thing\n"
    )
    return {"PYTHONPATH": str(site)}


@pytest.mark.slow
def test_external_stage_plugin_runs_inside_the_pipeline(cli):
    env = _external_plugin(cli.cwd / "site")
    listing = cli(env=env, module="qmdf.plugins")
    assert (
        "centroid" in listing.stdout
        and "entry point 'centroid = qmdf_centroid:Centroid' of qmdf-centroid 0.3" in listing.stdout
    )
    assert "broken           BROKEN: RuntimeError: the plugin author broke this" in listing.stdout

    proc = cli(*FAST, "pipeline.stages=[sample,centroid]", "centroid.scale=2", env=env)
    assert proc.returncode == 0, proc.stderr
    (m,) = manifests(cli.cwd / "runs")
    assert [s["name"] for s in m["stages"]] == ["sample", "centroid"] and m["status"] == "complete"
    out = json.loads(open(f"{m['run_dir']}/01_centroid/centroid.json").read())
    pts = np.load(f"{m['run_dir']}/00_sample/points.npz")["points"]
    assert out["n"] == 2000 and np.allclose(out["c"], pts.mean(0) * 2)

    bad = cli(*FAST, "centroid.scale=-1", "pipeline.stages=[sample,centroid]", env=env)
    assert bad.returncode == 2 and "centroid.scale: must be > 0, got -1" in bad.stderr

    broken = cli(*FAST, "pipeline.stages=[sample,broken]", env=env)
    assert broken.returncode == 2 and "Traceback" not in broken.stderr
    assert (
        "stage plugin 'broken' (entry point 'broken = qmdf_broken:Thing' of qmdf-centroid 0.3) failed to load: "
        "RuntimeError: the plugin author broke this" in broken.stderr
    )


def test_plugin_listing_and_bench_help_read_well():
    """'losss' and docs cut mid-sentence in the listing; `python -m qmdf.bench --help` exited 2."""
    from qmdf.bench.__main__ import main as bench_main
    from qmdf.plugins.__main__ import listing
    from qmdf.registry import STAGES

    text = listing()
    assert "losses (entry-point group" in text and "losss" not in text
    assert STAGES.get("sheet").doc.endswith(".") and "\n" not in STAGES.get("sheet").doc
    assert bench_main(["--help"]) == 0 and bench_main([]) == 2


def test_paths_with_spaces_parentheses_and_accents_just_work(cli):
    """Hydra's grammar refused them raw; a directory was reported as "unsupported file type ''"."""
    from qmdf.__main__ import quote_paths

    assert quote_paths(["input.path=a b.ply", "input.path=plain/x.ply", "input.path='q d.ply'", "seed=1"]) == [
        "input.path='a b.ply'",
        "input.path=plain/x.ply",
        "input.path='q d.ply'",
        "seed=1",
    ]
    folder = cli.cwd / "my scans (é)"
    folder.mkdir()
    np.savetxt(folder / "c.xyz", np.random.default_rng(0).uniform(-1, 1, (300, 3)))
    proc = cli(f"input.path={folder / 'c.xyz'}", STAGES_ONLY_SAMPLE)
    assert proc.returncode == 0, proc.stderr
    proc = cli(f"input.path={folder}", STAGES_ONLY_SAMPLE)
    assert proc.returncode != 0 and "is a directory; give a mesh or point-cloud file" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_help_lists_every_setting_with_its_doc(cli):
    """`--help` printed Hydra's config dump without the schemas' docs."""
    proc = cli("--help")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert out.startswith("usage: python -m qmdf") and "+experiment=  cad_features" in out
    assert "  contract.iterations  (int = 3000)\n      optimisation steps, cosine-decayed (paper: about 3k)" in out
    assert "train.supervision.point_surface  (str = 'poisson')" in out and "  input.path  (Optional = None)" in out
    # each sheet step's settings by its key path; the tuned constants folded into one line
    assert "  sheet.step.fit.iterations  (int = 12)" in out and "sheet.expert.valley_share" not in out
    assert "  sheet.expert.*  (12 tuned constants" in out
    assert "  sheet.expert.valley_share  (float = 0.5)" in cli("--help-expert").stdout
    assert not list((cli.cwd).glob("runs")) and not list(cli.cwd.glob("outputs"))  # no run for a help
