"""``export``: the MAT in the unit box and in the input's own units: ``.ma`` (Q-MAT / MATTopo format), PLY with a
``radius`` vertex property, OBJ; and the surface the MAT reconstructs (union of its primitives' envelopes),
meshed. The MAT is the single sheet when a ``sheet`` stage ran, else the contracted membrane, with the sheet's
settings (``sheet.radius``; centred and covered where ``sheet.steps`` centre and cover); the membrane is written as
``membrane.ma`` either way, for comparison."""

from __future__ import annotations

from dataclasses import dataclass


from qmdf.artifacts import FIELD, JSON, MAT, MESH, NORMALIZATION, POINTS, RAYS, file_kind
from qmdf.errors import QmdfError
from qmdf.medial.radii import membrane_to_mat
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage
from qmdf.stages.inputs import input_data, input_surface_balls


@dataclass
class ExportConfig:
    reconstruction_resolution: int = param(
        128, ge=16, le=1024, doc="grid nodes along the meshed reconstruction's longest side"
    )
    picture: bool = param(True, doc="the medial mesh coloured by radius, and the covering before/after contraction")
    sheet_fit_slack: float = param(
        3.0,
        ge=1,
        doc="with radius=data: a compact sheet whose envelope fits the data worse than this many times the "
        "membrane's (medial.coverage.keeps) is not the MAT; the membrane is, with a warning (the sharp sphere's "
        "sheet, from a covering of genus 31: 6.9x; the exact ellipsoid's 2,000-vertex disc 1.7x, kept)",
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
    config_deps = ("seed", "sheet")  # the radius source, centring and coverage: the sheet's settings
    version = "13"  # docs/history.md lists what each version changed; 13: the membrane centred where it may be the MAT

    def run(self, ctx: StageContext) -> None:
        from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh
        from qmdf.geometry.ma_format import MedialMesh, write_ma, write_obj, write_ply_with_radius

        sheet = ctx.sections["sheet"]
        from_data = sheet.radius == "data"
        mesh, points = input_data(ctx) if from_data else (None, None)
        sheet_stats = ctx.load("sheet_stats") if ctx.has("sheet_stats") else {}
        # centred where it may be the MAT, not beside a sheet that fits the data (a sphere's: 74 s, unused)
        field, centre = ctx.load("field"), "centre" in sheet.steps and not sheet_stats.get("fits_data", False)
        membrane = membrane_to_mat(ctx.load("membrane"), field, sheet.radius, mesh, points, centre=centre)
        ctx.save("membrane_mat", membrane)
        use_sheet = ctx.has("sheet") and sheet_stats.get("compact", True)
        mat = ctx.load("sheet") if use_sheet else membrane
        cover = from_data and "coverage" in sheet.steps
        balls = input_surface_balls(ctx, field, mesh, points) if from_data and (use_sheet or cover) else None
        # a sheet whose envelope the sheet stage found within its tolerance of the data needs no comparison (the
        # membrane's own fit is the costly one: a sphere's, thousands of balls all reaching every sample, 20 s)
        if use_sheet and balls is not None and not sheet_stats.get("fits_data", False):
            use_sheet = self._sheet_fits(ctx, mat, membrane, balls)
            mat = mat if use_sheet else membrane
        if not use_sheet and cover:
            mat = self._covered(ctx, mat, balls, sheet)
        v, radii = mat.vertices, mat.radii
        recon = reconstruct_mesh(EnvelopeUnion.from_mat(mat), ctx.cfg.reconstruction_resolution)
        if recon is None:
            raise QmdfError(
                f"the MAT's balls enclose no volume at export.reconstruction_resolution "
                f"{ctx.cfg.reconstruction_resolution} ({len(v)} vertices, largest radius {radii.max(initial=0.0):.3g} "
                "in the unit box): the field learned too little inside (see the train stage's slices.png). "
                "Train longer (train.optim.steps) or check the input"
            )
        ctx.save("mat", mat)
        ctx.save("reconstruction", recon)
        norm = ctx.load("normalization")
        in_units = MedialMesh(norm.to_input(v), norm.length_to_input(radii), mat.edges, mat.faces)
        for name, write, m in (
            ("mat_input_units", write_ma, in_units),
            ("mat_ply", write_ply_with_radius, mat),
            ("mat_ply_input_units", write_ply_with_radius, in_units),
            ("mat_obj", write_obj, mat),
            ("mat_obj_input_units", write_obj, in_units),
        ):
            write(ctx.path(name), m)
        if ctx.cfg.picture:
            from qmdf.viz import render_mat_pictures

            render_mat_pictures(ctx.stage_dir, mat, ctx.load("covering") if ctx.has("covering") else None, membrane)
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
        from qmdf.medial.coverage import judged

        fits, sheet_cd, membrane_cd = judged(sheet, membrane, balls, ctx.seed, ctx.cfg.sheet_fit_slack)
        if not fits:
            ctx.log.warning(
                "the single sheet's envelope fits the data %.1fx worse than the membrane's (CD %.3e against %.3e; "
                "export.sheet_fit_slack %.2g): the membrane is the MAT, the sheet stays in the sheet stage's folder",
                *(sheet_cd / membrane_cd, sheet_cd, membrane_cd, ctx.cfg.sheet_fit_slack),
            )
        return fits

    @staticmethod
    def _covered(ctx: StageContext, mat, balls, sheet):
        """Where the membrane is the MAT: the sheet's coverage step on it, with the sheet's settings, kept where it
        fits better (``medial.coverage.cover_mat``; no return to the budget: the membrane has none)."""
        from qmdf import schema
        from qmdf.medial.coverage import CoverageSettings, cover_mat

        c = schema.build(CoverageSettings, sheet.step.get("coverage") or {})
        settings = dict(tolerance=sheet.tolerance, spacing=c.spacing, overshoot=c.overshoot, max_rounds=c.rounds)
        covered, s = cover_mat(mat, balls, c.vertices, ctx.seed, **settings)
        if s["added"]:
            ctx.log.info(
                "coverage of the membrane: %d vertices added; CD %.3e against %.3e before: %s",
                *(s["added"], s["chamfer_after"], s["chamfer_before"], "kept" if s["kept"] else "not kept"),
            )
        return covered
