"""``feature_retrain``: continue training from the field with the sharp-feature terms (paper Sec. 4.3):
L_sharp1 = mean |sdf(p_i)| pins the zero level set onto the feature points, L_sharp2 = mean |mf(p_i)| drives
the medial field to zero there (the paper sums mf, a radius; |.| because our heads can go negative), so the
medial axis reaches the sharp edges. Not in the paper: behind each convex feature whose two faces' normals
are known (from a mesh, or from feature_detect's two-plane fits on a point cloud) the sheet is known too
(its bisector, as far as the input points allow, ``qmdf.geometry.bisectors``), and sdf = -r, mf = r are
asked there. The training settings (model, supervision, losses, batches, trainer) are ``train``'s, and so is the
fit (``qmdf.stages.training.fit_field``); put cover, contract and export again after this stage: the earlier ones
keep the result before enhancement for comparison."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MESH, NORMALIZATION, POINTS
from qmdf.errors import QmdfError
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class FeatureRetrainConfig:
    steps: int = param(500, ge=1, doc="more steps from the trained field")
    lr: float = param(3e-4, gt=0, doc="a gentler start than train.optim.lr: the field is already fitted")
    lr_final: float = param(1e-5, gt=0)
    weight_sdf: float = param(3000.0, ge=0, doc="L_sharp1 = mean |sdf| at the feature points (like the surface term)")
    weight_mf: float = param(100.0, ge=0, doc="L_sharp2 = mean |mf| at the feature points")
    bisector_weight: float = param(
        1000.0,
        ge=0,
        doc="not in the paper: mean |sdf + r| + |mf - r| at medial points "
        "walked along the inward bisector of each feature (0: the paper's losses only)",
    )
    bisector_length: float = param(
        0.3, ge=0, doc="how far each bisector walk may go (unit box); the walks stop earlier where the sheet ends"
    )
    bisector_spacing: float = param(0.005, gt=0, doc="step of the bisector walks")
    bisector_batch: int = param(4096, ge=1, doc="bisector samples per training step")


@register_stage("feature_retrain")
class FeatureRetrain(Stage):
    """Retrain the field with the detected feature points."""

    Config = FeatureRetrainConfig
    inputs = {"field": FIELD, "points": POINTS, "normalization": NORMALIZATION, "feature_points": POINTS}
    # the supervision route, as train's; the data the bisector walks are checked against
    optional_inputs = {"surface": MESH, "input_info": JSON, "point_surface": MESH}
    outputs = {"field": FIELD, "training": JSON}
    config_deps = ("seed", "train")
    version = "6"  # docs/history.md lists what each version changed; 6: train's fit (fields seeded alike)

    def run(self, ctx: StageContext) -> None:
        import dataclasses

        from qmdf.fields.field import Field
        from qmdf.geometry.bisectors import bisector_samples
        from qmdf.stages.training import fit_field, route_losses, supervise

        cfg: FeatureRetrainConfig = ctx.cfg
        field = ctx.load("field")
        if not isinstance(field, Field):
            raise QmdfError("feature_retrain needs a trained field (not an analytic one)")
        features = ctx.load("feature_points")
        feats = features.points
        if len(feats) == 0:
            raise QmdfError(
                "feature_detect found no feature points; lower feature_detect.dihedral_deg or raise "
                "feature_detect.max_radius"
            )
        points = ctx.load("points").points
        medial, radii = np.zeros((0, 3)), np.zeros(0)
        if cfg.bisector_weight > 0 and features.normals is not None:
            medial, radii = bisector_samples(
                feats, features.normals, points, cfg.bisector_length, cfg.bisector_spacing, **_walk_checks(ctx, field)
            )
        train = ctx.sections["train"]
        optim = dataclasses.replace(train.optim, lr=cfg.lr, lr_final=cfg.lr_final, steps=cfg.steps)
        sup = supervise(ctx, train.supervision)
        # the paper's L_sharp1 / L_sharp2 and the bisectors' medial samples, beside the route's own terms
        losses = {
            **route_losses(train.optim, sup.route),
            "sharp_sdf": {"weight": cfg.weight_sdf},
            "sharp_mf": {"weight": cfg.weight_mf},
            "sharp_medial": {"weight": cfg.bisector_weight, "batch": cfg.bisector_batch},
        }
        anchors = {"feature_points": feats, "medial_points": medial, "medial_radii": radii}
        out, fitted = fit_field(ctx, train, sup, losses, optim, start=field, anchors=anchors)
        before, after = field.evaluate(feats), out.evaluate(feats)
        stats = {
            "steps": cfg.steps,
            "feature_points": int(len(feats)),
            "bisector_samples": int(len(medial)),
            "device": fitted["device"],
            "feature_abs_sdf_before": float(abs(before["sdf"]).mean()),
            "feature_abs_sdf_after": float(abs(after["sdf"]).mean()),
            "feature_mf_before": float(abs(before["mf"]).mean()),
            "feature_mf_after": float(abs(after["mf"]).mean()),
            "history": fitted["history"],
            "axis_q": fitted["axis_q"],
            "supervision": sup.stats,  # as train's: the route's record (a cloud's Poisson surface's topology)
        }
        ctx.save("training", stats)
        ctx.log.info(
            "feature_retrain: at %d feature points |sdf| %.2e -> %.2e, |mf| %.2e -> %.2e; %d bisector samples%s",
            len(feats),
            stats["feature_abs_sdf_before"],
            stats["feature_abs_sdf_after"],
            stats["feature_mf_before"],
            stats["feature_mf_after"],
            len(medial),
            "" if features.normals is not None else " (the feature points carry no face normals: none walked)",
        )


def _walk_checks(ctx: StageContext, field) -> dict:
    """The bisector walks' distance, its tolerance and inside test: the input mesh's exact distance and winding
    number when the input is an undegraded mesh, else the input points and the trained field's sign."""
    from qmdf.medial.radii import data_distance, inside_test
    from qmdf.stages.inputs import input_data

    mesh, data_points = input_data(ctx)
    distance, tol = data_distance(mesh, data_points)
    return {"distance": lambda q: distance(q)[0], "tol": tol, "is_inside": inside_test(field, mesh)}
