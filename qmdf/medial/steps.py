"""The sheet's built-in refinement steps (``qmdf.medial.refinement``), in their default order: ``simplify`` to the
vertex budget under the spherical quadric error, ``centre`` each vertex on the data's axis, ``coverage`` where the
envelope falls short of the surface, ``rims`` out to where the axis ends, ``fit`` the spheres to the surface;
opt-in, ``maximal``: the balls that are not medial (flaps off the axis) back onto it. Every step but ``simplify``
reads the data (radius=data); feature tips (``SheetData.fixed``) stay in place."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.medial.coverage import CoverageSettings, refine_coverage
from qmdf.medial.envelope_fit import FitSettings, fit_envelope_to_samples
from qmdf.medial.radii import centre_on_data, data_distance
from qmdf.medial.refinement import MAT, SheetData, SheetStep, sheet_step
from qmdf.medial.rims import RimSettings, extend_rims
from qmdf.medial.simplify import SimplifySettings, simplify_medial_mesh
from qmdf.registry import SHEET_STEPS
from qmdf.schema import param


@dataclass
class NoSettings:
    """A step without settings."""


def _simplify_summary(s: dict) -> str:
    if "vertices" not in s:
        return s.get("skipped", "nothing to do")
    return (
        f"{s['vertices_before']} -> {s['vertices']} vertices ({s['collapses']} collapses; "
        f"{s['link_rejected']} refused by the link condition, {s['turn_rejected']} by the turn)"
    )


@sheet_step("simplify", SimplifySettings, needs_data=False, summary=_simplify_summary)
def simplify(mat: MAT, data: SheetData, cfg: SimplifySettings, fixed: np.ndarray | None = None):
    """Collapse edges, cheapest spherical quadric error first, without a change of topology (``medial.simplify``):
    while no collapse moves the envelope by more than ``cfg.deviation`` times ``data.tolerance``, then, where more
    than ``data.target_vertices`` are left, down to that cap; ``fixed`` (default: the feature tips) stay."""
    limit = cfg.deviation * data.tolerance
    cap = data.target_vertices
    if not cap or (not limit and len(mat.vertices) <= cap):
        return mat, {"skipped": f"{len(mat.vertices)} vertices, within the budget of {cap}"}
    fixed = data.fixed(mat.vertices) if fixed is None else fixed
    res = simplify_medial_mesh(*mat, 1 if limit else cap, cfg.boundary_weight, cfg.max_turn_deg, fixed, limit)
    stats = dict(res.stats)
    if limit and len(res.vertices) > cap:  # the cap: on from there at whatever deviation it takes
        again = (res.vertices, res.radii, res.edges, res.faces)
        res = simplify_medial_mesh(*again, cap, cfg.boundary_weight, cfg.max_turn_deg, res.fixed)
        stats.update(vertices=res.stats["vertices"], capped=True, collapses=stats["collapses"] + res.stats["collapses"])
    return MAT(res.vertices, res.radii, res.edges, res.faces), stats


@sheet_step("centre", NoSettings, summary="vertices moved by {median_move:.2e} median, {max_move:.2e} at most")
def centre(mat: MAT, data: SheetData, cfg: NoSettings):
    """Each vertex to the centre of the data's maximal ball through its closest point
    (``medial.radii.centre_on_data``; the teacup's CD 1.36e-3 -> 0.40e-3)."""
    v, r = mat.vertices, mat.radii
    moved, radii = centre_on_data(v, data.mesh, data.points, data.is_inside)
    fixed = data.fixed(v)  # feature tips stay on their sharp edges
    if fixed is not None:
        moved[fixed], radii[fixed] = v[fixed], r[fixed]
    step = np.linalg.norm(moved - v, axis=1)
    stats = {"median_move": float(np.median(step)) if len(step) else 0.0, "max_move": float(step.max(initial=0.0))}
    return MAT(moved, radii, mat.edges, mat.faces), stats


def _coverage_summary(s: dict) -> str:
    if "shortfall_before" not in s:
        return f"nothing added ({s.get('skipped', 'no budget, samples or edges')})"
    return (
        f"{s['added']} vertices added in {s['rounds']} rounds; the surface outside the envelope by "
        f"{s['shortfall_after']['mean']:.2e} on average (was {s['shortfall_before']['mean']:.2e}), at most "
        f"{s['shortfall_after']['max']:.2e} (was {s['shortfall_before']['max']:.2e})"
    )


@sheet_step("coverage", CoverageSettings, keep_if_better=True, summary=_coverage_summary)
def coverage(mat: MAT, data: SheetData, cfg: CoverageSettings):
    """Up to ``cfg.vertices`` of the data's medial balls inserted where the envelope falls short of the surface
    by more than ``data.tolerance`` (``medial.coverage``), then the MAT simplified back to the budget with the
    added balls and the tips fixed, and centred again where ``centre`` is a step (on the bunny 3,000 + 1,000 ->
    3,000 vertices kept CD 1.04e-3 of the 4,000's 0.97e-3)."""
    if not cfg.vertices:
        return mat, {"added": 0, "skipped": "no budget (sheet.step.coverage.vertices=0)"}
    if not data.is_compact(len(mat.vertices)):
        return mat, {"added": 0, "skipped": "the sheet is not compact (simplification stopped early)"}
    n0 = len(mat.vertices)
    # compact by tolerance (simplify's deviation): the envelope is asked to reach the data within the tolerance,
    # so no ball goes in for a gap below it; a fixed budget is spent on the smaller gaps too
    by_tolerance = bool(getattr(data.settings.get("simplify"), "deviation", 0.0))
    *out, stats = refine_coverage(
        *mat, data.balls, cfg.vertices, data.tolerance, cfg.spacing, cfg.overshoot, cfg.rounds, not by_tolerance
    )
    if not stats["added"]:
        return mat, stats
    new = MAT(*out)
    if data.target_vertices and len(new.vertices) > data.target_vertices:
        # back to the budget: the added balls (and the tips) stay, the collapses take what matters least
        fixed = np.arange(len(new.vertices)) >= n0
        tips = data.fixed(new.vertices)
        fixed = fixed if tips is None else fixed | tips
        new, stats["resimplify"] = simplify(new, data, data.settings.get("simplify") or SimplifySettings(), fixed)
        if "centre" in data.settings:
            new, stats["recentred"] = centre(new, data, data.settings["centre"])
    return new, stats


def _data_samples(data: SheetData) -> np.ndarray:
    """Points on the data's surface for the rims' guard: a mesh's vertices (its corners and sharp edges, which
    random samples seldom hit) and 20k samples of its faces; a cloud's points."""
    if data.mesh is None:
        return np.asarray(data.points, np.float64)
    from qmdf.geometry.sampling import sample_surface

    rng = np.random.default_rng(data.seed)
    return np.concatenate([np.asarray(data.mesh[0], np.float64), sample_surface(*data.mesh, 20_000, rng).points])


def _rims_summary(s: dict) -> str:
    return (
        f"{s['moved']} of {s['rim_vertices']} rim vertices and curve ends walked out to the axis's end (median "
        f"{s.get('median_step', 0.0):.2e}, at most {s.get('max_step', 0.0):.2e}; {s.get('reverted', 0)} sent back "
        "by the fit guard)"
    )


@sheet_step("rims", RimSettings, summary=_rims_summary)
def rims(mat: MAT, data: SheetData, cfg: RimSettings):
    """Each free rim's vertex and curve's end walked out to where the medial axis ends (``medial.rims``; the
    covering stops short of it), each move kept only where the envelope fits the samples near it as well or
    better; exact fields, 2,000 vertices: the ellipsoid's CD 1.38e-4 -> 0.75e-4, the box's 2.22e-5 -> 1.70e-5."""
    distance, _ = data_distance(data.mesh, data.points)
    v, r, stats = extend_rims(
        *mat, distance, data.is_inside, cfg, fixed=data.fixed(mat.vertices), samples=_data_samples(data)
    )
    return MAT(v, r, mat.edges, mat.faces), stats


def _fit_summary(s: dict) -> str:
    return (
        f"mean distance of the data's samples to the envelope {s['mean_distance'][0]:.2e} -> "
        f"{s['mean_distance'][s['iteration']]:.2e} in {s['iteration']} steps (vertices moved by "
        f"{s['median_move']:.2e} median, {s['max_move']:.2e} at most)"
    )


@sheet_step("fit", FitSettings, keep_if_better=True, summary=_fit_summary)
def fit(mat: MAT, data: SheetData, cfg: FitSettings):
    """Every sphere's centre and radius moved by damped Gauss-Newton steps so that the envelope passes through
    the data's surface samples, the rims faired as curves of balls (``medial.envelope_fit``), the tips fixed."""
    v, r, stats = fit_envelope_to_samples(
        *mat, data.balls.samples, data.fixed(mat.vertices), cfg.iterations, cfg.damping, cfg.rim_fairness
    )
    return MAT(v, r, mat.edges, mat.faces), stats


def resolve_steps(names: list[str], settings: dict, radius_from_data: bool) -> list[tuple[SheetStep, object]]:
    """The registered steps ``names`` in order (the built-ins here, a plugin's by its entry point), each with its
    typed settings from ``settings[name]``; without data radii, the steps that need them are left out."""
    from qmdf import schema

    out = []
    for name in names:
        step = SHEET_STEPS.get(name).obj.sheet_step
        if step.needs_data and not radius_from_data:
            continue
        out.append((step, schema.build(step.Config, settings.get(name) or {})))
    return out


@dataclass
class MaximalSettings:
    """The sheet's ``maximal`` step (``sheet.step.maximal``)."""

    reach: float = param(
        10.0,
        gt=0,
        doc="a ball is tested by growing it this many times sheet.tolerance away from its closest data point (10: "
        "1e-2, issue 53's bound on a vertex's distance to the axis)",
    )


@sheet_step(
    "maximal",
    MaximalSettings,
    summary="{moved} of {vertices} balls not maximal moved onto the axis ({max_move:.2e} at most)",
)
def maximal(mat: MAT, data: SheetData, cfg: MaximalSettings):
    """Every vertex whose ball is not a medial ball moved to the centre of the data's maximal ball through its
    closest point (``centre_on_data``). The test is the definition: a medial ball cannot grow away from its
    closest point; one that can by h, the distance to the data rising by (nearly) h, touches the surface on one side
    only: a flap off the axis (the fit carried rim balls of the box along a face, 33e-3 off its axis). On the axis
    the other contacts stop it (two faces at 90 degrees: no rise; a wall's two sides: a fall) and where the axis ends
    the surface's curvature does (a fall), so only flaps move. Opt-in: on the block it cost CD 1.7x, HD 4x (near sharp
    edges a ball with one contact is no flap)."""
    v, r = mat.vertices, mat.radii
    distance, _ = data_distance(data.mesh, data.points)
    h = cfg.reach * data.tolerance
    d, foot = distance(v)
    away = (v - foot) / np.maximum(d, 1e-300)[:, None]
    d_grown, foot_grown = distance(v + h * away)
    # grown by (nearly) h and still touching where it did: one contact, not two spokes that draw together where the
    # axis nears its end (the ellipsoid's rim: there the grown ball's closest point jumps to the other side)
    grows = (d_grown > d + 0.9 * h) & (np.linalg.norm(foot_grown - foot, axis=1) < 0.5 * h)
    fixed = data.fixed(v)
    if fixed is not None:
        grows &= ~fixed
    # outside the shape every ball grows away from its closest point: that is no flap (nor a ball of the MAT)
    idx = np.flatnonzero(grows & (d > h))
    idx = idx[np.asarray(data.is_inside(v[idx]), bool)] if len(idx) else idx
    stats = {"moved": int(len(idx)), "vertices": int(len(v)), "max_move": 0.0}
    if not len(idx):
        return mat, stats
    moved, radii = v.copy(), r.copy()
    moved[idx], radii[idx] = centre_on_data(v[idx], data.mesh, data.points, data.is_inside)
    stats["max_move"] = float(np.linalg.norm(moved[idx] - v[idx], axis=1).max())
    return MAT(moved, radii, mat.edges, mat.faces), stats
