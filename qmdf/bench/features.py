"""``python -m qmdf.bench features``: the sharp-feature module on CAD shapes, before and after enhancement.

Each model runs ``+experiment=cad_features`` in its own process (the first MAT stays in its stage folders);
``box-paper`` runs the paper's enhancement alone, ``box-detected`` finds the feature points by the
point-cloud route instead of the mesh, ``block-cloud1000`` runs on the 1,000-point block cloud (scored
against the block mesh).
From the input's convex sharp edges (dihedral angle above 30 degrees, sampled every 0.005 in the unit box;
the medial axis never reaches a concave edge) it reports the distance to the nearest point of the MAT's
boundary (its fold edges) before and after, the fraction of sharp-edge samples within 0.01 of it (the
issue's target: over 90% after), the fraction within 0.01 of any point of the MAT, CD / HD and the boundary
smoothness of both MATs, and the time.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from qmdf.bench.child import fmt

PROCEDURAL = ("box", "dodecahedron")
# ablations on the box: the paper's losses and energy alone (no bisector samples, no feature pull, no zip); the
# point-cloud route (two-plane fits of the input points and the paper's membrane boundary -> march -> QEM)
# instead of the mesh's dihedral angles
VARIANTS = (
    (
        "box-paper",
        ["input.shape=box", "feature_retrain.bisector_weight=0", "contract.feature_weight=0", "contract.zip_weight=0"],
    ),
    ("box-detected", ["input.shape=box", "feature_detect.source=field"]),
)
DATA_MODELS = (
    "cad/block.obj",
    "cad/sharp_sphere.off",
    "cad/abc_00000068.obj",
    "cad/abc_00000125.obj",
    "cad/abc_00000329.obj",
)
# point clouds of CAD models (features by the point-cloud route), scored against the model's mesh
CLOUD_MODELS = (("block-cloud1000", "pointclouds/sparse/block_1000.xyz", "cad/block.obj"),)


def boundary_distance(sharp: np.ndarray, mat, fold_deg: float = 150.0, spacing: float = 1e-3) -> np.ndarray:
    """Distance from each sharp-edge sample to the MAT's boundary (fold edges, densely sampled)."""
    from scipy.spatial import cKDTree

    from qmdf.geometry.metrics import fold_edges
    from qmdf.medial.features import sample_segments

    e = fold_edges(mat.vertices, mat.faces, fold_deg)
    if len(e) == 0:
        return np.full(len(sharp), np.inf)
    dense = sample_segments(mat.vertices[e[:, 0]], mat.vertices[e[:, 1]], spacing)
    return cKDTree(np.vstack([dense, mat.vertices[np.unique(e)]])).query(sharp)[0]


