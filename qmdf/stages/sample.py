"""``sample``: the input (file or procedural shape) as a normalised point set, with optional degradations."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qmdf import schema
from qmdf.artifacts import JSON, MESH, NORMALIZATION, POINTS, file_digest
from qmdf.errors import InputError
from qmdf.geometry.io import InputGeometry, Limits, load_geometry
from qmdf.geometry.normalize import Normalization
from qmdf.geometry.pointset import PointSet
from qmdf.geometry.sampling import sample_surface
from qmdf.geometry.shapes import get_shape
from qmdf.registry import DEGRADATIONS
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class SampleConfig:
    n_points: int = param(
        20000, ge=10, doc="points sampled uniformly (by area) on a mesh input; point clouds keep their own points"
    )
    degradations: dict[str, Any] = param(
        factory=dict, doc="degradation name -> its settings, applied in order (python -m qmdf.plugins lists them)"
    )

    def check(self) -> list[tuple[str, str]]:
        return schema.check_registered(self.degradations, DEGRADATIONS, "degradations")


def resolve_input_path(path: str, base_dir: Path) -> Path:
    p = Path(path).expanduser()
    return p if p.is_absolute() else (base_dir / p)


def read_input(ctx: StageContext) -> InputGeometry:
    inp = ctx.settings.input
    if inp.path is None:
        shape = get_shape(inp.shape)
        mesh = shape.mesh(inp.shape_resolution)
        return InputGeometry(f"procedural:{inp.shape}", PointSet(mesh.vertices), np.asarray(mesh.faces))
    limits = Limits(min_points=inp.min_points, max_abs_coordinate=inp.max_abs_coordinate)
    return load_geometry(resolve_input_path(inp.path, ctx.settings.base_dir), inp.kind, limits)


def outward_normals(samples: PointSet, vertices: np.ndarray, faces: np.ndarray, log) -> PointSet:
    """The samples with their face normals pointing out of the mesh: flipped when the winding turns inward
    (negative signed volume), dropped when the winding is inconsistent (no side is "out" to trust)."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if not mesh.is_winding_consistent:
        log.info("the mesh's face winding is inconsistent: its sampled points carry no normals")
        return PointSet(samples.points)
    return PointSet(samples.points, -samples.normals) if mesh.volume < 0 else samples


@register_stage("sample")
class Sample(Stage):
    """Read the input, normalise it into the unit box, sample a mesh, apply the configured degradations."""

    Config = SampleConfig
    config_deps = ("seed", "input")
    outputs = {"points": POINTS, "normalization": NORMALIZATION, "input_info": JSON}
    optional_outputs = {"surface": MESH, "clean_points": POINTS}  # clean_points: the points before degradations
    # 2: a mesh's sample normals point outward (or are dropped); 3: input_info; 4: clean_points only when degraded
    version = "4"

    def fingerprint(self, ctx: StageContext) -> str:
        inp = ctx.settings.input
        if inp.path is None:
            return ""
        path = resolve_input_path(inp.path, ctx.settings.base_dir)
        try:
            return file_digest(path)
        except OSError:
            return f"unreadable:{path}"  # load_geometry reports the real problem when the stage runs

    def run(self, ctx: StageContext) -> None:
        geom = read_input(ctx)
        norm = Normalization.fit(geom.points.points)
        unit = PointSet(norm.to_unit(geom.points.points), geom.points.normals)
        rng = ctx.rng()
        if geom.is_mesh:
            clean = outward_normals(
                sample_surface(unit.points, geom.faces, ctx.cfg.n_points, rng), unit.points, geom.faces, ctx.log
            )
            ctx.save("surface", _trimesh(unit.points, geom.faces))
            warn_if_open(geom.faces, geom.source, ctx.log)
            what = f"mesh with {len(geom.points)} vertices, {len(geom.faces)} faces; sampled {len(clean)} points"
        else:
            clean = unit
            what = f"point cloud with {len(clean)} points"
        points = clean
        for name, params in ctx.cfg.degradations.items():
            entry = DEGRADATIONS.get(name)
            before = len(points)
            points = entry.obj(points, schema.build(entry.config, params or {}), ctx.rng(name))
            ctx.log.info("degradation %s: %d -> %d points", name, before, len(points))
        if len(points) < ctx.settings.input.min_points:
            raise InputError(
                f"the degradations left {len(points)} points, "
                f"fewer than input.min_points={ctx.settings.input.min_points}"
            )
        ctx.save("points", points)
        # what train's supervision may use: a degraded mesh stands for a scan, so only its points count
        ctx.save(
            "input_info",
            {
                "kind": "mesh" if geom.is_mesh else "points",
                "source": geom.source,
                "degradations": list(ctx.cfg.degradations),
                "normals": points.normals is not None,
            },
        )
        if ctx.cfg.degradations:  # else they are the points themselves: no second copy
            ctx.save("clean_points", clean)
        ctx.save("normalization", norm)
        ctx.log.info("input %s: %s; unit-box scale %.6g", geom.source, what, norm.scale)


def warn_if_open(faces: np.ndarray, source: str, log) -> int:
    """Say so when a mesh has boundary edges (holes, open scans): inside/outside then comes from the generalized
    winding number, which closes small holes but guesses across large ones. Returns the boundary edge count."""
    from qmdf.geometry.metrics import single_face_edges

    open_edges = len(single_face_edges(faces))
    if open_edges:
        log.warning(
            "%s is an open mesh (%d boundary edges): inside and outside come from its winding number, "
            "which bridges small holes; check 01_train/slices.png across large ones",
            source,
            open_edges,
        )
    return open_edges


def _trimesh(vertices: np.ndarray, faces: np.ndarray):
    import trimesh

    return trimesh.Trimesh(vertices, faces, process=False)
