"""Pictures of what a run made, drawn with matplotlib (no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qmdf.geometry.triangles import face_cross


def decimated_for_display(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_faces`` faces, for drawing only: a fast quadric collapse without MeshLab's topology
    checks (a picture needs none)."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces)
    if len(faces) <= max_faces:
        return vertices, faces
    import fast_simplification

    v, f = fast_simplification.simplify(vertices.astype(np.float32), faces.astype(np.int32), target_count=max_faces)
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


def _decimated(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray | None, max_faces: int):
    """At most ``max_faces`` faces for drawing; per-vertex values follow their nearest kept vertex."""
    if len(faces) <= max_faces:
        return vertices, faces, values
    from scipy.spatial import cKDTree

    v, f = decimated_for_display(vertices, faces, max_faces)
    if values is not None:
        _, idx = cKDTree(vertices).query(v)
        values = values[idx]
    return v, f, values


def render_mesh(
    path: Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    values: np.ndarray | None = None,
    title: str = "",
    label: str = "",
    cmap: str = "viridis",
    max_faces: int = 30000,
    views: tuple[tuple[float, float], ...] = ((20, -60), (20, 120)),
    lines: tuple[tuple[np.ndarray, str], ...] = (),
) -> Path:
    """Shaded views of a triangle mesh, coloured by per-vertex ``values`` when given; ``lines``: (edges (E, 2)
    into ``vertices``, colour) drawn over it (a medial mesh's lone edges, its seams)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    segments = [(np.asarray(vertices, float)[np.asarray(e, np.int64).reshape(-1, 2)], colour) for e, colour in lines]
    v, f, val = _decimated(np.asarray(vertices, float), np.asarray(faces), values, max_faces)
    tri = v[f]
    normals = face_cross(v, f)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    shade = 0.45 + 0.55 * np.abs(normals @ np.array([0.3, -0.4, 0.85]) / np.linalg.norm([0.3, -0.4, 0.85]))
    if val is not None:
        fv = val[f].mean(1)
        norm = matplotlib.colors.Normalize(vmin=float(np.min(val)), vmax=float(np.percentile(val, 99)) or 1e-12)
        colors = plt.get_cmap(cmap)(norm(fv))
    else:
        colors = np.tile([0.75, 0.75, 0.78, 1.0], (len(f), 1))
    colors[:, :3] *= shade[:, None]
    fig = plt.figure(figsize=(5 * len(views) + (1 if val is not None else 0), 5))
    every = np.concatenate([v] + [seg.reshape(-1, 3) for seg, _ in segments])
    lo, hi = every.min(0), every.max(0)
    c, r = (lo + hi) / 2, float((hi - lo).max()) / 2
    for i, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolor="none"))
        for seg, colour in segments:
            if len(seg):
                ax.add_collection3d(Line3DCollection(seg, colors=colour, linewidths=1.2))
        ax.set_xlim(c[0] - r, c[0] + r), ax.set_ylim(c[1] - r, c[1] + r), ax.set_zlim(c[2] - r, c[2] + r)
        ax.view_init(elev, azim)
        ax.set_axis_off()
    if val is not None:
        sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=fig.axes, shrink=0.7, label=label)
    fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def render_mat_pictures(folder: Path, mat, covering=None, membrane=None) -> None:
    """export's pictures: ``mat.png`` (the MAT coloured by radius, lone edges black, seams red) and, with the
    ``covering`` and the contracted ``membrane``, ``covering_before.png`` and ``covering_after.png``."""
    from qmdf.geometry.metrics import seam_edges

    v, f = mat.vertices, mat.faces
    render_mesh(
        folder / "mat.png",
        v,
        f,
        mat.radii,
        label="radius (unit box)",
        title=f"medial mesh: {len(v)} vertices, {len(f)} faces; lone edges black, seams red",
        lines=((mat.lone_edges(), "black"), (seam_edges(f), "red")),
    )
    if covering is not None:
        render_mesh(folder / "covering_before.png", covering.vertices, covering.faces, title="eps-covering")
        render_mesh(
            folder / "covering_after.png", membrane.vertices, membrane.faces, title="after contraction (the membrane)"
        )


