"""What ``train`` and ``feature_retrain`` share: the route's targets (``supervise``) and one fit of a field to them
(``fit_field``: the network, the loss terms, Lightning with the configured trainer and logger, the saved field)."""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from qmdf.errors import QmdfError
from qmdf.fields.settings import OptimSettings, SupervisionSettings, TrainerSettings
from qmdf.stage import StageContext


def route_losses(optim: OptimSettings, route: str) -> dict:
    """The loss terms of ``route``: ``optim.paper_losses`` for the paper's, ``optim.losses`` for the others."""
    return optim.paper_losses if route == "paper" else optim.losses


def supervise(ctx: StageContext, settings: SupervisionSettings):
    """The route's training targets (``qmdf.fields.supervision``), logged and recorded in the stage's notes."""
    from qmdf.fields.supervision import build_supervision, choose_route, cloud_steps_in_words

    points = ctx.load("points")
    info = ctx.load("input_info") if ctx.has("input_info") else {}
    mesh_available = ctx.has("surface") and info.get("kind") == "mesh" and not info.get("degradations")
    route, why = choose_route(settings.route, mesh_available, points.normals is not None)
    mesh = None
    if route == "mesh":
        surface = ctx.load("surface")
        mesh = (np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64))
    proxy = "a Poisson surface" if settings.point_surface == "poisson" else "the points"
    cloud = route in ("oriented_points", "raw_points")
    ctx.log.info(
        "supervision: the %s route's targets for %d volume samples%s",
        *(route, settings.volume_samples, f" (normals, {proxy}, medial rays)" if cloud else ""),
    )
    t0 = time.perf_counter()
    sup = build_supervision(route, points.points, points.normals, np.random.default_rng([ctx.seed, 17]), mesh, settings)
    sup.stats.update(why=why, seconds=round(time.perf_counter() - t0, 2))
    ctx.notes["supervision"] = {"route": route, "why": why}
    s = sup.stats
    ctx.log.info(
        "supervision: %s (%s); %d volume samples, %d with a distance target, %d on medial rays (%.1f s)",
        *(route, why, s["volume_samples"], s["sdf_targets"], s["mf_targets"], s["seconds"]),
    )
    for line in cloud_steps_in_words(s):
        ctx.log.info(line)
    if "proxy" in s:
        ctx.notes["supervision"]["proxy"] = s["proxy"]
        surface = s.get("proxy_surface")
        ctx.log.info(
            "targets from: %s%s",
            s["proxy"],
            f" surface of the oriented points ({surface['vertices']} vertices)" if surface else "",
        )
    return sup


def fit_field(ctx: StageContext, train, sup, losses: dict, optim: OptimSettings, start=None, anchors=None):
    """One fit of a field to ``sup``'s targets under ``losses`` (name -> settings) and ``optim``: the network from
    ``train.model`` (or ``start``'s, a trained ``Field`` whose weights it starts from), seeded; Lightning with
    ``train.trainer``'s settings in the stage's work folder. Saves the field at ``ctx.path("field")`` and returns
    it with its record: history, device, the q statistics along the medial rays (``axis_q``)."""
    import torch

    from qmdf.fields.data import StepSampler
    from qmdf.fields.field import Field
    from qmdf.fields.fitting import fit
    from qmdf.fields.module import FieldModule, build_net, build_terms
    from qmdf.fields.quality import axis_q_stats

    model = train.model
    meta = (
        start.meta
        if start is not None
        else {"backbone": model.backbone, "backbone_params": dict(model.backbones.get(model.backbone) or {})}
    )
    torch.manual_seed(ctx.seed)  # the initial weights (and Fourier frequencies) too: the same seed, the same field
    sampler = StepSampler(sup, optim.surface_batch, optim.volume_batch, ctx.seed)
    module = FieldModule(
        build_net(meta["backbone"], meta["backbone_params"]),
        build_terms(losses, model.medial_field),
        sampler,
        steps=optim.steps,
        lr=optim.lr,
        lr_final=optim.lr_final,
        medial_field=model.medial_field,
        ridge_every=optim.ridge_every,
        ridge_start=optim.ridge_start,
        anchors=anchors,
    )
    if start is not None:
        module.net.load_state_dict(start.net.state_dict())
    trainer: TrainerSettings = train.trainer
    show = trainer.progress_bar == "on" or (trainer.progress_bar == "auto" and sys.stderr.isatty())
    logger, on_end = lightning_logger(trainer.logger, ctx.stage_dir)
    device = fit(
        module,
        optim.steps,
        work_dir=ctx.work_dir,
        seed=ctx.seed,
        log=ctx.log,
        logger=logger,
        checkpoint_every=trainer.checkpoint_every,
        resume=trainer.resume,
        accelerator=trainer.accelerator,
        show_progress=show,
        on_end=on_end,
    )
    # the axis statistics query the field where it trained (Lightning hands the net back on the CPU): on a GPU
    # they took 6 s of the teacup's 39 s training stage on the CPU
    net = module.net.to(device)
    axis = axis_q_stats(sampler.to(device), net) if sampler.has_rays and model.medial_field else None
    field = Field(net, ctx.load("normalization"), meta, device=device)
    field.save(ctx.path("field"))
    return field, {"history": module.history, "device": device, "axis_q": axis}


def lightning_logger(spec: dict[str, Any], save_dir) -> tuple[Any, Any]:
    """Lightning's logger from ``train.trainer.logger`` (``_target_``: its class; the other keys: its arguments;
    ``save_dir``: the stage's folder) and what to call when the fit ends (wandb: close its run, one per job also
    in a multirun; offline without WANDB_API_KEY)."""
    import os

    from hydra.utils import get_class

    target = spec.get("_target_", "")
    try:
        cls = get_class(target)
    except Exception as exc:  # Hydra raises ImportError or ValueError, wrapped differently across versions
        raise QmdfError(f"train.trainer.logger._target_: cannot import '{target}' ({exc})") from None
    kwargs = {k: v for k, v in spec.items() if k != "_target_"}
    if cls.__name__ == "WandbLogger":
        import wandb

        kwargs.setdefault("project", "qmdf")
        kwargs.setdefault("mode", "online" if os.environ.get("WANDB_API_KEY") else "offline")
        return cls(save_dir=str(save_dir), **kwargs), wandb.finish
    return cls(save_dir=str(save_dir), **kwargs), None
