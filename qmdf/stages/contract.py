"""``contract``: collapse the covering's volume onto the medial axis (paper Sec. 4.2, Fig. 8).

The contraction itself, its energy and its terms: ``qmdf.medial.contraction``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MESH, POINTS, TETS
from qmdf.errors import QmdfError
from qmdf.medial.contraction import ContractionSettings
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class ContractConfig(ContractionSettings):
    volume: str = param(
        "surface",
        choices=("surface", "tets"),
        doc="enclosed volume of the surface (default, measured better) or of the tets",
    )


@register_stage("contract")
class Contract(Stage):
    """Optimise the covering's vertices onto the minima of Q-MDF while its volume goes to zero."""

    Config = ContractConfig
    inputs = {"covering": MESH, "field": FIELD}
    optional_inputs = {"covering_tets": TETS, "feature_points": POINTS}
    outputs = {"membrane": MESH, "contraction": JSON}
    optional_outputs = {"contracted_tets": TETS}
    version = "2"  # 2: the volume's gradient summed per vertex, in parallel (its last bits differ)

    def run(self, ctx: StageContext) -> None:
        from qmdf.geometry.tets import boundary_faces
        from qmdf.medial.contraction import contract, surface_mesh
        from qmdf.progress import progress

        cfg: ContractConfig = ctx.cfg
        field = ctx.load("field")
        use_tets = cfg.volume == "tets"
        if use_tets:
            if not ctx.has("covering_tets"):
                raise QmdfError("contract.volume=tets needs the tetrahedralize stage before contract")
            v, t = ctx.load("covering_tets")
            faces = boundary_faces(t, v)
        else:
            mesh = ctx.load("covering")
            v, t, faces = np.asarray(mesh.vertices), None, np.asarray(mesh.faces)
        features = ctx.load("feature_points").points if ctx.has("feature_points") else None
        heart = progress(ctx.log, "contract: iteration", cfg.iterations)
        x, history, vol0, evaluations = contract(
            field,
            v,
            faces,
            t,
            features=features,
            settings=cfg,
            on_iteration=lambda done, total: heart.beat(done),
        )
        ctx.save("membrane", surface_mesh(x, faces))
        if t is not None:
            ctx.save("contracted_tets", (x, t))
        final = history[-1]
        ctx.save(
            "contraction",
            {
                "initial_volume": vol0,
                "final_volume": final["volume"],
                "volume_ratio": final["volume"] / vol0 if vol0 else None,
                "volume_mode": "tets" if use_tets else "surface",
                "field_evaluations": evaluations,
                "feature_points": 0 if features is None else int(len(features)),
                "pulling_features": final.get("pulling_features", 0),
                "feature_distance": final.get("feature_distance"),
                "history": history,
            },
        )
        ctx.log.info(
            "contracted (%s volume): volume %.3g -> %.3g (%.2f%%), mean q %.2e",
            "tet" if use_tets else "surface",
            vol0,
            final["volume"],
            100 * final["volume"] / vol0 if vol0 else float("nan"),
            final["q_mean"],
        )
