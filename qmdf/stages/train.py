"""``train``: the joint SDF + medial field with PyTorch Lightning, supervised by what the input carries (the mesh,
oriented or raw points: ``qmdf.fields.supervision``), or by the raw points alone as in the paper. Its settings in
groups: ``train.model``, ``train.supervision``, ``train.optim``, ``train.trainer`` (``qmdf.fields.settings``)."""

from __future__ import annotations

from dataclasses import dataclass

from qmdf import schema
from qmdf.artifacts import FIELD, JSON, MESH, NORMALIZATION, POINTS, RAYS
from qmdf.fields.settings import ModelSettings, OptimSettings, SupervisionSettings, TrainerSettings
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class TrainConfig:
    model: ModelSettings = param(factory=ModelSettings)
    supervision: SupervisionSettings = param(factory=SupervisionSettings)
    optim: OptimSettings = param(factory=OptimSettings)
    trainer: TrainerSettings = param(factory=TrainerSettings)

    def check(self) -> list[tuple[str, str]]:
        from qmdf.fields.backbones import BACKBONES
        from qmdf.fields.losses import LOSSES

        problems: list[tuple[str, str]] = []
        if self.model.backbone not in BACKBONES:
            problems.append(("model.backbone", BACKBONES.why_missing(self.model.backbone)))
        problems += schema.check_registered(self.model.backbones, BACKBONES, "model.backbones")
        for table in ("losses", "paper_losses"):
            problems += schema.check_registered(getattr(self.optim, table), LOSSES, f"optim.{table}")
        if "." not in str(self.trainer.logger.get("_target_", "")):
            problems.append(
                ("trainer.logger._target_", "must name a logger class, e.g. lightning.pytorch.loggers.CSVLogger")
            )
        return problems


@register_stage("train")
class Train(Stage):
    """Fit sdf, mf_inner, mf_outer to the sampled points; write the field for every later stage."""

    Config = TrainConfig
    inputs = {"points": POINTS, "normalization": NORMALIZATION}
    optional_inputs = {"surface": MESH, "input_info": JSON}
    outputs = {"field": FIELD, "training": JSON}
    optional_outputs = {"medial_rays": RAYS, "point_surface": MESH}
    version = "20"  # docs/history.md lists what each version changed; 20: given normals turned only where contradicted

    @classmethod
    def cache_config(cls, section: dict) -> dict:
        """Only the chosen backbone's settings: a change to another backbone's does not retrain this one."""
        model = dict(section.get("model") or {})
        chosen = model.get("backbone")
        model["backbones"] = {chosen: (model.get("backbones") or {}).get(chosen)}
        return {**section, "model": model}

    def run(self, ctx: StageContext) -> None:
        import torch

        from qmdf.stages.training import fit_field, route_losses, supervise

        cfg: TrainConfig = ctx.cfg
        points = ctx.load("points").points
        sup = supervise(ctx, cfg.supervision)
        # the medial ball behind each ray's origin, measured once for training, coverage and the fit alike (the
        # teacup's mesh: 10 s in sheet -> 0.5 s; a 3,000-point sphere's Poisson surface: every query near its
        # centre equally near every face, minutes in sheet)
        proxy_is_data = sup.proxy_mesh is not None and cfg.supervision.point_surface_as_data
        if (sup.route == "mesh" and sup.stats.get("mesh_rays") == "smooth") or proxy_is_data:
            origins = points if sup.ray_origins is None else sup.ray_origins
            rays = {"origins": origins, "directions": sup.ray_normals, "radii": sup.radii}
            ctx.save("medial_rays", {**rays, "tol": sup.stats["ray_tolerance"]})
        if proxy_is_data:
            import trimesh

            ctx.save("point_surface", trimesh.Trimesh(*sup.proxy_mesh, process=False))
        field, fitted = fit_field(ctx, cfg, sup, route_losses(cfg.optim, sup.route), cfg.optim)
        history = fitted["history"]
        final = history[-1] if history else {}
        record = {"steps": cfg.optim.steps, "final_losses": final, **fitted, "supervision": sup.stats}
        ctx.save("training", {**record, "torch_threads": torch.get_num_threads()})
        if cfg.trainer.picture:
            from qmdf.viz import plot_field_slices, plot_losses

            plot_field_slices(ctx.stage_dir / "slices.png", field)
            plot_losses(ctx.stage_dir / "losses.png", history)
        ctx.log.info(
            "trained %d steps on %d points; final total loss %.4g",
            *(cfg.optim.steps, len(points), final.get("loss/total", float("nan"))),
        )