def score(run_dir: Path, manifest: dict, reference: Path | None = None, after: Path | None = None) -> dict:
    """``reference``: the mesh a point-cloud input was sampled from, in the input's coordinates (the run's
    normalization brings it into the unit box); without it, the run's own input surface. ``after``: the
    folder of the MAT to score as "after" (default: the run's last export)."""
    import trimesh

    from qmdf.evaluate import score_mat
    from qmdf.geometry.io import load_geometry
    from qmdf.geometry.ma_format import read_ma
    from qmdf.geometry.metrics import point_to_mesh_distance
    from qmdf.geometry.normalize import Normalization
    from qmdf.medial.features import sample_segments, sharp_mesh_segments

    dirs = {}
    for s in manifest["stages"]:
        dirs.setdefault(s["name"], []).append(run_dir / s["dir"])
    if reference is None:
        surface = trimesh.load(dirs["sample"][0] / "surface.ply", process=False)
        v, f = np.asarray(surface.vertices, np.float64), np.asarray(surface.faces)
    else:
        mesh = load_geometry(reference)
        unit = Normalization.from_dict(json.loads((dirs["sample"][0] / "normalization.json").read_text()))
        v, f = unit.to_unit(mesh.points.points), np.asarray(mesh.faces)
    sharp = sample_segments(*sharp_mesh_segments(v, f, 30.0)[:2], 0.005)
    concave = sample_segments(*sharp_mesh_segments(v, f, 30.0, convex_only=False)[:2], 0.005)
    row: dict = {"sharp_samples": int(len(sharp)), "concave_samples_left_out": int(len(concave) - len(sharp))}
    for tag, export_dir in (("before", dirs["export"][0]), ("after", after or dirs["export"][-1])):
        mat = read_ma(export_dir / "mat.ma")
        d = boundary_distance(sharp, mat)
        recon = export_dir / "reconstruction.ply"
        m = score_mat(
            mat, v, f, samples=20_000, recon_mesh=trimesh.load(recon, process=False) if recon.exists() else None
        )
        # the MAT may reach an edge without folding flat there (its tip a V): within 0.01 of any MAT point
        reach = (
            point_to_mesh_distance(sharp, mat.vertices, mat.faces) if len(mat.faces) else np.full(len(sharp), np.inf)
        )
        row.update(
            {
                f"sharp_within_0.01_{tag}": float(np.mean(d < 0.01)),
                f"sharp_mean_{tag}": float(np.mean(d)),
                f"sharp_reached_0.01_{tag}": float(np.mean(reach < 0.01)),
                f"cd_{tag}": m["chamfer"],
                f"hd_{tag}": m["hausdorff"],
                f"smoothness_{tag}": m["boundary_smoothness"],
                f"chi_{tag}": m["chi"],
            }
        )
    return row


def run_model(
    name: str, override: list[str], out: Path, overrides: list[str], timeout: float, reference: Path | None = None
) -> dict:
    from qmdf.bench.child import last_error, run_child

    run_dir = out / name
    cmd = [sys.executable, "-m", "qmdf", *override, "+experiment=cad_features", f"hydra.run.dir={run_dir}", *overrides]
    code, wall, _ = run_child(cmd, run_dir, timeout)
    if code != 0:
        return {"shape": name, "wall_s": round(wall, 1), "note": last_error(run_dir)}
    return {"wall_s": round(wall, 1), **scored_row(name, run_dir, reference)}


def scored_row(name: str, run_dir: Path, reference: Path | None = None, after: Path | None = None) -> dict:
    """The bench row of a finished run: its stage timings and scores (``after``: see ``score``)."""
    from qmdf.bench.child import last_error

    row: dict = {"shape": name}
    manifest = json.loads((run_dir / "manifest.json").read_text()) if (run_dir / "manifest.json").exists() else {}
    if manifest.get("status") != "complete":
        row["note"] = last_error(run_dir)
        return row
    stages = manifest["stages"]
    row["stage_s"] = {f"{s['index']:02d}_{s['name']}": s["seconds"] for s in stages}
    row["feature_s"] = round(sum(s["seconds"] for s in stages if s["name"] in ("feature_detect", "feature_retrain")), 1)
    row["peak_mb"] = max((s.get("peak_rss_mb") or 0) for s in stages)
    row.update(score(run_dir, manifest, reference, after))
    return row


def recontracted_row(name: str, run_dir: Path, out: Path, overrides: list[str], reference: Path | None) -> dict:
    """The row of an earlier run whose last contraction ran again with ``overrides`` (its "after")."""
    from qmdf.bench.recontract import recontract
    from qmdf.errors import QmdfError

    t0 = time.perf_counter()
    try:
        after = recontract(run_dir, out / name, overrides)
    except QmdfError as exc:
        return {"shape": name, "note": str(exc)}
    return {
        "recontract_s": round(time.perf_counter() - t0, 1),
        "recontract": overrides,
        **scored_row(name, run_dir, reference, after),
    }


