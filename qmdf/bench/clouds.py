"""``python -m qmdf.bench clouds``: how raw clouds (no normals) are oriented, on every mesh of the data.

From every mesh in ``../shared/data`` (organic, cad, defects) and the embedded teacup and cyclide, seeded clouds
are drawn with the degradations the pipeline uses (``qmdf.geometry.degradations``): 20k clean points; 2,000 and
1,000; 20k with 0.5% and 1% Gaussian noise (of the bounding-box diagonal); 20k with three missing balls; a
density ramp. Each is oriented by every method of ``train.supervision.orientation`` and scored against the
source's outward normals: the share within 90 degrees (orientation accuracy), the median angle, the share the
cloud's own winding number contradicts, and the seconds: the step that decides inside from outside, alone.

``--pipeline`` runs the whole pipeline on each cloud instead (``python -m qmdf`` in its own process, as ``bench
models``, the cloud drawn by the sample stage's own degradations and normals dropped), scored against the source
mesh: the field's sign accuracy, CD / HD / chi, boundary smoothness, vertices, the run's verdict and wall time, and
beside them the same source's mesh-route CD (one more run per source; ``--no-mesh-route`` skips it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from qmdf.bench.models import default_data_dir

#: name -> the degradations (as in ``sample.degradations``) applied to 20k samples of the source mesh
CLOUDS = {
    "clean_20k": {},
    "sparse_2000": {"subsample": {"n": 2000}},
    "sparse_1000": {"subsample": {"n": 1000}},
    "noise_0.5%": {"noise": {"sigma": 0.005}},
    "noise_1%": {"noise": {"sigma": 0.01}},
    "holes_3": {"missing_region": {"count": 3}},
    "ramp": {"nonuniform": {}},
}
CATEGORIES = ("organic", "cad", "defects")
METHODS = ("wnnc", "propagation")


def sources(data: Path) -> list[tuple[str, object]]:
    """(name, loader) of every source mesh: the data's meshes where it is present, and two procedural shapes."""
    from qmdf.geometry.shapes import get_shape

    out = [(name, (lambda name=name: _procedural(get_shape(name)))) for name in ("teacup", "cyclide")]
    for category in CATEGORIES:
        for path in sorted((data / category).glob("*")) if (data / category).is_dir() else []:
            out.append((path.stem, (lambda path=path: _from_file(path))))
    return out


def _procedural(shape):
    mesh = shape.mesh(128)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def _from_file(path: Path):
    from qmdf.geometry.io import load_geometry

    geom = load_geometry(path)
    return geom.points.points, geom.faces


def make_cloud(vertices, faces, degradations: dict, seed: int = 0):
    """The cloud and its true outward normals, in the unit box."""
    from qmdf import schema
    from qmdf.geometry.degradations import DEGRADATIONS
    from qmdf.geometry.medial_radius import mesh_outward_normals
    from qmdf.geometry.normalize import Normalization
    from qmdf.geometry.pointset import PointSet
    from qmdf.geometry.sampling import sample_surface

    v = Normalization.fit(vertices).to_unit(vertices)
    points = sample_surface(v, faces, 20_000, np.random.default_rng(seed))
    normals, _ = mesh_outward_normals(points.points, points.normals, v, faces)
    points = PointSet(points.points, normals)
    for i, (name, params) in enumerate(degradations.items()):
        entry = DEGRADATIONS.get(name)
        points = entry.obj(points, schema.build(entry.config, params), np.random.default_rng([seed, i]))
    return points.points, points.normals


