"""``train``: the joint SDF + medial field with PyTorch Lightning, supervised by what the input carries (the mesh,
oriented or raw points: ``qmdf.fields.supervision``), or by the raw points alone as in the paper."""
from __future__ import annotations

import contextlib
import logging
import signal
import sys

import numpy as np
from dataclasses import dataclass
from typing import Any

from qmdf import schema
from qmdf.artifacts import FIELD, JSON, MESH, NORMALIZATION, POINTS
from qmdf.errors import Interrupted, QmdfError
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


def _default_losses() -> dict:
    from qmdf.fields.losses import default_losses

    return default_losses()


def _paper_losses() -> dict:
    from qmdf.fields.losses import paper_losses

    return paper_losses()


def _default_backbones() -> dict:
    """Every registered backbone's settings, so `train.backbones.NAME.key=value` always has a place."""
    from qmdf.fields.backbones import BACKBONES

    return {e.name: schema.defaults_of(e.config) for e in BACKBONES.entries()}


@dataclass
class TrainConfig:
    backbone: str = param("grid", doc="network trunk (python -m qmdf.plugins lists them); grid resolves the teacup's "
                          "0.046-thick walls with |grad sdf| 1.00 inside where the 128x4 MLP reached 0.16-0.55 (same 2,000 steps)")
    backbones: dict[str, Any] = param(factory=_default_backbones, doc="each backbone's settings; the chosen one is used")
    medial_field: bool = param(True, doc="train the medial field too; false: the paper's 'w/o MF' ablation")
    supervision: str = param("auto", choices=("auto", "mesh", "oriented_points", "raw_points", "paper"),
                             doc="what the field learns from: auto picks mesh (an undegraded mesh input), oriented_points "
                                 "(points with normals) or raw_points; paper: the raw points alone, no normals or distances")
    ridge_every: int = param(200, ge=0, doc="every this many steps (from ridge_start on), the mf targets on the medial rays "
                             "become the learned |sdf| at the rays' medial points, so q is 0 there although the network "
                             "rounds the |sdf| ridge (0: the rays' radii from the data)")
    ridge_start: float = param(0.3, ge=0, le=1, doc="share of the steps before the first ridge update")
    volume_samples: int = param(1_000_000, ge=1000, doc="volume samples with their targets, drawn once; each step picks volume_batch of them")
    steps: int = param(2000, ge=1)
    surface_batch: int = param(4096, ge=16, doc="input points per step (paper: 4096)")
    volume_batch: int = param(4096, ge=16, doc="volume samples per step")
    uniform_fraction: float = param(0.25, ge=0, le=1, doc="share of volume samples uniform in the box")
    ray_fraction: float = param(0.4, ge=0, le=1, doc="share of volume samples on the medial rays (inward from the surface "
                                "samples to their medial balls, half by the axis); the rest near the points. Not for the paper route")
    lr: float = param(1e-3, gt=0)
    lr_final: float = param(1e-4, gt=0, doc="cosine decay down to this")
    losses: dict[str, Any] = param(factory=_default_losses, doc="loss name -> {weight, ...} for the supervised routes "
                                   "(mesh, oriented_points, raw_points); weight 0 disables")
    paper_losses: dict[str, Any] = param(factory=_paper_losses, doc="the same for the paper route (raw points alone)")
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
        for section in ("losses", "paper_losses"):
            for name, params in getattr(self, section).items():
                if name not in LOSSES:
                    problems.append((f"{section}.{name}", LOSSES.why_missing(name)))
                else:
                    problems += [(p.key, p.message) for p in
                                 schema.check_section(LOSSES.get(name).config, params or {}, f"{section}.{name}")]
        return problems


