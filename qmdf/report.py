"""``report.html``: one self-contained page per run (plotly's JavaScript inlined, so it opens without a network):
an interactive 3D view of the MAT coloured by radius with toggles (legend clicks) for the input points, the
covering before and after contraction, the reconstruction and the feature points; the field slices and loss
curves; the metrics beside the paper's figures; the stage times and the composed config. Meshes are decimated for
display only (``DISPLAY_FACES``); the data files keep every face. ``python -m qmdf.report RUN_DIR`` writes it
again for any finished run; a sweep gets one page linking its jobs' reports (``sweep_report``)."""

from __future__ import annotations

import base64
import logging
import html
from pathlib import Path

import numpy as np

from qmdf.paper import TABLE3

log = logging.getLogger(__name__)

#: faces per mesh and points per cloud drawn in the 3D view (the page stays a few MB)
DISPLAY_FACES = 12_000
DISPLAY_POINTS = 10_000
#: the run's meshes beside the MAT, shown on demand by the report and the viewer: (artifact, label, RGB, opacity)
MESH_LAYERS = (
    ("covering", "covering (before contraction)", (255, 165, 0), 0.3),
    ("membrane", "covering after contraction", (220, 40, 40), 0.5),
    ("reconstruction", "reconstruction", (173, 216, 230), 0.35),
)


def _display_mesh(mesh) -> tuple[np.ndarray, np.ndarray]:
    from qmdf.viz import decimated_for_display

    v, f = decimated_for_display(mesh.vertices, mesh.faces, DISPLAY_FACES)
    return _short(v), f


def _short(a: np.ndarray, digits: int = 4) -> np.ndarray:
    """Coordinates rounded for the page (1e-4 of the unit box): a third of the characters of full floats."""
    return np.round(np.asarray(a, np.float64), digits)


def _mesh_trace(go, v, f, name, color, opacity, visible):
    return go.Mesh3d(
        x=v[:, 0],
        y=v[:, 1],
        z=v[:, 2],
        i=f[:, 0],
        j=f[:, 1],
        k=f[:, 2],
        name=name,
        color=color,
        opacity=opacity,
        showlegend=True,
        visible=visible,
        flatshading=True,
    )


def _points_trace(go, points, name, size, color):
    p = _short(points)
    return go.Scatter3d(
        x=p[:, 0],
        y=p[:, 1],
        z=p[:, 2],
        mode="markers",
        name=name,
        marker={"size": size, "color": color},
        visible="legendonly",
    )


def figure(run):
    """The plotly figure of a run (a ``RunResult``): the MAT and, one legend click away, the rest."""
    import plotly.graph_objects as go

    from qmdf.geometry.metrics import edges_off_polygons

    traces = []
    arts = run.artifacts
    if "mat" in arts:
        mat = run.load("mat")
        v, r = _short(mat.vertices), _short(mat.radii, 5)
        if len(mat.faces):
            f = np.asarray(mat.faces)
            traces.append(
                go.Mesh3d(
                    x=v[:, 0],
                    y=v[:, 1],
                    z=v[:, 2],
                    i=f[:, 0],
                    j=f[:, 1],
                    k=f[:, 2],
                    intensity=r,
                    colorscale="Viridis",
                    colorbar={"title": "radius"},
                    name="MAT (by radius)",
                    showlegend=True,
                    flatshading=True,
                )
            )
        else:  # a MAT of curves only (a torus's circle): its vertices, coloured the same way
            traces.append(
                go.Scatter3d(
                    x=v[:, 0],
                    y=v[:, 1],
                    z=v[:, 2],
                    mode="markers",
                    name="MAT (by radius)",
                    marker={"size": 3, "color": r, "colorscale": "Viridis", "colorbar": {"title": "radius"}},
                )
            )
        edges = np.asarray(mat.edges, np.int64).reshape(-1, 2)
        lone = edges[edges_off_polygons(edges, np.asarray(mat.faces))]
        if len(lone):
            xyz = np.full((3 * len(lone), 3), np.nan)
            xyz[0::3], xyz[1::3] = v[lone[:, 0]], v[lone[:, 1]]
            traces.append(
                go.Scatter3d(
                    x=xyz[:, 0],
                    y=xyz[:, 1],
                    z=xyz[:, 2],
                    mode="lines",
                    name="MAT curves",
                    line={"color": "black", "width": 4},
                )
            )
    if "points" in arts:
        p = run.load("points").points
        if len(p) > DISPLAY_POINTS:
            p = p[np.random.default_rng(0).choice(len(p), DISPLAY_POINTS, replace=False)]
        traces.append(_points_trace(go, p, "input points", 1.5, "grey"))
    for name, label, rgb, opacity in MESH_LAYERS:
        if name in arts:
            v, f = _display_mesh(run.load(name))
            traces.append(_mesh_trace(go, v, f, label, "rgb{}".format(rgb), opacity, "legendonly"))
    if "feature_points" in arts:
        traces.append(_points_trace(go, run.load("feature_points").points, "feature points", 3, "magenta"))
    fig = go.Figure(traces)
    fig.update_layout(
        scene={"aspectmode": "data"},
        height=700,
        margin={"l": 0, "r": 0, "t": 30, "b": 0},
        legend={"itemclick": "toggle", "x": 0.0, "y": 1.0, "xanchor": "left", "yanchor": "top"},
        title="click the legend to show or hide each layer",
    )
    return fig


