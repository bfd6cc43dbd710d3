"""``cover``: the eps-isosurface of Q-MDF inside the shape, a closed double covering of the medial axis
(paper Sec. 4.2, DCUDF). The field is evaluated only where the covering can pass: a coarse pass, then the
narrow band, level by level (``qmdf.medial.covering``)."""

from __future__ import annotations

from dataclasses import dataclass

from qmdf.artifacts import FIELD, GRID, JSON, MESH
from qmdf.medial.covering import CoveringSettings
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class CoverConfig(CoveringSettings):
    eps_from_field: bool = param(
        True,
        doc="raise eps to the field's noise floor on its axis (the 99th percentile of q's "
        "lowest value along train's medial rays) plus 2 grid cells, so the covering has no "
        "holes where q's valley stays above eps or the slab {q < eps} around a sheet falls "
        "between the grid's nodes; false: eps as given",
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
        mesh, stats, grid = build_covering(ctx.load("field"), cfg, log=ctx.log)
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