def plot_field_slices(path: Path, field, resolution: int = 160, extent: float = 0.6) -> Path:
    """SDF, MF and Q-MDF on the planes z = 0 and y = 0 (like the paper's Fig. 3 and 6), zero set in black,
    the eps = 0.005 level of Q-MDF inside the shape in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.linspace(-extent, extent, resolution)
    a, b = np.meshgrid(t, t, indexing="xy")
    fig, axes = plt.subplots(2, 3, figsize=(13, 8.5))
    for row, (plane, labels) in enumerate((("z", ("x", "y")), ("y", ("x", "z")))):
        pts = (
            np.column_stack([a.ravel(), b.ravel(), np.zeros(a.size)])
            if plane == "z"
            else np.column_stack([a.ravel(), np.zeros(a.size), b.ravel()])
        )
        vals = field.evaluate(pts)
        sdf = vals["sdf"].reshape(a.shape)
        for col, (name, cmap) in enumerate((("sdf", "RdBu_r"), ("mf", "viridis"), ("q", "magma"))):
            v = vals[name].reshape(a.shape)
            ax = axes[row, col]
            if name == "sdf":
                lim = float(np.abs(v).max())
                im = ax.imshow(
                    v, origin="lower", extent=(-extent, extent, -extent, extent), cmap=cmap, vmin=-lim, vmax=lim
                )
            else:
                shown = np.where(sdf < 0, v, np.nan)  # the inner fields are what the method uses
                im = ax.imshow(shown, origin="lower", extent=(-extent, extent, -extent, extent), cmap=cmap)
            ax.contour(t, t, sdf, levels=[0.0], colors="k", linewidths=0.8)
            if name == "q":
                ax.contour(t, t, np.where(sdf < 0, v, np.nan), levels=[0.005], colors="r", linewidths=0.8)
            ax.set_title(f"{name} on {plane} = 0")
            ax.set_xlabel(labels[0]), ax.set_ylabel(labels[1])
            fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def plot_losses(path: Path, history: list[dict]) -> Path:
    """Each loss term (unweighted) against the step, log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    if history:
        steps = [h["step"] for h in history]
        for key in history[0]:
            if key.startswith("loss/"):
                ys = np.array([h[key] for h in history])
                ax.plot(steps, np.abs(ys) + 1e-12, label=key[5:] + (" (negated)" if ys.mean() < 0 else ""))
        ax.set_yscale("log")
        ax.legend(fontsize=8)
    ax.set_xlabel("step")
    ax.set_title("training losses (unweighted)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def plot_points_over(
    path: Path,
    background: np.ndarray,
    highlight: np.ndarray,
    title: str = "",
    views: tuple[tuple[float, float], ...] = ((20, -60), (20, 120)),
    max_background: int = 8000,
) -> Path:
    """``highlight`` points (red) over a thinned, faint ``background`` point cloud."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bg = np.asarray(background)[:: max(1, len(background) // max_background)]
    hl = np.asarray(highlight)
    allp = np.vstack([bg, hl])
    c, r = (allp.min(0) + allp.max(0)) / 2, float((allp.max(0) - allp.min(0)).max()) / 2
    fig = plt.figure(figsize=(5 * len(views), 5))
    for i, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), i + 1, projection="3d")
        ax.scatter(*bg.T, s=0.3, c="0.7", alpha=0.4)
        ax.scatter(*hl.T, s=2.0, c="crimson")
        ax.set_xlim(c[0] - r, c[0] + r), ax.set_ylim(c[1] - r, c[1] + r), ax.set_zlim(c[2] - r, c[2] + r)
        ax.view_init(elev, azim)
        ax.set_axis_off()
    fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
