"""``cover``: the eps-isosurface of Q-MDF inside the shape, a closed double covering of the medial axis
(paper Sec. 4.2, DCUDF). The field is evaluated only where the covering can pass: a coarse pass, then the
narrow band, level by level (``qmdf.medial.covering``)."""

from __future__ import annotations

from dataclasses import dataclass

from qmdf.artifacts import FIELD, GRID, JSON, MESH
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class CoverConfig:
    eps: float = param(0.005, gt=0, doc="the isovalue of Q-MDF (paper: 0.005)")
    eps_from_field: bool = param(
        True,
        doc="raise eps to the field's noise floor on its axis (the 99th percentile of q's "
        "lowest value along train's medial rays) plus 2 grid cells, so the covering has no "
        "holes where q's valley stays above eps or the slab {q < eps} around a sheet falls "
        "between the grid's nodes; false: eps as given",
    )
    resolution: int = param(256, ge=16, le=1024, doc="grid nodes along the unit box (paper: 256)")
    coarse_step: int = param(8, ge=1, doc="first-pass spacing in grid cells; refined by halves near the covering")
    lipschitz: float = param(2.0, ge=1, doc="assumed bound on |grad q| when deciding where to refine (safety margin)")
    extent: float = param(0.55, gt=0, doc="half side of the grid box around the origin (the shape is in [-0.5, 0.5])")
    speck_fraction: float = param(
        0.01, ge=0, lt=1, doc="drop components with fewer faces than this share of the largest"
    )
    max_faces: int = param(
        30000,
        ge=0,
        doc="decimate larger coverings to this many faces (topology kept; 0: never); contraction and export cost "
        "scale with it (box: 60k faces -> 84 s, 30k -> 54 s, same accuracy; bench extraction)",
    )
    prepass_faces: int = param(
        200000,
        ge=0,
        doc="before MeshLab's topology-safe collapse, a fast one (fast-simplification) down to this many faces, "
        "on coverings of at least twice that, kept only where it changes neither the Euler characteristic, the "
        "components nor the closedness (teacup: 537k -> 30k faces in 3.2 s against 8.3 s); 0: MeshLab's pass alone",
    )
    decimation_workers: int = param(
        1,
        ge=1,
        le=2,
        doc="2: decimate two halves in two processes, welded along their cut (teacup cover 29 -> 25 s on 2 cores, "
        "537k -> 30k faces 14 -> 8 s), 1: one MeshLab pass. Not the default: the exact box's sheet then fit 1.25x "
        "its membrane's CD against 1.15x (bench extraction, 2026-12-03)",
    )


@register_stage("cover")
class Cover(Stage):
    """Marching cubes of {q = eps} inside the shape, specks dropped by a documented rule."""

    Config = CoverConfig
    inputs = {"field": FIELD}
    optional_inputs = {"training": JSON}
    outputs = {"covering": MESH, "covering_stats": JSON, "covering_grid": GRID}
    version = "7"  # 2: the grid nodes inside the covering (for sheet); 5: eps floor: p99 + 2 cells; 7: prepass

    def run(self, ctx: StageContext) -> None:
        import dataclasses

        cfg: CoverConfig = ctx.cfg
        from qmdf.medial.covering import build_covering, eps_floor

        axis_q = (ctx.load("training").get("axis_q") or {}) if ctx.has("training") else {}
        floor = eps_floor(axis_q, cfg.resolution, cfg.extent)
        if cfg.eps_from_field and floor is not None and floor > cfg.eps:
            ctx.log.info(
                "cover.eps %.4g raised to %.4g, the field's noise floor on its axis plus 2 grid cells "
                "(cover.eps_from_field)",
                cfg.eps,
                floor,
            )
            cfg = dataclasses.replace(cfg, eps=float(floor))
        params = {k: v for k, v in dataclasses.asdict(cfg).items() if k != "eps_from_field"}
        mesh, stats, grid = build_covering(ctx.load("field"), log=ctx.log, **params)
        stats["eps_requested"], stats["eps_floor"] = ctx.cfg.eps, floor
        if not stats["watertight"]:
            ctx.log.warning("the covering is not watertight; tetrahedralize will refuse it")
        ctx.save("covering", mesh)
        ctx.save("covering_stats", stats)
        ctx.save("covering_grid", grid)
        ctx.log.info(
            "covering: %d vertices, %d components (genus %s), volume %.3g, %d specks dropped; field evaluated "
            "at %d of %d grid nodes",
            stats["vertices"],
            stats["components"],
            stats["genus"],
            stats["volume"] or float("nan"),
            stats["dropped_specks"],
            stats["evaluated_nodes"],
            stats["grid_nodes"],
        )
