"""``sheet``: the single-layer medial mesh. The covering's solid collapses to one layer with the solid's topology
on the contracted membrane, with radii from the input (``qmdf.medial.sheet.thinned_sheet``); then the refinement
steps named in ``sheet.steps`` run in order (``qmdf.medial.refinement``; built-ins in ``qmdf.medial.steps``).
Built twice, under a narrow and a wide off-axis rule, the better fit kept (``qmdf.medial.sheet.pick_sheet``).
``export`` writes it as the MAT; the membrane stays for comparison."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from qmdf import schema
from qmdf.artifacts import FIELD, GRID, JSON, MAT, MESH, POINTS, RAYS
from qmdf.medial.coverage import TOLERANCE
from qmdf.medial.radii import RADIUS_SOURCES
from qmdf.medial.sheet import CollapseSettings
from qmdf.registry import SHEET_STEPS
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage
from qmdf.stages.inputs import input_data, input_surface_balls, known_solid_euler

DEFAULT_STEPS = ("simplify", "centre", "coverage", "rims", "fit")


@dataclass
class SheetExpert(CollapseSettings):
    compact_slack: float = param(
        1.5,
        ge=1,
        doc="a sheet left above this many times target_vertices (the link condition refusing on a tangled "
        "complex) is not compact: export then writes the membrane as the MAT, with a warning",
    )
    tip_reach: float = param(
        0.003,
        gt=0,
        doc="vertices within this of a feature point stay in place (unit box); 0.01 kept most of the sharp "
        "sphere's vertices off the axis: its CD 3.2e-3 against 1.1e-3 (2026-12-03)",
    )


@dataclass
class SheetConfig:
    radius: str = param("data", choices=RADIUS_SOURCES, doc="each vertex's radius (qmdf.medial.radii says why data)")
    target_vertices: int = param(
        3000, ge=0, doc="the vertex budget (0: no simplification); the teacup's CD 1.18x the membrane's at 3000"
    )
    tolerance: float = param(
        TOLERANCE,
        gt=0,
        doc="how far the surface may lie outside the MAT's envelope (unit box): coverage adds balls where it lies "
        "farther; a sheet thinned to one ball within it of the data is the MAT (a sphere's)",
    )
    steps: list[str] = param(
        factory=lambda: list(DEFAULT_STEPS),
        doc="the refinement steps in order (python -m qmdf.plugins lists them; a plugin adds its own)",
    )
    step: dict[str, Any] = param(
        factory=lambda: schema.registered_defaults(SHEET_STEPS),
        doc="each step's settings",
        schemas=lambda: schema.registered_schemas(SHEET_STEPS),
    )
    expert: SheetExpert = param(factory=SheetExpert, doc="the collapse's tuned constants (docs/configuration.md)")

    def check(self) -> list[tuple[str, str]]:
        problems = [
            (f"steps[{i}]", SHEET_STEPS.why_missing(n)) for i, n in enumerate(self.steps) if n not in SHEET_STEPS
        ]
        return problems + schema.check_registered(self.step, SHEET_STEPS, "step")


@register_stage("sheet")
class Sheet(Stage):
    """Collapse the covering's solid to one layer on the membrane; radii; the refinement steps."""

    Config = SheetConfig
    inputs = {"covering_grid": GRID, "membrane": MESH, "field": FIELD}
    optional_inputs = {
        "surface": MESH,
        "points": POINTS,
        "input_info": JSON,
        "feature_points": POINTS,
        "medial_rays": RAYS,
        "training": JSON,
        "point_surface": MESH,
    }
    outputs = {"sheet": MAT, "sheet_stats": JSON}
    version = "23"  # docs/history.md lists what each version changed; 23: coverage stops at the tolerance

    @classmethod
    def cache_config(cls, section: dict) -> dict:
        """Only the listed steps' settings: a change to a step that does not run changes nothing."""
        listed = section.get("steps") or []
        return {**section, "step": {k: v for k, v in (section.get("step") or {}).items() if k in listed}}

    def run(self, ctx: StageContext) -> None:
        from qmdf.medial.radii import inside_test, mat_radii
        from qmdf.medial.refinement import SheetData
        from qmdf.medial.steps import resolve_steps
        from qmdf.medial.sheet import refined_sheet, sheet_verdict

        cfg: SheetConfig = ctx.cfg
        field, membrane, grid = ctx.load("field"), ctx.load("membrane"), ctx.load("covering_grid")
        mesh, points = input_data(ctx)
        from_data = cfg.radius == "data"
        steps = resolve_steps(cfg.steps, cfg.step, from_data)
        data = SheetData(
            mesh,
            points,
            inside_test(field, mesh),
            lambda: input_surface_balls(ctx, field, mesh, points),
            target_vertices=cfg.target_vertices,
            tolerance=cfg.tolerance,
            tips=ctx.load("feature_points").points if ctx.has("feature_points") else None,
            tip_reach=cfg.expert.tip_reach,
            compact_slack=cfg.expert.compact_slack,
            seed=ctx.seed,
            settings={step.name: settings for step, settings in steps},
            log=ctx.log,
        )
        target_chi = known_solid_euler(ctx, mesh) if cfg.expert.match_topology else None
        radii_of = lambda x: mat_radii(x, cfg.radius, field, mesh, points)  # noqa: E731
        membrane = np.asarray(membrane.vertices), np.asarray(membrane.faces)
        wide = cfg.expert.off_axis_wide if from_data else 0.0
        mat, stats = refined_sheet(grid, field.evaluate, membrane, radii_of, data, steps, cfg.expert, target_chi, wide)
        warning = sheet_verdict(mat, stats, cfg.tolerance, cfg.target_vertices)
        if warning:
            ctx.log.warning("%s; the sheet stays in %s", warning, (ctx.output_dir or ctx.stage_dir) / "sheet.ma")
        ctx.save("sheet", mat.medial_mesh())
        ctx.save("sheet_stats", stats)
        a = stats["after"]
        ctx.log.info(
            "single sheet: %d vertices, %d faces, %d lone edges, chi %d, %d seam edges (before refinement: %d "
            "vertices, chi %d)",
            *(a["vertices"], a["faces"], a["lone_edges"], a["chi"], a["seam_edges"]),
            *(stats["before"]["vertices"], stats["before"]["chi"]),
        )
