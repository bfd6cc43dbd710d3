"""``analytic_field``: the exact field of a procedural shape with a known medial axis, in place of ``train``.

``pipeline.stages=[sample,analytic_field,cover,tetrahedralize,contract,export,evaluate] input.shape=torus``
proves the extraction on the exact answer, independently of training.
"""
from __future__ import annotations

from dataclasses import dataclass

from qmdf.artifacts import FIELD, NORMALIZATION
from qmdf.errors import QmdfError
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class AnalyticFieldConfig:
    pass


@register_stage("analytic_field")
class AnalyticFieldStage(Stage):
    """The exact SDF and medial field of input.shape (torus or box)."""

    Config = AnalyticFieldConfig
    inputs = {"normalization": NORMALIZATION}
    outputs = {"field": FIELD}
    config_deps = ("input",)

    def run(self, ctx: StageContext) -> None:
        import numpy as np
        import torch

        from qmdf.fields.analytic import ANALYTIC
        from qmdf.fields.field import ANALYTIC_FORMAT

        shape = ctx.settings.input.shape
        if ctx.settings.input.path is not None or shape not in ANALYTIC:
            raise QmdfError(f"analytic_field needs input.path=null and input.shape in {sorted(ANALYTIC)}")
        norm = ctx.load("normalization")
        if not (np.allclose(norm.center, 0, atol=1e-9) and abs(norm.scale - 1) < 1e-9):
            raise QmdfError(f"the {shape} is not already in the unit box (scale {norm.scale}); its field would not match")
        torch.save({"format": ANALYTIC_FORMAT, "shape": shape}, ctx.path("field"))
