"""``analytic_field``: the exact field of a procedural shape with a known medial axis, in place of ``train``.

``pipeline.stages=[sample,analytic_field,cover,tetrahedralize,contract,sheet,export,evaluate] input.shape=torus``
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
    """The exact SDF and medial field of input.shape (torus, box or ellipsoid), in the sampled input's unit box."""

    Config = AnalyticFieldConfig
    inputs = {"normalization": NORMALIZATION}
    outputs = {"field": FIELD}
    config_deps = ("input",)
    version = "2"  # 2: the field carries the normalisation (shapes not already in the unit box)

    def run(self, ctx: StageContext) -> None:
        import torch

        from qmdf.fields.analytic import ANALYTIC
        from qmdf.fields.field import ANALYTIC_FORMAT

        shape = ctx.settings.input.shape
        if ctx.settings.input.path is not None or shape not in ANALYTIC:
            raise QmdfError(f"analytic_field needs input.path=null and input.shape in {sorted(ANALYTIC)}")
        norm = ctx.load("normalization")
        torch.save({"format": ANALYTIC_FORMAT, "shape": shape, "normalization": norm.to_dict()}, ctx.path("field"))
