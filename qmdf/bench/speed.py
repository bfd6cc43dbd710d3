"""``python -m qmdf.bench speed``: the default pipeline on the teacup and the bunny, per stage wall time, CPU time
(all threads) and peak memory, each beside its floor: the same work done by the fastest well-kept tool for it,
timed here on the run's own artifacts, so each stage's ratio to its floor is visible.

Floors (what a stage cannot beat, not what it should equal):
- sample: reading (or making) the input;
- train: the same number of steps of the same network and batch in a plain torch loop (Adam, an L1 loss, one
  backward): no Lightning, no supervision, no data assembly, no second derivatives;
- cover: one scikit-image marching-cubes pass over a grid of the cover's resolution (values already computed);
- contract: one sparse Laplacian product per iteration over the covering (the per-iteration linear algebra);
- sheet: the membrane decimated to the sheet's vertex count by one fast quadric collapse (fast-simplification:
  no link condition, no thinning, no centring, no coverage);
- export: one vectorised envelope evaluation of the MAT meshed at the reconstruction's resolution;
- evaluate: one SciPy KD-tree built on and queried with the sample count.
Beside the whole run: the classic Voronoi-pole MAT (Delaunay and inner poles, ``qmdf.geometry.poles``) of the run's
own surface samples, timed in the same process after it.
Time it with nothing else running: two torch processes on 2 cores slow each other far more than 2x.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from qmdf.bench.child import last_error, run_child
from qmdf.bench.models import default_data_dir

MODELS = {"teacup": "input.shape=teacup", "bunny": "input.path={data}/organic/bunny.off"}


def _timed(fn, repeat: int = 1) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def floors(run_dir: Path) -> dict[str, tuple[float, str]]:
    """stage -> (floor seconds, what was timed), from the finished run in ``run_dir``."""
    import yaml

    from qmdf.pipeline import RunResult

    run = RunResult.open(run_dir)
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    out: dict[str, tuple[float, str]] = {}
    inp = cfg["input"]
    if inp.get("path"):
        from qmdf.geometry.io import load_geometry

        out["sample"] = (_timed(lambda: load_geometry(Path(inp["path"]))), "read the input file")
    else:
        from qmdf.geometry.shapes import get_shape

        out["sample"] = (_timed(lambda: get_shape(inp["shape"]).mesh(inp["shape_resolution"])), "make the shape's mesh")
    if "field" in run.artifacts and "training" in run.artifacts:
        out["train"] = (
            _train_floor(run, cfg["train"]["optim"]),
            f"{cfg['train']['optim']['steps']} plain torch steps, same net and batch",
        )
    res = int(cfg["cover"]["resolution"])
    out["cover"] = (_marching_cubes_floor(res), f"one marching-cubes pass over {res}^3")
    if "covering" in run.artifacts:
        out["contract"] = (
            _laplacian_floor(run.load("covering"), int(cfg["contract"]["iterations"])),
            f"{cfg['contract']['iterations']} sparse Laplacian products",
        )
    if "membrane" in run.artifacts and "sheet" in run.artifacts:
        n = len(run.load("sheet").vertices)
        out["sheet"] = (
            _simplify_floor(run.load("membrane"), n),
            f"the membrane to {n} vertices by one fast quadric collapse",
        )
    if "mat" in run.artifacts:
        from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh

        mat = run.load("mat")
        r = int(cfg["export"]["reconstruction_resolution"])
        out["export"] = (
            _timed(lambda: reconstruct_mesh(EnvelopeUnion.from_mat(mat), r)),
            f"the MAT's envelope meshed at {r}^3",
        )
    n = int(cfg["evaluate"]["samples"])
    out["evaluate"] = (_kdtree_floor(n), f"a KD-tree of {n} samples queried with {n}")
    return out


def pole_baseline(run_dir: Path) -> tuple[float | None, int]:
    """Seconds of the classic Voronoi-pole MAT (``qmdf.geometry.poles``: qhull's Delaunay and the inner poles) of
    the run's own surface samples with their normals, and their count; None where the samples carry no normals
    (a raw cloud: the poles need them)."""
    from qmdf.geometry.poles import inner_poles
    from qmdf.pipeline import RunResult

    points = RunResult.open(run_dir).load("points")
    if points.normals is None:
        return None, len(points.points)
    return round(_timed(lambda: inner_poles(points.points, points.normals)), 2), len(points.points)


def _train_floor(run, optim: dict) -> float:
    import torch

    from qmdf.fields.module import build_net

    meta = torch.load(run.path("field"), map_location="cpu", weights_only=True)
    net = build_net(meta["backbone"], meta["backbone_params"])
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, fused=True)
    surface = int(optim["surface_batch"])
    batch = surface + int(optim["volume_batch"])
    x = torch.rand(batch, 3) - 0.5
    target = torch.zeros(batch)
    steps, probe = int(optim["steps"]), 50

    def loop():  # the step the train stage takes (mf of the volume rows), without its sampling and bookkeeping
        for _ in range(probe):
            sdf, mf = net(x, medial_from=surface)
            loss = (sdf - target).abs().mean() + (mf - target[surface:]).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()

    return _timed(loop) * steps / probe


def _marching_cubes_floor(res: int) -> float:
    from skimage.measure import marching_cubes

    g = np.linspace(-0.55, 0.55, res, dtype=np.float32)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    values = np.sqrt(x * x + y * y + z * z) - 0.3
    return _timed(lambda: marching_cubes(values, 0.0))


def _simplify_floor(membrane, vertices: int) -> float:
    import fast_simplification

    v, f = np.asarray(membrane.vertices, np.float32), np.asarray(membrane.faces, np.int32)
    # a closed triangle mesh has about twice as many faces as vertices
    return _timed(lambda: fast_simplification.simplify(v, f, target_count=min(len(f), 2 * vertices)))


def _laplacian_floor(covering, iterations: int) -> float:
    from qmdf.medial.contraction import umbrella

    x = np.asarray(covering.vertices, np.float64)
    L = umbrella(len(x), np.asarray(covering.faces))

    def loop():
        for _ in range(iterations):
            L @ x

    return _timed(loop)


def _kdtree_floor(n: int) -> float:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    a, b = rng.random((n, 3)), rng.random((n, 3))
    return _timed(lambda: cKDTree(a).query(b, workers=-1))


def run_model(name: str, override: str, out: Path, overrides: list[str], timeout: int) -> dict:
    run_dir = out / name
    cmd = [sys.executable, "-m", "qmdf", override, f"hydra.run.dir={run_dir}", "cache.enabled=false", *overrides]
    code, wall, _ = run_child(cmd, run_dir, timeout)
    row: dict = {"model": name, "wall_s": round(wall, 1), "returncode": code}
    if code != 0:
        row["error"] = last_error(run_dir)
        return row
    manifest = json.loads((run_dir / "manifest.json").read_text())
    floor = floors(run_dir)
    row["stages"] = [
        {
            "stage": s["name"],
            "wall_s": s["seconds"],
            "cpu_s": s.get("cpu_seconds"),
            "peak_mb": s.get("peak_rss_mb"),
            "floor_s": floor.get(s["name"], (None, ""))[0],
            "floor": floor.get(s["name"], (None, "-"))[1],
        }
        for s in manifest["stages"]
    ]
    row["pipeline_s"] = round(sum(s["seconds"] for s in manifest["stages"]), 1)
    row["poles_s"], row["poles_samples"] = pole_baseline(run_dir)
    row["cover_to_evaluate_s"] = round(
        sum(
            s["seconds"]
            for s in manifest["stages"]
            if s["name"] in ("cover", "contract", "sheet", "export", "evaluate")
        ),
        1,
    )
    return row


def print_table(rows: list[dict]) -> None:
    for row in rows:
        print(
            f"\n{row['model']}: whole run {row['wall_s']} s (process start included)"
            + (
                f", pipeline {row['pipeline_s']} s, cover..evaluate {row['cover_to_evaluate_s']} s"
                if "stages" in row
                else f": failed ({row.get('error')})"
            )
        )
        if "stages" not in row:
            continue
        if row.get("poles_s"):
            print(
                f"  the Voronoi poles of the same {row['poles_samples']} samples: {row['poles_s']} s; the pipeline "
                f"{row['pipeline_s'] / row['poles_s']:.1f}x that"
            )
        print(f"  {'stage':<10}{'wall s':>8}{'CPU s':>8}{'peak MB':>9}{'floor s':>9}{'ratio':>8}  floor")
        for s in row["stages"]:
            f = s["floor_s"]
            ratio = (f"{s['wall_s'] / f:.1f}x" if s["wall_s"] / f < 10 else f"{s['wall_s'] / f:.0f}x") if f else "-"
            print(
                f"  {s['stage']:<10}{s['wall_s']:>8.1f}{s['cpu_s'] or 0:>8.1f}{s['peak_mb'] or 0:>9.0f}"
                f"{f if f is not None else float('nan'):>9.2f}{ratio:>8}  {s['floor']}"
            )
    print(
        "\nwall and CPU (all threads) per stage from the run's manifest; floor: the same work by the fastest "
        "tool for it (see python -m qmdf.bench speed --help), timed on the run's artifacts."
    )


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m qmdf.bench speed",
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--json", type=Path, help="write the rows as JSON")
    ap.add_argument("--only", default="", help="comma-separated: teacup, bunny")
    ap.add_argument("--data", type=Path, default=default_data_dir(), help="benchmark data (default ../shared/data)")
    ap.add_argument("--out", type=Path, default=Path("runs/bench/speed"), help="run directories")
    ap.add_argument("--timeout", type=int, default=3600)
    ap.add_argument("overrides", nargs="*", help="config overrides for every run")
    args = ap.parse_args(argv)
    only = [m for m in args.only.split(",") if m]
    rows = []
    for name, override in MODELS.items():
        if only and name not in only:
            continue
        if "{data}" in override and not (args.data / "organic" / "bunny.off").exists():
            print(f"{name}: skipped ({args.data} has no organic/bunny.off)", file=sys.stderr)
            continue
        rows.append(run_model(name, override.format(data=args.data), args.out, args.overrides, args.timeout))
        print_table(rows[-1:])
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=2))
    return 0 if all(r["returncode"] == 0 for r in rows) else 1
