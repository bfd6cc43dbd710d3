"""``export``: the medial membrane as a MAT (radius per vertex from the input, ``qmdf.medial.radii``), in the unit box and in the
input's own units: ``.ma`` (Q-MAT / MATTopo format), PLY with a ``radius`` vertex property, OBJ; and the
surface the MAT reconstructs (union of its primitives' envelopes), meshed."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MAT, MESH, NORMALIZATION, POINTS, file_kind
from qmdf.medial.radii import RADIUS_SOURCES, mat_radii
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class ExportConfig:
    reconstruction_resolution: int = param(128, ge=16, le=1024, doc="grid of the meshed reconstruction; 0 skips it")
    picture: bool = param(True, doc="the medial mesh coloured by radius, and the covering before/after contraction")
    radius: str = param("data", choices=RADIUS_SOURCES, doc="each vertex's radius: data (distance to the input mesh or "
                        "points), sdf (learned |sdf|) or mf (learned medial field); qmdf.medial.radii says why data")


def membrane_to_mat(membrane, field, radius: str = "sdf", mesh=None, points=None):
    """The MAT of a contracted membrane: its faces (and their edges), each vertex's radius from ``radius``."""
    from qmdf.geometry.ma_format import MedialMesh

    v = np.asarray(membrane.vertices, np.float64)
    radii = mat_radii(v, radius, field, mesh, points)
    return MedialMesh(v, radii, np.zeros((0, 2), np.int64), np.asarray(membrane.faces)).with_face_edges()


def input_data(ctx: StageContext):
    """(mesh, points) the radii may be measured to: the mesh of an undegraded mesh input, else the input points
    (what the method saw, never the clean reference of a simulated scan)."""
    info = ctx.load("input_info") if ctx.has("input_info") else {}
    if ctx.has("surface") and info.get("kind") == "mesh" and not info.get("degradations"):
        surface = ctx.load("surface")
        return (np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64)), None
    return None, ctx.load("points").points if ctx.has("points") else None


@register_stage("export")
class Export(Stage):
    """Write the MAT (.ma, .ply with radius, .obj) in both frames, and its reconstructed surface."""

    Config = ExportConfig
    inputs = {"membrane": MESH, "field": FIELD, "normalization": NORMALIZATION}
    optional_inputs = {"covering": MESH, "surface": MESH, "points": POINTS, "input_info": JSON}
    outputs = {"mat": MAT, "mat_input_units": file_kind(".ma"), "mat_ply": file_kind(".ply"),
               "mat_ply_input_units": file_kind(".ply"), "mat_obj": file_kind(".obj"), "reconstruction": MESH}

    def run(self, ctx: StageContext) -> None:
        from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh
        from qmdf.geometry.ma_format import MedialMesh, write_ma, write_obj, write_ply_with_radius

        norm = ctx.load("normalization")
        mesh, points = input_data(ctx) if ctx.cfg.radius == "data" else (None, None)
        mat = membrane_to_mat(ctx.load("membrane"), ctx.load("field"), ctx.cfg.radius, mesh, points)
        v, radii = mat.vertices, mat.radii
        ctx.save("mat", mat)
        in_units = MedialMesh(norm.to_input(v), norm.length_to_input(radii), mat.edges, mat.faces)
        write_ma(ctx.path("mat_input_units"), in_units)
        write_ply_with_radius(ctx.path("mat_ply"), mat)
        write_ply_with_radius(ctx.path("mat_ply_input_units"), in_units)
        write_obj(ctx.path("mat_obj"), mat)
        recon = reconstruct_mesh(EnvelopeUnion.from_mat(mat), ctx.cfg.reconstruction_resolution)
        ctx.save("reconstruction", recon)
        if ctx.cfg.picture:
            from qmdf.viz import render_mesh

            render_mesh(ctx.stage_dir / "mat.png", v, mat.faces, radii, title="medial mesh", label="radius (unit box)")
            if ctx.has("covering"):
                cov = ctx.load("covering")
                render_mesh(ctx.stage_dir / "covering_before.png", cov.vertices, cov.faces, title="eps-covering")
                render_mesh(ctx.stage_dir / "covering_after.png", v, mat.faces, title="after contraction")
        ctx.log.info("MAT: %d vertices, %d faces, radius %.3g..%.3g (unit box); reconstruction %d faces",
                     len(v), len(mat.faces), radii.min(), radii.max(), len(recon.faces))