def _image(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">'


def _metrics_table(metrics: dict, stem: str) -> str:
    rows = [
        ("CD", metrics.get("chamfer"), 1e-3),
        ("HD", metrics.get("hausdorff"), 1e-3),
        ("chi", metrics.get("chi"), None),
        ("boundary smoothness C_avg", metrics.get("boundary_smoothness"), None),
        ("C_avg, boundary resampled every 0.01", metrics.get("boundary_smoothness_resampled"), None),
        ("vertices", metrics.get("vertices"), None),
        ("faces", metrics.get("faces"), None),
    ]
    field = metrics.get("field") or {}
    rows += [
        ("sign accuracy", field.get("sign_accuracy"), None),
        ("mean |grad sdf| inside", field.get("grad_sdf_inside"), None),
    ]
    structure = metrics.get("structure") or {}  # the MAT's parts that contradict the shape (mat_structure)
    counts = {k: v for k, v in structure.items() if k not in ("vertices", "edges", "faces", "tolerance")}
    rows += [(f"structure: {k.replace('_', ' ')}", v, None) for k, v in counts.items()]
    paper = TABLE3.get(stem)
    paper_of = {"CD": paper[0] * 1e-3, "HD": paper[1] * 1e-3, "chi": paper[2]} if paper else {}
    out = ["<table><tr><th>metric</th><th>this run</th><th>paper (Table 3)</th></tr>"]
    for name, value, _ in rows:
        if value is None:
            continue
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        ref = paper_of.get(name)
        out.append(f"<tr><td>{name}</td><td>{shown}</td><td>{'' if ref is None else f'{ref:.4g}'}</td></tr>")
    out.append("</table>")
    reference = str(metrics.get("reference", ""))
    if metrics.get("reference_gap") is not None:  # a cloud: distances to it include up to half its gap
        reference += f", points a median {metrics['reference_gap']:.3g} apart (CD and HD include up to half that)"
    out.append(f"<p>reference: {html.escape(reference)}</p>")
    return "\n".join(out)


def _quality(manifest: dict) -> str:
    """The run's verdict on itself; a suspect one in red with its reasons."""
    quality = manifest.get("quality")
    if not quality:
        return ""
    if quality != "suspect":
        return f"<p>quality: <b>{html.escape(quality)}</b></p>"
    items = "".join(f"<li>{html.escape(r)}</li>" for r in manifest.get("quality_reasons") or [])
    return f"<p style='color:#b00'>quality: <b>suspect</b>: the result contradicts its input</p><ul>{items}</ul>"


def _stage_table(manifest: dict) -> str:
    out = ["<table><tr><th>stage</th><th>status</th><th>wall s</th><th>CPU s</th><th>peak MB</th></tr>"]
    for s in manifest.get("stages", []):
        out.append(
            f"<tr><td>{s['name']}</td><td>{s['status']}</td><td>{s['seconds']:.1f}</td>"
            f"<td>{s.get('cpu_seconds', '')}</td><td>{s.get('peak_rss_mb') or ''}</td></tr>"
        )
    out.append("</table>")
    return "\n".join(out)


STYLE = """body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}table{border-collapse:collapse}
td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}pre{background:#f6f6f6;padding:1em;overflow:auto}"""


def report_finished_run(run_dir: Path, cfg) -> None:
    """report.html of a finished run unless ``pipeline.report=false``; one that cannot be written is a warning,
    never a failed run (its results are complete without it)."""
    if not cfg.pipeline.get("report", True):
        return
    try:
        log.info("report: %s", write_report(run_dir))
    except Exception as exc:  # noqa: BLE001
        log.warning("report.html was not written: %s", exc)


def write_report(run_dir: Path | str) -> Path:
    """Write ``run_dir/report.html`` from the finished run in ``run_dir``; returns its path."""
    from qmdf.pipeline import RunResult

    run_dir = Path(run_dir)
    run = RunResult.open(run_dir)
    m = run.manifest
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>qmdf run {html.escape(run_dir.name)}</title>"
        f"<style>{STYLE}</style></head><body>",
        f"<h1>qmdf run {html.escape(str(run_dir))}</h1>",
        f"<p>status: <b>{html.escape(str(m.get('status')))}</b>"
        f"{' (' + html.escape(str(m.get('error'))) + ')' if m.get('error') else ''}</p>",
        _quality(m),
    ]
    parts.append(figure(run).to_html(full_html=False, include_plotlyjs=True, div_id="mat-view"))
    config_path = run_dir / "config.yaml"
    stem = ""
    if config_path.exists():
        import yaml

        cfg = yaml.safe_load(config_path.read_text()) or {}
        path = (cfg.get("input") or {}).get("path")
        stem = Path(path).stem if path else (cfg.get("input") or {}).get("shape", "")
    if "metrics" in run.artifacts:
        parts += ["<h2>Metrics</h2>", _metrics_table(run.load("metrics"), stem)]
    for title, name in (
        ("Field slices (sdf, mf, q)", "slices.png"),
        ("Loss curves", "losses.png"),
        ("MAT", "mat.png"),
        ("Reconstruction", "reconstruction.png"),
    ):
        found = sorted(run_dir.glob(f"*/{name}"))
        if found:
            parts += [f"<h2>{title}</h2>", _image(found[-1])]
    parts += ["<h2>Stages</h2>", _stage_table(m)]
    if config_path.exists():
        parts += ["<h2>Config</h2>", f"<pre>{html.escape(config_path.read_text())}</pre>"]
    parts.append("</body></html>")
    out = run_dir / "report.html"
    tmp = out.with_name(".report.html.tmp")
    tmp.write_text("\n".join(parts))
    tmp.replace(out)
    return out