@register_stage("train")
class Train(Stage):
    """Fit sdf, mf_inner, mf_outer to the sampled points; write the field for every later stage."""

    Config = TrainConfig
    inputs = {"points": POINTS, "normalization": NORMALIZATION}
    optional_inputs = {"surface": MESH, "input_info": JSON}
    outputs = {"field": FIELD, "training": JSON}
    version = "3"  # 2: the initial weights are seeded; 3: supervision routes, batches drawn by global step

    def run(self, ctx: StageContext) -> None:
        import torch

        from qmdf.fields.data import StepSampler
        from qmdf.fields.field import Field
        from qmdf.fields.module import FieldModule

        cfg: TrainConfig = ctx.cfg
        points = ctx.load("points").points
        sup = supervise(ctx, cfg)
        params = dict(cfg.backbones.get(cfg.backbone) or {})
        torch.manual_seed(ctx.seed)  # the initial weights (and Fourier frequencies) too: the same seed, the same field
        sampler = StepSampler(sup, cfg.surface_batch, cfg.volume_batch, ctx.seed)
        module = FieldModule(cfg.backbone, params, route_losses(cfg, sup.route), cfg.medial_field, cfg.lr, cfg.lr_final,
                             cfg.steps, sampler, cfg.ridge_every, cfg.ridge_start)
        device = fit(ctx, cfg, module, cfg.steps)
        axis = axis_q_stats(sampler.to("cpu"), module.net.cpu()) if sampler.has_rays and cfg.medial_field else None
        field = Field(module.net.cpu(), ctx.load("normalization"),
                      {"backbone": cfg.backbone, "backbone_params": params}, device="cpu")
        field.save(ctx.path("field"))
        final = module.history[-1] if module.history else {}
        ctx.save("training", {"steps": cfg.steps, "final_losses": final, "history": module.history,
                              "device": device, "torch_threads": torch.get_num_threads(), "supervision": sup.stats,
                              "axis_q": axis})
        if cfg.picture:
            from qmdf.viz import plot_field_slices, plot_losses

            plot_field_slices(ctx.stage_dir / "slices.png", field)
            plot_losses(ctx.stage_dir / "losses.png", module.history)
        ctx.log.info("trained %d steps on %d points; final total loss %.4g", cfg.steps, len(points), final.get("loss/total", float("nan")))


def axis_q_stats(sampler, net) -> dict:
    """Percentiles of the lowest q along the medial rays (0 where the learned valley of q is on the axis): the
    field's noise floor on its axis, which ``cover`` can take as its eps (cover.eps_from_field)."""
    q = sampler.axis_q(net).numpy()
    q = q[np.isfinite(q)]
    if not len(q):
        return None
    p50, p90, p99 = np.percentile(q, [50, 90, 99])
    return {"p50": float(p50), "p90": float(p90), "p99": float(p99), "rays": int(len(q))}


def route_losses(cfg: TrainConfig, route: str) -> dict:
    """The loss terms of ``route``: train.paper_losses for the paper's, train.losses for the others."""
    return cfg.paper_losses if route == "paper" else cfg.losses


def supervise(ctx: StageContext, cfg: TrainConfig):
    """The route's training targets (``qmdf.fields.supervision``), logged and recorded in training.json."""
    import time

    from qmdf.fields.supervision import build_supervision, choose_route

    points = ctx.load("points")
    info = ctx.load("input_info") if ctx.has("input_info") else {}
    mesh_available = ctx.has("surface") and info.get("kind") == "mesh" and not info.get("degradations")
    route, why = choose_route(cfg.supervision, mesh_available, points.normals is not None)
    mesh = None
    if route == "mesh":
        surface = ctx.load("surface")
        mesh = (np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64))
    t0 = time.perf_counter()
    sup = build_supervision(route, points.points, points.normals, np.random.default_rng([ctx.seed, 17]), mesh,
                            cfg.volume_samples, cfg.uniform_fraction, cfg.ray_fraction)
    sup.stats.update(why=why, seconds=round(time.perf_counter() - t0, 2))
    ctx.notes["supervision"] = {"route": route, "why": why}
    ctx.log.info("supervision: %s (%s); %d volume samples, %d with a distance target, %d on medial rays (%.1f s)",
                 route, why, sup.stats["volume_samples"], sup.stats["sdf_targets"], sup.stats["mf_targets"],
                 sup.stats["seconds"])
    if "orientation" in sup.stats:
        ctx.log.info("normals: %s", sup.stats["orientation"])
    return sup


