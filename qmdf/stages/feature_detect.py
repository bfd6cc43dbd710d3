"""``feature_detect``: points on the input's sharp features (paper Sec. 4.3, Fig. 5).

From a mesh: every convex edge whose dihedral angle exceeds ``dihedral_deg``, sampled along it every ``spacing``.
From a point cloud (no faces), ``field_seeds`` picks one or both of two routes. ``membrane``, the paper's
procedure on the first MAT:
  1. the medial membrane's boundary: fold edges (dihedral near 2*pi) where the radius (SDF) and MF are low;
  2. points sampled on them march along g1 + g2, the means of the two clusters of SDF gradients taken at six
     axis-offset samples (the two faces that meet at the edge), in steps of |sdf| (never past the surface,
     since sdf rises along g1 + g2 more slowly than along either normal), until |sdf| < ``march_tol``;
  3. each is refined by the quadric error metric over its ``qem_k`` nearest input points, with SDF gradients
     as their normals: the point closest to all their tangent planes, i.e. on the edge where they meet.
It finds only the edges the first MAT's membrane already comes near (about 10% of the box's). ``points``
(not in the paper): every input point whose ``qem_k`` neighbours split into two planes meeting in a convex
edge sharper than ``dihedral_deg`` gives the piece of that edge where both planes hold points
(``qmdf.geometry.sharp_points``), sampled every ``spacing``; the learned gradients only tell the two sides
apart, the planes come from the points themselves. With
``face_normals`` each feature point also carries the mean of its two planes' normals, so that
feature_retrain can walk the edge's inward bisector, as it does from a mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.artifacts import FIELD, JSON, MAT, MESH, POINTS
from qmdf.errors import QmdfError
from qmdf.schema import param
from qmdf.medial.features import field_feature_points, sample_segments, sharp_mesh_segments
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class FeatureDetectConfig:
    source: str = param(
        "auto",
        choices=("auto", "mesh", "field"),
        doc="auto: the input mesh when there is one, else the field procedure",
    )
    dihedral_deg: float = param(
        30.0, gt=0, lt=180, doc="mesh: an edge is sharp when its faces' normals turn by more than this"
    )
    convex_only: bool = param(
        True, doc="mesh: keep convex sharp edges only (the medial axis never reaches a concave one)"
    )
    spacing: float = param(0.005, gt=0, doc="distance between feature samples along an edge (unit box)")
    boundary_fold_deg: float = param(
        150.0, gt=90, lt=180, doc="field: a membrane edge is on its boundary when its faces fold back by more than this"
    )
    max_radius: float = param(
        0.03, gt=0, doc="field: boundary edges where the medial radius and MF are both below this"
    )
    offset: float = param(0.004, gt=0, doc="field: distance of the six axis-offset SDF-gradient samples")
    march_steps: int = param(60, ge=1)
    march_tol: float = param(5e-4, gt=0, doc="field: marching stops once |sdf| is below this")
    qem_k: int = param(16, ge=3, doc="field: input points in each point's quadric")
    qem_regularization: float = param(
        1e-3, ge=0, doc="field: pull toward the marched point, so a flat neighbourhood stays put"
    )
    field_seeds: str = param(
        "both",
        choices=("membrane", "points", "both"),
        doc="field: the paper's route from the first MAT's boundary, the input points' two-plane fits, or both",
    )
    plane_min_points: int = param(4, ge=3, doc="field: neighbours each of the two planes must hold")
    plane_tolerance: float = param(
        0.05,
        gt=0,
        doc="field: a neighbour farther than this fraction of the neighbourhood's "
        "radius from both planes is no part of them (a corner's third face, noise)",
    )
    plane_normal_deg: float = param(
        45.0, gt=0, lt=90, doc="field: nor is one whose SDF gradient turns by more than this from the plane's normal"
    )
    arc_ratio: float = param(
        0.5,
        ge=0,
        doc="field: the two planes must fit the neighbours better than one circular "
        "arc across the edge by this factor (RMS), or it is a curved patch; 0: no such test",
    )
    face_normals: bool = param(
        True,
        doc="field: feature points carry their two planes' mean normal (feature_retrain's "
        "bisector samples); false: the paper's feature points alone",
    )


@register_stage("feature_detect")
class FeatureDetect(Stage):
    """Sample the sharp features: from the input mesh's dihedral angles, or by the paper's procedure."""

    Config = FeatureDetectConfig
    inputs = {"points": POINTS}
    optional_inputs = {"surface": MESH, "field": FIELD, "mat": MAT}
    outputs = {"feature_points": POINTS, "features": JSON}

    def run(self, ctx: StageContext) -> None:
        from qmdf.geometry.pointset import PointSet

        cfg: FeatureDetectConfig = ctx.cfg
        points = ctx.load("points").points
        source = cfg.source if cfg.source != "auto" else ("mesh" if ctx.has("surface") else "field")
        stats: dict = {"source": source}
        if source == "mesh":
            if not ctx.has("surface"):
                raise QmdfError("feature_detect.source=mesh needs a mesh input (this input is a point cloud)")
            surface = ctx.load("surface")
            v = np.asarray(surface.vertices)
            a, b, mean_normal = sharp_mesh_segments(v, np.asarray(surface.faces), cfg.dihedral_deg, cfg.convex_only)
            feats, seg = sample_segments(a, b, cfg.spacing, return_index=True)
            normals = mean_normal[seg]
            stats["sharp_edges"] = int(len(a))
        else:
            feats, normals = self._from_field(ctx, cfg, points, stats)
        stats["feature_points"] = int(len(feats))
        # mesh features' "normals": the mean of the two faces' unit normals (length cos of half the dihedral
        # angle); feature_retrain follows the bisector inward from it
        ctx.save("feature_points", PointSet(feats, normals) if len(feats) else PointSet(np.zeros((0, 3))))
        ctx.save("features", stats)
        if len(feats):
            from qmdf.viz import plot_points_over

            plot_points_over(ctx.stage_dir / "features.png", points, feats, title=f"sharp features ({source})")
        ctx.log.info("feature_detect (%s): %d feature points", source, len(feats))

    @staticmethod
    def _from_field(ctx: StageContext, cfg: FeatureDetectConfig, points: np.ndarray, stats: dict):
        need_mat = cfg.field_seeds != "points"
        if not ctx.has("field") or (need_mat and not ctx.has("mat")):
            raise QmdfError(
                "feature_detect on a point cloud needs a trained field"
                + (
                    " and a first MAT: put it after train, cover, contract and export in pipeline.stages"
                    if need_mat
                    else ": put it after train in pipeline.stages"
                )
            )
        return field_feature_points(
            ctx.load("field"),
            points,
            ctx.load("mat") if need_mat else None,
            seeds=cfg.field_seeds,
            spacing=cfg.spacing,
            boundary_fold_deg=cfg.boundary_fold_deg,
            max_radius=cfg.max_radius,
            offset=cfg.offset,
            march_steps=cfg.march_steps,
            march_tol=cfg.march_tol,
            qem_k=cfg.qem_k,
            qem_regularization=cfg.qem_regularization,
            dihedral_deg=cfg.dihedral_deg,
            plane_min_points=cfg.plane_min_points,
            plane_tolerance=cfg.plane_tolerance,
            plane_normal_deg=cfg.plane_normal_deg,
            arc_ratio=cfg.arc_ratio,
            face_normals=cfg.face_normals,
            stats=stats,
        )
