"""``train``: the joint SDF + medial field from the sampled points (no normals), with PyTorch Lightning."""
from __future__ import annotations

import logging
import sys
from dataclasses import dataclass
from typing import Any

from qmdf import schema
from qmdf.artifacts import FIELD, JSON, NORMALIZATION, POINTS
from qmdf.errors import QmdfError
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


def _default_losses() -> dict:
    from qmdf.fields.losses import default_losses

    return default_losses()


def _default_backbones() -> dict:
    """Every registered backbone's settings, so `train.backbones.NAME.key=value` always has a place."""
    from qmdf.fields.backbones import BACKBONES

    return {e.name: schema.defaults_of(e.config) for e in BACKBONES.entries()}


@dataclass
class TrainConfig:
    backbone: str = param("mlp", doc="network trunk (python -m qmdf.plugins lists them)")
    backbones: dict[str, Any] = param(factory=_default_backbones, doc="each backbone's settings; the chosen one is used")
    medial_field: bool = param(True, doc="train the medial field too; false: the paper's 'w/o MF' ablation")
    steps: int = param(1500, ge=1)
    surface_batch: int = param(4096, ge=16, doc="input points per step (paper: 4096)")
    volume_batch: int = param(4096, ge=16, doc="volume samples per step")
    uniform_fraction: float = param(0.5, ge=0, le=1, doc="share of volume samples uniform in the box; the rest near the points")
    lr: float = param(1e-3, gt=0)
    lr_final: float = param(1e-4, gt=0, doc="cosine decay down to this")
    losses: dict[str, Any] = param(factory=_default_losses, doc="loss name -> {weight, ...}; weight 0 disables")
    checkpoint_every: int = param(250, ge=1, doc="steps between checkpoints (resume, and the last good state on divergence)")
    resume: bool = param(True, doc="continue from the last checkpoint of an interrupted run with the same key")
    logger: str = param("csv", choices=("csv", "tensorboard", "wandb"), doc="wandb runs offline without WANDB_API_KEY")
    accelerator: str = param("auto", doc="Lightning accelerator: auto uses a GPU when there is one")
    progress_bar: str = param("auto", choices=("auto", "on", "off"), doc="auto: only when stderr is a terminal")
    picture: bool = param(True, doc="cut-plane pictures of SDF, MF, Q-MDF and the loss curves")

    def check(self) -> list[tuple[str, str]]:
        from qmdf.fields.backbones import BACKBONES
        from qmdf.fields.losses import LOSSES

        problems: list[tuple[str, str]] = []
        if self.backbone not in BACKBONES:
            problems.append(("backbone", BACKBONES.why_missing(self.backbone)))
        for name, params in self.backbones.items():
            if name not in BACKBONES:
                problems.append((f"backbones.{name}", BACKBONES.why_missing(name)))
            else:
                cfg = BACKBONES.get(name).config
                problems += [(p.key, p.message) for p in schema.check_section(cfg, params or {}, f"backbones.{name}")]
        for name, params in self.losses.items():
            if name not in LOSSES:
                problems.append((f"losses.{name}", LOSSES.why_missing(name)))
            else:
                problems += [(p.key, p.message) for p in schema.check_section(LOSSES.get(name).config, params or {}, f"losses.{name}")]
        return problems


@register_stage("train")
class Train(Stage):
    """Fit sdf, mf_inner, mf_outer to the sampled points; write the field for every later stage."""

    Config = TrainConfig
    inputs = {"points": POINTS, "normalization": NORMALIZATION}
    outputs = {"field": FIELD, "training": JSON}
    version = "2"  # 2: the initial weights are seeded

    def run(self, ctx: StageContext) -> None:
        import torch

        from qmdf.fields.field import Field
        from qmdf.fields.module import FieldModule

        cfg: TrainConfig = ctx.cfg
        input_points = ctx.load("points")
        points = input_points.points
        params = dict(cfg.backbones.get(cfg.backbone) or {})
        torch.manual_seed(ctx.seed)  # the initial weights (and Fourier frequencies) too: the same seed, the same field
        module = FieldModule(cfg.backbone, params, cfg.losses, cfg.medial_field, cfg.lr, cfg.lr_final, cfg.steps)
        device = fit(ctx, cfg, module, points, cfg.steps, training_normals(ctx, cfg, input_points))
        field = Field(module.net.cpu(), ctx.load("normalization"),
                      {"backbone": cfg.backbone, "backbone_params": params}, device="cpu")
        field.save(ctx.path("field"))
        final = module.history[-1] if module.history else {}
        ctx.save("training", {"steps": cfg.steps, "final_losses": final, "history": module.history,
                              "device": device, "torch_threads": torch.get_num_threads()})
        if cfg.picture:
            from qmdf.viz import plot_field_slices, plot_losses

            plot_field_slices(ctx.stage_dir / "slices.png", field)
            plot_losses(ctx.stage_dir / "losses.png", module.history)
        ctx.log.info("trained %d steps on %d points; final total loss %.4g", cfg.steps, len(points), final.get("loss/total", float("nan")))


