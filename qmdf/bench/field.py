"""``python -m qmdf.bench field``: train on shapes with known SDFs and medial axes and score the field.

Per shape and backbone, from 20k surface points: training wall time and peak memory (the child process's
own), the SDF error inside the shape against the exact SDF, |grad sdf| there (1 for a metric SDF), mean |q|
on points of the true medial axis, the paper's centredness test (Sec. 5.2.1: points inside follow -grad q
to its local minima; mean distance of where they stop to the true axis; the paper reports 6.0e-4), and the
Chamfer distance of the zero level set to the true surface. Also the paper's Fig. 7 (the cut Dupin cyclide,
with and without the medial field, Chamfer to the full cyclide) and the paper route with and without pinning.
Targets (issue 4): training < 3 min, centredness < 2e-3, Chamfer < 2e-3, all in the unit box.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qmdf.bench.child import fmt

SHAPES = ("torus", "ellipsoid", "box", "teacup")
BACKBONES = ("mlp", "grid")


@dataclass
class Case:
    label: str
    shape: str
    backbone: str
    overrides: list[str] = field(default_factory=list)


def default_cases(shapes, backbones) -> list[Case]:
    cases = [Case(s, s, b) for s in shapes for b in backbones]
    cases.append(Case("torus, paper route", "torus", "mlp", ["train.supervision.route=paper"]))
    cases.append(
        Case(
            "torus, paper, no pinning",
            "torus",
            "mlp",
            ["train.supervision.route=paper", "train.optim.paper_losses.mf_maximal.weight=0"],
        )
    )
    cases.append(Case("cut cyclide, MF", "cyclide", backbones[0], ["+experiment=cut_cyclide"]))
    cases.append(
        Case(
            "cut cyclide, w/o MF",
            "cyclide",
            backbones[0],
            ["+experiment=cut_cyclide", "train.model.medial_field=false"],
        )
    )
    return cases


# --- scoring -----------------------------------------------------------------------------------------------
def inside_points(shape: str, n: int, seed: int = 0) -> np.ndarray:
    """Uniform points inside the solid (shape coordinates), by rejection against its exact SDF."""
    from qmdf.geometry.shapes import get_shape

    sh = get_shape(shape)
    lo, hi = sh.mesh(64).bounds
    rng = np.random.default_rng(seed)
    out = []
    while sum(len(o) for o in out) < n:
        p = rng.uniform(lo, hi, (4 * n, 3))
        out.append(p[sh.sdf(p) < 0])
    return np.vstack(out)[:n]


def descend_q(field, x: np.ndarray, iterations: int = 300, step: float = 0.01) -> np.ndarray:
    """Follow -grad q from each point to a local minimum (monotone: a step is kept only if q falls; the step
    grows after a success and halves after a failure, so the walk settles into the kink of q at the axis). A
    step that leaves the learned solid fails too: the minima sought are inside, and outside q falls forever."""
    x = np.asarray(x, np.float64).copy()
    s = np.full(len(x), step)
    cur = field.evaluate(x, grad=True)
    q, g = cur["q"].astype(np.float64), cur["q_grad"].astype(np.float64)
    for _ in range(iterations):
        active = s > 1e-6
        if not active.any():
            break
        idx = np.flatnonzero(active)
        d = g[idx] / np.maximum(np.linalg.norm(g[idx], axis=1, keepdims=True), 1e-12)
        trial = x[idx] - s[idx, None] * d
        new = field.evaluate(trial, grad=True)
        better = (new["q"] < q[idx]) & (new["sdf"] < 0)
        ok = idx[better]
        x[ok], q[ok], g[ok] = trial[better], new["q"][better], new["q_grad"][better]
        s[ok] = np.minimum(s[ok] * 1.5, 0.05)
        s[idx[~better]] *= 0.5
    return x


def zero_level_set(field, resolution: int = 128, extent: float = 0.55):
    """Marching cubes of the learned SDF on a full grid over the unit box (vertices, faces) or None."""
    from skimage.measure import marching_cubes

    axis = np.linspace(-extent, extent, resolution)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    values = field.evaluate(grid)["sdf"].reshape((resolution,) * 3)
    if not (values.min() < 0 < values.max()):
        return None
    v, f, _, _ = marching_cubes(values, 0.0, spacing=(axis[1] - axis[0],) * 3)
    return v - extent, f


def surface_chamfer(va, fa, vb, fb, samples: int = 30_000, seed: int = 0) -> float:
    """(mean d(A->B) + mean d(B->A)) / 2 with exact point-to-mesh distances from area-uniform samples."""
    import trimesh

    ma, mb = trimesh.Trimesh(va, fa, process=False), trimesh.Trimesh(vb, fb, process=False)
    a, b = ma.sample(samples, seed=seed), mb.sample(samples, seed=seed + 1)
    try:
        from qmdf.geometry.metrics import point_to_mesh_distance

        return float((point_to_mesh_distance(a, vb, fb).mean() + point_to_mesh_distance(b, va, fa).mean()) / 2)
    except ImportError:  # no pymeshlab (a bare GPU box): nearest of dense samples, biased up by ~1e-3
        from scipy.spatial import cKDTree

        da = cKDTree(mb.sample(20 * samples, seed=seed + 2)).query(a)[0]
        db = cKDTree(ma.sample(20 * samples, seed=seed + 3)).query(b)[0]
        return float((da.mean() + db.mean()) / 2)


def score_field(field, shape: str, n: int = 4000, resolution: int = 128, seed: int = 0) -> dict:
    """Everything the table reports about one trained field, in the unit box of its input."""
    from qmdf.fields.analytic import ANALYTIC
    from qmdf.geometry.shapes import get_shape

    norm = field.normalization
    sh = get_shape(shape)
    row: dict = {}
    if sh.sdf is not None:
        x = inside_points(shape, n, seed)
        out = field.evaluate(norm.to_unit(x), grad=True)
        row["sdf_err"] = float(np.abs(out["sdf"] - sh.sdf(x) * norm.scale).mean())
        row["grad_norm"] = float(np.linalg.norm(out["sdf_grad"], axis=1).mean())
        if shape in ANALYTIC:
            truth = ANALYTIC[shape]()
            row["q_on_axis"] = float(np.abs(field.evaluate(norm.to_unit(truth.axis_points(n, seed)))["q"]).mean())
            mapped = norm.to_input(descend_q(field, norm.to_unit(x)))
            d = truth.axis_distance(mapped) * norm.scale
            row["centredness"] = float(d.mean())
            row["centredness_p95"] = float(np.percentile(d, 95))
    level = zero_level_set(field, resolution)
    if level is None:
        row["chamfer"] = None
    else:
        ref = sh.mesh(256)
        row["chamfer"] = surface_chamfer(level[0], level[1], norm.to_unit(ref.vertices), np.asarray(ref.faces))
    return row


# --- running -----------------------------------------------------------------------------------------------
def run_case(case: Case, out: Path, n_points: int, overrides: list[str], timeout: float) -> dict:
    from qmdf.bench.child import last_error, run_child
    from qmdf.fields.field import Field

    run_dir = out / case.label.replace(", ", "_").replace(" ", "_").replace("/", "_")
    cmd = [
        sys.executable,
        "-m",
        "qmdf",
        f"input.shape={case.shape}",
        "input.shape_resolution=256",
        f"sample.n_points={n_points}",
        "pipeline.stages=[sample,train]",
        f"train.model.backbone={case.backbone}",
        f"hydra.run.dir={run_dir}",
        *overrides,
        *case.overrides,
    ]
    code, wall, peak = run_child(cmd, run_dir, timeout)
    row: dict = {"shape": case.label, "backbone": case.backbone, "wall_s": round(wall, 1), "peak_mb": round(peak)}
    manifest = json.loads((run_dir / "manifest.json").read_text()) if (run_dir / "manifest.json").exists() else {}
    if code != 0 or manifest.get("status") != "complete":
        row["note"] = last_error(run_dir)
        return row
    secs = {s["name"]: s["seconds"] for s in manifest["stages"]}
    training = json.loads((run_dir / "01_train" / "training.json").read_text())
    peak = max((s.get("peak_rss_mb") or 0) for s in manifest["stages"]) or peak  # the child's own, not inherited
    row.update(train_s=round(secs["train"], 1), steps=training["steps"], device=training["device"], peak_mb=round(peak))
    t0 = time.perf_counter()
    row.update(score_field(Field.load(run_dir / "01_train" / "field.pt"), case.shape))
    row["score_s"] = round(time.perf_counter() - t0, 1)
    return row


def print_table(rows: list[dict]) -> None:
    head = (
        f"{'shape':<22}{'backbone':<9}{'train s':>8}{'peak MB':>8}{'sdf err':>9}{'|grad|':>7}{'q on axis':>10}"
        f"{'centred':>9}{'c p95':>9}{'chamfer':>9}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        if "note" in r:
            print(f"{r['shape']:<22}{r['backbone']:<9} failed: {r['note']}")
            continue
        print(
            f"{r['shape']:<22}{r['backbone']:<9}{r['train_s']:>8.1f}{r['peak_mb']:>8}{fmt(r.get('sdf_err'), '9.2e')}"
            f"{fmt(r.get('grad_norm'), '7.3f')}{fmt(r.get('q_on_axis'), '10.2e')}{fmt(r.get('centredness'), '9.2e')}"
            f"{fmt(r.get('centredness_p95'), '9.2e')}{fmt(r.get('chamfer'), '9.2e')}"
        )
    print(
        "\nunit box. sdf err: mean |sdf - exact| inside; |grad|: mean |grad sdf| inside; centred: mean distance "
        "to the true axis of inside points after descending -grad q (paper: 6.0e-4); chamfer: zero level set "
        "(marching cubes 128^3) to the true (for the cut cyclide: the full) surface."
    )


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m qmdf.bench field", description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--out", type=Path, default=Path("runs/bench/field"))
    ap.add_argument("--shapes", default=",".join(SHAPES))
    ap.add_argument("--backbones", default=",".join(BACKBONES))
    ap.add_argument("--only-main", action="store_true", help="skip the pinning ablation and the cut cyclide")
    ap.add_argument("--points", type=int, default=20_000, help="surface points sampled from each shape")
    ap.add_argument("--timeout", type=float, default=1800)
    ap.add_argument("overrides", nargs="*", help="config overrides for every run (e.g. train.optim.steps=3000)")
    ap.add_argument("--reuse", action="store_true", help="reuse cached stage results (timings then mean nothing)")
    args = ap.parse_args(argv)
    if not args.reuse:
        args.overrides = ["cache.enabled=false", *args.overrides]
    cases = default_cases(args.shapes.split(","), args.backbones.split(","))
    if args.only_main:
        cases = [c for c in cases if c.label == c.shape]
    out = args.out / time.strftime("%Y-%m-%d_%H-%M-%S")
    rows = []
    for case in cases:
        print(f"[{len(rows) + 1}/{len(cases)}] {case.label} ({case.backbone}) ...", file=sys.stderr, flush=True)
        rows.append(run_case(case, out, args.points, args.overrides, args.timeout))
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0
