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
from qmdf.medial.features import FeatureSettings, field_feature_points, sample_segments, sharp_mesh_segments
from qmdf.stage import Stage, StageContext, register_stage


@dataclass
class FeatureDetectConfig(FeatureSettings):
    source: str = param(
        "auto",
        choices=("auto", "mesh", "field"),
        doc="auto: the input mesh when there is one, else the field procedure",
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
        return field_feature_points(ctx.load("field"), points, ctx.load("mat") if need_mat else None, cfg, stats)