def main(argv: list[str]) -> int:
    from qmdf.bench.models import default_data_dir

    ap = argparse.ArgumentParser(prog="python -m qmdf.bench features", description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--data", type=Path, default=default_data_dir())
    ap.add_argument("--only", default="", help="comma-separated model names")
    ap.add_argument("--out", type=Path, default=Path("runs/bench/features"))
    ap.add_argument("--timeout", type=float, default=3600)
    ap.add_argument("overrides", nargs="*")
    ap.add_argument("--reuse", action="store_true", help="reuse cached stage results (timings then mean nothing)")
    ap.add_argument(
        "--rescore", type=Path, help="score the runs of an earlier bench (its dated folder) again, running nothing"
    )
    ap.add_argument(
        "--recontract",
        type=Path,
        help="run the last contraction of an earlier bench's runs (its dated "
        "folder) again from their saved fields and coverings, with the contract.* overrides given, and "
        "score that as 'after'",
    )
    args = ap.parse_args(argv)
    if args.rescore and args.recontract:
        ap.error("--rescore and --recontract do not go together")
    recontract_overrides = list(args.overrides)
    if not args.reuse:
        args.overrides = ["cache.enabled=false", *args.overrides]
    models = [(s, [f"input.shape={s}"], None) for s in PROCEDURAL]
    models += [(name, override, None) for name, override in VARIANTS]
    models += [(Path(m).stem, [f"input.path={args.data / m}"], None) for m in DATA_MODELS if (args.data / m).exists()]
    models += [
        (name, [f"input.path={args.data / cloud}"], args.data / mesh)
        for name, cloud, mesh in CLOUD_MODELS
        if (args.data / cloud).exists() and (args.data / mesh).exists()
    ]
    if args.only:
        keep = set(args.only.split(","))
        models = [m for m in models if m[0] in keep]
    out = args.out / time.strftime("%Y-%m-%d_%H-%M-%S")
    rows = []
    earlier = args.rescore or args.recontract
    if earlier:
        models = [m for m in models if (earlier / m[0]).is_dir()]
    for name, override, reference in models:
        print(f"[{len(rows) + 1}/{len(models)}] {name} ...", file=sys.stderr, flush=True)
        if args.recontract:
            rows.append(recontracted_row(name, args.recontract / name, out, recontract_overrides, reference))
        elif args.rescore:
            rows.append(scored_row(name, args.rescore / name, reference))
        else:
            rows.append(run_model(name, override, out, args.overrides, args.timeout, reference))
    if args.recontract:
        given = " ".join(recontract_overrides) or "its own config"
        print(
            f"after: the last contraction of {args.recontract} run again with {given}; "
            "wall s: that contraction and its export"
        )
    head = (
        f"{'shape':<16}{'within .01 b/a':>16}{'reached b/a':>14}{'mean dist b/a':>20}{'CD b/a':>20}{'HD b/a':>20}"
        f"{'C_avg b/a':>14}{'feat s':>8}{'wall s':>8}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        if "note" in r:
            print(f"{r['shape']:<16} failed: {r['note']}")
            continue
        print(
            f"{r['shape']:<16}{r['sharp_within_0.01_before']:>8.2f}/{r['sharp_within_0.01_after']:<7.2f}"
            f"{r['sharp_reached_0.01_before']:>7.2f}/{r['sharp_reached_0.01_after']:<6.2f}"
            f"{r['sharp_mean_before']:>10.2e}/{r['sharp_mean_after']:<9.2e}{r['cd_before']:>10.2e}/{r['cd_after']:<9.2e}"
            f"{r['hd_before']:>10.2e}/{r['hd_after']:<9.2e}"
            f"{fmt(r['smoothness_before'], '6.3f')}/{fmt(r['smoothness_after'], '<7.3f')}"
            f"{r['feature_s']:>8.1f}{fmt(r.get('wall_s', r.get('recontract_s')), '.1f'):>8}"
        )
    print(
        "\nwithin .01: share of the input's sharp-edge samples within 0.01 of the MAT's boundary (its fold edges; "
        "unit box), before / after enhancement; reached: within 0.01 of any point of the MAT (a tip that ends in a V "
        "reaches the edge but does not fold there); CD / HD of each MAT's reconstruction against the input."
    )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0
