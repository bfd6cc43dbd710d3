"""``sheet``: the single-layer medial mesh. The covering's solid collapses to one layer with the solid's
topology (``qmdf.medial.thinning``), placed on the contracted membrane (``qmdf.medial.sheet``), given radii
from the input (``qmdf.medial.radii``) and simplified under the spherical quadric error without a change of
topology (``qmdf.medial.simplify``), its vertices centred on the data's axis (``qmdf.medial.radii``) and
completed where its envelope falls short of the surface (``qmdf.medial.coverage``); built twice, under a
narrow and a wide off-axis rule, the better fit kept (``qmdf.medial.sheet.pick_sheet``). ``export`` writes it as the
MAT; the membrane stays for comparison."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, GRID, JSON, MAT, MESH, POINTS, RAYS
from qmdf.medial.radii import RADIUS_SOURCES
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage
from qmdf.stages.inputs import input_data, input_surface_balls, known_solid_euler


@dataclass
class SheetConfig:
    valley_share: float = param(
        0.5,
        gt=0,
        le=1,
        doc="squares and edges whose q lies above this share of the way "
        "from q's local floor up to eps may collapse (the covering's outer shell)",
    )
    off_axis: float = param(
        0.75,
        gt=0,
        doc="squares whose corners lie farther than this many grid steps from the "
        "membrane are off the axis and may collapse",
    )
    off_axis_wide: float = param(
        3.0,
        ge=0,
        doc="with coverage's fit (radius=data): a second sheet with this off_axis, and the compact one with the "
        "input's chi whose envelope fits the data better is kept (0: only off_axis). Where a thin plate lies "
        "oblique to the grid, its squares' corners stand more than 0.75 steps off its membrane and its middle "
        "collapses away, two curves along its rims left (abc_00000125: CD 0.43e-3 -> 0.27e-3); on thick parts "
        "3 steps keeps the covering's outer shell (the block 0.56e-3 -> 1.12e-3, the pinion not compact)",
    )
    fin_area: float = param(
        0.25,
        ge=0,
        lt=1,
        doc="placed squares below this share of a grid square's area are "
        "flat: a fin around a curve-like axis or a step across a sheet",
    )
    valley_only: bool = param(
        True,
        doc="also release squares whose q is not a valley across them (below both parallel squares one node "
        "away) and edges not a valley across both other axes: one layer of a wide flat valley stays (the block: "
        "43k vertices after simplification -> 9.7k, seams 56k -> 1k; the teacup's seams 669 -> 240, CD before "
        "coverage 4.09e-4 -> 4.22e-4, HD 12.7e-3 -> 10.1e-3); false: the keep level alone",
    )
    fill_pockets: bool = param(
        True,
        doc="fill the covering's enclosed voids where the learned sdf is inside everywhere in them before the "
        "collapse: a covering thick around a junction of sheets encloses islands of higher q, and each became a "
        "closed pocket of the sheet (b2 > 0, chi off by one each); a void that reaches outside "
        "the shape (a hollow part of it) stays",
    )
    match_topology: bool = param(
        True,
        doc="where the input's solid has a known Euler characteristic (a closed mesh's: half the surface's; a "
        "cloud's closed Poisson surface's, whose sign the field learned), "
        "collapse the nodes below the highest of 15 levels from the covering's eps down to 0.3 eps whose solid has "
        "that Euler characteristic (the kitten at eps 0.047: chi -1, a bridge between two parts of the axis; "
        "at 0.040 chi 0 as its genus 1 implies); no such level: see grow_topology",
    )
    grow_topology: bool = param(
        True,
        doc="where no level of q has the input's Euler characteristic (at most 1: one piece of genus g), grow the "
        "solid in the covering from its lowest q, node by node in q's order, each joining only where it changes "
        "no topology, then the g lowest-q tunnels closed (medial.topology_growth; the sharp sphere's maze of "
        "genus 31); off, or chi above 1: the covering's nodes as they are, with a warning",
    )
    speck_fraction: float = param(
        0.01,
        ge=0,
        lt=1,
        doc="drop pieces of the covering's solid with fewer nodes than "
        "this share of the largest's (cover's rule for its specks)",
    )
    max_nodes: int = param(
        1_000_000,
        ge=1000,
        doc="collapse on every k-th grid node, k the smallest that leaves at most this many nodes inside the "
        "covering: a thick covering (the bunny's eps raised to 0.034: 2.2M nodes) took 370 s at every node; at "
        "eps 0.055 every second node (172k) gives chi 1 in 17 s, every sixth (a rule by layers) chi -3 and a "
        "coarser sheet; the teacup's 570k nodes keep every node",
    )
    compact_slack: float = param(
        1.5,
        ge=1,
        doc="a sheet whose simplification stops above this many times "
        "target_vertices (link condition refusing on a tangled complex) is not compact: "
        "export then writes the membrane as the MAT, with a warning",
    )
    radius: str = param(
        "data", choices=RADIUS_SOURCES, doc="each vertex's radius before simplification (see export.radius)"
    )
    centre: bool = param(
        True,
        doc="with radius=data: after simplification each vertex moves to the centre of the data's maximal ball "
        "through its closest point (medial.radii.centre_on_data); the teacup's CD 1.36e-3 -> 0.40e-3",
    )
    target_vertices: int = param(
        3000,
        ge=0,
        doc="simplify to this many vertices (0: no simplification); the teacup's CD over the membrane's: 1.18x at "
        "3000, 1.25x at 2000, 0.96x unsimplified (136k vertices)",
    )
    boundary_weight: float = param(
        1.0, ge=0, doc="weight of the rims' planes in the quadric (keeps the sheet's free boundary in place)"
    )
    max_turn_deg: float = param(60.0, gt=0, le=180, doc="refuse a collapse that turns a face by more than this")
    tip_reach: float = param(
        0.003,
        gt=0,
        doc="vertices within this of a feature point stay in place (unit box); 0.01 kept most of the sharp "
        "sphere's vertices (4,802 feature points) off the axis: its CD 3.2e-3 against 1.1e-3, the block's 1.2e-3 "
        "against 0.57e-3 (2026-12-03)",
    )
    coverage_vertices: int = param(
        1000,
        ge=0,
        doc="with radius=data: after centring, up to this many vertices added where the envelope falls short of "
        "the surface, each the data's medial ball behind the sample farthest out (medial.coverage); a second "
        "simplification, those fixed, brings the sheet back to target_vertices. 0: none",
    )
    coverage_tolerance: float = param(
        1e-3,
        gt=0,
        doc="a surface sample farther than this outside the envelope is uncovered (unit box); once all are "
        "within it, what is left of the budget goes to the smaller gaps, down to an eighth of it",
    )
    coverage_spacing: float = param(
        0.01, gt=0, doc="per round, no two added balls' samples closer than this (or half the ball's radius)"
    )
    coverage_overshoot: float = param(
        5e-3,
        gt=0,
        doc="refuse an added vertex whose new edges' balls reach out of the data by more than this (a spike "
        "to a branch the sheet lacks)",
    )
    coverage_rounds: int = param(10, ge=1, doc="rounds of insertion (the envelope is re-measured after each)")
    extend_rims: bool = param(
        True,
        doc="with radius=data: last, each free rim's vertex and curve's end walks out to where the medial axis "
        "ends (medial.rims; the covering stops short of it), kept only where the envelope fits the data as well "
        "or better; exact fields, 2,000 vertices: the ellipsoid's CD 1.38e-4 -> 0.75e-4 (HD 1.01e-3 -> 0.56e-3), "
        "the box's 2.22e-5 -> 1.70e-5",
    )
    fit_iterations: int = param(
        6,
        ge=0,
        doc="with radius=data: last, this many damped Gauss-Newton steps move every sphere (centre and radius; "
        "the feature tips fixed) so that the envelope passes through the data's surface samples "
        "(medial.envelope_fit), kept only where its CD to the data improves; 0: off. Sharp sphere under "
        "+experiment=cad_features, 3,000 vertices: CD / HD 1.14e-3 / 14.3e-3 (0) -> 0.51e-3 / 10.5e-3 (6, 3.8 s) "
        "-> 0.49e-3 / 9.8e-3 (12, 6.8 s); the bunny's 0.54e-3 / 5.5e-3 (6) -> 0.51e-3 / 7.9e-3 (12)",
    )
    fit_damping: float = param(
        0.12,
        gt=0,
        doc="the fit's Levenberg-Marquardt damping, per vertex's share of the samples: lower moves further per "
        "step and overshoots, higher needs more steps (sharp sphere, cad_features, 6 steps: CD 0.59e-3 at 0.04, "
        "0.51e-3 at 0.12, 0.58e-3 at 0.4)",
    )


@register_stage("sheet")
class Sheet(Stage):
    """Collapse the covering's solid to one layer on the membrane; radii; SQEM simplification; centring;
    coverage."""

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
    # 2: centre_on_data's inside test from the mesh's winding number; 3: feature tips not centred; 4: coverage;
    # 5: coverage kept only where it improves the envelope's fit; 6: surface balls centred inside the mesh;
    # 7: a vertex outside goes to the surface with radius 0; 8: squares and edges off q's valley released;
    # 9: the covering's voids inside the shape filled; 10: the level of q with the input's topology;
    # 11: rims carried out to the axis's end; 12: the centring's bisection starts at the vertex's own depth;
    # 13: the solid grown with the input's topology where no level of q has it; 14: tip_reach 0.003
    # 15: a cloud measured against its Poisson surface (train.point_surface_as_data); 16: a sheet thinned to a
    # point or to balls of no radius is not the MAT; 17: a second sheet at off_axis_wide, the better fit kept;
    # 18: the spheres fitted to the data's surface samples (medial.envelope_fit); 19: a point whose one ball fits the
    # data is the MAT (a sphere's); a Poisson surface's balls from train's rays
    version = "19"

    def run(self, ctx: StageContext) -> None:
        from qmdf.medial.coverage import envelope_fit, refine_coverage
        from qmdf.medial.envelope_fit import fit_envelope_to_samples
        from qmdf.medial.radii import centre_on_data, data_distance, inside_test, mat_radii
        from qmdf.medial.rims import extend_rims
        from qmdf.medial.sheet import pick_sheet, simplified_sheet

        cfg: SheetConfig = ctx.cfg
        field = ctx.load("field")
        mesh, points = input_data(ctx)
        tips = ctx.load("feature_points").points if ctx.has("feature_points") else None
        membrane = ctx.load("membrane")
        centre_of = refine_of = None
        if cfg.centre and cfg.radius == "data":

            def centre_of(x):
                return centre_on_data(x, mesh, points, inside_test(field, mesh))

        measured = []

        def balls():  # measured only when coverage or the fit runs (not on a sheet left above the target)
            if not measured:
                t0 = time.perf_counter()
                # a long step on a surface whose axis collapses to a point (a sphere): every query there is
                # equally near every face, so say what runs
                ctx.log.info("coverage: measuring the data's medial balls behind its surface samples")
                measured.append(input_surface_balls(ctx, field, mesh, points))
                ctx.log.info("coverage: %d balls measured in %.1f s", len(measured[0].radii), time.perf_counter() - t0)
            return measured[0]

        fit_of = None
        if cfg.coverage_vertices and cfg.radius == "data":

            def refine_of(v, r, e, f, budget):
                return refine_coverage(
                    v,
                    r,
                    e,
                    f,
                    balls(),
                    budget,
                    cfg.coverage_tolerance,
                    cfg.coverage_spacing,
                    cfg.coverage_overshoot,
                    cfg.coverage_rounds,
                )

            def fit_of(v, r, e, f):
                return envelope_fit(v, r, e, f, balls(), np.random.default_rng(ctx.seed))["chamfer"]

        extend_of = None
        if cfg.extend_rims and cfg.radius == "data":

            def extend_of(v, r, e, f, fixed):
                distance, _ = data_distance(mesh, points)
                guard = _data_samples(mesh, points, np.random.default_rng(ctx.seed))
                t0 = time.perf_counter()
                v, r, rim_stats = extend_rims(
                    v, r, e, f, distance, inside_test(field, mesh), fixed=fixed, samples=guard
                )
                return v, r, {**rim_stats, "seconds": round(time.perf_counter() - t0, 2)}

        fit_envelope_of = None
        if cfg.fit_iterations and cfg.radius == "data":

            def fit_envelope_of(v, r, e, f, fixed):
                samples = balls().samples
                return fit_envelope_to_samples(v, r, e, f, samples, fixed, cfg.fit_iterations, cfg.fit_damping)

        grid = ctx.load("covering_grid")
        target_chi = known_solid_euler(ctx, mesh) if cfg.match_topology else None

        def build(off_axis):
            return simplified_sheet(
                grid,
                field.evaluate,
                np.asarray(membrane.vertices),
                np.asarray(membrane.faces),
                lambda x: mat_radii(x, cfg.radius, field, mesh, points),
                max_nodes=cfg.max_nodes,
                speck_fraction=cfg.speck_fraction,
                valley_share=cfg.valley_share,
                off_axis=off_axis,
                fin_area=cfg.fin_area,
                valley_only=cfg.valley_only,
                fill_pockets=cfg.fill_pockets,
                target_chi=target_chi,
                grow_topology=cfg.grow_topology,
                target_vertices=cfg.target_vertices,
                compact_slack=cfg.compact_slack,
                boundary_weight=cfg.boundary_weight,
                max_turn_deg=cfg.max_turn_deg,
                tips=tips,
                tip_reach=cfg.tip_reach,
                centre_of=centre_of,
                refine_of=refine_of,
                refine_vertices=cfg.coverage_vertices,
                fit_of=fit_of,
                extend_of=extend_of,
                fit_envelope_of=fit_envelope_of,
            )

        mat, stats = build(cfg.off_axis)
        if fit_of is not None and cfg.off_axis_wide and cfg.off_axis_wide != cfg.off_axis:
            candidates = [(mat, stats), build(cfg.off_axis_wide)]
            kept, rows = pick_sheet(candidates, fit_of, target_chi)
            mat, stats = candidates[kept]
            for row, off_axis in zip(rows, (cfg.off_axis, cfg.off_axis_wide)):
                row["off_axis"] = off_axis
            stats["off_axis"] = {"tried": rows, "kept": rows[kept]["off_axis"]}
            ctx.log.info(
                "sheet: off_axis %s kept (%s)",
                rows[kept]["off_axis"],
                "; ".join(
                    f"{r['off_axis']}: CD {r['cd']:.3e} to the data, {r['vertices']} vertices, chi {r['chi']}"
                    + ("" if r["compact"] else ", not compact")
                    for r in rows
                ),
            )
        level = stats.get("level")
        if level and level.get("grown"):
            g = level["grown"]
            ctx.log.info(
                "sheet: no level of q from eps %.4g down gives the solid the input's Euler characteristic %d "
                "(scan: %s); grown in q's order instead: %d of the covering's %d nodes, %d tunnels closed, chi %d "
                "(sheet.grow_topology)",
                level["scan"][0][0],
                level["target_chi"],
                ", ".join(f"{e:.4f}: {c}" for e, c in level["scan"]),
                g["joined"],
                g["allowed"],
                len(g["closures_q"]),
                g["chi"],
            )
        elif level and level["eps"] is None:
            ctx.log.warning(
                "sheet: no level of q from eps %.4g down gives the solid the input's Euler characteristic %d "
                "(scan: %s); the covering's nodes are collapsed as they are",
                level["scan"][0][0],
                level["target_chi"],
                ", ".join(f"{e:.4f}: {c}" for e, c in level["scan"]),
            )
        elif level:
            ctx.log.info(
                "sheet: the nodes below q = %.4g collapsed, the highest level whose solid has the input's Euler "
                "characteristic %d (covering's eps %.4g; sheet.match_topology)",
                level["eps"],
                level["target_chi"],
                level["scan"][0][0],
            )
        c = stats.get("coverage")
        if c and "shortfall_before" in c:
            ctx.log.info(
                "coverage: %d vertices added in %d rounds; the surface outside the envelope by %.2e on average "
                "(was %.2e), at most %.2e (was %.2e)",
                c["added"],
                c["rounds"],
                c["shortfall_after"]["mean"],
                c["shortfall_before"]["mean"],
                c["shortfall_after"]["max"],
                c["shortfall_before"]["max"],
            )
            if c.get("kept") is False:
                ctx.log.info(
                    "coverage: not kept; with it the envelope fits the data worse (CD %.3e against %.3e before)",
                    c["cd_after"],
                    c["cd_before"],
                )
        elif c is not None:
            ctx.log.info("coverage: nothing added (%s)", c.get("skipped", "no budget, samples or edges"))
        rims = stats.get("rims")
        if rims:
            ctx.log.info(
                "rims: %d of %d rim vertices and curve ends walked out to the axis's end (median %.2e, at most "
                "%.2e; %d sent back by the fit guard) in %.1f s",
                rims["moved"],
                rims["rim_vertices"],
                rims.get("median_step", 0.0),
                rims.get("max_step", 0.0),
                rims.get("reverted", 0),
                rims["seconds"],
            )
        fitted = stats.get("envelope_fit")
        if fitted:
            ctx.log.info(
                "envelope fit: mean distance of the data's samples to the envelope %.2e -> %.2e in %d steps "
                "(vertices moved by %.2e median, %.2e at most) in %.1f s%s",
                fitted["mean_distance"][0],
                fitted["mean_distance"][fitted["iteration"]],
                fitted["iteration"],
                fitted["median_move"],
                fitted["max_move"],
                fitted["seconds"],
                ""
                if "kept" not in fitted
                else f"; CD {fitted['cd_before']:.3e} -> {fitted['cd_after']:.3e}, "
                + ("kept" if fitted["kept"] else "not kept"),
            )
        v = len(mat.vertices)
        # an undertrained field (no inside) thins to a point: no sheet, whatever its chi. But a sphere's MAT is one
        # ball: a point is the MAT where its fitted ball lies within the coverage tolerance of the data
        stats["fits_data"] = bool(stats.get("cd", float("inf")) <= cfg.coverage_tolerance)  # export takes it as is
        if (not (len(mat.faces) or len(mat.edges)) and not stats["fits_data"]) or not mat.radii.max(initial=0.0) > 0:
            stats["compact"] = False
            ctx.log.warning(
                "the single sheet collapsed to %d vertices, %d edges, %d faces, largest radius %.3g: the field's "
                "inside is too thin for a MAT here (see the train stage's slices.png); export writes the membrane",
                v,
                len(mat.edges),
                len(mat.faces),
                mat.radii.max(initial=0.0),
            )
        elif not stats["compact"]:
            ctx.log.warning(
                "the single sheet is not compact: simplification stopped at %d vertices (target %d; the "
                "link condition refused %s collapses on a tangled complex, %d seam edges). export writes "
                "the membrane as the MAT; the sheet stays in %s",
                v,
                cfg.target_vertices,
                stats.get("simplify", {}).get("link_rejected"),
                stats["after"]["seam_edges"],
                (ctx.output_dir or ctx.stage_dir) / "sheet.ma",
            )
        ctx.save("sheet", mat)
        ctx.save("sheet_stats", stats)
        ctx.log.info(
            "single sheet: %d vertices, %d faces, %d lone edges, chi %d, %d seam edges (before "
            "simplification: %d vertices, chi %d)",
            v,
            len(mat.faces),
            stats["after"]["lone_edges"],
            stats["after"]["chi"],
            stats["after"]["seam_edges"],
            stats["before"]["vertices"],
            stats["before"]["chi"],
        )


def _data_samples(mesh, points, rng: np.random.Generator) -> np.ndarray:
    """Points on the data's surface for the rims' guard: a mesh's vertices (its corners and sharp edges, which
    random samples seldom hit) and 20k samples of its faces; a cloud's points."""
    if mesh is None:
        return np.asarray(points, np.float64)
    from qmdf.geometry.sampling import sample_surface

    return np.concatenate([np.asarray(mesh[0], np.float64), sample_surface(*mesh, 20_000, rng).points])
