"""``evaluate``: the paper's metrics of the run's MAT against the input (Sec. 5.1), in ``metrics.json``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MAT, MESH, POINTS, TETS
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class EvaluateConfig:
    samples: int = param(100_000, ge=100, doc="samples per surface for CD / HD")
    resolution: int = param(128, ge=16, le=1024, doc="grid of the meshed reconstruction (sampling, pictures, mesh output)")
    picture: bool = param(True, doc="write reconstruction.png coloured by the distance to the reference")
    fold_deg: float = param(150.0, gt=90, lt=180, doc="a closed membrane's boundary: edges where the normals turn by more than this")
    field_samples: int = param(100_000, ge=0, doc="volume samples for the field's sign accuracy against the reference mesh (0: skip)")


@register_stage("evaluate")
class Evaluate(Stage):
    """CD / HD of the MAT's reconstruction against the input surface, chi, boundary smoothness, radii."""

    Config = EvaluateConfig
    inputs = {"mat": MAT}
    optional_inputs = {"surface": MESH, "clean_points": POINTS, "contracted_tets": TETS, "reconstruction": MESH,
                       "field": FIELD}
    outputs = {"metrics": JSON}
    optional_outputs = {"reconstruction": MESH}  # when no earlier stage meshed it
    version = "2"  # 2: the field's sign accuracy and metric inside

    def run(self, ctx: StageContext) -> None:
        from qmdf.evaluate import score_mat

        mat = ctx.load("mat")
        if ctx.has("surface"):
            ref = ctx.load("surface")
            ref_v, ref_f = np.asarray(ref.vertices), np.asarray(ref.faces)
        else:
            ref_v, ref_f = ctx.load("clean_points").points, None
        picture = ctx.stage_dir / "reconstruction.png" if ctx.cfg.picture else None
        given = ctx.load("reconstruction") if ctx.has("reconstruction") else None
        metrics, recon = score_mat(mat, ref_v, ref_f, ctx.cfg.samples, ctx.cfg.resolution, ctx.seed, picture,
                                   return_mesh=True, fold_deg=ctx.cfg.fold_deg, recon_mesh=given)
        metrics["reference"] = "input surface" if ctx.has("surface") else "input points"
        if ctx.has("contracted_tets"):  # the paper's chi: V - E + F - C of the contracted covering
            from qmdf.geometry.metrics import euler_tetrahedral

            verts, tets = ctx.load("contracted_tets")
            metrics["chi_membrane"] = metrics["chi"]
            metrics["chi"] = euler_tetrahedral(len(verts), tets)
            metrics["chi_rule"] = "V - E + F - C of the contracted tetrahedral covering"
        if ctx.has("surface") and ctx.has("field") and ctx.cfg.field_samples:
            from qmdf.fields.quality import field_quality

            metrics["field"] = field_quality(ctx.load("field"), ref_v, ref_f, ctx.cfg.field_samples, ctx.seed)
            ctx.log.info("field: sign accuracy %.4f, mean |grad sdf| inside %s", metrics["field"]["sign_accuracy"],
                         metrics["field"]["grad_sdf_inside"])
        ctx.save("metrics", metrics)
        if given is None:
            ctx.save("reconstruction", recon)
        ctx.log.info(
            "CD %.3e  HD %.3e  chi %d  V %d  F %d  (%s)", metrics["chamfer"], metrics["hausdorff"], metrics["chi"],
            metrics["vertices"], metrics["faces"], metrics["reference"],
        )
