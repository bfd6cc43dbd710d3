"""The sheet's refinement as a list of small steps.

Each step is a plain function ``run(mat, data, cfg) -> (mat, stats)`` over a ``MAT`` (four arrays), registered
under a name with its own settings dataclass and a one-line summary of its stats (``SHEET_STEPS``; built-ins in
``qmdf.medial.steps``, third parties through the ``qmdf.sheet_steps`` entry-point group). The config names the
list (``sheet.steps``) and ``refine`` runs it. A step that declares ``keep_if_better`` is kept only where the
MAT's envelope fits the data no worse than before: one rule (``medial.coverage.keeps``), applied here, to
the sheets of two off-axis rules (``medial.sheet.pick_sheet``) and to the membrane's coverage in export.

Write one like this::

    @dataclass
    class JitterConfig:
        scale: float = param(1e-3, gt=0)

    def jitter(mat, data, cfg):
        moved = mat.vertices + cfg.scale * np.random.default_rng(data.seed).normal(size=mat.vertices.shape)
        return mat._replace(vertices=moved), {"moved": len(moved)}

    sheet_step("jitter", JitterConfig, keep_if_better=True, summary="{moved} vertices jittered")(jitter)
"""

from __future__ import annotations

import logging
import time
from dataclasses import KW_ONLY, dataclass, field
from typing import Any, Callable, NamedTuple

import numpy as np

from qmdf.medial.coverage import envelope_fit, keeps
from qmdf.registry import SHEET_STEPS


class MAT(NamedTuple):
    """A medial mesh under refinement: vertices (V, 3), radii (V,), lone edges (E, 2: the edges of no face, a
    curve-like axis) and faces (F, 3)."""

    vertices: np.ndarray
    radii: np.ndarray
    edges: np.ndarray
    faces: np.ndarray

    def medial_mesh(self):
        """As a ``MedialMesh`` with every face edge listed (the ``.ma`` format's edges)."""
        from qmdf.geometry.ma_format import MedialMesh

        return MedialMesh(*self).with_face_edges()


@dataclass
class SheetData:
    """What the steps read besides the MAT: the data the MAT is fitted to and the sheet's public settings.

    ``mesh`` (vertices, faces) or ``points``: the data (``medial.radii.data_distance`` measures to it);
    ``is_inside(q) -> bool``: inside the shape; ``measure_balls() -> SurfaceBalls``: the data's medial balls
    behind its surface samples, measured once on first use (``balls``); ``tips``: feature points whose vertices
    within ``tip_reach`` stay where they are; a MAT above ``compact_slack`` times ``target_vertices`` is not
    compact (simplification refused on a tangled complex); ``settings``: the settings of every step in the list
    by name (a step that returns the MAT to the budget reads ``simplify``'s)."""

    mesh: tuple[np.ndarray, np.ndarray] | None
    points: np.ndarray | None
    is_inside: Callable[[np.ndarray], np.ndarray]
    measure_balls: Callable[[], Any]
    _: KW_ONLY  # the sheet's settings, no defaults here: their one source is the sheet stage's config
    target_vertices: int
    tolerance: float
    tip_reach: float
    compact_slack: float
    tips: np.ndarray | None = None
    seed: int = 0
    settings: dict[str, Any] = field(default_factory=dict)
    log: logging.Logger = field(default_factory=lambda: logging.getLogger("qmdf.sheet"))
    _balls: list = field(default_factory=list, repr=False)

    @property
    def balls(self):
        if not self._balls:
            t0 = time.perf_counter()
            # long on a surface whose axis collapses to a point (a sphere), so say what runs
            self.log.info("sheet: measuring the data's medial balls behind its surface samples")
            self._balls.append(self.measure_balls())
            self.log.info("sheet: %d balls measured in %.1f s", len(self._balls[0].radii), time.perf_counter() - t0)
        return self._balls[0]

    def fixed(self, x: np.ndarray) -> np.ndarray | None:
        """Which of the points ``x`` lie within ``tip_reach`` of a feature tip (None: no tips)."""
        if self.tips is None or not len(self.tips):
            return None
        from scipy.spatial import cKDTree

        return cKDTree(self.tips).query(x)[0] < self.tip_reach

    def is_compact(self, n: int) -> bool:
        """Whether a MAT of ``n`` vertices is within ``compact_slack`` times the budget (no budget: always)."""
        return not self.target_vertices or n <= self.compact_slack * self.target_vertices

    def chamfer(self, mat: MAT) -> float:
        """The CD between the MAT's envelope and the data (``medial.coverage.envelope_fit``, seeded): what
        ``keeps`` compares."""
        return float(envelope_fit(*mat, self.balls, np.random.default_rng(self.seed))["chamfer"])


@dataclass(frozen=True)
class SheetStep:
    name: str
    run: Callable[[MAT, SheetData, Any], tuple[MAT, dict]]
    Config: type
    keep_if_better: bool = False
    needs_data: bool = True  # reads the data (radius=data); skipped where the radii come from the field
    summary: str | Callable[[dict], str] = ""

    def describe(self, stats: dict) -> str:
        if callable(self.summary):
            return self.summary(stats)
        try:
            return self.summary.format(**stats)
        except (KeyError, IndexError, ValueError):
            return ", ".join(f"{k} {v}" for k, v in stats.items() if not isinstance(v, (dict, list)))


def sheet_step(name: str, config: type, keep_if_better: bool = False, needs_data: bool = True, summary=""):
    """Decorator: register ``run(mat, data, cfg) -> (mat, stats)`` as sheet step ``name`` with settings
    ``config``. Returning the same ``mat`` object says the step changed nothing."""

    def deco(run):
        # the function is what the registry lists (its doc and module), the step's declaration rides on it
        run.sheet_step = SheetStep(name, run, config, keep_if_better, needs_data, summary)
        SHEET_STEPS.add(name, run, config)
        return run

    return deco


def refine(mat: MAT, data: SheetData, steps: list[tuple[SheetStep, Any]]) -> tuple[MAT, dict, float | None]:
    """Run ``steps`` ((step, its settings) pairs) in order, each logged on one line; a ``keep_if_better`` step
    undone where ``keeps`` says so. Returns the MAT, each step's stats by name (with its seconds, and for a judged
    step ``cd_before``, ``cd_after`` and ``kept``), and the final MAT's CD where a judged step measured it."""
    stats: dict[str, dict] = {}
    cd = None
    for step, cfg in steps:
        t0 = time.perf_counter()
        new, s = step.run(mat, data, cfg)
        if new is not mat and step.keep_if_better:
            before = cd if cd is not None else data.chamfer(mat)
            after = data.chamfer(new)
            kept = keeps(after, before)
            s = {**s, "cd_before": before, "cd_after": after, "kept": kept}
            mat, cd = (new, after) if kept else (mat, before)
        elif new is not mat:
            mat, cd = new, None
        s = {**s, "seconds": round(time.perf_counter() - t0, 2)}
        stats[step.name] = s
        verdict = (
            ""
            if "kept" not in s
            else f"; CD {s['cd_before']:.3e} -> {s['cd_after']:.3e}, " + ("kept" if s["kept"] else "not kept")
        )
        data.log.info("%s: %s (%.1f s)%s", step.name, step.describe(s), s["seconds"], verdict)
    return mat, stats, cd