def fit(ctx: StageContext, cfg: TrainConfig, module, steps: int) -> str:
    """Train ``module`` for ``steps`` with Lightning in the stage's work folder (checkpoints, resume, loggers);
    returns the device it ran on. A training that ends short of ``steps`` is an error, never a result (the cache
    would keep it as complete). Used by train and by feature_retrain."""
    import gc
    import warnings

    import lightning as L
    import torch

    from qmdf.fields.data import loader
    from qmdf.fields.module import Diverged

    L.seed_everything(ctx.seed, workers=True, verbose=False)
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")  # Lightning's own deprecation noise, not ours
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    work = ctx.work_dir
    last = work / "last.ckpt"
    resume = str(last) if cfg.resume and last.exists() else None
    done = int(torch.load(last, map_location="cpu", weights_only=True)["global_step"]) if resume else 0
    checkpoint = L.pytorch.callbacks.ModelCheckpoint(dirpath=work, save_last=True, save_top_k=0,
                                                     every_n_train_steps=cfg.checkpoint_every)

    class SaveOnInterrupt(L.pytorch.callbacks.Callback):
        def on_exception(self, trainer, pl_module, exception):
            if isinstance(exception, KeyboardInterrupt) and trainer.global_step > 0:
                trainer.save_checkpoint(last)

    show_bar = cfg.progress_bar == "on" or (cfg.progress_bar == "auto" and sys.stderr.isatty())
    trainer = L.Trainer(
        max_steps=steps, max_epochs=1, accelerator=cfg.accelerator, devices=1, logger=_logger(cfg, ctx),
        callbacks=[checkpoint, SaveOnInterrupt()], enable_progress_bar=show_bar, enable_model_summary=False,
        log_every_n_steps=10, num_sanity_val_steps=0, limit_val_batches=0, default_root_dir=str(work),
    )
    if resume:
        ctx.log.info("resuming from %s (step %d of %d)", last, done, steps)
    stop = _StopSignal()
    try:
        with stop.terminate_as_interrupt():
            trainer.fit(module, train_dataloaders=loader(steps), ckpt_path=resume)
        if trainer.global_step != steps and not stop.received:
            raise QmdfError(f"training stopped at step {trainer.global_step} of {steps}; its result is not kept")
    except (KeyboardInterrupt, SystemExit) as exc:
        # Lightning turns Ctrl-C into SystemExit(1) after its on_exception callbacks: the checkpoint is saved
        if not (stop.received or isinstance(exc, KeyboardInterrupt)):
            raise
        stop.received = stop.received or signal.SIGINT
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
        at = trainer.global_step
        del trainer
        gc.collect()
    if stop.received:
        raise Interrupted(f"{signal.Signals(stop.received).name} at training step {at} of {steps}: checkpoint saved at "
                          f"{last}; run the same command again to resume", int(stop.received))
    return device


class _StopSignal:
    """Ctrl-C (SIGINT) and SIGTERM (what a cluster scheduler sends) end a training the same way: Lightning stops,
    ``SaveOnInterrupt`` writes the checkpoint, and the run ends as interrupted with 128 + the signal's number."""

    def __init__(self):
        self.received = 0

    @contextlib.contextmanager
    def terminate_as_interrupt(self):
        def handler(signum, frame):
            self.received = signum
            raise KeyboardInterrupt

        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            for s in old:
                signal.signal(s, handler)
        except ValueError:  # not the main thread (an API caller's worker): signals stay theirs
            old = {}
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)


def _logger(cfg: TrainConfig, ctx: StageContext):
    import os

    from lightning.pytorch import loggers

    if cfg.logger == "tensorboard":
        return loggers.TensorBoardLogger(save_dir=str(ctx.stage_dir), name="tensorboard")
    if cfg.logger == "wandb":
        mode = "online" if os.environ.get("WANDB_API_KEY") else "offline"
        return loggers.WandbLogger(save_dir=str(ctx.stage_dir), project="qmdf", mode=mode)
    return loggers.CSVLogger(save_dir=str(ctx.stage_dir), name="logs")