def sweep_report(sweep_dir: Path | str, rows: list[dict]) -> Path:
    """``sweep_dir/report.html``: the jobs' table (overrides, status, figures), each linking to its own report."""
    sweep_dir = Path(sweep_dir)
    keys = [k for k in ("chamfer", "hausdorff", "chi", "vertices") if any(k in r for r in rows)]
    out = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>qmdf sweep</title><style>{STYLE}</style></head>"
        f"<body><h1>qmdf sweep {html.escape(str(sweep_dir))}</h1><table><tr><th>job</th><th>overrides</th>"
        "<th>status</th>" + "".join(f"<th>{k}</th>" for k in keys) + "</tr>"
    ]
    for r in rows:
        job = str(r.get("job", ""))
        link = (
            f'<a href="{html.escape(job)}/report.html">{html.escape(job)}</a>'
            if (sweep_dir / job / "report.html").exists()
            else html.escape(job)
        )
        cells = "".join(
            f"<td>{r[k]:.4g}</td>" if isinstance(r.get(k), float) else f"<td>{html.escape(str(r.get(k, '')))}</td>"
            for k in keys
        )
        out.append(
            f"<tr><td>{link}</td><td>{html.escape(str(r.get('overrides', '')))}</td>"
            f"<td>{html.escape(str(r.get('status', '')))}</td>{cells}</tr>"
        )
    out.append("</table></body></html>")
    path = sweep_dir / "report.html"
    path.write_text("\n".join(out))
    return path


def main(argv: list[str] | None = None) -> int:
    import argparse
    import sys

    from qmdf.errors import QmdfError

    ap = argparse.ArgumentParser(prog="python -m qmdf.report", description="write RUN_DIR/report.html again")
    ap.add_argument("run_dir", type=Path)
    args = ap.parse_args(argv)
    try:
        print(write_report(args.run_dir))
    except QmdfError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
