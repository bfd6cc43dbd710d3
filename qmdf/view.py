"""``python -m qmdf.view RUN_DIR``: an interactive viewer of a finished run in the browser (viser), for a run on
this machine or on a remote one (viser serves over a port: forward it, or pass ``--host 0.0.0.0``).

Layers, each a checkbox: the MAT coloured by radius, its curves (edges of no face), its medial balls at a sample
of its vertices (how well the radii fill the shape), the input points, the covering before and after
contraction, the reconstruction (with an opacity slider) and the feature points; the run's metrics beside them.
The scene is built by ``build_scene`` from a ``RunResult``, so other tools can serve it too."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: medial balls drawn at most (spread over the MAT's vertices)
BALLS = 300


@dataclass
class Scene:
    """What ``build_scene`` added: layer name -> scene handle, and the GUI controls."""

    layers: dict = field(default_factory=dict)
    controls: dict = field(default_factory=dict)


def _viridis(values: np.ndarray) -> np.ndarray:
    from matplotlib import colormaps

    v = np.asarray(values, np.float64)
    span = np.ptp(v) if len(v) else 0.0
    t = (v - v.min()) / span if span > 0 else np.zeros_like(v)
    return (colormaps["viridis"](t)[:, :3] * 255).astype(np.uint8)


def _balls(centres: np.ndarray, radii: np.ndarray, count: int):
    """One mesh of ``count`` medial balls at evenly spread MAT vertices (farthest-point order)."""
    import trimesh

    idx = _spread(centres, count)
    unit = trimesh.creation.icosphere(subdivisions=1)
    v = (unit.vertices[None] * radii[idx, None, None] + centres[idx, None]).reshape(-1, 3)
    f = (unit.faces[None] + len(unit.vertices) * np.arange(len(idx))[:, None, None]).reshape(-1, 3)
    return v, f


def _spread(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of up to ``count`` points, each the farthest from those already taken."""
    count = min(count, len(points))
    if count == 0:
        return np.zeros(0, np.int64)
    taken = [0]
    dist = np.linalg.norm(points - points[0], axis=1)
    for _ in range(count - 1):
        i = int(np.argmax(dist))
        taken.append(i)
        dist = np.minimum(dist, np.linalg.norm(points - points[i], axis=1))
    return np.asarray(taken)


def _metrics_markdown(run) -> str:
    m = run.load("metrics") if "metrics" in run.artifacts else {}
    rows = [("CD", "chamfer"), ("HD", "hausdorff"), ("chi", "chi"), ("vertices", "vertices"), ("faces", "faces")]
    lines = [f"**{run.run_dir.name}** ({'complete' if run.complete else 'incomplete'})", ""]
    lines += [
        f"- {label}: {m[key]:.4g}" if isinstance(m.get(key), float) else f"- {label}: {m[key]}"
        for label, key in rows
        if key in m
    ]
    return "\n".join(lines)


def build_scene(server, run) -> Scene:
    """Add the run's layers and their controls to a viser server; returns the handles."""
    import trimesh

    from qmdf.geometry.metrics import edges_off_polygons
    from qmdf.report import MESH_LAYERS

    scene = Scene()
    arts = run.artifacts
    add = server.scene
    if "mat" in arts:
        mat = run.load("mat")
        v, r = np.asarray(mat.vertices, np.float64), np.asarray(mat.radii, np.float64)
        faces = np.asarray(mat.faces, np.int64).reshape(-1, 3)
        if len(faces):
            mesh = trimesh.Trimesh(v, faces, process=False)
            mesh.visual.vertex_colors = np.column_stack([_viridis(r), np.full(len(v), 255, np.uint8)])
            scene.layers["MAT (colour: radius)"] = add.add_mesh_trimesh("/mat", mesh)
        else:
            scene.layers["MAT (colour: radius)"] = add.add_point_cloud("/mat", v, _viridis(r), point_size=0.006)
        edges = np.asarray(mat.edges, np.int64).reshape(-1, 2)
        lone = edges[edges_off_polygons(edges, faces)] if len(edges) else edges
        if len(lone):
            scene.layers["MAT curves"] = add.add_line_segments(
                "/mat_curves", v[lone], (0, 0, 0), thickness=3, thickness_units="screen"
            )
        if len(v):
            bv, bf = _balls(v, r, BALLS)
            scene.layers[f"medial balls ({min(BALLS, len(v))})"] = add.add_mesh_simple(
                "/balls", bv, bf, color=(120, 180, 255), opacity=0.25, visible=False
            )
    if "points" in arts:
        p = run.load("points").points
        scene.layers["input points"] = add.add_point_cloud(
            "/points", p, (110, 110, 110), point_size=0.003, visible=False
        )
    for name, label, color, opacity in MESH_LAYERS:
        if name in arts:
            mesh = run.load(name)
            scene.layers[label] = add.add_mesh_simple(
                f"/{name}",
                np.asarray(mesh.vertices),
                np.asarray(mesh.faces),
                color=color,
                opacity=opacity,
                side="double",
                visible=False,
            )
    if "feature_points" in arts:
        scene.layers["feature points"] = add.add_point_cloud(
            "/features", run.load("feature_points").points, (230, 0, 230), point_size=0.008, visible=False
        )
    server.initial_camera.position = (1.1, -1.1, 0.8)  # the unit box fills the view
    server.initial_camera.look_at = (0.0, 0.0, 0.0)
    server.initial_camera.up = (0.0, 0.0, 1.0)
    server.gui.add_markdown(_metrics_markdown(run))
    with server.gui.add_folder("layers"):
        for label, handle in scene.layers.items():
            box = server.gui.add_checkbox(label, bool(handle.visible))
            box.on_update(lambda _, h=handle, b=box: setattr(h, "visible", b.value))
            scene.controls[label] = box
    if "reconstruction" in scene.layers:
        slider = server.gui.add_slider("reconstruction opacity", 0.0, 1.0, 0.05, 0.35)
        slider.on_update(lambda _: setattr(scene.layers["reconstruction"], "opacity", slider.value))
        scene.controls["reconstruction opacity"] = slider
    return scene


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m qmdf.view", description="an interactive viewer of a qmdf run (viser, in the browser)"
    )
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--host", default="127.0.0.1", help="0.0.0.0 to serve other machines (default: this one only)")
    ap.add_argument("--port", type=int, default=8080)
    ap.add_argument("--check", action="store_true", help="build the scene, list its layers and exit")
    args = ap.parse_args(argv)
    try:
        import viser
    except ImportError:
        print("qmdf.view: the viewer needs viser: pip install 'qmdf[view]'", file=sys.stderr)
        return 2
    from qmdf.errors import QmdfError
    from qmdf.pipeline import RunResult

    if not (args.run_dir / "manifest.json").is_file():
        print(f"qmdf.view: {args.run_dir} is not a qmdf run (no manifest.json)", file=sys.stderr)
        return 2
    try:
        run = RunResult.open(args.run_dir)
        server = viser.ViserServer(host=args.host, port=args.port, verbose=False)
        scene = build_scene(server, run)
    except (QmdfError, OSError, ValueError) as exc:
        print(f"qmdf.view: {exc}", file=sys.stderr)
        return 2
    print(f"qmdf.view: {args.run_dir}: {', '.join(scene.layers)}")
    if args.check:
        server.stop()
        return 0
    print(
        f"open http://{'localhost' if args.host in ('127.0.0.1', '0.0.0.0') else args.host}:{server.get_port()} "
        "(Ctrl-C stops)"
    )
    try:
        server.sleep_forever()
    except KeyboardInterrupt:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
