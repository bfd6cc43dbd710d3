"""How right a field's inside is, against a reference mesh: the share of volume samples whose sign agrees with
the mesh's generalized winding number, and how metric the SDF is inside (mean |grad sdf|, mean |sdf - d|)."""

from __future__ import annotations

import numpy as np


def field_quality(
    field, vertices: np.ndarray, faces: np.ndarray, samples: int = 100_000, seed: int = 0, half: float = 0.5
) -> dict:
    """Sign accuracy over ``samples`` uniform points of the box [-half, half]^3 (the unit box); metric figures
    over those inside deeper than 0.005."""
    from qmdf.geometry.inside import mesh_signed_distance

    q = np.random.default_rng(seed).uniform(-half, half, (samples, 3))
    ref = mesh_signed_distance(vertices, faces, q)
    out = field.evaluate(q, grad=True)
    inside = ref < -0.005
    grad = np.linalg.norm(out["sdf_grad"], axis=1)
    return {
        "sign_accuracy": float(np.mean((out["sdf"] < 0) == (ref < 0))),
        "grad_sdf_inside": float(grad[inside].mean()) if inside.any() else None,
        "sdf_error_inside": float(np.abs(out["sdf"][inside] - ref[inside]).mean()) if inside.any() else None,
        "inside_share": float(inside.mean()),
        "samples": samples,
    }
