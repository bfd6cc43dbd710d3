"""``contract``: collapse the covering's volume onto the medial axis (paper Sec. 4.2, Fig. 8).

The contraction itself, its energy and its terms: ``qmdf.medial.contraction``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MESH, POINTS, TETS
from qmdf.errors import QmdfError
from qmdf.schema import param
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class ContractConfig:
    iterations: int = param(3000, ge=1, doc="optimisation steps (paper: about 3k)")
    lr: float = param(5e-4, gt=0, doc="step length in the unit box (DCUDF: 5e-4), cosine-decayed")
    lr_final: float = param(1e-6, gt=0)
    lambda_volume: float = param(1.0, ge=0, doc="weight of the enclosed volume (per initial area)")
    lambda_laplacian: float = param(100.0, ge=0, doc="weight of the area-weighted Laplacian smoothness")
    volume: str = param(
        "surface",
        choices=("surface", "tets"),
        doc="enclosed volume of the surface (default, measured better) or of the tets",
    )
    lattice: float = param(
        1e-3,
        ge=0,
        doc="spacing of the lazily evaluated q lattice the vertices read (its error "
        "is below half of it); 0: evaluate the field at every vertex in every iteration",
    )
    feature_weight: float = param(
        10.0,
        ge=0,
        doc="pull of each feature point on its nearest vertex, where a "
        "feature_detect stage ran before (0: the paper's energy)",
    )
    feature_reach: float = param(
        0.02,
        gt=0,
        doc="feature points farther than this from the covering pull nothing "
        "(the covering never reached them; unit box)",
    )
    zip_weight: float = param(
        1000.0,
        ge=0,
        doc="near the feature points, pull of each vertex toward the facing "
        "layer within zip_reach: a local volume term that closes the tips (0: the paper's energy; "
        "acts only where a feature_detect stage ran before)",
    )
    zip_reach: float = param(
        0.02,
        gt=0,
        doc="how far the facing layer may be (unit box; 0.01 folded 4 to 13 points fewer "
        "of the sharp-edge samples on the procedural and well-fitted CAD shapes)",
    )
    zip_near: float = param(0.05, gt=0, doc="vertices within this of a feature point are zipped (unit box)")
    outside_weight: float = param(
        2.0,
        ge=0,
        doc="the vertices minimise q + outside_weight * max(sdf, 0): 2 continues "
        "q = mf - |sdf| as mf + sdf outside the shape, so q rises there instead of falling "
        "(0: the paper's q everywhere, which let the vertices of thin parts leave the shape)",
    )
    log_every: int = param(25, ge=1)


def contraction_params(cfg: ContractConfig) -> dict:
    """The config's keywords of ``qmdf.medial.contraction.contract`` (all but the volume mode)."""
    return {k: v for k, v in dataclasses.asdict(cfg).items() if k != "volume"}


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
            **contraction_params(cfg),
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