def training_normals(ctx: StageContext, cfg: TrainConfig, points):
    """The input points' normals when the ``normal`` loss is on; None (with a warning) when they have none."""
    if float((cfg.losses.get("normal") or {}).get("weight", 0.0)) <= 0:
        return None
    if points.normals is None:
        ctx.log.warning("train.losses.normal is on but the input points carry no normals: the term does nothing")
    return points.normals


def fit(ctx: StageContext, cfg: TrainConfig, module, points, steps: int, normals=None) -> str:
    """Train ``module`` for ``steps`` with Lightning in the stage's work folder (checkpoints, resume, loggers);
    returns the device it ran on. ``normals``: the points' outward normals, for the ``normal`` loss. Used by
    train and by feature_retrain."""
    import gc
    import warnings

    import lightning as L
    import torch

    from qmdf.fields.data import StepBatches, loader
    from qmdf.fields.module import Diverged

    L.seed_everything(ctx.seed, workers=True, verbose=False)
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")  # Lightning's own deprecation noise, not ours
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    work = ctx.work_dir
    last = work / "last.ckpt"
    resume = str(last) if cfg.resume and last.exists() else None
    done = int(torch.load(last, map_location="cpu", weights_only=True)["global_step"]) if resume else 0
    data = StepBatches(points, steps, cfg.surface_batch, cfg.volume_batch, cfg.uniform_fraction, ctx.seed, start=done,
                       normals=normals)
    checkpoint = L.pytorch.callbacks.ModelCheckpoint(dirpath=work, save_last=True, save_top_k=0,
                                                     every_n_train_steps=cfg.checkpoint_every)
    show_bar = cfg.progress_bar == "on" or (cfg.progress_bar == "auto" and sys.stderr.isatty())
    trainer = L.Trainer(
        max_steps=steps, max_epochs=1, accelerator=cfg.accelerator, devices=1, logger=_logger(cfg, ctx),
        callbacks=[checkpoint], enable_progress_bar=show_bar, enable_model_summary=False,
        log_every_n_steps=10, num_sanity_val_steps=0, limit_val_batches=0, default_root_dir=str(work),
    )
    if resume:
        ctx.log.info("resuming from %s (step %d of %d)", last, done, steps)
    try:
        trainer.fit(module, train_dataloaders=loader(data), ckpt_path=resume)
    except Diverged as exc:
        keep = f"; the last good checkpoint is {last}" if last.exists() else ""
        raise QmdfError(f"training diverged: {exc}{keep}. Lower train.lr or check the input") from None
    finally:
        for logger in trainer.loggers:
            logger.finalize("success")
        if cfg.logger == "wandb":
            import wandb

            wandb.finish()  # one wandb run per job, also in a multirun
        # Nothing of Lightning may outlive the stage: its loggers would flush into this scratch folder
        # after the pipeline moved it into place.
        device = str(trainer.strategy.root_device)
        del trainer
        gc.collect()
    return device


def _logger(cfg: TrainConfig, ctx: StageContext):
    import os

    from lightning.pytorch import loggers

    if cfg.logger == "tensorboard":
        return loggers.TensorBoardLogger(save_dir=str(ctx.stage_dir), name="tensorboard")
    if cfg.logger == "wandb":
        mode = "online" if os.environ.get("WANDB_API_KEY") else "offline"
        return loggers.WandbLogger(save_dir=str(ctx.stage_dir), project="qmdf", mode=mode)
    return loggers.CSVLogger(save_dir=str(ctx.stage_dir), name="logs")
