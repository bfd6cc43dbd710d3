"""``train``: the joint SDF + medial field with PyTorch Lightning, supervised by what the input carries (the mesh,
oriented or raw points: ``qmdf.fields.supervision``), or by the raw points alone as in the paper."""

from __future__ import annotations

import sys

import numpy as np
from dataclasses import dataclass
from typing import Any

from qmdf import schema
from qmdf.artifacts import FIELD, JSON, MESH, NORMALIZATION, POINTS, RAYS
from qmdf.geometry.orientation import ORIENTATIONS
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
    backbone: str = param(
        "grid",
        doc="network trunk (python -m qmdf.plugins lists them); grid resolves the teacup's "
        "0.046-thick walls with |grad sdf| 1.00 inside where the 128x4 MLP reached 0.16-0.55 (same 2,000 steps)",
    )
    backbones: dict[str, Any] = param(
        factory=_default_backbones, doc="each backbone's settings; the chosen one is used"
    )
    medial_field: bool = param(True, doc="train the medial field too; false: the paper's 'w/o MF' ablation")
    supervision: str = param(
        "auto",
        choices=("auto", "mesh", "oriented_points", "raw_points", "paper"),
        doc="what the field learns from: auto picks mesh (an undegraded mesh input), oriented_points "
        "(points with normals) or raw_points; paper: the raw points alone, no normals or distances",
    )
    orientation: str = param(
        "wnnc",
        choices=ORIENTATIONS,
        doc="raw points: how their estimated normals are oriented. wnnc: the winding number's normal "
        "consistency (Lin et al. 2024), global, right where a wall is as thin as the sampling gap (the "
        "1,500-point teacup: 99.9% right); propagation: along a spanning tree, then winding checks (56% there)",
    )
    point_surface: str = param(
        "poisson",
        choices=("poisson", "points"),
        doc="on a point cloud (oriented_points, raw_points): poisson: a screened Poisson surface of the "
        "oriented points gives the sign, the distances and the medial rays (the sparse bunny's "
        "covering: genus 301 from the points alone); points: the points' winding number and distances",
    )
    zero_level: str = param(
        "input",
        choices=("input", "proxy"),
        doc="with a Poisson surface: the zero level set passes through the input points (input) or "
        "through samples of the Poisson surface (proxy: smooths a noisy cloud's noise away, "
        "loses the exactness of a clean sparse cloud's points)",
    )
    mesh_rays: str = param(
        "smooth",
        choices=("smooth", "face"),
        doc="on a mesh, the medial rays' directions: smooth (normals interpolated from the corners, tol 3e-4 + 8% "
        "of the median edge: the torus's radii within 3e-4) or face (the faces' normals, tol 1e-4: they meet the "
        "faceted mesh's own medial sheets, the torus's radii 0.055 short)",
    )
    point_surface_as_data: bool = param(
        True,
        doc="hand a cloud's closed Poisson surface on as the data later stages measure the MAT against (radii, "
        "centring, coverage, rims): distances to sparse points over-estimate the depth by about gap^2 / (8 r) "
        "between them (the 1,000-point block's MAT radii 5.6e-3 too large on average, against 1.3e-3 to the "
        "surface); false: the input points",
    )
    poisson_depth: int = param(8, ge=5, le=11, doc="octree depth of the Poisson surface (8: cells of 1/256 of the box)")
    poisson_point_weight: float = param(
        4.0, ge=0, doc="screening weight: higher follows the points more closely, noise too"
    )
    poisson_samples_per_node: float = param(
        0.25,
        gt=0,
        doc="the Poisson octree refines a node while it holds this many points: small follows a sparse clean "
        "cloud between its points (the 1,000-point block's sign 99.16% -> 99.59% against 1.5)",
    )
    poisson_coarse_samples_per_node: float = param(
        1.5,
        gt=0,
        doc="the same for the coarse surface taken instead where the fine one has other pieces or another "
        "solid Euler characteristic (it fits noise); equal to poisson_samples_per_node: no check",
    )
    ridge_every: int = param(
        200,
        ge=0,
        doc="every this many steps (from ridge_start on), the mf targets on the medial rays "
        "become the learned |sdf| at the rays' medial points, so q is 0 there although the network "
        "rounds the |sdf| ridge (0: the rays' radii from the data)",
    )
    ridge_start: float = param(0.3, ge=0, le=1, doc="share of the steps before the first ridge update")
    volume_samples: int = param(
        1_000_000, ge=1000, doc="volume samples with their targets, drawn once; each step picks volume_batch of them"
    )
    steps: int = param(2000, ge=1)
    surface_batch: int = param(4096, ge=16, doc="input points per step (paper: 4096)")
    volume_batch: int = param(4096, ge=16, doc="volume samples per step")
    uniform_fraction: float = param(0.25, ge=0, le=1, doc="share of volume samples uniform in the box")
    ray_fraction: float = param(
        0.4,
        ge=0,
        le=1,
        doc="share of volume samples on the medial rays (inward from the surface "
        "samples to their medial balls, half by the axis); the rest near the points. Not for the paper route",
    )
    axis_band: str = param(
        "across",
        choices=("across", "inward"),
        doc="the ray samples by the axis: on both sides of it along the ray's line (where a mesh or a cloud's "
        "Poisson surface gives every sample its distance), so each side of the axis is sampled alike; inward: "
        "from the ray's own side only (before 2026-12-04: the torus's q valley 1.1e-3 inward of its axis, "
        "whose outer half sends 1.75x the rays)",
    )
    lr: float = param(1e-3, gt=0)
    lr_final: float = param(1e-4, gt=0, doc="cosine decay down to this")
    losses: dict[str, Any] = param(
        factory=_default_losses,
        doc="loss name -> {weight, ...} for the supervised routes "
        "(mesh, oriented_points, raw_points); weight 0 disables",
    )
    paper_losses: dict[str, Any] = param(factory=_paper_losses, doc="the same for the paper route (raw points alone)")
    checkpoint_every: int = param(
        250, ge=1, doc="steps between checkpoints (resume, and the last good state on divergence)"
    )
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
                    problems += [
                        (p.key, p.message)
                        for p in schema.check_section(LOSSES.get(name).config, params or {}, f"{section}.{name}")
                    ]
        return problems


