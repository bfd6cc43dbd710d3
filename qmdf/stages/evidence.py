"""What the evaluate stage reads besides the MAT, gathered from the run's artifacts: the reference it scores
against, and what it hands the run's verdict (``qmdf.verdict``): the MAT's structural defects against the data it
was built from, and the evidence of every other check."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qmdf.stage import StageContext


def structure(ctx: StageContext, mat, field) -> dict:
    """``mat_structure.structural_defects`` against the data the MAT was built from (``stages.inputs.input_data``:
    an input mesh, else a cloud's Poisson surface, else its points with the learned sign as the inside), not
    against a clean reference: a noisy cloud's balls may stand out of the clean surface by its noise; {} where
    there is no inside to check against."""
    from qmdf.geometry.mat_structure import structural_defects
    from qmdf.medial.radii import data_distance, inside_test
    from qmdf.stages.inputs import input_data

    mesh, points = input_data(ctx)
    if mesh is None and (points is None or field is None):
        return {}
    distance, _ = data_distance(mesh, points)
    return structural_defects(
        mat.vertices, mat.radii, mat.edges, mat.faces, lambda q: distance(q)[0], inside_test(field, mesh)
    )


def evidence(ctx: StageContext, metrics: dict, recon, field, ref_v: np.ndarray, ref_f: np.ndarray | None):
    """What the verdict checks (``qmdf.verdict.Evidence``), from the run's artifacts. The input's solid: the
    reference mesh where it is closed, else a cloud's closed Poisson surface."""
    import trimesh

    from qmdf.geometry.metrics import solid_euler
    from qmdf.verdict import Evidence, zero_set_distance

    e = Evidence(chi=metrics["chi"], vertices=metrics["vertices"], structure=metrics.get("structure") or None)
    e.sign_accuracy = (metrics.get("field") or {}).get("sign_accuracy")
    e.volume = float(recon.volume) if recon is not None and recon.is_watertight else None
    sup = (ctx.load("training").get("supervision") or {}) if ctx.has("training") else {}
    e.orientation, e.proxy = sup.get("orientation"), sup.get("proxy")
    e.proxy_pieces = (sup.get("proxy_surface") or {}).get("pieces")
    upsample = sup.get("upsample") or {}
    if "resolved_euler" in upsample and not upsample.get("fallback"):  # the surface of the new points was kept
        e.proxy_euler = (upsample["solid_euler"], upsample["resolved_euler"])
    if field is not None and ctx.has("points"):
        e.zero_set_distance = zero_set_distance(field.evaluate(ctx.load("points").points)["sdf"])
    solid = trimesh.Trimesh(ref_v, ref_f, process=False) if ref_f is not None else None
    if (solid is None or not solid.is_watertight) and ctx.has("point_surface"):
        solid = ctx.load("point_surface")
    if solid is not None and solid.is_watertight:
        e.input_volume, e.input_chi = float(abs(solid.volume)), solid_euler(np.asarray(solid.faces))
    return e


def reference_path(ctx: StageContext) -> Path:
    """``evaluate.reference`` resolved against the caller's directory."""
    from qmdf.stages.sample import resolve_input_path

    return resolve_input_path(ctx.cfg.reference, ctx.settings.base_dir)


def reference(ctx: StageContext) -> tuple[np.ndarray, np.ndarray | None, str]:
    """What evaluate scores against: the reference's vertices (or points) in the unit box, its faces (None for
    points), and what it is: ``evaluate.reference``, else the input surface, else the input points before
    degradations."""
    if ctx.cfg.reference:
        from qmdf.errors import QmdfError
        from qmdf.geometry.io import load_geometry

        if not ctx.has("normalization"):
            raise QmdfError("evaluate.reference needs the run's normalization (a pipeline with the sample stage)")
        ref = load_geometry(reference_path(ctx))
        v = ctx.load("normalization").to_unit(ref.points.points)
        return v, ref.faces, f"evaluate.reference ({Path(ctx.cfg.reference).name})"
    if ctx.has("surface"):
        ref = ctx.load("surface")
        return np.asarray(ref.vertices), np.asarray(ref.faces), "input surface"
    clean = ctx.load("clean_points") if ctx.has("clean_points") else ctx.load("points")  # before degradations
    return clean.points, None, "input points"
