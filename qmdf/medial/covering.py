"""The covering: the eps-isosurface of Q-MDF inside the shape, a closed double covering of the medial axis
(paper Sec. 4.2, DCUDF). The field is evaluated only where the covering can pass: a coarse pass, then the
narrow band, level by level."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.errors import QmdfError
from qmdf.schema import param


@dataclass
class CoveringSettings:
    """``build_covering``'s settings: the ``cover`` stage's config (``cover.*``), one source for both."""

    eps: float = param(0.005, gt=0, doc="the isovalue of Q-MDF (paper: 0.005)")
    resolution: int = param(256, ge=16, le=1024, doc="grid nodes along the unit box (paper: 256)")
    coarse_step: int = param(8, ge=1, doc="first-pass spacing in grid cells; refined by halves near the covering")
    lipschitz: float = param(2.0, ge=1, doc="assumed bound on |grad q| when deciding where to refine (safety margin)")
    extent: float = param(0.55, gt=0, doc="half side of the grid box around the origin (the shape is in [-0.5, 0.5])")
    speck_fraction: float = param(
        0.01, ge=0, lt=1, doc="drop components with fewer faces than this share of the largest"
    )
    max_faces: int = param(
        30000,
        ge=0,
        doc="decimate larger coverings to this many faces (topology kept; 0: never); contraction and export cost "
        "scale with it (box: 60k faces -> 84 s, 30k -> 54 s, same accuracy; bench extraction)",
    )
    prepass_faces: int = param(
        200000,
        ge=0,
        doc="before MeshLab's topology-safe collapse, a fast one (fast-simplification) down to this many faces, "
        "on coverings of at least twice that, kept only where it changes neither the Euler characteristic, the "
        "components nor the closedness (teacup: 537k -> 30k faces in 3.2 s against 8.3 s); 0: MeshLab's pass alone",
    )
    decimation_workers: int = param(
        1,
        ge=1,
        le=2,
        doc="2: decimate two halves in two processes, welded along their cut (teacup cover 29 -> 25 s on 2 cores, "
        "537k -> 30k faces 14 -> 8 s), 1: one MeshLab pass. Not the default: the exact box's sheet then fit 1.25x "
        "its membrane's CD against 1.15x (bench extraction, 2026-12-03)",
    )


def covering_field(field, eps: float, lipschitz: float, voxel: float):
    """max(q - eps, sdf): the covering wraps the inner medial axis only. The intersection is continuous, so
    where the covering meets the surface (the tips that reach sharp edges) marching cubes places it on
    sdf = 0; a step to a constant outside stopped it about a voxel short (measured on the exact box: sharp-edge
    samples within 0.005 of the covering 0.20 with the step, 0.44 without). Beyond two voxels outside, where
    no grid edge reaches a node inside, it is a constant again so the narrow band skips the outer shell."""

    def f(points: np.ndarray, band: float) -> np.ndarray:
        out = field.evaluate(points)
        inside = np.maximum(out["q"] - eps, out["sdf"])
        return np.where(out["sdf"] < 2 * voxel, inside, 1.0) / lipschitz

    return f


def mesh_stats(mesh) -> dict:
    parts = mesh.split(only_watertight=False)
    return {
        "vertices": int(len(mesh.vertices)),
        "faces": int(len(mesh.faces)),
        "components": len(parts),
        "watertight": bool(mesh.is_watertight),
        "volume": float(mesh.volume) if mesh.is_watertight else None,
        "genus": [int((2 - p.euler_number) // 2) for p in parts],
    }


def decimate(mesh, target_faces: int, workers: int = 1, prepass_faces: int = 0):
    """Quadric edge collapse that keeps the topology (``qmdf.geometry.decimation``), so the covering stays closed
    with its genus."""
    import trimesh

    from qmdf.geometry.decimation import decimate as collapse

    v, f = collapse(mesh.vertices, mesh.faces, target_faces, workers=workers, prepass_faces=prepass_faces)
    out = trimesh.Trimesh(v, f, process=True)
    if out.is_watertight and out.volume < 0:
        out.invert()
    return out


def eps_floor(axis_q: dict, resolution: int, extent: float) -> float | None:
    """The least eps whose covering holds the learned axis: the valley of q stays under its 99th percentile
    (``axis_q``, from train), and the slab {q < eps} around a sheet, 2 (eps - q) thick as q grows at rate 1 off
    the axis, keeps its grid nodes connected across it when eps - q is 2 cells (half a cell's diagonal is the
    bare minimum; the margin also holds the valley's rarer spots above p99). Two teacup fields with p99 0.0019:
    11 holes in the covering at eps 0.005, 3 at 0.0061, where the valley rose to 0.0086; at 0.008 none in one
    field and one in the other, none in either at 0.009 and 0.010; this floor gives 0.0105. (The 99.9th
    percentile instead raised the bunny's eps to 0.095, where branches the field could not learn stay above any
    eps that keeps the covering thin.) None without the statistics."""
    q = axis_q.get("p99")
    if q is None:
        return None
    voxel = 2 * extent / (resolution - 1)
    return float(q) + 2.0 * voxel


def build_covering(
    field,
    settings: CoveringSettings = CoveringSettings(),
    log=None,
):
    """The covering mesh (specks dropped, decimated), its statistics and the grid nodes inside it
    (``CoveringSettings`` documents each setting)."""
    import trimesh

    eps, resolution, extent, speck_fraction = (
        settings.eps,
        settings.resolution,
        settings.extent,
        settings.speck_fraction,
    )

    from qmdf.geometry.grid import narrow_band_level_set

    lo, hi = np.full(3, -extent), np.full(3, extent)
    voxel = 2 * extent / (resolution - 1)
    if eps < 0.5 * voxel and log is not None:  # a tube of radius eps around a curve-like axis falls between nodes
        log.warning(
            "cover.eps=%g is below half the grid step %.4g: thin parts of the covering may be "
            "missed; raise cover.resolution (or cover.eps)",
            eps,
            voxel,
        )
    grid = narrow_band_level_set(
        covering_field(field, eps, settings.lipschitz, voxel), lo, hi, resolution, coarse_step=settings.coarse_step
    )
    mesh = grid.mesh()
    if mesh is None or len(mesh.faces) == 0:
        raise QmdfError(
            f"Q-MDF never drops below cover.eps={eps} at the grid nodes inside the shape: no "
            f"covering (grid step {voxel:.4g}; is the field trained? raise cover.resolution or cover.eps)"
        )
    parts = mesh.split(only_watertight=False)
    biggest = max(len(p.faces) for p in parts)
    kept = [p for p in parts if len(p.faces) >= speck_fraction * biggest]
    dropped = len(parts) - len(kept)
    mesh = trimesh.util.concatenate(kept) if len(kept) > 1 else kept[0]
    faces_before = len(mesh.faces)
    if settings.max_faces and len(mesh.faces) > settings.max_faces:
        mesh = decimate(mesh, settings.max_faces, settings.decimation_workers, settings.prepass_faces)
    stats = mesh_stats(mesh)
    stats["faces_before_decimation"] = faces_before
    stats.update(
        dropped_specks=dropped,
        speck_rule=f"components with < {speck_fraction:g} x the largest's faces",
        evaluated_nodes=grid.evaluated,
        grid_nodes=int(np.prod(grid.values.shape)),
        eps=eps,
    )
    return mesh, stats, {"inside": grid.values < 0, "lo": grid.lo, "spacing": grid.spacing, "eps": eps}