@register_stage("train")
class Train(Stage):
    """Fit sdf, mf_inner, mf_outer to the sampled points; write the field for every later stage."""

    Config = TrainConfig
    inputs = {"points": POINTS, "normalization": NORMALIZATION}
    optional_inputs = {"surface": MESH, "input_info": JSON}
    outputs = {"field": FIELD, "training": JSON}
    optional_outputs = {"medial_rays": RAYS, "point_surface": MESH}
    # 2: seeded weights; 3: supervision routes; 4: Poisson proxy of clouds; 5: mesh rays along smooth normals;
    # 6: axis_q's p999 and max; 7: the mesh route's medial rays saved (sheet's and export's coverage reuse them)
    # 8: a cloud's Poisson surface's solid Euler characteristic recorded (sheet.match_topology)
    # 9: a cloud's Poisson surface from a fine octree where it does not fit noise (poisson_samples_per_node), and
    # saved for the later stages (point_surface_as_data); 10: the ray samples by the axis straddle it (axis_band),
    # Adam fused; 11: the encoding's compiled backward, mf of the volume samples only (the same function, 2x faster
    # on the CPU; the last bits differ); 12: raw points oriented by WNNC (orientation); 13: their normals refitted on
    # their own side of a wall, a Poisson surface clipped by the solver's domain solved again in a wider one; 14: the
    # Poisson surface's medial rays saved too (the sheet's balls measured once)
    version = "14"

    @classmethod
    def cache_config(cls, section: dict) -> dict:
        """Only the chosen backbone's settings: a change to another backbone's does not retrain this one."""
        chosen = section.get("backbone")
        return {**section, "backbones": {chosen: (section.get("backbones") or {}).get(chosen)}}

    def run(self, ctx: StageContext) -> None:
        import torch

        from qmdf.fields.data import StepSampler
        from qmdf.fields.field import Field
        from qmdf.fields.quality import axis_q_stats
        from qmdf.fields.module import FieldModule, build_net, build_terms

        cfg: TrainConfig = ctx.cfg
        points = ctx.load("points").points
        sup = supervise(ctx, cfg)
        # the medial ball behind each ray's origin, measured once for training, coverage and the fit alike (the
        # teacup's mesh: 10 s in sheet -> 0.5 s; a 3,000-point sphere's Poisson surface: every query near its
        # centre equally near every face, minutes in sheet)
        proxy_is_data = sup.proxy_mesh is not None and cfg.point_surface_as_data
        if (sup.route == "mesh" and sup.stats.get("mesh_rays") == "smooth") or proxy_is_data:
            origins = points if sup.ray_origins is None else sup.ray_origins
            ctx.save(
                "medial_rays",
                {
                    "origins": origins,
                    "directions": sup.ray_normals,
                    "radii": sup.radii,
                    "tol": sup.stats["ray_tolerance"],
                },
            )
        if proxy_is_data:
            import trimesh

            ctx.save("point_surface", trimesh.Trimesh(*sup.proxy_mesh, process=False))
        params = dict(cfg.backbones.get(cfg.backbone) or {})
        torch.manual_seed(ctx.seed)  # the initial weights (and Fourier frequencies) too: the same seed, the same field
        sampler = StepSampler(sup, cfg.surface_batch, cfg.volume_batch, ctx.seed)
        module = FieldModule(
            build_net(cfg.backbone, params),
            build_terms(route_losses(cfg, sup.route), cfg.medial_field),
            sampler,
            steps=cfg.steps,
            lr=cfg.lr,
            lr_final=cfg.lr_final,
            medial_field=cfg.medial_field,
            ridge_every=cfg.ridge_every,
            ridge_start=cfg.ridge_start,
        )
        device = fit(ctx, cfg, module, cfg.steps)
        # the axis statistics and the slices query the field where it trained (Lightning hands the net back on
        # the CPU): on a GPU they took 6 s of the teacup's 39 s training stage on the CPU
        net = module.net.to(device)
        axis = axis_q_stats(sampler.to(device), net) if sampler.has_rays and cfg.medial_field else None
        field = Field(
            net, ctx.load("normalization"), {"backbone": cfg.backbone, "backbone_params": params}, device=device
        )
        field.save(ctx.path("field"))
        final = module.history[-1] if module.history else {}
        ctx.save(
            "training",
            {
                "steps": cfg.steps,
                "final_losses": final,
                "history": module.history,
                "device": device,
                "torch_threads": torch.get_num_threads(),
                "supervision": sup.stats,
                "axis_q": axis,
            },
        )
        if cfg.picture:
            from qmdf.viz import plot_field_slices, plot_losses

            plot_field_slices(ctx.stage_dir / "slices.png", field)
            plot_losses(ctx.stage_dir / "losses.png", module.history)
        ctx.log.info(
            "trained %d steps on %d points; final total loss %.4g",
            cfg.steps,
            len(points),
            final.get("loss/total", float("nan")),
        )


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
    ctx.log.info(
        "supervision: the %s route's targets for %d volume samples%s",
        route,
        cfg.volume_samples,
        f" (normals, {'a Poisson surface' if cfg.point_surface == 'poisson' else 'the points'}, medial rays)"
        if route in ("oriented_points", "raw_points")
        else "",
    )
    t0 = time.perf_counter()
    sup = build_supervision(
        route,
        points.points,
        points.normals,
        np.random.default_rng([ctx.seed, 17]),
        mesh,
        cfg.volume_samples,
        cfg.uniform_fraction,
        cfg.ray_fraction,
        proxy=cfg.point_surface,
        poisson_depth=cfg.poisson_depth,
        poisson_point_weight=cfg.poisson_point_weight,
        poisson_samples_per_node=(cfg.poisson_samples_per_node, cfg.poisson_coarse_samples_per_node),
        zero_level=cfg.zero_level,
        mesh_rays=cfg.mesh_rays,
        axis_band=cfg.axis_band,
        orientation=cfg.orientation,
    )
    sup.stats.update(why=why, seconds=round(time.perf_counter() - t0, 2))
    ctx.notes["supervision"] = {"route": route, "why": why}
    ctx.log.info(
        "supervision: %s (%s); %d volume samples, %d with a distance target, %d on medial rays (%.1f s)",
        route,
        why,
        sup.stats["volume_samples"],
        sup.stats["sdf_targets"],
        sup.stats["mf_targets"],
        sup.stats["seconds"],
    )
    if "orientation" in sup.stats:
        ctx.log.info("normals: %s", sup.stats["orientation"])
    if "proxy" in sup.stats:
        ctx.notes["supervision"]["proxy"] = sup.stats["proxy"]
        ctx.log.info(
            "targets from: %s%s",
            sup.stats["proxy"],
            ""
            if "proxy_surface" not in sup.stats
            else " surface of the oriented points (%d vertices)" % sup.stats["proxy_surface"]["vertices"],
        )
    return sup


