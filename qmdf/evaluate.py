"""``python -m qmdf.evaluate MAT.ma REFERENCE_MESH [--json PATH]``: score any MAT against a reference surface.

The same code scores our runs (the ``evaluate`` stage) and other methods' ``.ma`` files, so numbers compare.
Both are normalised into the reference's unit box (longest bounding-box side 1, as in the paper) unless
``--no-normalize`` says they already are.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from qmdf.errors import QmdfError
from qmdf.geometry import metrics as M
from qmdf.geometry.envelope_scores import reconstruction_distances
from qmdf.geometry.ma_format import MedialMesh
from qmdf.geometry.normalize import Normalization


def score_mat(
    mat: MedialMesh,
    ref_vertices: np.ndarray,
    ref_faces: np.ndarray | None,
    samples: int = 100_000,
    resolution: int = 128,
    seed: int = 0,
    picture: Path | None = None,
    return_mesh: bool = False,
    fold_deg: float = 150.0,
    recon_mesh=None,
):
    """Every metric of ``mat`` against the reference (a mesh, or points when ``ref_faces`` is None), both
    already in the same (unit-box) frame. With ``return_mesh``, also the meshed reconstruction."""
    from qmdf.geometry.envelope import EnvelopeUnion

    if len(mat.vertices) == 0:
        raise QmdfError("the MAT has no vertices")
    if np.any(mat.radii < 0) or not np.all(np.isfinite(mat.radii)) or not np.all(np.isfinite(mat.vertices)):
        raise QmdfError("the MAT has negative or non-finite radii or coordinates")
    t0 = time.perf_counter()
    union = EnvelopeUnion.from_mat(mat)
    dist, recon, _, _ = reconstruction_distances(
        union, ref_vertices, ref_faces, samples, np.random.default_rng(seed), resolution, recon_mesh=recon_mesh
    )
    # A single-layer MAT's boundary is its one-face edges; our closed double-covering membrane has none,
    # and its boundary is where it folds back on itself (dihedral angle near 2*pi, paper Sec. 4.3).
    boundary = M.single_face_edges(mat.faces)
    boundary_rule = "edges of one face"
    if len(mat.faces) and not len(boundary):
        boundary, boundary_rule = (
            M.fold_edges(mat.vertices, mat.faces, fold_deg),
            f"fold edges (normals turn > {fold_deg} deg)",
        )
    closed = len(mat.faces) > 0 and M.is_closed_surface(mat.faces)
    if closed:  # our membrane: it bounds a (flat) solid whose chi, V - E + F - C, is half its surface's
        chi, chi_rule = (
            M.euler_surface(len(np.unique(mat.faces)), mat.faces) // 2,
            "(V - E + F) / 2 of the closed membrane = chi of the solid it bounds",
        )
    else:
        chi, chi_rule = M.euler_medial_mesh(len(mat.vertices), mat.edges, mat.faces), "V - E + F of the medial mesh"
    out = {
        "chamfer": dist["chamfer"],
        "hausdorff": dist["hausdorff"],
        "chi": chi,
        "chi_rule": chi_rule,
        "boundary_smoothness": M.boundary_smoothness(mat.vertices, boundary) if len(boundary) else None,
        # the same on the boundary resampled every 0.01 of the unit box: subdividing a jagged boundary lowers C_avg
        "boundary_smoothness_resampled": M.boundary_smoothness(mat.vertices, boundary, 0.01) if len(boundary) else None,
        "boundary_rule": boundary_rule,
        "boundary_edges": int(len(boundary)),
        "vertices": int(len(mat.vertices)),
        "edges": int(len(M.medial_edges(mat.edges, mat.faces))),
        "faces": int(len(mat.faces)),
        "radius": M.radius_stats(mat.radii),
        "distances": {k: v for k, v in dist.items() if k not in ("chamfer", "hausdorff", "definition")},
        "reconstruction": {
            "vertices": int(len(recon.vertices)),
            "faces": int(len(recon.faces)),
            "genus": int((2 - recon.euler_number) // 2) if recon.is_watertight else None,
            "resolution": resolution,
        },
        "definition": dist["definition"],
        "seconds": round(time.perf_counter() - t0, 2),
    }
    if picture is not None:
        from qmdf.viz import render_mesh

        if ref_faces is None:
            from scipy.spatial import cKDTree

            d = cKDTree(ref_vertices).query(recon.vertices)[0]
        else:
            d = M.point_to_mesh_distance(recon.vertices, ref_vertices, ref_faces)
        render_mesh(
            picture,
            recon.vertices,
            recon.faces,
            d,
            title="reconstruction from the MAT",
            label="distance to the reference (unit box)",
            cmap="magma",
        )
    return (out, recon) if return_mesh else out


def format_report(name: str, m: dict) -> str:
    lines = [
        f"{name}",
        f"  CD  {m['chamfer']:.3e}   ({m['chamfer'] * 1e3:.3f} x 1e-3)",
        f"  HD  {m['hausdorff']:.3e}   ({m['hausdorff'] * 1e3:.3f} x 1e-3)",
        f"  chi {m['chi']}   (V - E + F of the medial mesh)",
        "  boundary smoothness C_avg "
        f"{m['boundary_smoothness'] if m['boundary_smoothness'] is not None else 'n/a (no boundary)'}",
        f"  V {m['vertices']}  F {m['faces']}  radius min/mean/max "
        f"{m['radius']['min']:.4g}/{m['radius']['mean']:.4g}/{m['radius']['max']:.4g}",
        f"  definition: {m['definition']}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from qmdf.geometry.io import load_geometry
    from qmdf.geometry.ma_format import read_ma

    ap = argparse.ArgumentParser(prog="python -m qmdf.evaluate", description=__doc__.splitlines()[0])
    ap.add_argument("mat", type=Path, help="medial axis in .ma format")
    ap.add_argument("reference", type=Path, help="reference surface mesh (obj/off/ply/stl)")
    ap.add_argument("--json", type=Path, help="write the metrics here")
    ap.add_argument("--picture", type=Path, help="PNG of the reconstruction coloured by its distance to the reference")
    ap.add_argument("--samples", type=int, default=100_000, help="samples per surface (default 100000)")
    ap.add_argument(
        "--resolution",
        type=int,
        default=128,
        help="grid resolution of the meshed reconstruction (sampling and pictures)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-normalize", action="store_true", help="the inputs are already in the unit box")
    args = ap.parse_args(argv)
    try:
        mat = read_ma(args.mat)
        ref = load_geometry(args.reference, kind="mesh")
        norm = Normalization.identity() if args.no_normalize else Normalization.fit(ref.points.points)
        mat = MedialMesh(norm.to_unit(mat.vertices), mat.radii * norm.scale, mat.edges, mat.faces)
        metrics = score_mat(
            mat, norm.to_unit(ref.points.points), ref.faces, args.samples, args.resolution, args.seed, args.picture
        )
    except (QmdfError, ValueError) as exc:
        print(f"qmdf.evaluate: error: {exc}", file=sys.stderr)
        return 2
    metrics["mat"], metrics["reference"] = str(args.mat), str(args.reference)
    print(format_report(f"{args.mat} vs {args.reference}", metrics))
    if args.json:
        args.json.write_text(json.dumps(metrics, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