def score(points: np.ndarray, true: np.ndarray, method: str) -> dict:
    from qmdf.geometry.orientation import estimate_oriented_normals

    t0 = time.perf_counter()
    est, _, info = estimate_oriented_normals(points, method=method)
    seconds = time.perf_counter() - t0
    cos = np.clip((est * true).sum(1), -1, 1)
    return {
        "orientation": float(np.mean(cos > 0)),
        "median_angle": float(np.degrees(np.median(np.arccos(cos)))),
        "inconsistent": float(info.get("inconsistent_share", float("nan"))),
        "seconds": round(seconds, 2),
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m qmdf.bench clouds", description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=default_data_dir(), help="benchmark data (default ../shared/data)")
    ap.add_argument("--only", default="", help="comma-separated source names")
    ap.add_argument("--clouds", default=",".join(CLOUDS), help="comma-separated cloud kinds")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated orientation methods")
    ap.add_argument("--json", type=Path, help="write the rows as a JSON list")
    ap.add_argument("--pipeline", action="store_true", help="run the whole pipeline on each cloud (minutes a row)")
    ap.add_argument("--no-mesh-route", action="store_true", help="with --pipeline: no mesh-route run per source")
    ap.add_argument("--out", type=Path, default=Path("runs/bench/clouds"), help="with --pipeline: run directories")
    ap.add_argument("--timeout", type=int, default=3600, help="with --pipeline: seconds per run")
    ap.add_argument("overrides", nargs="*", help="with --pipeline: config overrides for every run")
    args = ap.parse_args(argv)
    if args.pipeline:
        return pipeline_main(args)
    only = {s for s in args.only.split(",") if s}
    kinds = [k for k in args.clouds.split(",") if k]
    methods = [m for m in args.methods.split(",") if m]
    rows = []
    print(f"{'source':<22}{'cloud':<13}{'points':>7}  " + "  ".join(f"{m:>30}" for m in methods), flush=True)
    for name, load in sources(args.data):
        if only and name not in only:
            continue
        vertices, faces = load()
        for kind in kinds:
            points, true = make_cloud(vertices, faces, CLOUDS[kind])
            row = {"source": name, "cloud": kind, "points": int(len(points))}
            cells = []
            for method in methods:
                row[method] = s = score(points, true, method)
                cells.append(
                    f"{100 * s['orientation']:6.2f}% {s['median_angle']:5.1f}deg {100 * s['inconsistent']:5.2f}% "
                    f"{s['seconds']:5.1f}s"
                )
            rows.append(row)
            print(f"{name:<22}{kind:<13}{len(points):>7}  " + "  ".join(f"{c:>30}" for c in cells), flush=True)
    for method in methods:
        for kind in kinds:
            got = [r[method]["orientation"] for r in rows if r["cloud"] == kind]
            if got:
                print(
                    f"{method:<12}{kind:<13} min {100 * min(got):6.2f}%  mean {100 * np.mean(got):6.2f}%  n={len(got)}"
                )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


def degradation_overrides(kind: str) -> list[str]:
    """The sample stage's overrides that draw cloud ``kind`` from the input mesh, its normals dropped."""
    out = []
    for name, params in CLOUDS[kind].items():
        out += [f"+sample.degradations.{name}.{key}={_hydra_value(value)}" for key, value in params.items()]
        out += [] if params else [f"+sample.degradations.{name}={{}}"]  # its defaults
    return out + ["+sample.degradations.drop_normals.enabled=true"]


def _hydra_value(value) -> str:
    return "[" + ",".join(map(str, value)) + "]" if isinstance(value, (list, tuple)) else str(value)


def pipeline_main(args) -> int:
    from qmdf.bench.models import discover, run_model

    only = {s for s in args.only.split(",") if s}
    kinds = [k for k in args.clouds.split(",") if k]
    models = [
        m
        for m in discover(args.data)
        if (m.category in CATEGORIES or m.name in ("teacup", "cyclide")) and (not only or m.name in only)
    ]
    overrides = ["cache.enabled=false", *args.overrides]
    out = args.out / time.strftime("%Y-%m-%d_%H-%M-%S")
    rows = []
    for model in models:
        mesh_cd = None
        if not args.no_mesh_route:
            print(f"{model.name}: the mesh route ...", file=sys.stderr, flush=True)
            mesh_cd = run_model(model, out / "mesh", overrides, args.timeout).get("cd")
        for kind in kinds:
            print(f"{model.name}: {kind} ...", file=sys.stderr, flush=True)
            row = run_model(model, out / kind, overrides + degradation_overrides(kind), args.timeout)
            row.update(source=model.name, cloud=kind, mesh_cd=mesh_cd)
            row["quality"] = _quality(out / kind / model.name)
            rows.append(row)
            print_pipeline_row(row)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


def _quality(run_dir: Path) -> str:
    manifest = run_dir / "manifest.json"
    if not manifest.exists():
        return "failed"
    m = json.loads(manifest.read_text())
    reasons = m.get("quality_reasons") or []
    return str(m.get("quality", "unchecked")) + (f" ({'; '.join(reasons)})" if reasons else "")


def print_pipeline_row(r: dict) -> None:
    def f(v, scale=1.0, digits=2):
        return "-" if v is None else f"{v * scale:.{digits}f}"

    ratio = r["cd"] / r["mesh_cd"] if r.get("cd") and r.get("mesh_cd") else None
    print(
        f"{r['source']:<16}{r['cloud']:<13}sign {f(r.get('sign'), 100, 2):>6}%  CD {f(r.get('cd'), 1e3):>6}e-3 "
        f"HD {f(r.get('hd'), 1e3, 1):>6}e-3  chi {r.get('chi', '-')!s:>5} ({r.get('expected_chi', '-')!s})  "
        f"C_avg {f(r.get('smoothness'), 1, 3):>6}  V {r.get('vertices', '-')!s:>5}  "
        f"mesh CD {f(r.get('mesh_cd'), 1e3)}e-3 "
        f"(x{f(ratio, 1, 1)})  {r['wall_s']:.0f} s  {r.get('quality')}",
        flush=True,
    )