def fit(ctx: StageContext, cfg: TrainConfig, module, steps: int) -> str:
    """``qmdf.fields.fitting.fit`` in the stage's work folder with the configured logger; used by train and by
    feature_retrain."""
    from qmdf.fields.fitting import fit as fit_module

    show = cfg.progress_bar == "on" or (cfg.progress_bar == "auto" and sys.stderr.isatty())
    return fit_module(
        module,
        steps,
        work_dir=ctx.work_dir,
        seed=ctx.seed,
        log=ctx.log,
        logger=_logger(cfg, ctx),
        checkpoint_every=cfg.checkpoint_every,
        resume=cfg.resume,
        accelerator=cfg.accelerator,
        show_progress=show,
        on_end=_wandb_finish if cfg.logger == "wandb" else None,
    )


def _wandb_finish() -> None:
    import wandb

    wandb.finish()  # one wandb run per job, also in a multirun


def _logger(cfg: TrainConfig, ctx: StageContext):
    import os

    from lightning.pytorch import loggers

    if cfg.logger == "tensorboard":
        return loggers.TensorBoardLogger(save_dir=str(ctx.stage_dir), name="tensorboard")
    if cfg.logger == "wandb":
        mode = "online" if os.environ.get("WANDB_API_KEY") else "offline"
        return loggers.WandbLogger(save_dir=str(ctx.stage_dir), project="qmdf", mode=mode)
    return loggers.CSVLogger(save_dir=str(ctx.stage_dir), name="logs")
