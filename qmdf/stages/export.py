"""``export``: the MAT in the unit box and in the input's own units: ``.ma`` (Q-MAT / MATTopo format), PLY with a
``radius`` vertex property, OBJ; and the surface the MAT reconstructs (union of its primitives' envelopes),
meshed. The MAT is the single sheet when a ``sheet`` stage ran, else the contracted membrane (radius per vertex
from ``radius``, ``qmdf.medial.radii``); the membrane is written as ``membrane.ma`` either way, for comparison."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MAT, MESH, NORMALIZATION, POINTS, RAYS, file_kind
from qmdf.errors import QmdfError
from qmdf.medial.radii import RADIUS_SOURCES, membrane_to_mat
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage
from qmdf.stages.inputs import input_data, input_surface_balls


@dataclass
class ExportConfig:
    reconstruction_resolution: int = param(
        128, ge=16, le=1024, doc="grid nodes along the meshed reconstruction's longest side"
    )
    picture: bool = param(True, doc="the medial mesh coloured by radius, and the covering before/after contraction")
    radius: str = param(
        "data",
        choices=RADIUS_SOURCES,
        doc="each vertex's radius: data (distance to the input mesh or "
        "points), sdf (learned |sdf|) or mf (learned medial field); qmdf.medial.radii says why data",
    )
    centre: bool = param(
        True,
        doc="with radius=data: the membrane's vertices move onto the data's axis (sheet.centre's step), in "
        "membrane.ma and where the membrane is the MAT (the kitten's non-compact sheet: CD 7.04e-3 -> 4.30e-3)",
    )
    coverage_vertices: int = param(
        1000,
        ge=0,
        doc="with radius=data, where the membrane is the MAT (a sheet that is not compact): up to this many "
        "vertices added where its envelope falls short of the surface (sheet.coverage_vertices' step, "
        "medial.coverage, with its default settings); membrane.ma stays as contracted",
    )
    sheet_fit_slack: float = param(
        3.0,
        ge=1,
        doc="with radius=data: a compact sheet whose envelope fits the data worse than this many times the "
        "membrane's (medial.coverage.envelope_fit's CD) is not the MAT; the membrane is, with a warning (the sharp "
        "sphere's sheet, from a covering of genus 31: 6.9x, CD 5.0e-3 against 0.74e-3; the exact ellipsoid's "
        "2,000-vertex disc 1.7x, CD 1.7e-4 against 1.0e-4, kept)",
    )


@register_stage("export")
class Export(Stage):
    """Write the MAT (.ma, .ply with radius, .obj) in both frames, and its reconstructed surface."""

    Config = ExportConfig
    inputs = {"membrane": MESH, "field": FIELD, "normalization": NORMALIZATION}
    optional_inputs = {
        "covering": MESH,
        "surface": MESH,
        "points": POINTS,
        "input_info": JSON,
        "sheet": MAT,
        "sheet_stats": JSON,
        "medial_rays": RAYS,
        "point_surface": MESH,
    }
    outputs = {
        "mat": MAT,
        "mat_input_units": file_kind(".ma"),
        "mat_ply": file_kind(".ply"),
        "mat_ply_input_units": file_kind(".ply"),
        "mat_obj": file_kind(".obj"),
        "mat_obj_input_units": file_kind(".obj"),
        "reconstruction": MESH,
        "membrane_mat": MAT,
    }
    # 2: the single sheet when present; the membrane as membrane.ma; 3: centre_on_data; 4: coverage; 5: coverage
    # kept only where it improves the envelope's fit; 6: surface balls centred inside the mesh;
    # 7: a vertex outside goes to the surface with radius 0; 8: a sheet that fits worse than the membrane is not
    # the MAT; 9: the centring's bisection starts at the vertex's own depth and stops at tol / 8
    # 10: a cloud measured against its Poisson surface (train.point_surface_as_data); 11: a sheet that fits the data
    # within the sheet's tolerance is not compared with the membrane
    version = "11"

    def run(self, ctx: StageContext) -> None:
        from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh
        from qmdf.geometry.ma_format import MedialMesh, write_ma, write_obj, write_ply_with_radius

        norm = ctx.load("normalization")
        mesh, points = input_data(ctx) if ctx.cfg.radius == "data" else (None, None)
        field = ctx.load("field")
        membrane = membrane_to_mat(ctx.load("membrane"), field, ctx.cfg.radius, mesh, points, centre=ctx.cfg.centre)
        ctx.save("membrane_mat", membrane)
        sheet_stats = ctx.load("sheet_stats") if ctx.has("sheet_stats") else {}
        use_sheet = ctx.has("sheet") and sheet_stats.get("compact", True)
        mat = ctx.load("sheet") if use_sheet else membrane
        wanted = ctx.cfg.radius == "data" and (use_sheet or ctx.cfg.coverage_vertices)
        balls = input_surface_balls(ctx, field, mesh, points) if wanted else None
        # a sheet whose envelope the sheet stage found within its tolerance of the data needs no comparison (the
        # membrane's own fit is the costly one: a sphere's, thousands of balls all reaching every sample, 20 s)
        if use_sheet and balls is not None and not sheet_stats.get("fits_data", False):
            use_sheet = self._sheet_fits(ctx, mat, membrane, balls)
            mat = mat if use_sheet else membrane
        if not use_sheet and balls is not None and ctx.cfg.coverage_vertices:
            mat = self._covered(ctx, mat, balls)
        v, radii = mat.vertices, mat.radii
        recon = reconstruct_mesh(EnvelopeUnion.from_mat(mat), ctx.cfg.reconstruction_resolution)
        if recon is None:
            raise QmdfError(
                f"the MAT's balls enclose no volume at export.reconstruction_resolution "
                f"{ctx.cfg.reconstruction_resolution} ({len(v)} vertices, largest radius {radii.max(initial=0.0):.3g} "
                "in the unit box): the field learned too little inside (see the train stage's slices.png). "
                "Train longer (train.steps) or check the input"
            )
        ctx.save("mat", mat)
        in_units = MedialMesh(norm.to_input(v), norm.length_to_input(radii), mat.edges, mat.faces)
        write_ma(ctx.path("mat_input_units"), in_units)
        write_ply_with_radius(ctx.path("mat_ply"), mat)
        write_ply_with_radius(ctx.path("mat_ply_input_units"), in_units)
        write_obj(ctx.path("mat_obj"), mat)
        write_obj(ctx.path("mat_obj_input_units"), in_units)
        ctx.save("reconstruction", recon)
        if ctx.cfg.picture:
            from qmdf.geometry.metrics import seam_edges
            from qmdf.viz import render_mesh

            lone = mat.lone_edges()
            render_mesh(
                ctx.stage_dir / "mat.png",
                v,
                mat.faces,
                radii,
                label="radius (unit box)",
                title=f"medial mesh: {len(v)} vertices, {len(mat.faces)} faces; lone edges black, seams red",
                lines=((lone, "black"), (seam_edges(mat.faces), "red")),
            )
            if ctx.has("covering"):
                cov = ctx.load("covering")
                render_mesh(ctx.stage_dir / "covering_before.png", cov.vertices, cov.faces, title="eps-covering")
                render_mesh(
                    ctx.stage_dir / "covering_after.png",
                    membrane.vertices,
                    membrane.faces,
                    title="after contraction (the membrane)",
                )
        ctx.log.info(
            "MAT (%s): %d vertices, %d faces, radius %.3g..%.3g (unit box); reconstruction %d faces",
            "single sheet" if use_sheet else "membrane",
            len(v),
            len(mat.faces),
            radii.min(),
            radii.max(),
            len(recon.faces),
        )

    @staticmethod
    def _sheet_fits(ctx: StageContext, sheet, membrane, balls) -> bool:
        from qmdf.medial.coverage import envelope_fit

        sheet_cd, membrane_cd = (
            envelope_fit(m.vertices, m.radii, m.lone_edges(), m.faces, balls, np.random.default_rng(ctx.seed))[
                "chamfer"
            ]
            for m in (sheet, membrane)
        )
        fits = sheet_cd <= ctx.cfg.sheet_fit_slack * membrane_cd
        if not fits:
            ctx.log.warning(
                "the single sheet's envelope fits the data %.1fx worse than the membrane's (CD %.3e against %.3e; "
                "export.sheet_fit_slack %.2g): the membrane is the MAT, the sheet stays in the sheet stage's folder",
                sheet_cd / membrane_cd,
                sheet_cd,
                membrane_cd,
                ctx.cfg.sheet_fit_slack,
            )
        return fits

    @staticmethod
    def _covered(ctx: StageContext, mat, balls):
        from qmdf.medial.coverage import cover_mat

        covered, stats = cover_mat(mat, balls, ctx.cfg.coverage_vertices, ctx.seed)
        if stats["added"]:
            ctx.log.info(
                "coverage of the membrane: %d vertices added; the surface outside the envelope by %.2e on average "
                "(was %.2e); CD %.3e against %.3e before: %s",
                stats["added"],
                stats.get("shortfall_after", {}).get("mean", float("nan")),
                stats.get("shortfall_before", {}).get("mean", float("nan")),
                stats["chamfer_after"],
                stats["chamfer_before"],
                "kept" if stats["kept"] else "not kept",
            )
        return covered
