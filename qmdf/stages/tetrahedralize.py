"""``tetrahedralize``: fTetWild (pytetwild) on the covering, so contraction can move interior vertices and
measure the enclosed volume on tetrahedra (paper Sec. 4.2)."""

from __future__ import annotations

from dataclasses import dataclass

from qmdf.artifacts import MESH, TETS
from qmdf.errors import QmdfError
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class TetrahedralizeConfig:
    edge_length_fac: float = param(
        0.05, gt=0, doc="ideal tet edge length as a fraction of the bbox diagonal (fTetWild)"
    )
    epsilon: float = param(
        1e-4, gt=0, doc="envelope: max distance of the tet boundary from the covering, relative to the bbox"
    )
    optimize: bool = param(True, doc="improve tet quality (slower)")
    stop_energy: float = param(10.0, gt=0)


@register_stage("tetrahedralize")
class Tetrahedralize(Stage):
    """Tetrahedral mesh of the closed covering."""

    Config = TetrahedralizeConfig
    inputs = {"covering": MESH}
    outputs = {"covering_tets": TETS}

    def run(self, ctx: StageContext) -> None:
        from qmdf.geometry.tetwild_worker import tetrahedralize

        cfg: TetrahedralizeConfig = ctx.cfg
        mesh = ctx.load("covering")
        if not mesh.is_watertight:
            raise QmdfError(
                "the covering is not closed (watertight), so it cannot be tetrahedralised; "
                "raise cover.resolution or cover.eps"
            )
        # fTetWild writes a file into the working directory: it runs in a child process inside work_dir
        v, t = tetrahedralize(
            mesh.vertices,
            mesh.faces,
            ctx.work_dir,
            edge_length_fac=cfg.edge_length_fac,
            epsilon=cfg.epsilon,
            optimize=cfg.optimize,
            stop_energy=cfg.stop_energy,
        )
        if len(t) == 0:
            raise QmdfError("fTetWild produced no tetrahedra for the covering")
        ctx.save("covering_tets", (v, t))
        ctx.log.info("tetrahedralised: %d vertices, %d tets", len(v), len(t))
